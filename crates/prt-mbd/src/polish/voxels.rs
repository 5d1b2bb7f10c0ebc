//! The exact quadrature for basis kernels stored at the voxel centres ([`crate::WallAware`],
//! [`crate::LabelKernels`]).
//!
//! The basis `b(x) = Σ_n ψ_n(x) B_n` with `ψ_n(x) = Σ_v w_v(x) W_{v,n}` (the voxel centres'
//! rows `W_v`, blended by the same trilinear hats `w_v` as the coefficients and the target) is
//! trilinear between voxel centres, like `c(x)` and `f(x)`, and constant in the outer half
//! voxels. So the voxel centres (and the field's faces) are the only breakpoints: on each
//! voxel-centre cell the residual has degree ≤ 2 per axis and the 3-point rule per interval is
//! exact. The loss depends on the basis only through each voxel's blended basis
//! `β_v = Σ_n W_{v,n} B_n`, so both systems are assembled per voxel-centre cell from its eight
//! corners' rows (a few kernels each), whatever the union of kernels a cell blends.

use std::ops::Range;

use ndarray::{Array2, linalg::general_mat_mul};
use prt_core::{GridField, Progress};
use rayon::prelude::*;

use super::{
    Axis, BasisSystem, BoxSystem, CoefficientSystem, add_pair_blocks, corner_voxel, zeroed,
};
use crate::MbdError;
use crate::voxel_weights::VoxelWeights;

/// Voxel-centre cells assembled in parallel before their contributions are added in cell
/// order (the sums do not depend on the thread count).
const CELL_BATCH: usize = 512;

/// The quadrature of a field with basis kernels stored at its voxel centres (module docs).
pub(super) struct VoxelQuadrature<'a> {
    weights: &'a VoxelWeights,
    axes: [Axis; 3],
    /// Per axis, the points of each voxel-centre cell `i` (between centres `i` and `i + 1`;
    /// the first and last also hold the outer half voxels).
    runs: [Vec<Range<usize>>; 3],
    voxels: [usize; 3],
    kernels: usize,
}

