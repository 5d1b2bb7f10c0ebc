//! The Monte Carlo estimate of MBD's loss, its gradient and its diagonal Hessian, computed cell
//! by cell with small matrix products (paper section 3.3, eqs. 9, 11, 13, 14).
//!
//! With one jittered sample `x_s` per voxel (stratum) of the target grid,
//!
//! ```text
//! E(c, B)        = Σ_s ‖f(x_s) − f̂(x_s)‖² + λ/2 ‖c‖²
//! ∂E/∂c_{m,l}    = −2 Σ_s φ_m(x_s) b_l(x_s)·r_s + λ c_{m,l}        H = 2 Σ_s φ_m(x_s)² ‖b_l(x_s)‖² + λ
//! ∂E/∂B_{n,l,d}  = −2 Σ_s ψ_n(x_s) c_l(x_s) r_{s,d}                 H = 2 Σ_s ψ_n(x_s)² c_l(x_s)²
//! ```
//!
//! with `r_s = f(x_s) − f̂(x_s)`. The data term is the integral of the squared error in units of
//! one voxel's volume, so `λ` weighs against per-voxel squared errors. The loss is quadratic in
//! `c` for fixed `B` and in `B` for fixed `c`, so both diagonals are exact diagonals of the
//! block Hessians of the estimate.
//!
//! All samples of one basis cell share the same basis nodes, so per cell, with `P[s, (j,l)] =
//! ψ_j(x_s) c_l(x_s)` (`S × nL`) and the cell's basis rows `B_g` (`nL × D`):
//! `R = F − P B_g`, `∇_B = −2 Pᵀ R`, `b(x_s)·r_s = ψ-contraction of R B_gᵀ`. Those three f32
//! products carry almost all the work; per-cell sums are short, and everything summed across
//! cells is accumulated in f64 in a fixed order, so the result does not depend on the number of
//! threads.

use glam::Vec3;
use ndarray::{ArrayView2, ArrayViewMut2, linalg::general_mat_mul};
use prt_core::{CoreError, GridField, KernelWeights, Progress, SpatialKernels};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;
use rayon::prelude::*;

/// Samples per group when the basis kernels have no cell structure and the points are not
/// one per voxel.
const FALLBACK_GROUP: usize = 64;
/// Voxels per axis of the groups of [`Samples::draw`] when the basis kernels have no cell
/// structure (scattered kernels): bricks of 4³ samples, which touch fewer kernels than the
/// same number of samples along a row of voxels (measured in `docs/results.md`).
const FALLBACK_BRICK: usize = 4;
/// Groups evaluated in parallel before their results are reduced (fixed, so the reduction
/// order does not depend on the thread count).
const GROUP_BATCH: usize = 128;
/// [`Problem::prepare`] keeps the targets `f(x_s)` of a sample set (one D-vector per sample)
/// only up to this many floats (64 MiB): enough for 32³ × 324 voxels, while a 64³ × 324 field
/// or the 512 × 512 × 128 × 12 scale run would double its memory for a few per cent of time.
const PREPARED_TARGET_FLOATS: usize = 1 << 24;

/// The fixed parts of an MBD fit: target, kernels, rank, regularisation.
pub(crate) struct Problem<'a, C, B> {
    pub field: &'a GridField,
    /// Per voxel, whether its value is data (`None`: every voxel). Samples lie in valid voxels
    /// only and the target blends valid voxels only: invalid voxels' values are never read.
    pub mask: Option<&'a [bool]>,
    pub coefficient_kernels: &'a C,
    pub basis_kernels: &'a B,
    pub rank: usize,
    pub lambda: f32,
    pub preconditioner: Preconditioner,
}

/// The diagonal scaling of the quasi-Newton step.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[non_exhaustive]
pub enum Preconditioner {
    /// The paper's diagonal Hessian (eqs. 11, 14): `2 Σ_s φ_m(x_s)² ‖b_l(x_s)‖² + λ` and
    /// `2 Σ_s ψ_n(x_s)² c_l(x_s)²`. Overlapping kernels make the true curvature along smooth
    /// directions larger than the diagonal (up to 3.4× for trilinear hats), so full steps
    /// overshoot and the line search has to halve them.
    Diagonal,
    /// Full `L × L` blocks per kernel with each kernel's overlap lumped in (beyond the paper):
    /// `2 Σ_s φ_m Σφ b(x_s) b(x_s)ᵀ + λ I` for the coefficients of kernel `m` and
    /// `2 Σ_s ψ_n Σψ c(x_s) c(x_s)ᵀ` for the basis vectors of node `n`. It accounts for the
    /// coupling between the L basis vectors and between overlapping kernels (a block Gershgorin
    /// bound of each block's Hessian), so a full step never increases the loss in either block
    /// alone and full steps are accepted far more often.
    #[default]
    Block,
}

impl Preconditioner {
    /// Entries per (kernel, l) row of the curvature: L for [`Preconditioner::Block`], else 1.
    pub(crate) fn width(self, rank: usize) -> usize {
        if self == Preconditioner::Block {
            rank
        } else {
            1
        }
    }
}

/// One jittered sample per voxel, grouped by basis cell.
pub(crate) struct Samples {
    points: Vec<Vec3>,
    /// Sample indices ordered by group.
    order: Vec<u32>,
    /// Group boundaries into `order`.
    groups: Vec<(usize, usize)>,
    /// Per group, what does not depend on the parameters (filled by [`Problem::prepare`] for
    /// sample sets evaluated more than once; the first `prepared` entries are valid).
    geometry: Vec<Geometry>,
    prepared: usize,
}

