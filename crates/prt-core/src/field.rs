use glam::Vec3;
use ndarray::{Array2, ArrayViewMut2};

use crate::{Aabb, CoreError};

/// A dense 3D grid of `dim`-dimensional vectors over a box: the target of compression (MBD and
/// the PCA family) and the output of the transfer-volume baker.
///
/// * Voxel `(ix, iy, iz)` of a `[nx, ny, nz]` grid has flat index `ix + nx * (iy + ny * iz)`
///   (x fastest) and its value is row `index` of [`GridField::data`] (`voxels × dim`, row-major).
/// * The box is split into `nx × ny × nz` equal cells; a voxel's value sits at its cell's centre
///   `min + (i + 0.5) * size / n`.
/// * [`GridField::sample`] interpolates trilinearly between voxel centres. Outside the box of
///   voxel centres it **clamps** to that box (constant extension along each axis), so sampling is
///   defined everywhere; a non-finite query point is a [`CoreError::NonFinite`].
/// * Construction checks that every value is finite; [`GridField::data_mut`] hands out the raw
///   array, and [`GridField::check_finite`] re-checks after such edits.
#[derive(Debug, Clone, PartialEq)]
pub struct GridField {
    dims: [usize; 3],
    bounds: Aabb,
    data: Array2<f32>,
}

/// The eight voxels (flat indices) and weights of a trilinear interpolation.
///
/// Weights are non-negative and sum to one. On an axis with a single voxel both corners
/// coincide, so repeated indices can occur; their weights still sum correctly.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrilinearWeights {
    /// Flat voxel indices, corner `c` has bits (x, y, z) = (c & 1, c >> 1 & 1, c >> 2 & 1).
    pub indices: [usize; 8],
    /// Interpolation weights, in the same order.
    pub weights: [f32; 8],
}

impl TrilinearWeights {
    /// The voxels and weights that trilinearly interpolate at `p` on a grid of `dims` voxels
    /// filling `bounds` (clamped to the box of voxel centres), for models that store a grid's
    /// values in another form than a [`GridField`].
    pub fn at(dims: [usize; 3], bounds: Aabb, p: Vec3) -> Result<Self, CoreError> {
        if !p.is_finite() {
            let index = (0..3).find(|&k| !p[k].is_finite()).unwrap_or(0);
            return Err(CoreError::NonFinite {
                what: "query point",
                index,
            });
        }
        let local = bounds.to_local(p);
        let mut lo = [0usize; 3];
        let mut hi = [0usize; 3];
        let mut t = [0.0f32; 3];
        for k in 0..3 {
            let n = dims[k];
            // Continuous voxel coordinate: voxel centres sit at integers.
            let u = (local[k] * n as f32 - 0.5).clamp(0.0, (n - 1) as f32);
            let i0 = (u.floor() as usize).min(n.saturating_sub(2));
            lo[k] = i0;
            hi[k] = (i0 + 1).min(n - 1);
            t[k] = if n == 1 { 0.0 } else { u - i0 as f32 };
        }
        let mut indices = [0usize; 8];
        let mut weights = [0.0f32; 8];
        for c in 0..8 {
            let pick = |k: usize| {
                if (c >> k) & 1 == 1 {
                    (hi[k], t[k])
                } else {
                    (lo[k], 1.0 - t[k])
                }
            };
            let (ix, wx) = pick(0);
            let (iy, wy) = pick(1);
            let (iz, wz) = pick(2);
            indices[c] = ix + dims[0] * (iy + dims[1] * iz);
            weights[c] = wx * wy * wz;
        }
        Ok(Self { indices, weights })
    }
}

impl GridField {
    /// A zero field. Errors if a dimension or `dim` is zero or the bounds are not a valid box.
    pub fn new(dims: [usize; 3], bounds: Aabb, dim: usize) -> Result<Self, CoreError> {
        Self::check_shape(dims, bounds, dim)?;
        let voxels = dims[0] * dims[1] * dims[2];
        Ok(Self {
            dims,
            bounds,
            data: Array2::zeros((voxels, dim)),
        })
    }

    /// A field from a `voxels × dim` array (x fastest). Errors on a shape mismatch or a
    /// non-finite value (naming its flat index in `data`).
    pub fn from_data(dims: [usize; 3], bounds: Aabb, data: Array2<f32>) -> Result<Self, CoreError> {
        Self::check_shape(dims, bounds, data.ncols())?;
        let voxels = dims[0] * dims[1] * dims[2];
        if data.nrows() != voxels {
            return Err(CoreError::LengthMismatch {
                what: "field rows (voxels)",
                expected: voxels,
                got: data.nrows(),
            });
        }
        let data = data.as_standard_layout().into_owned();
        let field = Self { dims, bounds, data };
        field.check_finite()?;
        Ok(field)
    }

    /// A field whose voxel values are `f(voxel centre, out)`.
    pub fn from_fn(
        dims: [usize; 3],
        bounds: Aabb,
        dim: usize,
        mut f: impl FnMut(Vec3, &mut [f32]),
    ) -> Result<Self, CoreError> {
        let mut field = Self::new(dims, bounds, dim)?;
        for v in 0..field.num_voxels() {
            let centre = field.centre_of(v);
            f(centre, field.voxel_mut(v));
        }
        field.check_finite()?;
        Ok(field)
    }

