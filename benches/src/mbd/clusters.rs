//! Basis kernels that follow the field's values: clustered PCA's clusters as MBD basis
//! kernels (`mbd_walls`' `CLUSTER` controls, `mbd_clustered`; MBD sessions 7 and 8 in
//! `docs/results.md`).
//!
//! At each voxel centre, kernel `n` weighs the share of label `n` among the voxel's neighbours
//! within Chebyshev distance [`LabelSmoothing::radius`], each neighbour weighted
//! `falloff^(L1 distance)` (neighbours outside the validity mask do not spread their label);
//! between voxel centres the weights are interpolated trilinearly, clamped to the box of the
//! voxel centres like the field's own sampling. A convex combination of partitions of unity is
//! one, so the family is a non-negative, continuous partition of unity. Radius 0 is the sharp
//! cluster indicators.
//!
//! Kept in the sweeps rather than in `prt-mbd`: measured, the family does not pay for itself
//! (1.4× CPCA's error on traced Sponza against the hat grid's 1.84×, at 2–3.5× the CPU, and
//! worse than the hat grid on the smooth synthetic field), because MBD's coefficients are
//! trilinear per voxel while CPCA's labels change from voxel to voxel (80 % of Sponza's valid
//! voxels border another cluster): a basis that switches inside one voxel cell leaves cross
//! terms `c_A · b_B` the coefficients cannot follow.

use glam::Vec3;
use ndarray::{Array2, Array3, Axis};
use prt_core::{Aabb, CoreError, GridField, KernelWeights, NoProgress, SpatialKernels};
use prt_kernels::HatGrid;
use prt_mbd::{
    ClusterModel, MbdError, MbdModel, MbdOptions, SolveReport, solve, solve_from_basis,
    voxel_centre_box,
};

/// How [`LabelKernels`] smooth the voxel labels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LabelSmoothing {
    /// Chebyshev radius in voxels of the neighbourhood whose labels a voxel centre blends
    /// (default 1: the 3³ neighbours; 0: the sharp labels).
    pub radius: usize,
    /// Weight of a neighbour at L1 distance `d` voxels: `falloff^d`, in (0, 1] (default 0.5).
    pub falloff: f32,
}

impl Default for LabelSmoothing {
    fn default() -> Self {
        Self {
            radius: 1,
            falloff: 0.5,
        }
    }
}

/// The largest [`LabelSmoothing::radius`]: a 9³ neighbourhood.
pub const MAX_LABEL_RADIUS: usize = 4;

/// Basis kernels from per-voxel labels, smoothed over a neighbourhood and interpolated between
/// voxel centres (module docs).
#[derive(Debug, Clone)]
pub struct LabelKernels {
    dims: [usize; 3],
    bounds: Aabb,
    len: usize,
    labels: Vec<u32>,
    /// Per voxel, its weights `(kernel, weight)` in `entries[offsets[v]..offsets[v + 1]]`.
    offsets: Vec<usize>,
    entries: Vec<(u32, f32)>,
    max_support: usize,
}