/// What one group's evaluation needs that depends on its samples only: the coefficient kernel
/// weights of every sample, the basis nodes of the cell, ψ of every sample over them, and
/// (when prepared) the target `f(x_s)` of every sample. Built once per sample set by
/// [`Problem::prepare`], or per evaluation in the thread's scratch.
#[derive(Default)]
pub(crate) struct Geometry {
    /// Coefficient kernel weights of every sample, flattened with offsets.
    phi_off: Vec<usize>,
    phi_idx: Vec<u32>,
    phi_w: Vec<f32>,
    /// The coefficient kernels the group touches, sorted, and each weight's position in them.
    coef_nodes: Vec<u32>,
    phi_local: Vec<u32>,
    /// The cell's basis nodes, sorted.
    basis_nodes: Vec<u32>,
    /// ψ of every sample over the cell's nodes (`S × nb`).
    psi_dense: Vec<f32>,
    /// `f(x_s)` (`S × D`); empty when the residual is blended from the field on the fly.
    target: Vec<f32>,
}

/// Scratch of [`Problem::geometry`].
#[derive(Default)]
struct KernelScratch {
    phi: KernelWeights,
    psi: KernelWeights,
    psi_off: Vec<usize>,
    psi_idx: Vec<u32>,
    psi_w: Vec<f32>,
    psi_local: Vec<u32>,
    /// Scratch of [`local_indices`].
    marks: Vec<u32>,
}

impl Samples {
    /// One jittered sample per voxel for `iteration`, reproducible from `seed`. With
    /// `jitter = false` the samples sit at the voxel centres.
    #[cfg(test)]
    pub fn draw<B: SpatialKernels>(
        field: &GridField,
        basis: &B,
        seed: u64,
        iteration: u64,
        jitter: bool,
    ) -> Self {
        Self::draw_masked(field, None, basis, seed, iteration, jitter)
    }

    /// [`Samples::draw`] in the voxels where `mask` holds only (every voxel without one). The
    /// random numbers of every voxel are drawn either way, so a voxel's sample does not depend
    /// on the mask.
    pub fn draw_masked<B: SpatialKernels>(
        field: &GridField,
        mask: Option<&[bool]>,
        basis: &B,
        seed: u64,
        iteration: u64,
        jitter: bool,
    ) -> Self {
        let size = field.voxel_size();
        let mut rng = Pcg64Mcg::seed_from_u64(mix(seed, iteration));
        let mut voxels = Vec::new();
        let points: Vec<Vec3> = (0..field.num_voxels())
            .filter_map(|v| {
                let centre = field.centre_of(v);
                let point = if jitter {
                    let u = Vec3::new(
                        rng.random::<f32>(),
                        rng.random::<f32>(),
                        rng.random::<f32>(),
                    );
                    centre + (u - 0.5) * size
                } else {
                    centre
                };
                let keep = mask.is_none_or(|m| m[v]);
                if keep {
                    voxels.push(v);
                }
                keep.then_some(point)
            })
            .collect();
        if basis.num_support_cells() == 0 {
            // Sample v lies in voxel v: group by bricks of voxels, so that a group's samples
            // are close together and share most of their (scattered) basis kernels.
            let dims = field.dims();
            let bricks = dims.map(|d| d.div_ceil(FALLBACK_BRICK));
            let keys = voxels
                .iter()
                .map(|&v| {
                    let b = [
                        v % dims[0],
                        (v / dims[0]) % dims[1],
                        v / (dims[0] * dims[1]),
                    ]
                    .map(|c| c / FALLBACK_BRICK);
                    (b[0] + bricks[0] * (b[1] + bricks[1] * b[2])) as u32
                })
                .collect();
            return Self::group_by(points, Some(keys), bricks.iter().product());
        }
        Self::group(points, basis)
    }

    /// Groups arbitrary points by basis cell (families without cells: runs of
    /// `FALLBACK_GROUP` points in the given order).
    pub fn group<B: SpatialKernels>(points: Vec<Vec3>, basis: &B) -> Self {
        let cells = basis.num_support_cells();
        let keys: Option<Vec<u32>> = if cells > 0 {
            points
                .par_iter()
                .map(|&x| {
                    basis
                        .support_cell(x)
                        .filter(|&c| c < cells)
                        .map(|c| c as u32)
                })
                .collect()
        } else {
            None
        };
        Self::group_by(points, keys, cells)
    }

    /// Groups points by `keys` (each `< cells`), stably; without keys, runs of
    /// `FALLBACK_GROUP` points.
    fn group_by(points: Vec<Vec3>, keys: Option<Vec<u32>>, cells: usize) -> Self {
        let (order, groups) = match keys {
            Some(keys) => {
                // Counting sort: stable, so samples stay in stratum order inside a cell.
                let mut counts = vec![0usize; cells + 1];
                for &k in &keys {
                    counts[k as usize + 1] += 1;
                }
                for i in 0..cells {
                    counts[i + 1] += counts[i];
                }
                let mut next = counts.clone();
                let mut order = vec![0u32; keys.len()];
                for (s, &k) in keys.iter().enumerate() {
                    order[next[k as usize]] = s as u32;
                    next[k as usize] += 1;
                }
                let groups = (0..cells)
                    .map(|c| (counts[c], counts[c + 1]))
                    .filter(|(a, b)| b > a)
                    .collect();
                (order, groups)
            }
            None => {
                let n = points.len();
                let order = (0..n as u32).collect();
                let groups = (0..n)
                    .step_by(FALLBACK_GROUP)
                    .map(|a| (a, (a + FALLBACK_GROUP).min(n)))
                    .collect();
                (order, groups)
            }
        };
        Self {
            points,
            order,
            groups,
            geometry: Vec::new(),
            prepared: 0,
        }
    }

    /// Takes over the prepared storage of an earlier sample set (its allocations; nothing of
    /// its contents is used), so that preparing every iteration's samples does not allocate.
    pub fn recycle(&mut self, earlier: Samples) {
        self.geometry = earlier.geometry;
        self.prepared = 0;
    }
}

