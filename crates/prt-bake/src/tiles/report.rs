//! `tiles.json`: what `prt merge` records beside the bake folder it writes.

use serde::{Deserialize, Serialize};

use super::{HaloAgreement, StreamedMerge, TilePlan, TileSeams};

/// A merged bake folder's `tiles.json` ([`crate::BakeFolder::tiles_report`]): the tiling that
/// was assembled, and what the merge measured: seams across tile borders and the halo's
/// agreement (in-memory merge), or the streamed merge's figures.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TilesReport {
    /// Tiles merged.
    pub tiles: usize,
    /// Tiles per axis.
    pub counts: [usize; 3],
    /// Voxels traced around each tile's core.
    pub halo: usize,
    /// The global voxel lattice.
    pub lattice: [usize; 3],
    /// The in-memory merge's seam ratios across tile borders.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seam_ratio_across_tile_borders: Option<SeamRatios>,
    /// How the tiles agree on the voxels two of them traced (in-memory merge, with a halo).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub halo_agreement: Option<HaloRecord>,
    /// The streamed merge's figures.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub streamed: Option<StreamedRecord>,
}

/// [`TileSeams`] as recorded.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SeamRatios {
    /// The traced volume's seam ratio.
    pub trace: f64,
    /// MBD's error seam ratio.
    pub mbd_error: f64,
    /// MBD's basis seam ratio.
    pub mbd_basis: f64,
}

/// [`HaloAgreement`] as recorded.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct HaloRecord {
    /// Voxels compared.
    pub voxels: usize,
    /// Relative RMS difference of the two traces.
    pub relative_rms_difference: f64,
}

/// A streamed merge ([`StreamedMerge`]) as recorded.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StreamedRecord {
    /// The grid the basis was first fitted on.
    pub coarse_grid: [usize; 3],
    /// Solver iterations of that fit.
    pub coarse_iterations: usize,
    /// Conjugate-gradient iterations of each sweep's basis solve.
    #[serde(default)]
    pub basis_solve_iterations: Vec<usize>,
    /// Sweeps over the tiles after it.
    pub sweeps: usize,
    /// The relative error at the valid voxel centres after the coarse fit, then after each sweep.
    pub relative_error_at_valid_voxel_centres: Vec<f64>,
    /// The same of the loss-weighted vectors: the loss the sweeps descend (equal to the above
    /// without a loss weighting).
    #[serde(default)]
    pub weighted_relative_error: Vec<f64>,
    /// Valid voxels of the lattice.
    pub valid_voxels: usize,
    /// Bytes of the container written, if one was.
    pub container_bytes: Option<u64>,
    /// Those bytes per valid voxel.
    pub bytes_per_valid_voxel: Option<f64>,
    /// `(stage, seconds)` in order.
    pub stage_seconds: Vec<(String, f64)>,
    /// The whole merge, seconds.
    pub total_seconds: f64,
}

impl TilesReport {
    /// The tiling of `plan`, nothing measured yet.
    pub fn of_plan(plan: &TilePlan) -> Self {
        Self {
            tiles: plan.tiles.len(),
            counts: plan.counts,
            halo: plan.halo,
            lattice: plan.lattice_dims,
            seam_ratio_across_tile_borders: None,
            halo_agreement: None,
            streamed: None,
        }
    }

    /// With the in-memory merge's seam measures and halo agreement.
    pub fn with_seams(self, seams: &TileSeams, halo: Option<HaloAgreement>) -> Self {
        Self {
            seam_ratio_across_tile_borders: Some(SeamRatios {
                trace: seams.trace,
                mbd_error: seams.mbd,
                mbd_basis: seams.basis,
            }),
            halo_agreement: halo.map(|h| HaloRecord {
                voxels: h.voxels,
                relative_rms_difference: h.relative_rms_difference,
            }),
            ..self
        }
    }

    /// With a streamed merge's figures: `sweeps` asked for, `total_seconds` of the whole merge.
    pub fn with_streamed(self, merged: &StreamedMerge, sweeps: usize, total_seconds: f64) -> Self {
        let valid = merged.valid_voxels as usize;
        let bytes = merged.container.as_ref().map(|c| c.total_bytes);
        Self {
            streamed: Some(StreamedRecord {
                coarse_grid: merged.coarse_dims,
                coarse_iterations: merged.coarse_iterations,
                basis_solve_iterations: merged.basis_solves.iter().map(|s| s.iterations).collect(),
                sweeps,
                relative_error_at_valid_voxel_centres: merged.relative_errors.clone(),
                weighted_relative_error: merged.weighted_errors.clone(),
                valid_voxels: valid,
                container_bytes: bytes,
                bytes_per_valid_voxel: bytes.map(|b| b as f64 / valid.max(1) as f64),
                stage_seconds: merged
                    .stage_times
                    .iter()
                    .map(|(name, time)| (name.to_string(), time.as_secs_f64()))
                    .collect(),
                total_seconds,
            }),
            ..self
        }
    }
}
