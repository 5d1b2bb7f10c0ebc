//! The compression methods a bake fits: MBD on a hat-grid basis and the PCA baselines at equal
//! basis count. Every fitting call into prt-mbd is here.

use prt_core::{Compressor, GridField, Progress};
use prt_kernels::HatGrid;
use prt_mbd::{
    Basis, BasisKernels, BlockPca, ClusteredPca, CoarseStart, Mbd, MbdError, MbdModel,
    PiecewisePcaModel, SolveReport, SolverOptions,
};

use crate::BakeConfig;

/// MBD of rank `config.rank` on `basis_nodes` hat-grid nodes per axis, after the config's
/// coarse start; with `valid`, on the valid voxels only.
pub(crate) fn fit_mbd(
    field: &GridField,
    valid: Option<&[bool]>,
    config: &BakeConfig,
    basis_nodes: [usize; 3],
    progress: &dyn Progress,
) -> Result<(MbdModel<HatGrid, HatGrid>, SolveReport), MbdError> {
    let levels = config.coarse_levels(field.dims());
    let mbd = Mbd {
        solver: SolverOptions {
            lambda: config.lambda,
            max_iterations: if levels > 0 {
                config.full_iterations
            } else {
                config.max_iterations
            },
            seed: config.seed ^ 0x4D42_4400,
            ..SolverOptions::default()
        },
        coarse_start: (levels > 0).then_some(CoarseStart {
            levels,
            iterations: config.max_iterations,
        }),
        loss_weighting: config.loss_weighting,
        centre_projection: config.centre_projection,
        ..Mbd::new(config.rank, Basis::HatGrid { nodes: basis_nodes })
    };
    let fit = match valid {
        Some(valid) => mbd.fit_masked(field, valid, progress)?,
        None => mbd.fit(field, progress)?,
    };
    // A hat-grid basis is what the container stores; unwrap it from the basis enum.
    let (coefficient_kernels, basis_kernels, coefficients, basis) = fit.model.into_parts();
    let BasisKernels::HatGrid(basis_kernels) = basis_kernels else {
        return Err(MbdError::InvalidKernels {
            which: "basis",
            why: "the container stores a hat-grid basis only".into(),
        });
    };
    let model = MbdModel::new(coefficient_kernels, basis_kernels, coefficients, basis)?;
    Ok((model, fit.solve))
}

/// The basis cell of every voxel: MBD's "clusters" for the seam measure.
pub(crate) fn basis_cells(kernels: &HatGrid, field: &GridField) -> Result<Vec<u32>, MbdError> {
    prt_mbd::expert::kernel_labels(kernels, field)
}

/// Blockwise PCA with one rank-L basis per basis node of MBD (`blocks` per axis), under the
/// config's loss weighting (as MBD).
pub(crate) fn fit_bpca(
    field: &GridField,
    config: &BakeConfig,
    blocks: [usize; 3],
    progress: &dyn Progress,
) -> Result<PiecewisePcaModel, MbdError> {
    BlockPca {
        rank: config.rank,
        blocks,
        window: 1.0,
        loss_weighting: config.loss_weighting,
    }
    .compress(field, progress)
}

/// Clustered PCA with `clusters` rank-L bases, under the config's loss weighting (as MBD); with
/// `valid`, of the valid voxels only.
pub(crate) fn fit_cpca(
    field: &GridField,
    valid: Option<&[bool]>,
    config: &BakeConfig,
    clusters: usize,
    progress: &dyn Progress,
) -> Result<PiecewisePcaModel, MbdError> {
    let cpca = ClusteredPca {
        seed: config.seed,
        loss_weighting: config.loss_weighting,
        ..ClusteredPca::new(config.rank, clusters)
    };
    match valid {
        Some(valid) => cpca.compress_masked(field, valid, progress),
        None => cpca.compress(field, progress),
    }
}
