//! What can go wrong while rendering.

use prt_core::CoreError;
use prt_trace::TraceError;

/// An error of [`render`](crate::render) or of what it reads.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum RenderError {
    /// An option or input is out of range (`what` names it).
    #[error("invalid {what}: {why}")]
    InvalidOption {
        /// The option or input.
        what: &'static str,
        /// Why it is invalid.
        why: String,
    },
    /// The ray tracer or the view refused the job.
    #[error(transparent)]
    Trace(#[from] TraceError),
    /// A grid, a model evaluation or cancellation.
    #[error(transparent)]
    Core(#[from] CoreError),
}
