//! Kernel weights stored at voxel centres and blended trilinearly between them: the storage
//! and evaluation of [`crate::expert::LabelKernels`].

use glam::Vec3;
use prt_core::{Aabb, CoreError, KernelWeights};
use rayon::prelude::*;

use crate::MbdError;

/// Per-voxel `(kernel, weight)` rows on a `dims` grid over `bounds` (CSR), evaluated anywhere
/// as the trilinear blend of the eight surrounding voxel centres' rows, clamped to the box of
/// the voxel centres like the field's own sampling. If every row is a non-negative partition
/// of unity, so is the blend, and it is continuous.
#[derive(Debug, Clone)]
pub struct VoxelWeights {
    dims: [usize; 3],
    bounds: Aabb,
    origin: [f64; 3],
    /// Voxels per unit length, per axis.
    scale: [f64; 3],
    /// Voxel `v`'s row is `offsets[v]..offsets[v + 1]` into `indices` / `weights`.
    offsets: Vec<usize>,
    indices: Vec<u32>,
    weights: Vec<f32>,
    max_support: usize,
}

impl VoxelWeights {
    /// The number of voxels of a `dims` grid over `bounds`, after checking that it is a
    /// non-empty grid of fewer than 2^32 voxels in a box of positive extent.
    pub(crate) fn voxel_count(dims: [usize; 3], bounds: Aabb) -> Result<usize, MbdError> {
        let n = dims.iter().try_fold(1usize, |a, &d| a.checked_mul(d));
        let n = match n {
            Some(n) if n > 0 && n < u32::MAX as usize => n,
            _ => {
                return Err(MbdError::InvalidOption {
                    what: "dims",
                    why: format!("{dims:?} is not a non-empty grid of fewer than 2^32 voxels"),
                });
            }
        };
        if !bounds.is_valid() || (0..3).any(|k| bounds.max[k] <= bounds.min[k]) {
            return Err(MbdError::InvalidKernels {
                which: "basis",
                why: format!("{bounds:?} is not a box of positive extent"),
            });
        }
        Ok(n)
    }

    /// The rows of every voxel in order (x fastest); the grid must have passed
    /// [`VoxelWeights::voxel_count`] and `rows` hold one row per voxel.
    pub(crate) fn new<R>(dims: [usize; 3], bounds: Aabb, rows: impl IntoIterator<Item = R>) -> Self
    where
        R: IntoIterator<Item = (u32, f32)>,
    {
        let mut offsets = vec![0];
        let (mut indices, mut weights) = (Vec::new(), Vec::new());
        for row in rows {
            for (i, w) in row {
                indices.push(i);
                weights.push(w);
            }
            offsets.push(indices.len());
        }
        let origin = [0, 1, 2].map(|k| f64::from(bounds.min[k]));
        let scale = [0, 1, 2].map(|k| dims[k] as f64 / (f64::from(bounds.max[k]) - origin[k]));
        let mut table = Self {
            dims,
            bounds,
            origin,
            scale,
            offsets,
            indices,
            weights,
            max_support: 0,
        };
        table.max_support = table.largest_union();
        table
    }

    pub(crate) fn dims(&self) -> [usize; 3] {
        self.dims
    }

    pub(crate) fn bounds(&self) -> Aabb {
        self.bounds
    }

    /// The most distinct kernels over the eight voxel centres of any voxel-centre cell, i.e.
    /// non-zero at a point.
    pub(crate) fn max_support(&self) -> usize {
        self.max_support
    }

    /// Voxel `v`'s row as `(kernel, weight)` pairs; empty for `v` out of range.
    pub(crate) fn row(&self, v: usize) -> impl Iterator<Item = (u32, f32)> + '_ {
        let (a, b) = self.row_range(v);
        self.indices[a..b]
            .iter()
            .copied()
            .zip(self.weights[a..b].iter().copied())
    }

    fn row_range(&self, v: usize) -> (usize, usize) {
        match (self.offsets.get(v), self.offsets.get(v + 1)) {
            (Some(&a), Some(&b)) => (a, b),
            _ => (0, 0),
        }
    }

    /// The voxel-centre cell of `x` (clamped): per axis the lower voxel and the fraction.
    pub(crate) fn locate(&self, x: Vec3) -> Result<([usize; 3], [f32; 3]), CoreError> {
        if let Some(index) = (0..3).find(|&k| !x[k].is_finite()) {
            return Err(CoreError::NonFinite {
                what: "query point",
                index,
            });
        }
        let mut cell = [0usize; 3];
        let mut t = [0.0f32; 3];
        for k in 0..3 {
            let last = (self.dims[k] - 1) as f64;
            let u = ((f64::from(x[k]) - self.origin[k]) * self.scale[k] - 0.5).clamp(0.0, last);
            let c = (u as usize).min(self.dims[k].saturating_sub(2));
            cell[k] = c;
            t[k] = (u - c as f64) as f32;
        }
        Ok((cell, t))
    }

    /// The trilinear blend of the eight voxel centres' rows around `x`.
    pub(crate) fn eval(&self, x: Vec3, out: &mut KernelWeights) -> Result<(), CoreError> {
        out.clear();
        let (cell, t) = self.locate(x)?;
        for corner in 0..8 {
            let tw = [0, 1, 2]
                .map(|k| {
                    if corner >> k & 1 == 1 {
                        t[k]
                    } else {
                        1.0 - t[k]
                    }
                })
                .iter()
                .product::<f32>();
            if tw <= 0.0 {
                continue;
            }
            let (a, b) = self.row_range(self.corner_voxel(cell, corner));
            for (&i, &w) in self.indices[a..b].iter().zip(&self.weights[a..b]) {
                match out.indices.iter().position(|&j| j == i) {
                    Some(p) => out.weights[p] += tw * w,
                    None => out.push(i, tw * w),
                }
            }
        }
        Ok(())
    }

    fn largest_union(&self) -> usize {
        let cells = self.dims.map(|d| d.saturating_sub(1).max(1));
        let count: usize = cells.iter().product();
        (0..count)
            .into_par_iter()
            .map_init(Vec::new, |seen: &mut Vec<u32>, c| {
                seen.clear();
                let cell = [
                    c % cells[0],
                    (c / cells[0]) % cells[1],
                    c / (cells[0] * cells[1]),
                ];
                for corner in 0..8 {
                    let (a, b) = self.row_range(self.corner_voxel(cell, corner));
                    for &i in &self.indices[a..b] {
                        if !seen.contains(&i) {
                            seen.push(i);
                        }
                    }
                }
                seen.len()
            })
            .max()
            .unwrap_or(0)
    }

    /// Voxel at corner `corner` (bit k: one step up along axis k, clamped) of the voxel-centre
    /// cell whose lowest voxel is `cell`.
    #[inline]
    fn corner_voxel(&self, cell: [usize; 3], corner: usize) -> usize {
        let c = [0, 1, 2].map(|k| (cell[k] + (corner >> k & 1)).min(self.dims[k] - 1));
        c[0] + self.dims[0] * (c[1] + self.dims[1] * c[2])
    }
}
