//! The exact quadrature for basis kernels stored at the voxel centres
//! ([`crate::expert::LabelKernels`]).
//!
//! The basis `b(x) = Σ_n ψ_n(x) B_n` with `ψ_n(x) = Σ_v w_v(x) W_{v,n}` (the voxel centres'
//! rows `W_v`, blended by the same trilinear hats `w_v` as the coefficients and the target) is
//! trilinear between voxel centres, like `c(x)` and `f(x)`, and constant in the outer half
//! voxels. So the voxel centres (and the field's faces) are the only breakpoints: on each
//! voxel-centre cell the residual has degree ≤ 2 per axis and the 3-point rule per interval is
//! exact. The loss depends on the basis only through each voxel's blended basis
//! `β_v = Σ_n W_{v,n} B_n`, so both systems are assembled per voxel-centre cell from its eight
//! corners' rows (a few kernels each), whatever the union of kernels a cell blends: the
//! coefficient system from the corners' `β` (each voxel slice blended once), the basis system
//! per voxel over its neighbours' rows. The products of the corners' hats that a cell
//! integrates factor over the axes ([`CellHats`]), so no loop visits the quadrature points.

use std::ops::Range;

use ndarray::{Array2, ArrayView2, ArrayViewMut2, Axis as ArrayAxis, linalg::general_mat_mul, s};
use prt_core::{GridField, Progress};
use rayon::prelude::*;

use super::{
    Axis, BasisSystem, BoxSystem, CoefficientSystem, STORED_BLOCKS, add_pair_blocks, column_order,
    corner_voxel, neighbours, pair_block, symmetrise, zeroed,
};
use crate::MbdError;
use crate::voxel_weights::VoxelWeights;

/// Voxel-centre cells assembled in parallel before their contributions are added in cell
/// order (the sums do not depend on the thread count).
const CELL_BATCH: usize = 512;

/// The quadrature of a field with basis kernels stored at its voxel centres (module docs).
pub(super) struct VoxelQuadrature<'a> {
    weights: &'a VoxelWeights,
    /// Per axis, the hat integrals `(quartic, cubic)` of [`CellHats`] over each voxel-centre
    /// cell `i` (between centres `i` and `i + 1`; the first and last also hold the outer half
    /// voxels).
    hats: [Vec<AxisHats>; 3],
    voxels: [usize; 3],
    kernels: usize,
}

/// A voxel's share of the basis system: the kernels `n` of its neighbours' rows with their
/// `L × L` blocks of `Σ_u W_u ⊗ H_{v,u}` and their `L`-vectors `S_{v,n} = Σ_u W_{u,n} T_{v,u}`.
type VoxelBasisPart = (Vec<u32>, Vec<f64>, Vec<f64>);

/// Offsets `(dx, dy)` of the neighbours within a voxel slice whose Grams `β_v β_uᵀ` voxel `v`
/// holds (the other four are the transposes its neighbours hold).
const WITHIN_SLICE: [(isize, isize); 5] = [(0, 0), (1, 0), (-1, 1), (0, 1), (1, 1)];
/// Offsets `(dx, dy)` of the neighbours in the next voxel slice whose Grams voxel `v` holds:
/// all nine.
const ACROSS_SLICES: [(isize, isize); 9] = [
    (-1, -1),
    (0, -1),
    (1, -1),
    (-1, 0),
    (0, 0),
    (1, 0),
    (-1, 1),
    (0, 1),
    (1, 1),
];

/// The quadrature over one voxel-centre cell of products of its corners' trilinear hats
/// `φ_k = Π_a h_{k_a}(t_a)` (`h_0 = 1 − t`, `h_1 = t`; bit `a` of `k` is the step along axis `a`).
/// The hats and the quadrature factor over the axes, and a product of hats along an axis depends
/// only on how many of them are `t`: `quartic[a][q] = Σ w (1 − t)^{4−q} t^q` and
/// `cubic[a][q] = Σ w (1 − t)^{3−q} t^q` over the cell's points along axis `a`. The products
/// the systems need follow from these 27 numbers instead of a loop over the cell's points.
struct CellHats {
    quartic: [[f64; 5]; 3],
    cubic: [[f64; 4]; 3],
}