/// SplitMix64-style mixing of a seed and a stream number.
pub(crate) fn mix(seed: u64, stream: u64) -> u64 {
    let mut z = seed
        ^ stream
            .wrapping_mul(0x9E37_79B9_7F4A_7C15)
            .wrapping_add(0x6A09_E667_F3BC_C909);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Loss and (optionally) gradient and diagonal Hessian of the estimate.
pub(crate) struct Evaluation {
    /// Data term `Σ_s ‖r_s‖²`.
    pub data_loss: f64,
    /// Regularisation `λ/2 ‖c‖²`.
    pub reg_loss: f64,
    /// `∂E/∂c` (`M × L`) and its curvature (`M × L × w`, `w` = [`Preconditioner::width`]);
    /// empty when not requested.
    pub grad_c: Vec<f64>,
    pub hess_c: Vec<f64>,
    /// `∂E/∂B` (`N × L × D`), curvature per (node, l) (`N × L × w`, the same for every d).
    pub grad_b: Vec<f64>,
    pub hess_b: Vec<f64>,
}

impl Evaluation {
    pub fn loss(&self) -> f64 {
        self.data_loss + self.reg_loss
    }
}

/// What one group (basis cell) contributes.
struct GroupOut {
    loss: f64,
    basis_nodes: Vec<u32>,
    grad_b: Vec<f32>,
    hess_b: Vec<f64>,
    coef_nodes: Vec<u32>,
    grad_c: Vec<f64>,
    hess_c: Vec<f64>,
}

impl<C: SpatialKernels, B: SpatialKernels> Problem<'_, C, B> {
    pub fn dim(&self) -> usize {
        self.field.dim()
    }

    /// Computes once what every evaluation on `samples` would otherwise recompute: kernel
    /// weights, the cells' nodes and the targets `f(x_s)` (the line search and the held-out
    /// measurements evaluate the same samples several times). Skipped above
    /// [`PREPARED_TARGET_FLOATS`]. Evaluations give bit-identical results either way.
    pub fn prepare(&self, samples: &mut Samples) -> Result<(), CoreError> {
        samples.prepared = 0;
        if samples.points.len().saturating_mul(self.dim()) > PREPARED_TARGET_FLOATS {
            return Ok(());
        }
        let groups = samples.groups.len();
        samples.geometry.resize_with(groups, Geometry::default);
        let (points, order) = (&samples.points, &samples.order);
        samples
            .geometry
            .par_iter_mut()
            .zip(&samples.groups)
            .try_for_each_init(KernelScratch::default, |kernels, (geometry, &(a, b))| {
                self.geometry(points, &order[a..b], true, geometry, kernels)
            })?;
        samples.prepared = groups;
        Ok(())
    }

    /// `Σ_s ‖f(x_s)‖²`: the data term of the zero model, bit-identical to
    /// `evaluate(samples, 0, B).data_loss` for any finite `B` (same per-group sums, same order).
    pub fn target_energy(
        &self,
        samples: &Samples,
        progress: &dyn Progress,
    ) -> Result<f64, CoreError> {
        if samples.prepared == samples.groups.len() {
            return Ok(samples.geometry[..samples.prepared]
                .iter()
                .fold(0.0, |total, g| total + sum_of_squares(&g.target)));
        }
        let (l, d) = (self.rank, self.dim());
        let coefficients = vec![0.0; self.coefficient_kernels.len() * l];
        let basis = vec![0.0; self.basis_kernels.len() * l * d];
        Ok(self
            .evaluate(samples, &coefficients, &basis, false, progress)?
            .data_loss)
    }

    /// Fills `geometry` for the samples `ids` of one group (and their targets if `targets`).
    fn geometry(
        &self,
        points: &[Vec3],
        ids: &[u32],
        targets: bool,
        geometry: &mut Geometry,
        kernels: &mut KernelScratch,
    ) -> Result<(), CoreError> {
        let (g, k) = (geometry, kernels);
        let s_len = ids.len();
        g.phi_off.clear();
        g.phi_idx.clear();
        g.phi_w.clear();
        k.psi_off.clear();
        k.psi_idx.clear();
        k.psi_w.clear();
        g.phi_off.push(0);
        k.psi_off.push(0);
        for &s in ids {
            let x = points[s as usize];
            self.coefficient_kernels.eval(x, &mut k.phi)?;
            self.basis_kernels.eval(x, &mut k.psi)?;
            g.phi_idx.extend_from_slice(&k.phi.indices);
            g.phi_w.extend_from_slice(&k.phi.weights);
            g.phi_off.push(g.phi_idx.len());
            k.psi_idx.extend_from_slice(&k.psi.indices);
            k.psi_w.extend_from_slice(&k.psi.weights);
            k.psi_off.push(k.psi_idx.len());
        }
        local_indices(
            &g.phi_idx,
            &mut g.coef_nodes,
            &mut g.phi_local,
            &mut k.marks,
        );
        local_indices(
            &k.psi_idx,
            &mut g.basis_nodes,
            &mut k.psi_local,
            &mut k.marks,
        );
        let nb = g.basis_nodes.len();
        g.psi_dense.clear();
        g.psi_dense.resize(s_len * nb, 0.0);
        for s in 0..s_len {
            let psi_row = &mut g.psi_dense[s * nb..(s + 1) * nb];
            for j in k.psi_off[s]..k.psi_off[s + 1] {
                psi_row[k.psi_local[j] as usize] += k.psi_w[j];
            }
        }
        if targets {
            // Every row is overwritten, so a recycled buffer of the same size is not cleared.
            g.target.resize(s_len * self.dim(), 0.0);
            self.blend_targets(points, ids, &mut g.target)?;
        } else {
            g.target.clear();
        }
        Ok(())
    }

    /// `f(x_s)` of the samples `ids` into the rows of `out`, each blended from its eight voxels
    /// in one pass.
    fn blend_targets(
        &self,
        points: &[Vec3],
        ids: &[u32],
        out: &mut [f32],
    ) -> Result<(), CoreError> {
        for (row, &id) in out.chunks_exact_mut(self.dim()).zip(ids) {
            self.target_at(points[id as usize], row)?;
        }
        Ok(())
    }

    /// The target `f(x)`: the trilinear blend of the field's voxels; with a mask, the invalid
    /// voxels count as zero and are never read. (Renormalising the valid corners' weights
    /// instead makes a target the trilinear coefficient hats cannot follow across a wall one
    /// voxel thick: measured on Sponza 128, 3.7x the error.)
    pub fn target_at(&self, x: Vec3, out: &mut [f32]) -> Result<(), CoreError> {
        let tw = self.field.trilinear_weights(x)?;
        let Some(mask) = self.mask else {
            blend8(out, tw.indices.map(|v| self.field.voxel(v)), tw.weights);
            return Ok(());
        };
        let mut weights = tw.weights;
        let mut any_valid = None;
        for (w, &v) in weights.iter_mut().zip(&tw.indices) {
            if mask[v] {
                any_valid = Some(v);
            } else {
                *w = 0.0;
            }
        }
        match any_valid {
            Some(valid) => {
                // Invalid corners read a valid voxel at weight zero: their values stay unread.
                let rows = tw
                    .indices
                    .map(|v| self.field.voxel(if mask[v] { v } else { valid }));
                blend8(out, rows, weights);
            }
            None => out.fill(0.0),
        }
        Ok(())
    }

    /// Evaluates the estimate on `samples` at parameters `coefficients` (`M × L`) and `basis`
    /// (`N × L × D`, flat).
    pub fn evaluate(
        &self,
        samples: &Samples,
        coefficients: &[f32],
        basis: &[f32],
        want_gradient: bool,
        progress: &dyn Progress,
    ) -> Result<Evaluation, CoreError> {
        let (l, d) = (self.rank, self.dim());
        let m = self.coefficient_kernels.len();
        let n = self.basis_kernels.len();
        let mut eval = Evaluation {
            data_loss: 0.0,
            reg_loss: 0.5
                * self.lambda as f64
                * coefficients
                    .iter()
                    .map(|&c| (c as f64) * (c as f64))
                    .sum::<f64>(),
            grad_c: Vec::new(),
            hess_c: Vec::new(),
            grad_b: Vec::new(),
            hess_b: Vec::new(),
        };
        let w = self.preconditioner.width(l);
        if want_gradient {
            let lambda = self.lambda as f64;
            eval.grad_c = coefficients.iter().map(|&c| lambda * c as f64).collect();
            eval.hess_c = vec![0.0; m * l * w];
            for (k, h) in eval.hess_c.chunks_exact_mut(w).enumerate() {
                h[if w == 1 { 0 } else { k % l }] = lambda;
            }
            eval.grad_b = vec![0.0; n * l * d];
            eval.hess_b = vec![0.0; n * l * w];
        }
        let prepared = &samples.geometry[..samples.prepared];
        for (batch_index, batch) in samples.groups.chunks(GROUP_BATCH).enumerate() {
            progress.check()?;
            let first = batch_index * GROUP_BATCH;
            let outs: Vec<GroupOut> = batch
                .par_iter()
                .enumerate()
                .map(|(k, &(a, b))| {
                    SCRATCH.with_borrow_mut(|scratch| {
                        let Scratch {
                            geometry,
                            kernels,
                            buffers,
                        } = scratch;
                        let ids = &samples.order[a..b];
                        let geometry = match prepared.get(first + k) {
                            Some(g) => g,
                            None => {
                                self.geometry(&samples.points, ids, false, geometry, kernels)?;
                                &*geometry
                            }
                        };
                        self.evaluate_group(
                            &samples.points,
                            ids,
                            geometry,
                            coefficients,
                            basis,
                            want_gradient,
                            buffers,
                        )
                    })
                })
                .collect::<Result<_, _>>()?;
            for out in &outs {
                eval.data_loss += out.loss;
            }
            if want_gradient {
                accumulate(&mut eval, &outs, l, d, w);
            }
        }
        Ok(eval)
    }
}

