use std::path::PathBuf;

use prt_core::CoreError;
use prt_kernels::KernelError;
use prt_mbd::MbdError;
use prt_texture::TextureError;
use prt_trace::TraceError;
use thiserror::Error;

/// Everything that can stop a bake.
#[derive(Debug, Error)]
#[non_exhaustive]
pub enum BakeError {
    /// A knob of [`crate::BakeConfig`] is out of range.
    #[error("{field} {why}")]
    InvalidConfig {
        /// The field of [`crate::BakeConfig`].
        field: &'static str,
        /// What is wrong with it.
        why: String,
    },
    /// The bake would need more memory than its budget ([`crate::BakeConfig::max_memory`]).
    #[error(
        "the bake needs about {} of memory, over the budget of {}; {}",
        gib(*need),
        gib(*budget),
        match largest_resolution {
            Some(res) => format!("the largest resolution that fits is {res} voxels along the longest axis (or raise the budget)"),
            None => "not even 2 voxels fit (raise the budget)".to_string(),
        }
    )]
    OverMemoryBudget {
        /// Estimated peak bytes ([`crate::memory::MemoryEstimate`]).
        need: u64,
        /// The budget in bytes.
        budget: u64,
        /// The largest resolution that fits the budget with the other knobs unchanged.
        largest_resolution: Option<usize>,
    },
    /// The scene file does not exist.
    #[error("scene file {} does not exist", .0.display())]
    MissingScene(PathBuf),
    /// The scene file could not be loaded as glTF.
    #[error("cannot load {} as glTF", path.display())]
    LoadScene {
        /// The scene file.
        path: PathBuf,
        /// Why.
        #[source]
        source: TraceError,
    },
    /// The scene has no triangles.
    #[error("{scene} has no triangles to bake")]
    EmptyScene {
        /// The scene's name or file.
        scene: String,
    },
    /// The tracer could not be set up (bad options for this scene).
    #[error("cannot set up the baker")]
    TracerSetup(#[source] TraceError),
    /// Tracing failed or was cancelled.
    #[error("baking failed")]
    Trace(#[source] TraceError),
    /// The MBD solve failed or was cancelled.
    #[error("MBD solve failed")]
    Mbd(#[source] MbdError),
    /// A baseline failed or was cancelled.
    #[error("{method} failed")]
    Baseline {
        /// The baseline's name.
        method: &'static str,
        /// Why.
        #[source]
        source: MbdError,
    },
    /// Scoring a method failed.
    #[error("cannot score {method}")]
    Score {
        /// The method's name.
        method: String,
        /// Why.
        #[source]
        source: MbdError,
    },
    /// The container could not be written or read back.
    #[error("cannot write the MBD container")]
    Container(#[source] ContainerError),
    /// A model to light does not hold transfer vectors.
    #[error("lighting a basis needs {expected}-D transfer vectors, the model's are {got}-D")]
    NotTransfer {
        /// The transfer dimension, 324.
        expected: usize,
        /// The model's dimension.
        got: usize,
    },
    /// The work was cancelled between stages.
    #[error("cancelled")]
    Cancelled(#[source] CoreError),
}

/// Everything that can go wrong writing or reading an MBD container.
#[derive(Debug, Error)]
#[non_exhaustive]
pub enum ContainerError {
    /// A file is missing, unreadable, malformed or over the [`prt_texture::Limits`].
    #[error(transparent)]
    Texture(#[from] TextureError),
    /// The manifest lacks an array or kernel family an MBD container has.
    #[error("the container has no {kind} {name:?}")]
    Missing {
        /// `"array"`, `"kernels"` or `"attribute"`.
        kind: &'static str,
        /// Its name.
        name: &'static str,
    },
    /// The container is well-formed but does not describe a consistent MBD model.
    #[error("not a consistent MBD container: {0}")]
    Inconsistent(String),
    /// A kernel description does not give a valid hat grid.
    #[error("invalid {which} kernels")]
    Kernels {
        /// `"coefficients"` or `"basis"`.
        which: &'static str,
        /// Why.
        #[source]
        source: KernelError,
    },
    /// The arrays do not form a valid model (shapes, non-finite values).
    #[error("invalid MBD model")]
    Model(#[source] MbdError),
}

/// Bytes as GiB with two decimals, for messages.
fn gib(bytes: u64) -> String {
    format!("{:.2} GiB", bytes as f64 / f64::from(1u32 << 30))
}