impl CellHats {
    /// `∫ φ_j φ_k φ_k'`.
    fn cubic(&self, j: usize, k: usize, k2: usize) -> f64 {
        (0..3)
            .map(|a| self.cubic[a][(j >> a & 1) + (k >> a & 1) + (k2 >> a & 1)])
            .product()
    }

    /// `Σ_{k,k'} ∫ φ_j φ_j' φ_k φ_k' X_kk'` for the corner pairs `j ≤ j'` in order, from the 64
    /// blocks `X_kk'` (`size` values each, at `8k + k'`): one pass per axis, each replacing that
    /// axis's bits of `(k, k')` by those of `(j, j')`.
    fn quartic(&self, mut x: Vec<f64>, size: usize, pairs: &[(usize, usize)]) -> Vec<f64> {
        let mut next = vec![0.0; x.len()];
        for axis in 0..3 {
            let bit = 1 << axis;
            for (e, out) in next.chunks_mut(size).enumerate() {
                let (j, j2) = (e >> 3, e & 7);
                let ones = (j >> axis & 1) + (j2 >> axis & 1);
                out.fill(0.0);
                for p in 0..2 {
                    for q in 0..2 {
                        let weight = self.quartic[axis][ones + p + q];
                        let k = (j & !bit) | p << axis;
                        let k2 = (j2 & !bit) | q << axis;
                        let src = &x[(8 * k + k2) * size..(8 * k + k2 + 1) * size];
                        for (o, &v) in out.iter_mut().zip(src) {
                            *o += weight * v;
                        }
                    }
                }
            }
            std::mem::swap(&mut x, &mut next);
        }
        pairs
            .iter()
            .flat_map(|&(j, j2)| {
                x[(8 * j + j2) * size..(8 * j + j2 + 1) * size]
                    .iter()
                    .copied()
            })
            .collect()
    }
}

/// One axis's factors of [`CellHats`] over one voxel-centre cell: `(quartic, cubic)`.
type AxisHats = ([f64; 5], [f64; 4]);

/// The corner pairs `k ≤ k'` of a voxel-centre cell, in the order of [`BoxSystem::a`].
fn corner_pairs() -> Vec<(usize, usize)> {
    (0..8).flat_map(|k| (k..8).map(move |m| (k, m))).collect()
}

impl<'a> VoxelQuadrature<'a> {
    /// The quadrature of `field` (at least 2 voxels per axis, checked by the caller) for the
    /// `kernels` kernels stored in `weights`, which must lie on the field's own voxels.
    pub(super) fn new(
        field: &GridField,
        weights: &'a VoxelWeights,
        kernels: usize,
    ) -> Result<Self, MbdError> {
        let voxels = field.dims();
        if weights.dims() != voxels || weights.bounds() != field.bounds() {
            return Err(MbdError::InvalidKernels {
                which: "basis",
                why: format!(
                    "the polish needs basis kernels stored on the field's voxels ({voxels:?} over \
                     {:?}), not {:?} over {:?}",
                    field.bounds(),
                    weights.dims(),
                    weights.bounds()
                ),
            });
        }
        let hats = [0, 1, 2].map(|k| {
            let axis = Axis::new(voxels[k], 2, (0.0, voxels[k] as f64));
            let mut hats = vec![([0.0; 5], [0.0; 4]); voxels[k] - 1];
            for p in &axis.points {
                // `ci` ≤ n − 2: the outer half voxels' points are the first and last cells'.
                let (quartic, cubic) = &mut hats[p.ci];
                let (t, s) = (p.ct, 1.0 - p.ct);
                for (q, o) in quartic.iter_mut().enumerate() {
                    *o += p.w * s.powi(4 - q as i32) * t.powi(q as i32);
                }
                for (q, o) in cubic.iter_mut().enumerate() {
                    *o += p.w * s.powi(3 - q as i32) * t.powi(q as i32);
                }
            }
            hats
        });
        Ok(Self {
            weights,
            hats,
            voxels,
            kernels,
        })
    }