/// Coefficient kernels per work unit of [`accumulate`].
const ACCUMULATE_CHUNK: usize = 256;

/// Adds the groups' gradients and curvatures into `eval`, in parallel over the output (basis
/// nodes one by one, coefficient kernels in chunks), each entry summing the groups in their
/// order, so the result does not depend on the thread count (nor differs from a serial loop).
fn accumulate(eval: &mut Evaluation, outs: &[GroupOut], l: usize, d: usize, w: usize) {
    eval.grad_b
        .par_chunks_mut(l * d)
        .zip(eval.hess_b.par_chunks_mut(l * w))
        .enumerate()
        .for_each(|(node, (grad, hess))| {
            for out in outs {
                let Ok(j) = out.basis_nodes.binary_search(&(node as u32)) else {
                    continue;
                };
                for (g, &v) in grad.iter_mut().zip(&out.grad_b[j * l * d..(j + 1) * l * d]) {
                    *g += v as f64;
                }
                for (h, &v) in hess.iter_mut().zip(&out.hess_b[j * l * w..(j + 1) * l * w]) {
                    *h += v;
                }
            }
        });
    eval.grad_c
        .par_chunks_mut(ACCUMULATE_CHUNK * l)
        .zip(eval.hess_c.par_chunks_mut(ACCUMULATE_CHUNK * l * w))
        .enumerate()
        .for_each(|(chunk, (grad, hess))| {
            let lo = (chunk * ACCUMULATE_CHUNK) as u32;
            let hi = lo + (grad.len() / l) as u32;
            for out in outs {
                // Most groups lie wholly outside a chunk (a large field has many more chunks
                // than a batch has groups): skip them before searching.
                match (out.coef_nodes.first(), out.coef_nodes.last()) {
                    (Some(&first), Some(&last)) if first < hi && last >= lo => {}
                    _ => continue,
                }
                let a = out.coef_nodes.partition_point(|&n| n < lo);
                let b = out.coef_nodes.partition_point(|&n| n < hi);
                for j in a..b {
                    let k = (out.coef_nodes[j] - lo) as usize;
                    for (g, &v) in grad[k * l..(k + 1) * l]
                        .iter_mut()
                        .zip(&out.grad_c[j * l..(j + 1) * l])
                    {
                        *g += v;
                    }
                    for (h, &v) in hess[k * l * w..(k + 1) * l * w]
                        .iter_mut()
                        .zip(&out.hess_c[j * l * w..(j + 1) * l * w])
                    {
                        *h += v;
                    }
                }
            }
        });
}