impl LabelKernels {
    /// Kernels of the labels `labels` (one per voxel of a grid of `dims` over `bounds`, x
    /// fastest), `len` kernels (every label must be below it; a kernel without voxels is zero
    /// everywhere). Voxels outside `valid` (if given; e.g. inside geometry) do not spread their
    /// label to their neighbours (they keep it themselves).
    ///
    /// # Errors
    /// [`MbdError::ShapeMismatch`] when `labels` is not one per voxel;
    /// [`MbdError::InvalidOption`] for a label ≥ `len`, a radius above [`MAX_LABEL_RADIUS`] or
    /// a falloff outside (0, 1]; [`MbdError::InvalidKernels`] for an empty grid or `len` 0.
    pub fn new(
        dims: [usize; 3],
        bounds: Aabb,
        labels: &[u32],
        len: usize,
        valid: Option<&[bool]>,
        smoothing: &LabelSmoothing,
    ) -> Result<Self, MbdError> {
        let voxels: usize = dims.iter().product();
        if voxels == 0 || len == 0 {
            return Err(MbdError::InvalidKernels {
                which: "basis",
                why: format!("{len} labels on a {dims:?} grid"),
            });
        }
        if labels.len() != voxels {
            return Err(MbdError::ShapeMismatch {
                what: "labels",
                expected: vec![voxels],
                got: vec![labels.len()],
            });
        }
        if let Some(valid) = valid
            && valid.len() != voxels
        {
            return Err(MbdError::ShapeMismatch {
                what: "valid",
                expected: vec![voxels],
                got: vec![valid.len()],
            });
        }
        if let Some(v) = labels.iter().position(|&k| k as usize >= len) {
            return Err(MbdError::InvalidOption {
                what: "labels",
                why: format!("voxel {v} has label {}, not below {len}", labels[v]),
            });
        }
        if smoothing.radius > MAX_LABEL_RADIUS {
            return Err(MbdError::InvalidOption {
                what: "radius",
                why: format!("{} is above {MAX_LABEL_RADIUS}", smoothing.radius),
            });
        }
        if !(smoothing.falloff > 0.0 && smoothing.falloff <= 1.0) {
            return Err(MbdError::InvalidOption {
                what: "falloff",
                why: format!("{} is not in (0, 1]", smoothing.falloff),
            });
        }
        let r = smoothing.radius as i64;
        let mut offsets = Vec::with_capacity(voxels + 1);
        let mut entries: Vec<(u32, f32)> = Vec::new();
        offsets.push(0);
        let mut row: Vec<(u32, f64)> = Vec::new();
        for z in 0..dims[2] as i64 {
            for y in 0..dims[1] as i64 {
                for x in 0..dims[0] as i64 {
                    row.clear();
                    for dz in -r..=r {
                        for dy in -r..=r {
                            for dx in -r..=r {
                                let q = [x + dx, y + dy, z + dz];
                                if (0..3).any(|k| q[k] < 0 || q[k] >= dims[k] as i64) {
                                    continue;
                                }
                                let u = q[0] as usize
                                    + dims[0] * (q[1] as usize + dims[1] * q[2] as usize);
                                let own = dx == 0 && dy == 0 && dz == 0;
                                if !own && valid.is_some_and(|valid| !valid[u]) {
                                    continue;
                                }
                                let w = f64::from(smoothing.falloff)
                                    .powi((dx.abs() + dy.abs() + dz.abs()) as i32);
                                match row.iter_mut().find(|e| e.0 == labels[u]) {
                                    Some(e) => e.1 += w,
                                    None => row.push((labels[u], w)),
                                }
                            }
                        }
                    }
                    let total: f64 = row.iter().map(|e| e.1).sum();
                    row.sort_by_key(|e| e.0);
                    entries.extend(row.iter().map(|&(k, w)| (k, (w / total) as f32)));
                    offsets.push(entries.len());
                }
            }
        }
        let mut kernels = Self {
            dims,
            bounds,
            len,
            labels: labels.to_vec(),
            offsets,
            entries,
            max_support: 0,
        };
        kernels.max_support = kernels.largest_support();
        Ok(kernels)
    }

    /// The voxel labels.
    pub fn labels(&self) -> &[u32] {
        &self.labels
    }

    /// The kernel weights `(kernel, weight)` at the centre of voxel `v` (they sum to one).
    pub fn voxel_weights(&self, v: usize) -> &[(u32, f32)] {
        &self.entries[self.offsets[v]..self.offsets[v + 1]]
    }

    /// The most distinct kernels over the eight voxel centres around any point.
    fn largest_support(&self) -> usize {
        let d = self.dims;
        let mut seen: Vec<u32> = Vec::new();
        let mut largest = 1;
        for z in 0..d[2].saturating_sub(1).max(1) {
            for y in 0..d[1].saturating_sub(1).max(1) {
                for x in 0..d[0].saturating_sub(1).max(1) {
                    seen.clear();
                    for corner in 0..8 {
                        let c = [x, y, z];
                        let c = [0, 1, 2].map(|k| (c[k] + (corner >> k & 1)).min(d[k] - 1));
                        let v = c[0] + d[0] * (c[1] + d[1] * c[2]);
                        for &(i, _) in self.voxel_weights(v) {
                            if !seen.contains(&i) {
                                seen.push(i);
                            }
                        }
                    }
                    largest = largest.max(seen.len());
                }
            }
        }
        largest
    }
}

impl SpatialKernels for LabelKernels {
    fn len(&self) -> usize {
        self.len
    }

    fn max_support(&self) -> usize {
        self.max_support
    }

    fn domain(&self) -> Aabb {
        self.bounds
    }

