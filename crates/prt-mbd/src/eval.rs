//! Evaluation: relative MSE over dense jittered samples, per-block operator Frobenius errors,
//! and the error's seams.

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
/// On the voxel grid, with the error `e_v = f̂_v − f_v` of every voxel (optionally denoised, see
/// [`SeamOptions`]), each pair of face-adjacent voxels `(u, v)` has the error jump
/// `‖e_u − e_v‖²`. Pairs whose voxels lie in different clusters are *boundary* pairs, the others
/// *interior* pairs.
///
/// * `boundary` = `sqrt(mean_boundary ‖e_u − e_v‖² / mean_v ‖f_v‖²)`: the RMS jump of the error
///   across cluster boundaries, relative to the field's RMS. A method whose clusters are fitted
///   independently (BPCA, CPCA) changes its error abruptly at a boundary, a seamless method
///   (MBD, whose basis moves continuously) does not.
/// * `interior` = the same over interior pairs: what a smooth change of error between neighbours
///   costs anyway, for comparison. Each axis's interior mean is weighted by that axis's share
///   of the boundary pairs (all axes alike without boundaries), so an error that changes faster
///   along one axis than the others does not make boundaries across that axis look like seams.
/// * [`ErrorSeams::ratio`] = `boundary / interior`: about 1 when a viewer cannot tell where the
///   boundaries are, well above 1 when the error steps there. This is **the seam metric** of the
///   sweeps (on the denoised error, [`SeamOptions::denoised`]).
///
/// Both are 0 when there is no pair of the kind (a single cluster has no boundary) or the field is
/// zero (the jumps are then reported unnormalised, so a non-zero error on a zero field is still
/// visible).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ErrorSeams {
    /// RMS error jump across cluster boundaries, relative to the field's RMS.
    pub boundary: f64,
    /// RMS error jump between neighbours inside clusters, relative to the field's RMS.
    pub interior: f64,
}

impl ErrorSeams {
    /// `boundary / interior`: 1 when boundaries look like the inside of clusters. 0 without
    /// boundary pairs or jumps there; `∞` when only the boundaries jump.
    pub fn ratio(&self) -> f64 {
        if self.boundary == 0.0 {
            0.0
        } else if self.interior == 0.0 {
            f64::INFINITY
        } else {
            self.boundary / self.interior
        }
    }
    /// `sqrt(max(0, boundary² − interior²))`: the RMS height of the steps at the boundaries
    /// beyond the jumps seen inside clusters, relative to the field's RMS. Independent noise in
    /// the reference adds the same mean square to boundary and interior pairs, so it cancels here
    /// in expectation without any blur (with the sampling error of the two means).
    pub fn excess(&self) -> f64 {
        (self.boundary * self.boundary - self.interior * self.interior)
            .max(0.0)
            .sqrt()
    }
}

/// Options of [`error_seams`].
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct SeamOptions<'a> {
    /// Standard deviation, in voxels, of a Gaussian blur of the *reference* field before the
    /// error `f̂_v − (G_σ * f)_v` is taken; 0 uses the raw field.
    ///
    /// Why: a traced reference carries Monte Carlo noise that is independent from voxel to voxel.
    /// A rank-L compressor keeps little of it (its projection onto L of D dimensions), so the
    /// noise sits in every method's raw error, and its jumps (RMS `√2 σ_noise` per component)
    /// swamp boundary and interior pairs alike, pulling every ratio towards 1. The blur removes
    /// it from the reference (14× smaller jumps between neighbours at σ = 1) while the
    /// reconstruction, whose seams are measured, is left untouched: a step of `f̂` at a boundary
    /// keeps its full height. The blur is the same everywhere (it does not know the clusters), so
    /// it cannot create a boundary; it does bend the reference where the field has sharp
    /// features (walls, shadow edges), which shows in boundary and interior pairs alike.
    pub denoise_sigma: f64,
    /// Voxels to include (e.g. a baker's validity mask, `false` inside geometry): pairs with an
    /// excluded voxel are skipped, and the blur averages over included voxels only (normalised
    /// convolution). `None`: all voxels.
    pub valid: Option<&'a [bool]>,
}

impl SeamOptions<'_> {
    /// The sweeps' seam metric: the error blurred with a Gaussian of σ = 1 voxel, all voxels.
    pub fn denoised() -> Self {
        Self {
            denoise_sigma: 1.0,
            valid: None,
        }
    }
}

