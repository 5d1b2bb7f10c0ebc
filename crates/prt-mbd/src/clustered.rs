//! Basis kernels that follow the field's values rather than a grid ([`crate::Basis::Clusters`],
//! beyond the paper).
//!
//! A hat basis node serves whatever transfer its cell holds. Where transfer changes with
//! geometry on scales finer than a basis cell (columns, arches, openings), clustered PCA, which
//! groups voxels by *value* and switches subspaces from voxel to voxel, stays far ahead of MBD
//! on the hat grid at the same number of basis vectors. These kernels give MBD the same
//! grouping while keeping the reconstruction continuous:
//!
//! 1. **Clusters.** [`crate::ClusteredPca`] (Sloan et al. 2003) with one cluster per basis
//!    kernel labels every voxel.
//! 2. **Kernels.** [`LabelKernels`]: at each voxel centre, kernel `n` weighs the share of label
//!    `n` among the voxel's neighbours within Chebyshev distance [`LabelSmoothing::radius`],
//!    each neighbour weighted `falloff^(L1 distance)`; voxels inside geometry (exactly zero,
//!    the baker's convention) do not spread their label. Between voxel centres the weights are
//!    interpolated trilinearly (clamped to the box of the voxel centres, like the field's own
//!    sampling). A convex combination of partitions of unity is one, so the family is a
//!    non-negative, continuous partition of unity, and the model is continuous.
//! 3. **Start.** Each kernel's basis starts from its cluster's subspace, rotated inside it
//!    (orthogonal Procrustes) to be as close as possible to the global principal subspace, so
//!    that neighbouring kernels' `l`-th vectors point the same way and blend without
//!    cancelling; then the stochastic solver runs as for any kernels.
//!
//! **Why smoothing.** MBD's coefficients are trilinear at voxel resolution, so a basis that
//! switches inside one voxel cell leaves cross terms `c_A · b_B` that the coefficients cannot
//! follow; the default radius 2 blends over about five voxels.

use glam::Vec3;
use ndarray::{Array2, Array3, Axis};
use prt_core::{Aabb, CoreError, KernelWeights, SpatialKernels};
use rayon::prelude::*;

use crate::MbdError;
use crate::voxel_weights::VoxelWeights;

/// How [`LabelKernels`] smooth the voxel labels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LabelSmoothing {
    /// Chebyshev radius in voxels of the neighbourhood whose labels a voxel centre blends
    /// (default 2: the 5³ neighbours; 0: the sharp labels).
    pub radius: usize,
    /// Weight of a neighbour at L1 distance `d` voxels: `falloff^d`, in (0, 1] (default 0.5).
    pub falloff: f32,
}

impl Default for LabelSmoothing {
    fn default() -> Self {
        Self {
            radius: 2,
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
    len: usize,
    labels: Vec<u32>,
    weights: VoxelWeights,
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
    /// a falloff outside (0, 1] or more than 2^32 voxels; [`MbdError::InvalidKernels`] for an
    /// empty grid, `len` 0 or a box of zero extent.
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
        VoxelWeights::voxel_count(dims, bounds)?;
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
        let falloff = f64::from(smoothing.falloff);
        let row = |v: usize| {
            let c = [
                v % dims[0],
                (v / dims[0]) % dims[1],
                v / (dims[0] * dims[1]),
            ]
            .map(|x| x as i64);
            let mut row: Vec<(u32, f64)> = Vec::new();
            for dz in -r..=r {
                for dy in -r..=r {
                    for dx in -r..=r {
                        let q = [c[0] + dx, c[1] + dy, c[2] + dz];
                        if (0..3).any(|k| q[k] < 0 || q[k] >= dims[k] as i64) {
                            continue;
                        }
                        let u = q[0] as usize + dims[0] * (q[1] as usize + dims[1] * q[2] as usize);
                        let own = u == v;
                        if !own && valid.is_some_and(|valid| !valid[u]) {
                            continue;
                        }
                        let w = falloff.powi((dx.abs() + dy.abs() + dz.abs()) as i32);
                        match row.iter_mut().find(|e| e.0 == labels[u]) {
                            Some(e) => e.1 += w,
                            None => row.push((labels[u], w)),
                        }
                    }
                }
            }
            let total: f64 = row.iter().map(|e| e.1).sum();
            row.sort_by_key(|e| e.0);
            row.into_iter()
                .map(|(k, w)| (k, (w / total) as f32))
                .collect::<Vec<_>>()
        };
        let rows: Vec<Vec<(u32, f32)>> = (0..voxels).into_par_iter().map(row).collect();
        Ok(Self {
            len,
            labels: labels.to_vec(),
            weights: VoxelWeights::new(dims, bounds, rows),
        })
    }

    /// The voxel labels.
    pub fn labels(&self) -> &[u32] {
        &self.labels
    }

    /// The kernel weights `(kernel, weight)` at the centre of voxel `v` (they sum to one);
    /// empty for `v` out of range.
    pub fn voxel_weights(&self, v: usize) -> impl Iterator<Item = (u32, f32)> + '_ {
        self.weights.row(v)
    }
}

impl crate::polish::sealed::Sealed for LabelKernels {
    fn layout(&self) -> crate::polish::BasisLayout<'_> {
        crate::polish::BasisLayout::Voxels(&self.weights)
    }
}

impl crate::polish::PolishBasis for LabelKernels {}

impl SpatialKernels for LabelKernels {
    fn len(&self) -> usize {
        self.len
    }

    fn max_support(&self) -> usize {
        self.weights.max_support()
    }

    fn domain(&self) -> Aabb {
        self.weights.bounds()
    }

    /// The trilinear blend of the eight surrounding voxel centres' weights; points outside the
    /// box are clamped to it.
    fn eval(&self, x: Vec3, out: &mut KernelWeights) -> Result<(), CoreError> {
        self.weights.eval(x, out)
    }
}

/// Rotates each `L × D` block of `bases` (orthonormal rows) inside its row space to be as close
/// as possible, in the Frobenius norm, to `reference` (`L × D`): orthogonal Procrustes,
/// `R = V Uᵀ` from the SVD `B Gᵀ = U S Vᵀ`.
pub(crate) fn align_to(bases: &mut Array3<f32>, reference: &Array2<f32>) -> Result<(), MbdError> {
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
