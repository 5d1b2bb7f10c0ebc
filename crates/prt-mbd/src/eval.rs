//! Evaluation: relative MSE over dense jittered samples, per-block operator Frobenius errors,
//! and a seam metric.

use glam::Vec3;
use prt_core::{CoreError, FieldModel, GridField};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;
use rayon::prelude::*;

use crate::MbdError;
use crate::objective::mix;

/// Options of [`evaluate`].
#[derive(Debug, Clone, PartialEq)]
pub struct EvalOptions {
    /// Jittered samples per voxel (default 4).
    pub samples_per_voxel: usize,
    /// Seed of the sample positions.
    pub seed: u64,
    /// Lengths of consecutive blocks of the D-vector reported separately (the 324-D transfer
    /// vector is four 9 × 9 operators: `[81, 81, 81, 81]`). Empty: the whole vector is one block.
    pub blocks: Vec<usize>,
}

impl Default for EvalOptions {
    fn default() -> Self {
        Self {
            samples_per_voxel: 4,
            seed: 0xE7A1,
            blocks: Vec::new(),
        }
    }
}

/// Errors of a model against a field.
#[derive(Debug, Clone, PartialEq)]
pub struct Evaluation {
    /// `Σ ‖f̂(x) − f(x)‖² / Σ ‖f(x)‖²` over the jittered samples, `f` the field's trilinear
    /// interpolation (the MBD paper's error measure).
    pub relative_mse: f64,
    /// Per block of the vector, `sqrt(Σ_x ‖Â(x) − A(x)‖²_F / Σ_x ‖A(x)‖²_F)`: the relative
    /// Frobenius error of each operator over the volume.
    pub block_relative_frobenius: Vec<f64>,
}

/// Samples per parallel chunk (a fixed chunking keeps the f64 sums independent of threads).
const EVAL_CHUNK: usize = 4096;

/// Evaluates `model` against `field` on `samples_per_voxel` jittered samples per voxel.
///
/// A zero field gives `relative_mse = 0` if the model is zero there too and `∞` otherwise (as in
/// [`prt_core::metrics::relative_mse`]).
///
/// # Errors
/// A dimension mismatch, block lengths that do not add up to D, zero samples, or a non-finite
/// model output ([`CoreError::NonFinite`] naming "model output").
pub fn evaluate(
    model: &dyn FieldModel,
    field: &GridField,
    options: &EvalOptions,
) -> Result<Evaluation, MbdError> {
    let d = field.dim();
    if model.dim() != d {
        return Err(CoreError::LengthMismatch {
            what: "model dimension",
            expected: d,
            got: model.dim(),
        }
        .into());
    }
    let blocks = if options.blocks.is_empty() {
        vec![d]
    } else {
        options.blocks.clone()
    };
    if blocks.iter().sum::<usize>() != d || blocks.contains(&0) {
        return Err(MbdError::InvalidOption {
            what: "blocks",
            why: format!("{blocks:?} does not partition {d}"),
        });
    }
    if options.samples_per_voxel == 0 {
        return Err(MbdError::InvalidOption {
            what: "samples_per_voxel",
            why: "must be at least 1".into(),
        });
    }
    let total = field.num_voxels() * options.samples_per_voxel;
    let size = field.voxel_size();
    let chunks = total.div_ceil(EVAL_CHUNK);
    let nb = blocks.len();
    let partial: Vec<Result<Vec<f64>, CoreError>> = (0..chunks)
        .into_par_iter()
        .map(|chunk| {
            let mut rng = Pcg64Mcg::seed_from_u64(mix(options.seed, chunk as u64));
            let mut f = vec![0.0f32; d];
            let mut g = vec![0.0f32; d];
            // [error_b..., energy_b...] per block.
            let mut sums = vec![0.0f64; 2 * nb];
            for i in chunk * EVAL_CHUNK..((chunk + 1) * EVAL_CHUNK).min(total) {
                let v = i / options.samples_per_voxel;
                let u = Vec3::new(
                    rng.random::<f32>(),
                    rng.random::<f32>(),
                    rng.random::<f32>(),
                );
                let x = field.centre_of(v) + (u - 0.5) * size;
                field.sample(x, &mut f)?;
                model.eval(x, &mut g)?;
                if let Some(k) = g.iter().position(|v| !v.is_finite()) {
                    return Err(CoreError::NonFinite {
                        what: "model output",
                        index: k,
                    });
                }
                let mut start = 0;
                for (b, &len) in blocks.iter().enumerate() {
                    for k in start..start + len {
                        let e = g[k] as f64 - f[k] as f64;
                        sums[b] += e * e;
                        sums[nb + b] += (f[k] as f64) * (f[k] as f64);
                    }
                    start += len;
                }
            }
            Ok(sums)
        })
        .collect();
    let mut sums = vec![0.0f64; 2 * nb];
    for p in partial {
        for (s, v) in sums.iter_mut().zip(p?) {
            *s += v;
        }
    }
    let err: f64 = sums[..nb].iter().sum();
    let energy: f64 = sums[nb..].iter().sum();
    Ok(Evaluation {
        relative_mse: ratio(err, energy),
        block_relative_frobenius: (0..nb)
            .map(|b| ratio(sums[b], sums[nb + b]).sqrt())
            .collect(),
    })
}

fn ratio(num: f64, den: f64) -> f64 {
    if den > 0.0 {
        num / den
    } else if num == 0.0 {
        0.0
    } else {
        f64::INFINITY
    }
}