thread_local! {
    /// Each worker thread's buffers, kept across groups, evaluations and iterations.
    static SCRATCH: std::cell::RefCell<Scratch> = std::cell::RefCell::new(Scratch::default());
}

/// A thread's scratch: the geometry of unprepared sample sets and the buffers of
/// [`Problem::evaluate_group`].
#[derive(Default)]
struct Scratch {
    geometry: Geometry,
    kernels: KernelScratch,
    buffers: Buffers,
}

/// Buffers of one group's evaluation, reused for every group a thread evaluates (the matrices
/// are row-major and resized per group, never shrunk).
#[derive(Default)]
struct Buffers {
    /// `c(x_s)` (`S × L`).
    c_at: Vec<f32>,
    /// `P[s, j L + l] = ψ_j(x_s) c_l(x_s)` (`S × nb L`).
    p: Vec<f32>,
    /// The cell's basis rows `B_g` (`nb L × D`).
    bg: Vec<f32>,
    /// Residuals `R = F − P B_g` (`S × D`).
    r: Vec<f32>,
    /// Gradient-only products.
    pw: Vec<f32>,
    hb: Vec<f32>,
    q: Vec<f32>,
    gram: Vec<f32>,
    psi2: Vec<f32>,
    pair_grams: Vec<f32>,
    bbt: Vec<f32>,
}

/// `buf` resized to `rows × cols` and viewed as a matrix. Contents are unspecified: callers
/// overwrite every entry (or multiply with β = 0).
fn matrix(buf: &mut Vec<f32>, rows: usize, cols: usize) -> ArrayViewMut2<'_, f32> {
    buf.resize(rows * cols, 0.0);
    match ArrayViewMut2::from_shape((rows, cols), &mut buf[..rows * cols]) {
        Ok(view) => view,
        Err(_) => unreachable!("a buffer of rows × cols elements has that shape"),
    }
}

fn view(buf: &[f32], rows: usize, cols: usize) -> ArrayView2<'_, f32> {
    match ArrayView2::from_shape((rows, cols), &buf[..rows * cols]) {
        Ok(view) => view,
        Err(_) => unreachable!("a buffer of rows × cols elements has that shape"),
    }
}

/// `Σ x²` in f64 with eight independent lanes (vectorisable, and the order is fixed).
fn sum_of_squares(x: &[f32]) -> f64 {
    let mut lanes = [0.0f64; 8];
    let chunks = x.chunks_exact(8);
    let rest: f64 = chunks
        .remainder()
        .iter()
        .map(|&v| v as f64 * v as f64)
        .sum();
    for chunk in chunks {
        for (acc, &v) in lanes.iter_mut().zip(chunk) {
            *acc += v as f64 * v as f64;
        }
    }
    lanes.iter().sum::<f64>() + rest
}

/// `out = Σ_k w_k v_k` over the eight trilinear corners, in one pass over `out`.
fn blend8(out: &mut [f32], rows: [&[f32]; 8], w: [f32; 8]) {
    let d = out.len();
    let [r0, r1, r2, r3, r4, r5, r6, r7] = rows.map(|r| &r[..d]);
    for k in 0..d {
        out[k] = w[0] * r0[k]
            + w[1] * r1[k]
            + w[2] * r2[k]
            + w[3] * r3[k]
            + w[4] * r4[k]
            + w[5] * r5[k]
            + w[6] * r6[k]
            + w[7] * r7[k];
    }
}

