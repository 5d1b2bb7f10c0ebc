//! The comparison: each method's errors, seams, size and time, as data.

use std::time::Duration;

use prt_core::{FieldModel, GridField};
use prt_mbd::{EvalOptions, MbdError};
use prt_texture::Encoding;

/// The transfer vector is four 9 × 9 operators: direct, then indirect R, G, B.
const OPERATOR_BLOCKS: [usize; 4] = [81, 81, 81, 81];

/// Bytes per raw transfer vector: 324 f32.
const RAW_BYTES_PER_VOXEL: f64 = 324.0 * 4.0;

/// A compressed representation the bake scores.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Method {
    /// Moving Basis Decomposition, in memory (f32).
    Mbd,
    /// The MBD model read back from the container written with this encoding.
    MbdAsWritten(Encoding),
    /// Blockwise PCA: one rank-L basis per block of a regular grid.
    Bpca,
    /// Clustered PCA: one rank-L basis per k-means cluster.
    Cpca,
}

impl Method {
    /// The name the report's table shows.
    pub fn name(&self) -> String {
        match self {
            Method::Mbd => "MBD".into(),
            Method::MbdAsWritten(encoding) => format!("MBD as written ({encoding:?})"),
            Method::Bpca => "BPCA".into(),
            Method::Cpca => "CPCA".into(),
        }
    }

    /// A lower-case key for file names.
    pub fn key(&self) -> &'static str {
        match self {
            Method::Mbd => "mbd",
            Method::MbdAsWritten(_) => "mbd_written",
            Method::Bpca => "bpca",
            Method::Cpca => "cpca",
        }
    }
}

/// One method's line of the comparison.
#[derive(Debug, Clone, PartialEq)]
pub struct MethodScores {
    /// The method.
    pub method: Method,
    /// `Σ‖f̂ − f‖² / Σ‖f‖²` over jittered samples, `f` the trilinear input.
    pub relative_mse: f64,
    /// Relative Frobenius error of each 9 × 9 operator over the volume: direct, indirect R, G, B.
    pub operator_frobenius: Vec<f64>,
    /// RMS jump of the error between neighbouring voxels across cluster (or basis-cell)
    /// boundaries, relative to the field's RMS.
    pub seam_boundary: f64,
    /// The same jump between neighbours inside clusters.
    pub seam_interior: f64,
    /// The seam ratio of the method's basis alone, on the denoised reference (see
    /// [`SeamView`](crate::seams::SeamView)); `None` where not measured.
    pub denoised_seam_ratio: Option<f64>,
    /// Scalars the model stores.
    pub stored_scalars: usize,
    /// Bytes per voxel actually written; `None` when nothing was written for the method.
    pub bytes_per_voxel: Option<f64>,
    /// Voxels of the scored field.
    pub voxels: usize,
    /// Time to fit the method (zero for a read-back).
    pub time: Duration,
}

impl MethodScores {
    /// `seam_boundary / seam_interior`: about 1 without seams (0 when there is no interior).
    pub fn seam_ratio(&self) -> f64 {
        if self.seam_interior > 0.0 {
            self.seam_boundary / self.seam_interior
        } else {
            0.0
        }
    }

    /// Bytes per voxel as written, or estimated from the stored scalars at 2 bytes (f16).
    pub fn bytes_per_voxel_or_estimate(&self) -> f64 {
        self.bytes_per_voxel
            .unwrap_or(2.0 * self.stored_scalars as f64 / self.voxels.max(1) as f64)
    }

    /// Raw f32 transfer vectors over [`bytes_per_voxel_or_estimate`](Self::bytes_per_voxel_or_estimate).
    pub fn compression_ratio(&self) -> f64 {
        RAW_BYTES_PER_VOXEL / self.bytes_per_voxel_or_estimate()
    }
}

/// The evaluation options every method is scored with.
pub(crate) fn eval_options(seed: u64) -> EvalOptions {
    EvalOptions {
        blocks: OPERATOR_BLOCKS.to_vec(),
        seed: seed ^ 0xE7A1,
        ..EvalOptions::default()
    }
}

/// Scores `model` against `field`; `reconstruction` is the model on the field's grid and
/// `labels` its clusters (basis cells for MBD) for the seam measure.
pub(crate) fn score(
    method: Method,
    model: &dyn FieldModel,
    field: &GridField,
    reconstruction: &GridField,
    labels: &[u32],
    eval_options: &EvalOptions,
    time: Duration,
) -> Result<MethodScores, MbdError> {
    let evaluation = prt_mbd::evaluate(model, field, eval_options)?;
    let seams = prt_mbd::error_seams(
        field,
        reconstruction,
        labels,
        &prt_mbd::SeamOptions::default(),
    )?;
    Ok(MethodScores {
        method,
        relative_mse: evaluation.relative_mse,
        operator_frobenius: evaluation.block_relative_frobenius,
        seam_boundary: seams.boundary,
        seam_interior: seams.interior,
        denoised_seam_ratio: None,
        stored_scalars: model.stored_scalars(),
        bytes_per_voxel: None,
        voxels: field.num_voxels(),
        time,
    })
}