/// How discontinuous a reconstruction's error is across cluster boundaries.
///
/// On the voxel grid, with the error `e_v = f̂_v − f_v` of every voxel, each pair of
/// face-adjacent voxels `(u, v)` has the error jump `‖e_u − e_v‖²`. Pairs whose voxels lie in
/// different clusters are *boundary* pairs, the others *interior* pairs.
///
/// * `boundary` = `sqrt(mean_boundary ‖e_u − e_v‖² / mean_v ‖f_v‖²)`: the RMS jump of the error
///   across cluster boundaries, relative to the field's RMS. This is **the seam metric**: a
///   method whose clusters are fitted independently (BPCA, CPCA) changes its error abruptly
///   at a boundary, a seamless method (MBD, whose basis moves continuously) does not.
/// * `interior` = the same over interior pairs: what a smooth change of error between neighbours
///   costs anyway, for comparison.
///
/// Both are 0 when there is no pair of the kind (a single cluster has no boundary) or the field is
/// zero (the jumps are then reported unnormalised, so a non-zero error on a zero field is still
/// visible).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SeamMetric {
    /// RMS error jump across cluster boundaries, relative to the field's RMS.
    pub boundary: f64,
    /// RMS error jump between neighbours inside clusters, relative to the field's RMS.
    pub interior: f64,
}

/// The [`SeamMetric`] of `reconstruction` (on the field's grid, e.g. from
/// [`prt_core::resample_to_grid`]) with voxel cluster `labels`.
///
/// # Errors
/// Grid or dimension mismatch between `field` and `reconstruction`, or `labels.len()` not the
/// number of voxels.
pub fn seam_metric(
    field: &GridField,
    reconstruction: &GridField,
    labels: &[u32],
) -> Result<SeamMetric, MbdError> {
    if reconstruction.dims() != field.dims() {
        return Err(MbdError::ShapeMismatch {
            what: "reconstruction grid",
            expected: field.dims().to_vec(),
            got: reconstruction.dims().to_vec(),
        });
    }
    if reconstruction.dim() != field.dim() {
        return Err(CoreError::LengthMismatch {
            what: "reconstruction dimension",
            expected: field.dim(),
            got: reconstruction.dim(),
        }
        .into());
    }
    if labels.len() != field.num_voxels() {
        return Err(CoreError::LengthMismatch {
            what: "labels",
            expected: field.num_voxels(),
            got: labels.len(),
        }
        .into());
    }
    let dims = field.dims();
    let strides = [1, dims[0], dims[0] * dims[1]];
    // Per z-slab: [boundary sum, boundary count, interior sum, interior count, energy].
    let slabs: Vec<[f64; 5]> = (0..dims[2])
        .into_par_iter()
        .map(|z| {
            let mut acc = [0.0f64; 5];
            for y in 0..dims[1] {
                for x in 0..dims[0] {
                    let v = field.index(x, y, z);
                    let fv = field.voxel(v);
                    let rv = reconstruction.voxel(v);
                    acc[4] += fv.iter().map(|&a| (a as f64) * (a as f64)).sum::<f64>();
                    let coords = [x, y, z];
                    for k in 0..3 {
                        if coords[k] + 1 >= dims[k] {
                            continue;
                        }
                        let u = v + strides[k];
                        let (fu, ru) = (field.voxel(u), reconstruction.voxel(u));
                        let mut jump = 0.0f64;
                        for i in 0..fv.len() {
                            let e = (rv[i] as f64 - fv[i] as f64) - (ru[i] as f64 - fu[i] as f64);
                            jump += e * e;
                        }
                        let slot = if labels[u] != labels[v] { 0 } else { 2 };
                        acc[slot] += jump;
                        acc[slot + 1] += 1.0;
                    }
                }
            }
            acc
        })
        .collect();
    let mut acc = [0.0f64; 5];
    for s in slabs {
        for (a, v) in acc.iter_mut().zip(s) {
            *a += v;
        }
    }
    let mean_energy = acc[4] / field.num_voxels() as f64;
    let rel = |sum: f64, count: f64| {
        if count == 0.0 {
            0.0
        } else if mean_energy > 0.0 {
            (sum / count / mean_energy).sqrt()
        } else {
            (sum / count).sqrt()
        }
    };
    Ok(SeamMetric {
        boundary: rel(acc[0], acc[1]),
        interior: rel(acc[2], acc[3]),
    })
}

/// Cluster labels of a kernel family on the voxels of `field`: the
/// [`SpatialKernels::support_cell`](prt_core::SpatialKernels::support_cell) of each voxel centre
/// (MBD's basis cells, for the seam metric), or, for families without cells, the kernel of
/// largest weight.
pub fn kernel_labels<K: prt_core::SpatialKernels>(
    kernels: &K,
    field: &GridField,
) -> Result<Vec<u32>, MbdError> {
    let mut w = prt_core::KernelWeights::default();
    (0..field.num_voxels())
        .map(|v| {
            let x = field.centre_of(v);
            if let Some(cell) = kernels.support_cell(x) {
                return Ok(cell as u32);
            }
            kernels.eval(x, &mut w)?;
            let best = w.iter().fold((0u32, f32::NEG_INFINITY), |b, (i, wi)| {
                if wi > b.1 { (i, wi) } else { b }
            });
            Ok(best.0)
        })
        .collect()
}