    fn num_cells(&self) -> usize {
        self.voxels.iter().map(|n| n - 1).product()
    }

    /// The hat integrals of the voxel-centre cell whose lowest voxel is `lower`.
    fn cell_hats(&self, lower: [usize; 3]) -> CellHats {
        CellHats {
            quartic: [0, 1, 2].map(|a| self.hats[a][lower[a]].0),
            cubic: [0, 1, 2].map(|a| self.hats[a][lower[a]].1),
        }
    }

    /// Runs `assemble(lower, corners)` on the voxel-centre cells `cells` (its lowest voxel and
    /// its corners' indices) in parallel batches, and hands the results to `add` in cell order, so
    /// that the sums do not depend on the thread count.
    fn for_cells<T: Send>(
        &self,
        cells: Range<usize>,
        progress: &dyn Progress,
        assemble: impl Fn([usize; 3], [usize; 8]) -> T + Sync,
        mut add: impl FnMut([usize; 3], T),
    ) -> Result<(), MbdError> {
        let cells: Vec<usize> = cells.collect();
        for batch in cells.chunks(CELL_BATCH) {
            progress.check()?;
            let parts: Vec<([usize; 3], T)> = batch
                .par_iter()
                .map(|&index| {
                    let lower = self.lower(index);
                    let corners = std::array::from_fn(|k| corner_voxel(lower, k, self.voxels));
                    (lower, assemble(lower, corners))
                })
                .collect();
            for (lower, part) in parts {
                add(lower, part);
            }
        }
        Ok(())
    }

    /// The lowest voxel of voxel-centre cell `cell`.
    fn lower(&self, cell: usize) -> [usize; 3] {
        let [cx, cy, _] = self.voxels.map(|n| n - 1);
        [cell % cx, cell / cx % cy, cell / (cx * cy)]
    }

