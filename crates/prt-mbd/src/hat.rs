//! MBD on hat grids: the paper's setting, as a [`Compressor`].

use glam::Vec3;
use prt_core::{Aabb, Compressor, GridField, Progress};
use prt_kernels::HatGrid;

use crate::baselines::voxel_centre_box;
use crate::{MbdError, MbdModel, MbdOptions, SolveReport, solve};

/// Rank-L MBD with trilinear hat kernels: one coefficient node per voxel centre of the input
/// grid, and a `basis_nodes` grid of basis nodes spanning the box of the voxel centres
/// ([`basis_box`]).
#[derive(Debug, Clone, PartialEq)]
pub struct Mbd {
    /// Basis nodes per axis (at least 2 on every axis).
    pub basis_nodes: [usize; 3],
    /// Solver options (rank, λ, iterations, ...).
    pub options: MbdOptions,
}

impl Mbd {
    /// The coefficient and basis kernels for `field`.
    ///
    /// # Errors
    /// [`MbdError::InvalidKernels`] if an axis has fewer than 2 basis nodes.
    pub fn kernels(&self, field: &GridField) -> Result<(HatGrid, HatGrid), MbdError> {
        if let Some(axis) = (0..3).find(|&k| self.basis_nodes[k] < 2) {
            return Err(MbdError::InvalidKernels {
                which: "basis",
                why: format!(
                    "axis {axis} has {} nodes, need at least 2",
                    self.basis_nodes[axis]
                ),
            });
        }
        let kernel_error = |which: &'static str| {
            move |e: prt_kernels::KernelError| MbdError::InvalidKernels {
                which,
                why: e.to_string(),
            }
        };
        let coefficients = HatGrid::new(field.dims(), voxel_centre_box(field))
            .map_err(kernel_error("coefficient"))?;
        let basis =
            HatGrid::new(self.basis_nodes, basis_box(field)).map_err(kernel_error("basis"))?;
        Ok((coefficients, basis))
    }

    /// Fits the model and returns the solver's report too.
    pub fn fit(
        &self,
        field: &GridField,
        progress: &dyn Progress,
    ) -> Result<(MbdModel<HatGrid, HatGrid>, SolveReport), MbdError> {
        let (coefficients, basis) = self.kernels(field)?;
        solve(field, coefficients, basis, &self.options, progress)
    }
}

/// The box the basis nodes of [`Mbd`] span: the box of the voxel centres (on an axis of one
/// voxel, the field's box).
///
/// The target (the field's trilinear interpolation) and the coefficient kernels are constant in
/// the outer half voxel, so basis nodes on the field's faces would spend half a voxel per side
/// where nothing changes; spanning the voxel centres makes every basis cell slightly smaller at
/// the same node count and cost (MBD session 7 in `docs/results.md`).
pub fn basis_box(field: &GridField) -> Aabb {
    let (centres, bounds, dims) = (voxel_centre_box(field), field.bounds(), field.dims());
    let pick = |c: Vec3, b: Vec3| {
        Vec3::new(
            if dims[0] >= 2 { c.x } else { b.x },
            if dims[1] >= 2 { c.y } else { b.y },
            if dims[2] >= 2 { c.z } else { b.z },
        )
    };
    Aabb::new(pick(centres.min, bounds.min), pick(centres.max, bounds.max))
}

impl Compressor for Mbd {
    type Model = MbdModel<HatGrid, HatGrid>;
    type Error = MbdError;

    fn compress(
        &self,
        field: &GridField,
        progress: &dyn Progress,
    ) -> Result<Self::Model, MbdError> {
        Ok(self.fit(field, progress)?.0)
    }
}