/// A voxel's share of the basis system: the kernels of its neighbours' rows with their
/// `L × L` blocks of `Σ_u W_u ⊗ H_{v,u}`, and its `L × D` right-hand side `Σ_u T_{v,u} f_uᵀ`.
type VoxelBasisPart = (Vec<u32>, Vec<f64>, Vec<f64>);

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
        let axes = [0, 1, 2].map(|k| Axis::new(voxels[k], 2, (0.0, voxels[k] as f64)));
        let runs = [0, 1, 2].map(|k| {
            let points = &axes[k].points;
            (0..voxels[k] - 1)
                .map(|i| {
                    points.partition_point(|p| p.ci < i)..points.partition_point(|p| p.ci <= i)
                })
                .collect()
        });
        Ok(Self {
            weights,
            axes,
            runs,
            voxels,
            kernels,
        })
    }

    fn num_cells(&self) -> usize {
        self.voxels.iter().map(|n| n - 1).product()
    }

    /// Calls `visit(w, φ)` for every quadrature point of the voxel-centre cell whose lowest
    /// voxel is `lower`: the point's weight and the eight corners' hat weights.
    fn for_points(&self, lower: [usize; 3], mut visit: impl FnMut(f64, &[f64; 8])) {
        let mut phi = [0.0; 8];
        let ranges = [0, 1, 2].map(|k| self.runs[k][lower[k]].clone());
        for pz in &self.axes[2].points[ranges[2].clone()] {
            for py in &self.axes[1].points[ranges[1].clone()] {
                for px in &self.axes[0].points[ranges[0].clone()] {
                    let t = [px.ct, py.ct, pz.ct];
                    for (k, o) in phi.iter_mut().enumerate() {
                        *o = (0..3)
                            .map(|a| if k >> a & 1 == 1 { t[a] } else { 1.0 - t[a] })
                            .product();
                    }
                    visit(px.w * py.w * pz.w, &phi);
                }
            }
        }
    }

    /// Runs `assemble(lower, corners)` on every voxel-centre cell (its lowest voxel and its
    /// corners' indices) in parallel batches, and hands the results to `add` in cell order, so
    /// that the sums do not depend on the thread count.
    fn for_cells<T: Send>(
        &self,
        progress: &dyn Progress,
        assemble: impl Fn([usize; 3], [usize; 8]) -> T + Sync,
        mut add: impl FnMut([usize; 3], T),
    ) -> Result<(), MbdError> {
        let cells: Vec<usize> = (0..self.num_cells()).collect();
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
    /// kernels) rather than with the cells' unions.
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
        zeroed(h, count * 27 * ll);
        let mut t = vec![0.0; count * 27 * l];
        self.for_cells(
            progress,
            |lower, corners| {
                let mut a = vec![0.0; corner_pairs.len() * ll];
                let mut moments = vec![0.0; corner_pairs.len() * l];
                let (mut cx, mut cc) = (vec![0.0; l], vec![0.0; ll]);
                self.for_points(lower, |w, phi| {
                    cx.fill(0.0);
                    for k in 0..8 {
                        let ck = &c[corners[k] * l..(corners[k] + 1) * l];
                        for (o, &x) in cx.iter_mut().zip(ck) {
                            *o += phi[k] * x;
                        }
                    }
                    for i in 0..l {
                        for j in 0..l {
                            cc[i * l + j] = cx[i] * cx[j];
                        }
                    }
                    for (pair, &(k, k2)) in corner_pairs.iter().enumerate() {
                        let weight = w * phi[k] * phi[k2];
                        if weight == 0.0 {
                            continue;
                        }
                        for (o, &x) in a[pair * ll..(pair + 1) * ll].iter_mut().zip(&cc) {
                            *o += weight * x;
                        }
                        for (o, &x) in moments[pair * l..(pair + 1) * l].iter_mut().zip(&cx) {
                            *o += weight * x;
                        }
                    }
                });
                (a, moments)
            },
            |lower, (a, moments)| {
                add_pair_blocks(h, [l, l], lower, &a, self.voxels);
                add_pair_blocks(&mut t, [l, 1], lower, &moments, self.voxels);
            },
        )?;
        // Per voxel v (parallel batches, added in voxel order): Q_v = Σ_u W_u ⊗ H_{v,u} over
        // the kernels of its neighbours' rows and R_v = Σ_u T_{v,u} f_uᵀ; then
        // G += W_vᵀ ⊗ Q_v and R += W_vᵀ ⊗ R_v.
        let unknowns = self.kernels * l;
        let mut gram = Array2::<f64>::zeros((unknowns, unknowns));
        let mut rhs = Array2::<f64>::zeros((unknowns, d));
        let voxels: Vec<usize> = (0..count).collect();
        for batch in voxels.chunks(CELL_BATCH) {
            progress.check()?;
            let parts: Vec<VoxelBasisPart> = batch
                .par_iter()
                .map(|&v| {
                    let mut kernels: Vec<u32> = Vec::new();
                    let mut q: Vec<f64> = Vec::new();
                    let mut r = vec![0.0; l * d];
                    for (nbr, u) in self.neighbours(v) {
                        let block = &h[(v * 27 + nbr) * ll..(v * 27 + nbr + 1) * ll];
                        for (n, a) in self.weights.row(u) {
                            let j = match kernels.iter().position(|&m| m == n) {
                                Some(j) => j,
                                None => {
                                    kernels.push(n);
                                    q.resize(q.len() + ll, 0.0);
                                    kernels.len() - 1
                                }
                            };
                            let a = f64::from(a);
                            for (o, &x) in q[j * ll..(j + 1) * ll].iter_mut().zip(block) {
                                *o += a * x;
                            }
                        }
                        let moment = &t[(v * 27 + nbr) * l..(v * 27 + nbr + 1) * l];
                        let fu = field.voxel(u);
                        for (row, &m) in r.chunks_mut(d).zip(moment) {
                            for (o, &x) in row.iter_mut().zip(fu) {
                                *o += m * f64::from(x);
                            }
                        }
                    }
                    (kernels, q, r)
                })
                .collect();
            let g = gram.as_slice_mut().unwrap_or(&mut []);
            let out = rhs.as_slice_mut().unwrap_or(&mut []);
            for (&v, (kernels, q, r)) in batch.iter().zip(&parts) {
                for (n, a) in self.weights.row(v) {
                    let a = f64::from(a);
                    for (&n2, block) in kernels.iter().zip(q.chunks(ll)) {
                        for i in 0..l {
                            let at = (n as usize * l + i) * unknowns + n2 as usize * l;
                            for (o, &x) in g[at..at + l].iter_mut().zip(&block[i * l..(i + 1) * l])
                            {
                                *o += a * x;
                            }
                        }
                    }
                    let at = n as usize * l * d;
                    for (o, &x) in out[at..at + l * d].iter_mut().zip(r) {
                        *o += a * x;
                    }
                }
            }
        }
        Ok(BasisSystem { gram, rhs })
    }

    /// The neighbours `u` of voxel `v` in its 3³ block that lie in the grid, with their index
    /// `(dx+1) + 3(dy+1) + 9(dz+1)`.
    fn neighbours(&self, v: usize) -> impl Iterator<Item = (usize, usize)> + '_ {
        let [nx, ny, nz] = self.voxels;
        let at = [v % nx, v / nx % ny, v / (nx * ny)];
        (0..27).filter_map(move |nbr| {
            // Coordinates shifted by one, so that −1 is 0.
            let q = [0, 1, 2].map(|k| at[k] + [nbr % 3, nbr / 3 % 3, nbr / 9][k]);
            if (0..3).any(|k| q[k] == 0 || q[k] > [nx, ny, nz][k]) {
                return None;
            }
            Some((nbr, (q[0] - 1) + nx * ((q[1] - 1) + ny * (q[2] - 1))))
        })
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
        self.for_cells(
            progress,
            |lower, corners| {
                // The corners' blended bases β_k = Σ_n W_{k,n} B_n (8L × D), their Gram and
                // their products with the corners' values (one GEMM each).
                let mut beta = Array2::<f64>::zeros((8 * l, d));
                {
                    let out = beta.as_slice_mut().unwrap_or(&mut []);
                    for (k, &v) in corners.iter().enumerate() {
                        let out = &mut out[k * l * d..(k + 1) * l * d];
                        for (n, a) in self.weights.row(v) {
                            let src = &b[n as usize * l * d..(n as usize + 1) * l * d];
                            for (o, &x) in out.iter_mut().zip(src) {
                                *o += f64::from(a) * x;
                            }
                        }
                    }
                }
                let mut gram = Array2::<f64>::zeros((8 * l, 8 * l));
                general_mat_mul(1.0, &beta, &beta.t(), 0.0, &mut gram);
                let f =
                    Array2::from_shape_fn((d, 8), |(i, k)| f64::from(field.voxel(corners[k])[i]));
                let mut products = Array2::<f64>::zeros((8 * l, 8));
                general_mat_mul(1.0, &beta, &f, 0.0, &mut products);
                // b(x) b(x)ᵀ = Σ_{k ≤ k'} φ_k φ_k' K_kk', the pair standing for both orders.
                let mut pair_gram = vec![0.0; corner_pairs.len() * ll];
                for (pair, &(k, k2)) in corner_pairs.iter().enumerate() {
                    for i in 0..l {
                        for j in 0..l {
                            let mut x = gram[[k * l + i, k2 * l + j]];
                            if k != k2 {
                                x += gram[[k2 * l + i, k * l + j]];
                            }
                            pair_gram[pair * ll + i * l + j] = x;
                        }
                    }
                }
                // b(x) f(x) = Σ_k Σ_k' φ_k φ_k' β_k f_k'.
                let projections: Vec<f64> = (0..64)
                    .flat_map(|e| {
                        let (k, k2) = (e / 8, e % 8);
                        let products = &products;
                        (0..l).map(move |i| products[[k * l + i, k2]])
                    })
                    .collect();
                let mut a = vec![0.0; corner_pairs.len() * ll];
                let mut r = vec![0.0; 8 * l];
                let (mut m, mut s) = (vec![0.0; ll], vec![0.0; l]);
                self.for_points(lower, |w, phi| {
                    m.fill(0.0);
                    for (pair, &(k, k2)) in corner_pairs.iter().enumerate() {
                        let weight = phi[k] * phi[k2];
                        if weight == 0.0 {
                            continue;
                        }
                        for (o, &x) in m.iter_mut().zip(&pair_gram[pair * ll..(pair + 1) * ll]) {
                            *o += weight * x;
                        }
                    }
                    s.fill(0.0);
                    for k in 0..8 {
                        for k2 in 0..8 {
                            let weight = phi[k] * phi[k2];
                            if weight == 0.0 {
                                continue;
                            }
                            let p = &projections[(k * 8 + k2) * l..(k * 8 + k2 + 1) * l];
                            for (o, &x) in s.iter_mut().zip(p) {
                                *o += weight * x;
                            }
                        }
                    }
                    for (pair, &(k, k2)) in corner_pairs.iter().enumerate() {
                        let weight = w * phi[k] * phi[k2];
                        if weight == 0.0 {
                            continue;
                        }
                        for (o, &x) in a[pair * ll..(pair + 1) * ll].iter_mut().zip(&m) {
                            *o += weight * x;
                        }
                    }
                    for k in 0..8 {
                        let weight = w * phi[k];
                        for (o, &x) in r[k * l..(k + 1) * l].iter_mut().zip(&s) {
                            *o += weight * x;
                        }
                    }
                });
                BoxSystem { lower, a, r }
            },
            |_, boxed| system.add(&boxed, self.voxels),
        )
    }
}