    /// The basis step's normal equations at coefficients `c`. The loss depends on the basis only
    /// through the voxels' blended bases `β_v = Σ_n W_{v,n} B_n`, and is quadratic in them with
    /// the 27-neighbour blocks `H_{v,u} = ∫ w_v w_u c cᵀ` and the right-hand sides
    /// `Σ_u T_{v,u} f_uᵀ`, `T_{v,u} = ∫ w_v w_u c`; so `G = Σ_{v,u} W_vᵀ W_u ⊗ H_{v,u}` and
    /// `R = Σ_v W_vᵀ ⊗ Σ_u T_{v,u} f_uᵀ`, whose cost grows with the rows' lengths (a few
    /// kernels) rather than with the cells' unions. As `T` is symmetric, `R`'s block of kernel
    /// `n` is `Σ_v S_{v,n} f_vᵀ` with `S_{v,n} = Σ_u W_{u,n} T_{v,u}`: `L`-vectors per voxel,
    /// then one GEMM per batch of voxels instead of an `L × D` sum at each.
    pub(super) fn basis_system(
        &self,
        field: &GridField,
        c: &[f64],
        l: usize,
        h: &mut Vec<f64>,
        progress: &dyn Progress,
    ) -> Result<BasisSystem, MbdError> {
        let (d, ll) = (field.dim(), l * l);
        let count: usize = self.voxels.iter().product();
        let corner_pairs = corner_pairs();
        zeroed(h, count * STORED_BLOCKS * ll);
        let mut t = vec![0.0; count * STORED_BLOCKS * l];
        self.for_cells(
            0..self.num_cells(),
            progress,
            |lower, corners| {
                // ∫ φ_k φ_k' c cᵀ and ∫ φ_k φ_k' c with c(x) = Σ_j φ_j c_j.
                let hats = self.cell_hats(lower);
                let mut outer = vec![0.0; 64 * ll];
                for (e, block) in outer.chunks_mut(ll).enumerate() {
                    let (cj, cj2) = (corners[e >> 3] * l, corners[e & 7] * l);
                    for (row, &x) in block.chunks_mut(l).zip(&c[cj..cj + l]) {
                        for (o, &y) in row.iter_mut().zip(&c[cj2..cj2 + l]) {
                            *o = x * y;
                        }
                    }
                }
                let a = hats.quartic(outer, ll, &corner_pairs);
                let mut moments = vec![0.0; corner_pairs.len() * l];
                for (out, &(k, k2)) in moments.chunks_mut(l).zip(&corner_pairs) {
                    for (j, &v) in corners.iter().enumerate() {
                        let weight = hats.cubic(j, k, k2);
                        for (o, &x) in out.iter_mut().zip(&c[v * l..(v + 1) * l]) {
                            *o += weight * x;
                        }
                    }
                }
                (a, moments)
            },
            |lower, (a, moments)| {
                add_pair_blocks(h, ll, lower, &a, self.voxels);
                add_pair_blocks(&mut t, l, lower, &moments, self.voxels);
            },
        )?;
        symmetrise(h, l);
        // Per voxel v (parallel batches, added in column order): Q_v = Σ_u W_u ⊗ H_{v,u} and
        // S_v over the kernels of its neighbours' rows; then G += W_vᵀ ⊗ Q_v and
        // R_n += S_{v,n} f_vᵀ.
        let unknowns = self.kernels * l;
        let mut gram = Array2::<f64>::zeros((unknowns, unknowns));
        let mut rhs = Array2::<f64>::zeros((unknowns, d));
        // In columns, so that the blocks read from backward neighbours are still in cache.
        let (voxels, _) = column_order(self.voxels);
        // The right-hand side's GEMM operands, reused from batch to batch.
        let (mut weights_buffer, mut values_buffer, mut sums_buffer) =
            (Vec::new(), Vec::new(), Vec::new());
        for batch in voxels.chunks(CELL_BATCH) {
            progress.check()?;
            let parts: Vec<VoxelBasisPart> = batch
                .par_iter()
                .map(|&v| {
                    let mut kernels: Vec<u32> = Vec::new();
                    let (mut q, mut sums): (Vec<f64>, Vec<f64>) = (Vec::new(), Vec::new());
                    for (nbr, u) in neighbours(v, self.voxels) {
                        // H's blocks are symmetric, T's are columns: both serve either voxel
                        // of their pair as stored.
                        let stored = pair_block(v, u, nbr);
                        let block = &h[stored * ll..(stored + 1) * ll];
                        let moment = &t[stored * l..(stored + 1) * l];
                        for (n, a) in self.weights.row(u) {
                            let j = match kernels.iter().position(|&m| m == n) {
                                Some(j) => j,
                                None => {
                                    kernels.push(n);
                                    q.resize(q.len() + ll, 0.0);
                                    sums.resize(sums.len() + l, 0.0);
                                    kernels.len() - 1
                                }
                            };
                            let a = f64::from(a);
                            for (o, &x) in q[j * ll..(j + 1) * ll].iter_mut().zip(block) {
                                *o += a * x;
                            }
                            for (o, &x) in sums[j * l..(j + 1) * l].iter_mut().zip(moment) {
                                *o += a * x;
                            }
                        }
                    }
                    (kernels, q, sums)
                })
                .collect();
            // G's rows of kernel n in parallel over n, each summing its voxels in batch order.
            let mut by_kernel: Vec<Vec<(usize, f64)>> = vec![Vec::new(); self.kernels];
            for (i, &v) in batch.iter().enumerate() {
                for (n, a) in self.weights.row(v) {
                    by_kernel[n as usize].push((i, f64::from(a)));
                }
            }
            if let Some(g) = gram.as_slice_mut() {
                g.par_chunks_mut(l * unknowns)
                    .zip(&by_kernel)
                    .for_each(|(rows, voxels)| {
                        for &(i, a) in voxels {
                            let (kernels, q, _) = &parts[i];
                            for (&n2, block) in kernels.iter().zip(q.chunks(ll)) {
                                for (row, src) in rows.chunks_mut(unknowns).zip(block.chunks(l)) {
                                    let at = n2 as usize * l;
                                    for (o, &x) in row[at..at + l].iter_mut().zip(src) {
                                        *o += a * x;
                                    }
                                }
                            }
                        }
                    });
            }
            // R_n += Σ_v S_{v,n} f_vᵀ over the batch's voxels: one GEMM over the kernels the
            // batch touches.
            let mut columns = vec![usize::MAX; self.kernels];
            let mut touched: Vec<u32> = Vec::new();
            for (kernels, _, _) in &parts {
                for &n in kernels {
                    if columns[n as usize] == usize::MAX {
                        columns[n as usize] = touched.len();
                        touched.push(n);
                    }
                }
            }
            let shape = (batch.len(), touched.len() * l);
            zeroed(&mut weights_buffer, shape.0 * shape.1);
            let mut weights = ArrayViewMut2::from_shape(shape, &mut weights_buffer[..])
                .expect("the buffer has the batch's shape");
            for (mut row, (kernels, _, sums)) in weights.rows_mut().into_iter().zip(&parts) {
                for (&n, sum) in kernels.iter().zip(sums.chunks(l)) {
                    let at = columns[n as usize] * l;
                    row.slice_mut(s![at..at + l])
                        .iter_mut()
                        .zip(sum)
                        .for_each(|(o, &x)| *o = x);
                }
            }
            values_buffer.clear();
            values_buffer.extend(
                batch
                    .iter()
                    .flat_map(|&v| field.voxel(v).iter().map(|&x| f64::from(x))),
            );
            let values = ArrayView2::from_shape((batch.len(), d), &values_buffer[..])
                .expect("the buffer has the batch's shape");
            zeroed(&mut sums_buffer, touched.len() * l * d);
            let mut sums = ArrayViewMut2::from_shape((touched.len() * l, d), &mut sums_buffer[..])
                .expect("the buffer has the sums' shape");
            general_mat_mul(1.0, &weights.t(), &values, 0.0, &mut sums);
            for (&n, sum) in touched.iter().zip(sums.axis_chunks_iter(ArrayAxis(0), l)) {
                let at = n as usize * l;
                let mut rows = rhs.slice_mut(s![at..at + l, ..]);
                rows += &sum;
            }
        }
        Ok(BasisSystem { gram, rhs })
    }