    fn check_shape(dims: [usize; 3], bounds: Aabb, dim: usize) -> Result<(), CoreError> {
        if dims.contains(&0) {
            return Err(CoreError::Empty {
                what: "grid dimensions",
            });
        }
        if dim == 0 {
            return Err(CoreError::Empty {
                what: "field vector dimension",
            });
        }
        if !bounds.is_valid() {
            return Err(CoreError::Invalid {
                what: "field bounds",
                why: format!("{bounds:?} is not a finite box with min <= max"),
            });
        }
        dims[0]
            .checked_mul(dims[1])
            .and_then(|n| n.checked_mul(dims[2]))
            .and_then(|n| n.checked_mul(dim))
            .ok_or_else(|| CoreError::Invalid {
                what: "field size",
                why: format!("{dims:?} x {dim} overflows"),
            })?;
        Ok(())
    }

    /// Errors naming the first non-finite value (flat index into `data`, row-major).
    pub fn check_finite(&self) -> Result<(), CoreError> {
        match self.data.iter().position(|v| !v.is_finite()) {
            Some(index) => Err(CoreError::NonFinite {
                what: "field data",
                index,
            }),
            None => Ok(()),
        }
    }

    /// Grid resolution `[nx, ny, nz]`.
    pub fn dims(&self) -> [usize; 3] {
        self.dims
    }

    /// The box the grid covers.
    pub fn bounds(&self) -> Aabb {
        self.bounds
    }

    /// Dimension D of each voxel's vector.
    pub fn dim(&self) -> usize {
        self.data.ncols()
    }

    /// Number of voxels `nx * ny * nz`.
    pub fn num_voxels(&self) -> usize {
        self.data.nrows()
    }

    /// The `voxels × dim` values.
    pub fn data(&self) -> &Array2<f32> {
        &self.data
    }

    /// Mutable values (a view: shape and layout cannot change). Writing non-finite values
    /// breaks the field's invariant; call [`GridField::check_finite`] after untrusted edits.
    pub fn data_mut(&mut self) -> ArrayViewMut2<'_, f32> {
        self.data.view_mut()
    }

    /// The values, consuming the field.
    pub fn into_data(self) -> Array2<f32> {
        self.data
    }

    /// Flat index of voxel `(ix, iy, iz)`.
    #[inline]
    pub fn index(&self, ix: usize, iy: usize, iz: usize) -> usize {
        ix + self.dims[0] * (iy + self.dims[1] * iz)
    }

    /// Grid coordinates of flat index `v`.
    #[inline]
    pub fn coords(&self, v: usize) -> [usize; 3] {
        let [nx, ny, _] = self.dims;
        [v % nx, (v / nx) % ny, v / (nx * ny)]
    }

    /// Edge lengths of one voxel cell.
    pub fn voxel_size(&self) -> Vec3 {
        self.bounds.size()
            / Vec3::new(
                self.dims[0] as f32,
                self.dims[1] as f32,
                self.dims[2] as f32,
            )
    }

    /// World-space centre of voxel `(ix, iy, iz)`.
    pub fn voxel_centre(&self, ix: usize, iy: usize, iz: usize) -> Vec3 {
        let cell = Vec3::new(ix as f32 + 0.5, iy as f32 + 0.5, iz as f32 + 0.5);
        self.bounds.min + cell * self.voxel_size()
    }

    /// World-space centre of flat voxel `v`.
    pub fn centre_of(&self, v: usize) -> Vec3 {
        let [ix, iy, iz] = self.coords(v);
        self.voxel_centre(ix, iy, iz)
    }

    /// The vector of flat voxel `v`.
    pub fn voxel(&self, v: usize) -> &[f32] {
        let dim = self.dim();
        match self.data.as_slice() {
            Some(s) => &s[v * dim..(v + 1) * dim],
            None => unreachable!("GridField data is always in standard layout"),
        }
    }

    /// The mutable vector of flat voxel `v`.
    pub fn voxel_mut(&mut self, v: usize) -> &mut [f32] {
        let dim = self.dim();
        let start = v * dim;
        let all = self.data.as_slice_mut();
        match all {
            Some(s) => &mut s[start..start + dim],
            None => unreachable!("GridField data is always in standard layout"),
        }
    }

    /// The voxels and weights that trilinearly interpolate at `p` (clamped to the box of voxel
    /// centres).
    pub fn trilinear_weights(&self, p: Vec3) -> Result<TrilinearWeights, CoreError> {
        TrilinearWeights::at(self.dims, self.bounds, p)
    }

    /// Trilinear interpolation at `p` into `out` (`out.len()` must equal [`GridField::dim`]).
    pub fn sample(&self, p: Vec3, out: &mut [f32]) -> Result<(), CoreError> {
        if out.len() != self.dim() {
            return Err(CoreError::LengthMismatch {
                what: "sample output",
                expected: self.dim(),
                got: out.len(),
            });
        }
        let tw = self.trilinear_weights(p)?;
        out.fill(0.0);
        for (&v, &w) in tw.indices.iter().zip(&tw.weights) {
            if w == 0.0 {
                continue;
            }
            for (o, &x) in out.iter_mut().zip(self.voxel(v)) {
                *o += w * x;
            }
        }
        Ok(())
    }
}