    fn eval(&self, x: Vec3, out: &mut KernelWeights) -> Result<(), CoreError> {
        out.clear();
        if !x.is_finite() {
            return Err(CoreError::NonFinite {
                what: "query point",
                index: 0,
            });
        }
        let size = self.bounds.size();
        let mut cell = [0usize; 3];
        let mut t = [0.0f32; 3];
        for k in 0..3 {
            let last = (self.dims[k] - 1) as f32;
            let u = ((x[k] - self.bounds.min[k]) / size[k] * self.dims[k] as f32 - 0.5)
                .clamp(0.0, last);
            cell[k] = (u as usize).min(self.dims[k].saturating_sub(2));
            t[k] = u - cell[k] as f32;
        }
        for corner in 0..8 {
            let tw: f32 = (0..3)
                .map(|k| {
                    if corner >> k & 1 == 1 {
                        t[k]
                    } else {
                        1.0 - t[k]
                    }
                })
                .product();
            if tw <= 0.0 {
                continue;
            }
            let c = [0, 1, 2].map(|k| (cell[k] + (corner >> k & 1)).min(self.dims[k] - 1));
            let v = c[0] + self.dims[0] * (c[1] + self.dims[1] * c[2]);
            for &(i, w) in self.voxel_weights(v) {
                match out.indices.iter().position(|&j| j == i) {
                    Some(p) => out.weights[p] += tw * w,
                    None => out.push(i, tw * w),
                }
            }
        }
        Ok(())
    }
}

/// Rotates each `L × D` block of `bases` (orthonormal rows) inside its row space to be as close
/// as possible, in the Frobenius norm, to `reference` (`L × D`): orthogonal Procrustes,
/// `R = V Uᵀ` from the SVD `B Gᵀ = U S Vᵀ`.
pub fn align_to(bases: &mut Array3<f32>, reference: &Array2<f32>) -> Result<(), MbdError> {
    let g = reference.mapv(f64::from);
    for mut block in bases.axis_iter_mut(Axis(0)) {
        let b = block.mapv(f64::from);
        let m = b.dot(&g.t());
        let svd = prt_linalg::thin_svd(m.view()).map_err(|e| MbdError::InvalidOption {
            what: "initial basis",
            why: format!("Procrustes alignment failed: {e}"),
        })?;
        let rotation = svd.vt.t().dot(&svd.u.t());
        block.assign(&rotation.dot(&b).mapv(|x| x as f32));
    }
    Ok(())
}

/// Where [`fit_clustered`] starts the basis.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ClusterStart {
    /// Every kernel starts from the global principal subspace (the solver's default).
    GlobalPca,
    /// Each kernel starts from its cluster's subspace, rotated inside it to be as close as
    /// possible to the global principal subspace ([`align_to`]), so that neighbouring kernels'
    /// `l`-th vectors point the same way.
    AlignedClusters,
}

/// MBD with the default coefficient kernels and CPCA's clusters (`cpca`, fitted at
/// `options.rank`) as basis kernels, smoothed by `smoothing` over the field's valid voxels
/// (those not exactly zero, the baker's convention for voxels inside geometry).
///
/// # Errors
/// As [`LabelKernels::new`] and [`solve_from_basis`].
pub fn fit_clustered(
    field: &GridField,
    cpca: &ClusterModel,
    smoothing: &LabelSmoothing,
    start: ClusterStart,
    options: &MbdOptions,
) -> Result<(MbdModel<HatGrid, LabelKernels>, SolveReport), MbdError> {
    let valid: Vec<bool> = (0..field.num_voxels())
        .map(|v| field.voxel(v).iter().any(|&x| x != 0.0))
        .collect();
    let bases = cpca.bases();
    let kernels = LabelKernels::new(
        field.dims(),
        field.bounds(),
        cpca.labels(),
        bases.dim().0,
        Some(&valid),
        smoothing,
    )?;
    let coefficient_kernels = HatGrid::new(field.dims(), voxel_centre_box(field)).map_err(|e| {
        MbdError::InvalidKernels {
            which: "coefficient",
            why: e.to_string(),
        }
    })?;
    match start {
        ClusterStart::GlobalPca => solve(field, coefficient_kernels, kernels, options, &NoProgress),
        ClusterStart::AlignedClusters => {
            let global = prt_mbd::GlobalPca { rank: options.rank };
            let global = prt_core::Compressor::compress(&global, field, &NoProgress)?;
            let mut basis = bases.clone();
            align_to(
                &mut basis,
                &global.bases().index_axis(Axis(0), 0).to_owned(),
            )?;
            solve_from_basis(
                field,
                coefficient_kernels,
                kernels,
                &basis,
                options,
                &NoProgress,
            )
        }
    }
}