impl<C: SpatialKernels, B: SpatialKernels> Problem<'_, C, B> {
    #[allow(clippy::too_many_arguments)]
    fn evaluate_group(
        &self,
        points: &[Vec3],
        ids: &[u32],
        geometry: &Geometry,
        coefficients: &[f32],
        basis: &[f32],
        want_gradient: bool,
        buffers: &mut Buffers,
    ) -> Result<GroupOut, CoreError> {
        let (l, d) = (self.rank, self.dim());
        let s_len = ids.len();
        let (g, sc) = (geometry, buffers);
        let basis_nodes = g.basis_nodes.clone();
        let nb = basis_nodes.len();
        let nbl = nb * l;

        // c(x_s) (S × L).
        sc.c_at.clear();
        sc.c_at.resize(s_len * l, 0.0);
        for s in 0..s_len {
            let c_row = &mut sc.c_at[s * l..(s + 1) * l];
            for k in g.phi_off[s]..g.phi_off[s + 1] {
                let w = g.phi_w[k];
                let node = g.phi_idx[k] as usize;
                for (o, &c) in c_row
                    .iter_mut()
                    .zip(&coefficients[node * l..(node + 1) * l])
                {
                    *o += w * c;
                }
            }
        }
        // P[s, j L + l] = ψ_j(x_s) c_l(x_s).
        let mut p = matrix(&mut sc.p, s_len, nbl);
        for (s, mut row) in p.rows_mut().into_iter().enumerate() {
            let c_row = &sc.c_at[s * l..(s + 1) * l];
            for (chunk, &w) in row
                .as_slice_mut()
                .unwrap_or(&mut [])
                .chunks_exact_mut(l)
                .zip(&g.psi_dense[s * nb..(s + 1) * nb])
            {
                for (o, &c) in chunk.iter_mut().zip(c_row) {
                    *o = w * c;
                }
            }
        }
        // The cell's basis rows B_g (nb L × D).
        sc.bg.resize(nbl * d, 0.0);
        for (j, &node) in basis_nodes.iter().enumerate() {
            let node = node as usize;
            sc.bg[j * l * d..(j + 1) * l * d]
                .copy_from_slice(&basis[node * l * d..(node + 1) * l * d]);
        }
        // Residual R = F − P B_g.
        sc.r.resize(s_len * d, 0.0);
        if g.target.is_empty() {
            self.blend_targets(points, ids, &mut sc.r[..s_len * d])?;
        } else {
            sc.r[..s_len * d].copy_from_slice(&g.target);
        }
        let bg = view(&sc.bg, nbl, d);
        let p = view(&sc.p, s_len, nbl);
        {
            let mut r = matrix(&mut sc.r, s_len, d);
            general_mat_mul(-1.0, &p, &bg, 1.0, &mut r);
        }
        let loss = sum_of_squares(&sc.r[..s_len * d]);
        if !want_gradient {
            return Ok(GroupOut {
                loss,
                basis_nodes,
                grad_b: Vec::new(),
                hess_b: Vec::new(),
                coef_nodes: Vec::new(),
                grad_c: Vec::new(),
                hess_c: Vec::new(),
            });
        }
        let r = view(&sc.r, s_len, d);
        // ∇_B = −2 Pᵀ R.
        let mut grad_b = Vec::new();
        general_mat_mul(-2.0, &p.t(), &r, 0.0, &mut matrix(&mut grad_b, nbl, d));
        let lumped = self.preconditioner == Preconditioner::Block;
        let w = self.preconditioner.width(l);
        // Curvature of the basis: Σ_s ψ_j(x_s) κ_s c(x_s) c(x_s)ᵀ with κ_s = Σψ (blocks) or
        // ψ_j (the paper's diagonal), as one product (diag(2κ) P)ᵀ C for the blocks.
        let mut hess_b = vec![0.0f64; nbl * w];
        if lumped {
            let mut pw = matrix(&mut sc.pw, s_len, nbl);
            for (s, (mut row, prow)) in pw.rows_mut().into_iter().zip(p.rows()).enumerate() {
                let overlap: f32 = g.psi_dense[s * nb..(s + 1) * nb].iter().sum();
                row.zip_mut_with(&prow, |o, &v| *o = 2.0 * v * overlap);
            }
            let c_at = view(&sc.c_at, s_len, l);
            let mut hb = matrix(&mut sc.hb, nbl, l);
            general_mat_mul(1.0, &pw.t(), &c_at, 0.0, &mut hb);
            for (jl, row) in hb.rows().into_iter().enumerate() {
                for (h, &v) in hess_b[jl * l..(jl + 1) * l].iter_mut().zip(row.iter()) {
                    *h = v as f64;
                }
            }
        } else {
            for row in p.rows() {
                for (h, &v) in hess_b.iter_mut().zip(row.iter()) {
                    *h += 2.0 * (v as f64) * (v as f64);
                }
            }
        }
        // b(x_s)·r_s through Q = R B_gᵀ, and ‖b_l(x_s)‖² through the cell Gram G = B_g B_gᵀ.
        let mut q = matrix(&mut sc.q, s_len, nbl);
        general_mat_mul(1.0, &r, &bg.t(), 0.0, &mut q);
        let mut gram = matrix(&mut sc.gram, nbl, nbl);
        general_mat_mul(1.0, &bg, &bg.t(), 0.0, &mut gram);

        let coef_nodes = g.coef_nodes.clone();
        let nc = coef_nodes.len();
        let mut grad_c = vec![0.0f64; nc * l];
        let mut hess_c = vec![0.0f64; nc * l * w];
        // b(x_s) b(x_s)ᵀ = Σ_jk ψ_j ψ_k B_j B_kᵀ for every sample at once: (ψ ⊗ ψ) (S × nb²)
        // times the cell's node-pair Grams (nb² × L²).
        let mut psi2 = matrix(&mut sc.psi2, s_len, nb * nb);
        for (s, mut row) in psi2.rows_mut().into_iter().enumerate() {
            let prow = &g.psi_dense[s * nb..(s + 1) * nb];
            for j in 0..nb {
                for k in 0..nb {
                    row[j * nb + k] = prow[j] * prow[k];
                }
            }
        }
        let mut pair_grams = matrix(&mut sc.pair_grams, nb * nb, l * l);
        for j in 0..nb {
            for k in 0..nb {
                let mut row = pair_grams.row_mut(j * nb + k);
                for li in 0..l {
                    for lj in 0..l {
                        row[li * l + lj] = gram[[j * l + li, k * l + lj]];
                    }
                }
            }
        }
        let mut bbt = matrix(&mut sc.bbt, s_len, l * l);
        general_mat_mul(1.0, &psi2, &pair_grams, 0.0, &mut bbt);
        let mut br = vec![0.0f64; l];
        let mut bb = vec![0.0f64; l * w];
        for s in 0..s_len {
            br.fill(0.0);
            let q_row = &sc.q[s * nbl..(s + 1) * nbl];
            for (&wj, q_j) in g.psi_dense[s * nb..(s + 1) * nb]
                .iter()
                .zip(q_row.chunks_exact(l))
            {
                if wj == 0.0 {
                    continue;
                }
                for (b, &v) in br.iter_mut().zip(q_j) {
                    *b += wj as f64 * v as f64;
                }
            }
            let row = &sc.bbt[s * l * l..(s + 1) * l * l];
            if w == 1 {
                for (li, b) in bb.iter_mut().enumerate() {
                    *b = row[li * l + li] as f64;
                }
            } else {
                for (b, &v) in bb.iter_mut().zip(row) {
                    *b = v as f64;
                }
            }
            let phi_w = &g.phi_w[g.phi_off[s]..g.phi_off[s + 1]];
            let overlap: f64 = if lumped {
                phi_w.iter().map(|&v| v as f64).sum()
            } else {
                0.0
            };
            for (&local, &weight) in g.phi_local[g.phi_off[s]..g.phi_off[s + 1]]
                .iter()
                .zip(phi_w)
            {
                let local = local as usize;
                let weight = weight as f64;
                let scale = if lumped {
                    2.0 * weight * overlap
                } else {
                    2.0 * weight * weight
                };
                for li in 0..l {
                    grad_c[local * l + li] -= 2.0 * weight * br[li];
                }
                for (h, &v) in hess_c[local * l * w..(local + 1) * l * w]
                    .iter_mut()
                    .zip(&bb)
                {
                    *h += scale * v;
                }
            }
        }
        Ok(GroupOut {
            loss,
            basis_nodes,
            grad_b,
            hess_b,
            coef_nodes,
            grad_c,
            hess_c,
        })
    }
}