/// Per axis `[boundary sum, boundary count, interior sum, interior count]` of the squared jump
/// `‖e_u − e_v‖²` of `err` (`voxels × d`, x fastest on a `dims` grid) between face neighbours
/// that are both `valid`, split by whether their `labels` differ. Summed per z-slab in parallel
/// and the slabs in order, so the result does not depend on the thread count.
pub(crate) fn neighbour_jumps(
    dims: [usize; 3],
    d: usize,
    valid: &(impl Fn(usize) -> bool + Sync),
    labels: &[u32],
    err: &[f32],
) -> [[f64; 4]; 3] {
    let at = |v: usize| &err[v * d..(v + 1) * d];
    let strides = [1, dims[0], dims[0] * dims[1]];
    let slabs: Vec<[[f64; 4]; 3]> = (0..dims[2])
        .into_par_iter()
        .map(|z| {
            let mut acc = [[0.0f64; 4]; 3];
            for y in 0..dims[1] {
                for x in 0..dims[0] {
                    let v = x + dims[0] * (y + dims[1] * z);
                    if !valid(v) {
                        continue;
                    }
                    for (k, c) in [x, y, z].into_iter().enumerate() {
                        let u = v + strides[k];
                        if c + 1 >= dims[k] || !valid(u) {
                            continue;
                        }
                        let jump: f64 = at(u)
                            .iter()
                            .zip(at(v))
                            .map(|(&a, &b)| (a as f64 - b as f64).powi(2))
                            .sum();
                        let slot = if labels[u] != labels[v] { 0 } else { 2 };
                        acc[k][slot] += jump;
                        acc[k][slot + 1] += 1.0;
                    }
                }
            }
            acc
        })
        .collect();
    let mut total = [[0.0f64; 4]; 3];
    for slab in slabs {
        for (t, s) in total.iter_mut().zip(slab) {
            for (a, b) in t.iter_mut().zip(s) {
                *a += b;
            }
        }
    }
    total
}

/// The [`ErrorSeams`] of `reconstruction` (on the field's grid) with voxel cluster `labels`,
/// measured on the error blurred by `options.denoise_sigma` over the `options.valid` voxels.
///
/// # Errors
/// Grid or dimension mismatch between `field` and `reconstruction`; `labels` or `options.valid`
/// not of the number of voxels; a negative or non-finite `denoise_sigma`.
pub fn error_seams(
    field: &GridField,
    reconstruction: &GridField,
    labels: &[u32],
    options: &SeamOptions<'_>,
) -> Result<ErrorSeams, MbdError> {
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
    let voxels = field.num_voxels();
    if labels.len() != voxels {
        return Err(CoreError::LengthMismatch {
            what: "labels",
            expected: voxels,
            got: labels.len(),
        }
        .into());
    }
    if let Some(valid) = options.valid
        && valid.len() != voxels
    {
        return Err(CoreError::LengthMismatch {
            what: "validity mask",
            expected: voxels,
            got: valid.len(),
        }
        .into());
    }
    let sigma = options.denoise_sigma;
    if !(sigma.is_finite() && sigma >= 0.0) {
        return Err(MbdError::InvalidOption {
            what: "denoise_sigma",
            why: format!("{sigma} is not a finite non-negative number of voxels"),
        });
    }
    let valid = |v: usize| options.valid.is_none_or(|m| m[v]);
    let d = field.dim();
    let reference: Vec<f32> = if sigma > 0.0 {
        let mut values = vec![0.0f32; voxels * d];
        values
            .par_chunks_mut(d)
            .enumerate()
            .filter(|(v, _)| valid(*v))
            .for_each(|(v, r)| r.copy_from_slice(field.voxel(v)));
        blur_masked(values, d, field.dims(), &valid, sigma)
    } else {
        Vec::new()
    };
    let mut error: Vec<f32> = vec![0.0; voxels * d];
    error
        .par_chunks_mut(d)
        .enumerate()
        .filter(|(v, _)| valid(*v))
        .for_each(|(v, e)| {
            let f = if sigma > 0.0 {
                &reference[v * d..(v + 1) * d]
            } else {
                field.voxel(v)
            };
            for ((e, &r), &f) in e.iter_mut().zip(reconstruction.voxel(v)).zip(f) {
                *e = r - f;
            }
        });
    let dims = field.dims();
    let jumps = neighbour_jumps(dims, d, &valid, labels, &error);
    // [energy, voxels] of the valid voxels, per z-slab then in order.
    let slabs: Vec<[f64; 2]> = (0..dims[2])
        .into_par_iter()
        .map(|z| {
            let mut acc = [0.0f64; 2];
            for y in 0..dims[1] {
                for x in 0..dims[0] {
                    let v = field.index(x, y, z);
                    if valid(v) {
                        acc[0] += field
                            .voxel(v)
                            .iter()
                            .map(|&a| (a as f64) * (a as f64))
                            .sum::<f64>();
                        acc[1] += 1.0;
                    }
                }
            }
            acc
        })
        .collect();
    let (energy, counted) = slabs
        .iter()
        .fold((0.0, 0.0), |(e, n), s| (e + s[0], n + s[1]));
    let axis = |k: usize| &jumps[k];
    let sum = |i: usize| (0..3).map(|k| axis(k)[i]).sum::<f64>();
    let (boundary_sum, boundary_count) = (sum(0), sum(1));
    let interior_mean = if sum(3) > 0.0 { sum(2) / sum(3) } else { 0.0 };
    // The interior mean of each axis, weighted by that axis's share of the boundary pairs: what
    // the boundary pairs would show if boundaries were like the inside of clusters (the error
    // may change faster along one axis than another).
    let expected_interior = if boundary_count > 0.0 {
        (0..3)
            .map(|k| {
                let [_, bc, is, ic] = [axis(k)[0], axis(k)[1], axis(k)[2], axis(k)[3]];
                bc * if ic > 0.0 { is / ic } else { interior_mean }
            })
            .sum::<f64>()
            / boundary_count
    } else {
        interior_mean
    };
    let mean_energy = if counted > 0.0 { energy / counted } else { 0.0 };
    let rel = |mean_square: f64| {
        if mean_energy > 0.0 {
            (mean_square / mean_energy).sqrt()
        } else {
            mean_square.sqrt()
        }
    };
    Ok(ErrorSeams {
        boundary: if boundary_count > 0.0 {
            rel(boundary_sum / boundary_count)
        } else {
            0.0
        },
        interior: rel(expected_interior),
    })
}

