//! The compression methods a bake fits: MBD on a hat-grid basis and the PCA baselines at equal
//! basis count. Every fitting call into prt-mbd is here.

use prt_core::{Compressor, GridField, Progress};
use prt_kernels::HatGrid;
use prt_mbd::{
    BlockPca, ClusterModel, ClusteredPca, Mbd, MbdError, MbdModel, MbdOptions, SolveReport,
};

use crate::BakeConfig;

/// MBD of rank `config.rank` on `basis_nodes` hat-grid nodes per axis.
pub(crate) fn fit_mbd(
    field: &GridField,
    config: &BakeConfig,
    basis_nodes: [usize; 3],
    progress: &dyn Progress,
) -> Result<(MbdModel<HatGrid, HatGrid>, SolveReport), MbdError> {
    let mbd = Mbd {
        basis_nodes,
        options: MbdOptions {
            rank: config.rank,
            lambda: config.lambda,
            max_iterations: config.max_iterations,
            seed: config.seed ^ 0x4D42_4400,
            ..MbdOptions::default()
        },
    };
    mbd.fit(field, progress)
}

/// The basis cell of every voxel: MBD's "clusters" for the seam measure.
pub(crate) fn basis_cells(kernels: &HatGrid, field: &GridField) -> Result<Vec<u32>, MbdError> {
    prt_mbd::kernel_labels(kernels, field)
}

/// Blockwise PCA with one rank-L basis per basis node of MBD (`blocks` per axis).
pub(crate) fn fit_bpca(
    field: &GridField,
    config: &BakeConfig,
    blocks: [usize; 3],
    progress: &dyn Progress,
) -> Result<ClusterModel, MbdError> {
    BlockPca {
        rank: config.rank,
        blocks,
        window: 1.0,
    }
    .compress(field, progress)
}

/// Clustered PCA with `clusters` rank-L bases.
pub(crate) fn fit_cpca(
    field: &GridField,
    config: &BakeConfig,
    clusters: usize,
    progress: &dyn Progress,
) -> Result<ClusterModel, MbdError> {
    ClusteredPca {
        seed: config.seed,
        ..ClusteredPca::new(config.rank, clusters)
    }
    .compress(field, progress)
}
