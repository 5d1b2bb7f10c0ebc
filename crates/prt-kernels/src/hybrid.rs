use glam::Vec3;
use prt_core::{Aabb, CoreError, KernelWeights, SpatialKernels};

use crate::{HatGrid, HatLocal, KernelError};

/// Hat kernels on a 2D grid over the ground plane (XZ), constant along Y: the basis-vector
/// family of the production setup of Moving Basis Decomposition (Silvennoinen & Sloan 2021,
/// "hybrid" MBD), where basis vectors live on a terrain-sized 2D grid while coefficients live on
/// a 3D grid over the same box ([`HybridKernels::coefficient_grid`]).
///
/// Node `(i, k)` sits at `(min.x + i * size.x / (nx - 1), centre.y, min.z + k * size.z / (nz - 1))`
/// with flat index `i + nx * k`. At most 4 kernels are non-zero at a point. Points outside the
/// box are clamped to it; a non-finite point is [`CoreError::NonFinite`]. The support cells are
/// the grid's columns (index `cx + (nx - 1) * cz`): every voxel of a column shares the same 4
/// basis nodes, whatever its height.
///
/// ```
/// use glam::Vec3;
/// use prt_core::{Aabb, SpatialKernels};
/// use prt_kernels::HybridKernels;
///
/// let terrain = Aabb::new(Vec3::new(0.0, 0.0, 0.0), Vec3::new(1024.0, 64.0, 1024.0));
/// let basis = HybridKernels::new(17, 17, terrain).unwrap();
/// let coefficients = basis.coefficient_grid([129, 9, 129]).unwrap();
/// assert_eq!((basis.len(), basis.max_support()), (17 * 17, 4));
/// assert_eq!(coefficients.max_support(), 8);
/// ```
#[derive(Debug, Clone, PartialEq)]
pub struct HybridKernels {
    plane: HatGrid,
}

impl HybridKernels {
    /// `nx × nz` basis nodes over the ground plane of `domain` (at least 2 per axis), any height.
    ///
    /// Errors as [`HatGrid::new`], and [`KernelError::TooFewNodes`] for a single node along x
    /// or z (the family would be constant along a ground axis).
    pub fn new(nx: usize, nz: usize, domain: Aabb) -> Result<HybridKernels, KernelError> {
        for (axis, n) in [(0, nx), (2, nz)] {
            if n == 1 {
                return Err(KernelError::TooFewNodes {
                    axis,
                    nodes: n,
                    min: 2,
                });
            }
        }
        Ok(HybridKernels {
            plane: HatGrid::plane_xz(nx, nz, domain)?,
        })
    }

    /// The underlying `[nx, 1, nz]` hat grid (for its concrete helpers).
    pub fn grid(&self) -> &HatGrid {
        &self.plane
    }

    /// A 3D hat grid with `nodes` nodes per axis over the same box: the coefficient family that
    /// pairs with this basis family.
    pub fn coefficient_grid(&self, nodes: [usize; 3]) -> Result<HatGrid, KernelError> {
        HatGrid::new(nodes, self.plane.domain())
    }

    /// The grid column `(cx, cz)` holding `x` (clamped to the box).
    pub fn column_of(&self, x: Vec3) -> Result<[usize; 2], CoreError> {
        let [cx, _, cz] = self.plane.cell_of(x)?;
        Ok([cx, cz])
    }

    /// The 4 corner weights at `x` without allocating (see [`HatGrid::eval_local`]).
    #[inline]
    pub fn eval_local(&self, x: Vec3) -> Result<HatLocal, CoreError> {
        self.plane.eval_local(x)
    }
}

impl SpatialKernels for HybridKernels {
    fn len(&self) -> usize {
        self.plane.len()
    }

    fn max_support(&self) -> usize {
        self.plane.max_support()
    }

    fn domain(&self) -> Aabb {
        self.plane.domain()
    }

    fn eval(&self, x: Vec3, out: &mut KernelWeights) -> Result<(), CoreError> {
        self.plane.eval(x, out)
    }

    fn support_cell(&self, x: Vec3) -> Option<usize> {
        self.plane.support_cell(x)
    }

    fn num_support_cells(&self) -> usize {
        self.plane.num_support_cells()
    }

    fn centre(&self, i: usize) -> Option<Vec3> {
        self.plane.centre(i)
    }
}