/// The voxels holding any non-zero value: the validity mask of a baked transfer volume, whose
/// baker zeroes the voxels inside geometry (prt-trace's convention).
pub fn nonzero_voxels(field: &GridField) -> Vec<bool> {
    (0..field.num_voxels())
        .map(|v| field.voxel(v).iter().any(|&x| x != 0.0))
        .collect()
}

/// `field` blurred by a separable Gaussian of `sigma` voxels (taps to 3σ) over the voxels where
/// `valid` is true only: each output is the weighted mean of the valid voxels under the kernel,
/// so the box edges and invalid voxels do not pull values towards 0. Invalid voxels are 0;
/// `sigma <= 0` only zeroes them. This is the denoised reference [`error_seams`] measures
/// against (see [`SeamOptions`]).
///
/// # Errors
/// `valid` not one flag per voxel.
pub fn blur_valid(field: &GridField, valid: &[bool], sigma: f64) -> Result<GridField, MbdError> {
    if valid.len() != field.num_voxels() {
        return Err(MbdError::ShapeMismatch {
            what: "validity mask",
            expected: vec![field.num_voxels()],
            got: vec![valid.len()],
        });
    }
    let d = field.dim();
    let mut values = vec![0.0f32; field.num_voxels() * d];
    values
        .par_chunks_mut(d)
        .enumerate()
        .filter(|(v, _)| valid[*v])
        .for_each(|(v, r)| r.copy_from_slice(field.voxel(v)));
    if sigma > 0.0 {
        values = blur_masked(values, d, field.dims(), &|v| valid[v], sigma);
    }
    let mut out = GridField::new(field.dims(), field.bounds(), d)?;
    for (v, x) in values.chunks_exact(d).enumerate() {
        out.voxel_mut(v).copy_from_slice(x);
    }
    Ok(out)
}

/// `data` (`voxels × d`, excluded voxels zero) blurred by a separable Gaussian of `sigma` voxels
/// (taps to 3σ) over the included voxels only: each output is the weighted mean of the included
/// voxels under the kernel, so the box edges and excluded voxels do not pull values towards 0.
/// Excluded voxels stay 0.
fn blur_masked(
    data: Vec<f32>,
    d: usize,
    dims: [usize; 3],
    valid: &(dyn Fn(usize) -> bool + Sync),
    sigma: f64,
) -> Vec<f32> {
    let voxels = dims.iter().product::<usize>();
    let radius = (3.0 * sigma).ceil() as isize;
    let taps: Vec<f64> = (-radius..=radius)
        .map(|t| (-((t * t) as f64) / (2.0 * sigma * sigma)).exp())
        .collect();
    // Column d carries the inclusion weight through the same blur.
    let width = d + 1;
    let mut rows: Vec<f32> = Vec::with_capacity(voxels * width);
    for v in 0..voxels {
        rows.extend_from_slice(&data[v * d..(v + 1) * d]);
        rows.push(if valid(v) { 1.0 } else { 0.0 });
    }
    let strides = [1, dims[0], dims[0] * dims[1]];
    for axis in 0..3 {
        let source = &rows;
        let mut blurred = vec![0.0f32; voxels * width];
        blurred.par_chunks_mut(width).enumerate().for_each_init(
            || vec![0.0f64; width],
            |acc, (v, out)| {
                let c = ((v / strides[axis]) % dims[axis]) as isize;
                acc.fill(0.0);
                for (k, &w) in taps.iter().enumerate() {
                    let t = c + k as isize - radius;
                    if t < 0 || t >= dims[axis] as isize {
                        continue;
                    }
                    let u = (v as isize + (t - c) * strides[axis] as isize) as usize;
                    for (a, &x) in acc.iter_mut().zip(&source[u * width..(u + 1) * width]) {
                        *a += w * x as f64;
                    }
                }
                for (o, &a) in out.iter_mut().zip(acc.iter()) {
                    *o = a as f32;
                }
            },
        );
        rows = blurred;
    }
    let mut out = data;
    out.par_chunks_mut(d).enumerate().for_each(|(v, o)| {
        let row = &rows[v * width..(v + 1) * width];
        let weight = row[d];
        if valid(v) && weight > 0.0 {
            for (o, &x) in o.iter_mut().zip(&row[..d]) {
                *o = x / weight;
            }
        } else {
            o.fill(0.0);
        }
    });
    out
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