    /// Adds the coefficient step's normal equations at basis `b` (`N·L × D` rows, without the
    /// ridge) to `system`: per cell, `∫ φ_k φ_k' b(x) b(x)ᵀ` for its corner pairs and
    /// `∫ φ_k b(x) f(x)`.
    pub(super) fn add_coefficient_system(
        &self,
        field: &GridField,
        b: &[f64],
        l: usize,
        system: &mut CoefficientSystem,
        progress: &dyn Progress,
    ) -> Result<(), MbdError> {
        let d = field.dim();
        let ll = l * l;
        let corner_pairs = corner_pairs();
        if b.len() != self.kernels * l * d {
            return Err(MbdError::ShapeMismatch {
                what: "basis rows",
                expected: vec![self.kernels * l * d],
                got: vec![b.len()],
            });
        }
        let [nx, ny, nz] = self.voxels;
        let (slice, cells_per_slab) = (nx * ny, (nx - 1) * (ny - 1));
        // The slab of cells between voxel slices z and z + 1 blends the bases of those two
        // slices, each blended once rather than at each of its eight cells, and takes the Grams
        // β_v β_uᵀ of neighbouring voxels, each computed once rather than at each cell that has
        // both as corners (up to eight).
        // Two slices' buffers, reused from slab to slab (fresh ones cost page faults).
        let mut below = Array2::<f64>::zeros((slice * l, d));
        let mut above = Array2::<f64>::zeros((slice * l, d));
        let (mut within_below, mut within_above, mut across) = (Vec::new(), Vec::new(), Vec::new());
        self.blend_bases(b, l, 0, &mut below);
        self.neighbour_grams(&below, &below, &WITHIN_SLICE, l, &mut within_below);
        for z in 0..nz - 1 {
            self.blend_bases(b, l, z + 1, &mut above);
            self.neighbour_grams(&above, &above, &WITHIN_SLICE, l, &mut within_above);
            self.neighbour_grams(&below, &above, &ACROSS_SLICES, l, &mut across);
            let slices = [&below, &above];
            let within = [&within_below, &within_above];
            // β_k β_k'ᵀ for corners k, k' of the cell: stored from one of the two, transposed
            // when stored from the other.
            let corner_gram = |corners: &[usize; 8], k: usize, k2: usize, out: &mut [f64]| {
                let at = |k: usize| corners[k] - (z + (k >> 2)) * slice;
                let step = |k: usize, k2: usize| {
                    let bit = |k: usize, a: usize| (k >> a & 1) as isize;
                    (bit(k2, 0) - bit(k, 0), bit(k2, 1) - bit(k, 1))
                };
                let slot = |offsets: &[(isize, isize)], d| {
                    offsets
                        .iter()
                        .position(|&o| o == d)
                        .expect("a cell's corners are neighbours")
                };
                let (grams, offsets, from, d, transpose) = match (k >> 2).cmp(&(k2 >> 2)) {
                    std::cmp::Ordering::Equal => {
                        let d = step(k, k2);
                        if WITHIN_SLICE.contains(&d) {
                            (within[k >> 2], &WITHIN_SLICE[..], at(k), d, false)
                        } else {
                            (within[k >> 2], &WITHIN_SLICE[..], at(k2), step(k2, k), true)
                        }
                    }
                    std::cmp::Ordering::Less => {
                        (&across, &ACROSS_SLICES[..], at(k), step(k, k2), false)
                    }
                    std::cmp::Ordering::Greater => {
                        (&across, &ACROSS_SLICES[..], at(k2), step(k2, k), true)
                    }
                };
                let start = (from * offsets.len() + slot(offsets, d)) * ll;
                let block = &grams[start..start + ll];
                for i in 0..l {
                    for j in 0..l {
                        out[i * l + j] = if transpose {
                            block[j * l + i]
                        } else {
                            block[i * l + j]
                        };
                    }
                }
            };
            self.for_cells(
                z * cells_per_slab..(z + 1) * cells_per_slab,
                progress,
                |lower, corners| {
                    // The corners' blended bases β_k (8L × D) and their products with the
                    // corners' values (one GEMM).
                    let mut beta = Array2::<f64>::zeros((8 * l, d));
                    for (k, mut rows) in beta.axis_chunks_iter_mut(ArrayAxis(0), l).enumerate() {
                        let upper = k >> 2;
                        let at = corners[k] - (z + upper) * slice;
                        rows.assign(&slices[upper].slice(s![at * l..(at + 1) * l, ..]));
                    }
                    let f = Array2::from_shape_fn((d, 8), |(i, k)| {
                        f64::from(field.voxel(corners[k])[i])
                    });
                    let mut products = Array2::<f64>::zeros((8 * l, 8));
                    general_mat_mul(1.0, &beta, &f, 0.0, &mut products);
                    // ∫ φ_j φ_j' b bᵀ and ∫ φ_j b f with b(x) b(x)ᵀ = Σ_{k,k'} φ_k φ_k' β_k β_k'ᵀ
                    // and b(x) f(x) = Σ_{k,k'} φ_k φ_k' β_k f_k'.
                    let hats = self.cell_hats(lower);
                    let mut blocks = vec![0.0; 64 * ll];
                    for (e, block) in blocks.chunks_mut(ll).enumerate() {
                        corner_gram(&corners, e >> 3, e & 7, block);
                    }
                    let a = hats.quartic(blocks, ll, &corner_pairs);
                    let mut r = vec![0.0; 8 * l];
                    for (j, out) in r.chunks_mut(l).enumerate() {
                        for e in 0..64 {
                            let weight = hats.cubic(j, e >> 3, e & 7);
                            for (o, &x) in out.iter_mut().zip(
                                &products
                                    .column(e & 7)
                                    .slice(s![(e >> 3) * l..(e >> 3) * l + l]),
                            ) {
                                *o += weight * x;
                            }
                        }
                    }
                    BoxSystem { lower, a, r }
                },
                |_, boxed| system.add(&boxed, self.voxels),
            )?;
            std::mem::swap(&mut below, &mut above);
            std::mem::swap(&mut within_below, &mut within_above);
        }
        Ok(())
    }