/// The distinct `indices`, sorted, into `nodes`, and each index's position in them into
/// `local`. Kernel indices of one basis cell span a narrow range, so a table over that range
/// replaces sorting and searching (falling back to them for a sparse spread).
fn local_indices(
    indices: &[u32],
    nodes: &mut Vec<u32>,
    local: &mut Vec<u32>,
    marks: &mut Vec<u32>,
) {
    nodes.clear();
    local.clear();
    let (Some(&lo), Some(&hi)) = (indices.iter().min(), indices.iter().max()) else {
        return;
    };
    let span = (hi - lo) as usize + 1;
    if span <= 4 * indices.len() + 64 {
        marks.clear();
        marks.resize(span, u32::MAX);
        for &i in indices {
            marks[(i - lo) as usize] = 0;
        }
        for (offset, mark) in marks.iter_mut().enumerate() {
            if *mark == 0 {
                *mark = nodes.len() as u32;
                nodes.push(lo + offset as u32);
            }
        }
        local.extend(indices.iter().map(|&i| marks[(i - lo) as usize]));
    } else {
        nodes.extend_from_slice(indices);
        nodes.sort_unstable();
        nodes.dedup();
        local.extend(
            indices
                .iter()
                .map(|i| nodes.binary_search(i).unwrap_or(0) as u32),
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use prt_core::{Aabb, NoProgress};
    use prt_kernels::HatGrid;
    use rand::Rng;

    /// A random problem: field 5×4×3 of 4-vectors, coefficient nodes at the voxel centres, a
    /// 3×2×2 basis grid, rank 2, and random parameters.
    fn setup(seed: u64) -> (GridField, HatGrid, HatGrid, Vec<f32>, Vec<f32>) {
        let mut rng = Pcg64Mcg::seed_from_u64(seed);
        let field = GridField::from_fn([5, 4, 3], Aabb::UNIT, 4, |_, out| {
            out.iter_mut()
                .for_each(|o| *o = rng.random::<f32>() * 2.0 - 1.0)
        })
        .unwrap();
        let coef = HatGrid::new([5, 4, 3], crate::baselines::voxel_centre_box(&field)).unwrap();
        let basis = HatGrid::new([3, 2, 2], Aabb::UNIT).unwrap();
        let c = (0..coef.len() * 2)
            .map(|_| rng.random::<f32>() * 2.0 - 1.0)
            .collect();
        let b = (0..basis.len() * 2 * 4)
            .map(|_| rng.random::<f32>() * 2.0 - 1.0)
            .collect();
        (field, coef, basis, c, b)
    }

    fn loss(p: &Problem<'_, HatGrid, HatGrid>, s: &Samples, c: &[f32], b: &[f32]) -> f64 {
        p.evaluate(s, c, b, false, &NoProgress).unwrap().loss()
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(12))]

        /// The loss is quadratic in every single parameter, so central differences are exact up
        /// to rounding: `(E(θ+h) − E(θ−h)) / 2h = g` and `E(θ+h) + E(θ−h) − 2E(θ) = h² H`.
        #[test]
        fn gradient_and_diagonal_hessian_match_finite_differences(seed in 0u64..1000, pick in 0usize..1000) {
            let (field, coef, basis, c, b) = setup(seed);
            let p = Problem { field: &field, mask: None, coefficient_kernels: &coef, basis_kernels: &basis, rank: 2, lambda: 0.3, preconditioner: Preconditioner::Diagonal };
            let samples = Samples::draw(&field, &basis, seed, 3, true);
            let e = p.evaluate(&samples, &c, &b, true, &NoProgress).unwrap();
            let e0 = e.loss();
            let h = 0.125f32;
            // One coefficient and one basis entry.
            let i = pick % c.len();
            let (mut cp, mut cm) = (c.clone(), c.clone());
            cp[i] += h;
            cm[i] -= h;
            let (lp, lm) = (loss(&p, &samples, &cp, &b), loss(&p, &samples, &cm, &b));
            let scale = e0.abs().max(1.0);
            prop_assert!(((lp - lm) / (2.0 * h as f64) - e.grad_c[i]).abs() < 1e-4 * scale, "grad c {} vs {}", (lp - lm) / (2.0 * h as f64), e.grad_c[i]);
            prop_assert!(((lp + lm - 2.0 * e0) / (h as f64 * h as f64) - e.hess_c[i]).abs() < 1e-3 * scale, "hess c");
            let k = pick % b.len();
            let (mut bp, mut bm) = (b.clone(), b.clone());
            bp[k] += h;
            bm[k] -= h;
            let (lp, lm) = (loss(&p, &samples, &c, &bp), loss(&p, &samples, &c, &bm));
            prop_assert!(((lp - lm) / (2.0 * h as f64) - e.grad_b[k]).abs() < 1e-4 * scale, "grad B {} vs {}", (lp - lm) / (2.0 * h as f64), e.grad_b[k]);
            prop_assert!(((lp + lm - 2.0 * e0) / (h as f64 * h as f64) - e.hess_b[k / 4]).abs() < 1e-3 * scale, "hess B");
        }

        /// The block preconditioner's diagonal dominates the exact diagonal (the weights are a
        /// partition of unity), its blocks are symmetric, and it leaves the gradient alone.
        #[test]
        fn block_preconditioner_dominates_the_hessian_diagonal(seed in 0u64..1000) {
            let (field, coef, basis, c, b) = setup(seed);
            let mut p = Problem { field: &field, mask: None, coefficient_kernels: &coef, basis_kernels: &basis, rank: 2, lambda: 0.0, preconditioner: Preconditioner::Diagonal };
            let samples = Samples::draw(&field, &basis, seed, 0, true);
            let exact = p.evaluate(&samples, &c, &b, true, &NoProgress).unwrap();
            p.preconditioner = Preconditioner::Block;
            let block = p.evaluate(&samples, &c, &b, true, &NoProgress).unwrap();
            prop_assert_eq!(&block.grad_c, &exact.grad_c);
            for (blocks, diag) in [(&block.hess_c, &exact.hess_c), (&block.hess_b, &exact.hess_b)] {
                for (k, &dv) in diag.iter().enumerate() {
                    let (node, li) = (k / 2, k % 2);
                    let at = |i: usize, j: usize| blocks[(node * 2 + i) * 2 + j];
                    prop_assert!(at(li, li) >= dv * (1.0 - 1e-5));
                    prop_assert!((at(0, 1) - at(1, 0)).abs() <= 1e-5 * at(0, 0).abs().max(1.0));
                }
            }
        }
    }

    /// Prepared sample sets (cached kernel weights and targets) evaluate bit for bit like
    /// unprepared ones, also after recycling another set's storage; the target energy is the
    /// zero model's data term.
    #[test]
    fn prepared_samples_evaluate_bit_identically() {
        let (field, coef, basis, c, b) = setup(5);
        let p = Problem {
            field: &field,
            mask: None,
            coefficient_kernels: &coef,
            basis_kernels: &basis,
            rank: 2,
            lambda: 0.3,
            preconditioner: Preconditioner::Block,
        };
        let mut other = Samples::draw(&field, &basis, 9, 1, true);
        p.prepare(&mut other).unwrap();
        let plain = Samples::draw(&field, &basis, 9, 0, true);
        let mut prepared = Samples::draw(&field, &basis, 9, 0, true);
        prepared.recycle(other);
        p.prepare(&mut prepared).unwrap();
        assert_eq!(prepared.prepared, prepared.groups.len());
        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        for want_gradient in [false, true] {
            let a = p
                .evaluate(&plain, &c, &b, want_gradient, &NoProgress)
                .unwrap();
            let e = p
                .evaluate(&prepared, &c, &b, want_gradient, &NoProgress)
                .unwrap();
            assert_eq!(a.data_loss.to_bits(), e.data_loss.to_bits());
            assert_eq!(bits(&a.grad_c), bits(&e.grad_c));
            assert_eq!(bits(&a.hess_c), bits(&e.hess_c));
            assert_eq!(bits(&a.grad_b), bits(&e.grad_b));
            assert_eq!(bits(&a.hess_b), bits(&e.hess_b));
        }
        let zero = vec![0.0; c.len()];
        let energy = p.evaluate(&plain, &zero, &b, false, &NoProgress).unwrap();
        assert!(energy.data_loss > 0.0);
        for samples in [&plain, &prepared] {
            let e = p.target_energy(samples, &NoProgress).unwrap();
            assert_eq!(e.to_bits(), energy.data_loss.to_bits());
        }
    }

    #[test]
    fn samples_are_grouped_by_basis_cell_and_cover_every_voxel_once() {
        let (field, _, basis, _, _) = setup(1);
        let s = Samples::draw(&field, &basis, 7, 0, true);
        let mut seen = s.order.clone();
        seen.sort_unstable();
        assert_eq!(seen, (0..field.num_voxels() as u32).collect::<Vec<_>>());
        for &(a, b) in &s.groups {
            let cell = basis.support_cell(s.points[s.order[a] as usize]);
            assert!(
                s.order[a..b]
                    .iter()
                    .all(|&i| basis.support_cell(s.points[i as usize]) == cell)
            );
        }
        // Every sample stays inside its voxel.
        let size = field.voxel_size();
        for (v, p) in s.points.iter().enumerate() {
            assert!(((*p - field.centre_of(v)).abs() - 0.5 * size).max_element() <= 1e-6);
        }
    }

    /// Scattered kernels (no cells): samples are grouped by 4³ bricks of voxels, each voxel's
    /// sample once, in voxel order inside a brick, and the same points as with cells.
    #[test]
    fn samples_without_cells_are_grouped_by_voxel_bricks() {
        let field = GridField::from_fn([9, 5, 6], Aabb::UNIT, 2, |x, out| out.fill(x.x)).unwrap();
        let centres = (0..field.num_voxels())
            .step_by(7)
            .map(|v| field.centre_of(v))
            .collect();
        let shepard = prt_kernels::Shepard::with_radius(centres, 0.6).unwrap();
        assert_eq!(shepard.num_support_cells(), 0);
        let hat = HatGrid::new([2, 2, 2], Aabb::UNIT).unwrap();
        let s = Samples::draw(&field, &shepard, 7, 0, true);
        assert_eq!(s.points, Samples::draw(&field, &hat, 7, 0, true).points);
        let mut seen = s.order.clone();
        seen.sort_unstable();
        assert_eq!(seen, (0..field.num_voxels() as u32).collect::<Vec<_>>());
        let dims = field.dims();
        let brick = |v: u32| {
            let v = v as usize;
            [
                v % dims[0],
                (v / dims[0]) % dims[1],
                v / (dims[0] * dims[1]),
            ]
            .map(|c| c / 4)
        };
        // ceil(9/4) · ceil(5/4) · ceil(6/4) = 3 · 2 · 2 bricks, none empty.
        assert_eq!(s.groups.len(), 12);
        for &(a, b) in &s.groups {
            let ids = &s.order[a..b];
            assert!(ids.iter().all(|&i| brick(i) == brick(ids[0])));
            assert!(ids.windows(2).all(|w| w[0] < w[1]));
            assert!(ids.len() <= 64);
        }
    }
}