    /// `β_v β_uᵀ` (`L × L`, row-major) for every voxel `v` of the slice whose blended bases are
    /// `from` and its neighbours `u` at `offsets` `(dx, dy)` in slice `to`, `offsets.len()`
    /// blocks per voxel, written over `grams`; those of neighbours outside the grid are zero. One
    /// GEMM per voxel and neighbour row.
    fn neighbour_grams(
        &self,
        from: &Array2<f64>,
        to: &Array2<f64>,
        offsets: &[(isize, isize)],
        l: usize,
        grams: &mut Vec<f64>,
    ) {
        let [nx, ny, _] = self.voxels.map(|n| n as isize);
        let ll = l * l;
        zeroed(grams, (nx * ny) as usize * offsets.len() * ll);
        grams
            .par_chunks_mut(offsets.len() * ll)
            .enumerate()
            .for_each(|(i, out)| {
                let (x, y) = ((i as isize) % nx, (i as isize) / nx);
                let bv = from.slice(s![i * l..(i + 1) * l, ..]);
                for dy in -1..=1 {
                    let dxs = || offsets.iter().enumerate().filter(move |(_, o)| o.1 == dy);
                    let lo = dxs().map(|(_, o)| o.0).min().map(|dx| dx.max(-x));
                    let hi = dxs().map(|(_, o)| o.0).max().map(|dx| dx.min(nx - 1 - x));
                    let (Some(lo), Some(hi)) = (lo, hi) else {
                        continue;
                    };
                    if y + dy < 0 || y + dy >= ny || lo > hi {
                        continue;
                    }
                    let start = ((y + dy) * nx + x + lo) as usize;
                    let count = (hi - lo + 1) as usize;
                    let bu = to.slice(s![start * l..(start + count) * l, ..]);
                    let mut g = Array2::<f64>::zeros((l, count * l));
                    general_mat_mul(1.0, &bv, &bu.t(), 0.0, &mut g);
                    for (slot, &(dx, _)) in dxs() {
                        if dx < lo || dx > hi {
                            continue;
                        }
                        let column = (dx - lo) as usize * l;
                        let block = g.slice(s![.., column..column + l]);
                        for (o, &v) in out[slot * ll..(slot + 1) * ll].iter_mut().zip(block) {
                            *o = v;
                        }
                    }
                }
            });
    }

    /// The blended bases `β_v = Σ_n W_{v,n} B_n` of voxel slice `z` (`L` rows of `D` per voxel),
    /// written over `beta`.
    fn blend_bases(&self, b: &[f64], l: usize, z: usize, beta: &mut Array2<f64>) {
        let d = beta.ncols();
        let slice = self.voxels[0] * self.voxels[1];
        if let Some(out) = beta.as_slice_mut() {
            out.par_chunks_mut(l * d).enumerate().for_each(|(i, out)| {
                out.fill(0.0);
                for (n, a) in self.weights.row(z * slice + i) {
                    let src = &b[n as usize * l * d..(n as usize + 1) * l * d];
                    for (o, &x) in out.iter_mut().zip(src) {
                        *o += f64::from(a) * x;
                    }
                }
            });
        }
    }
}
