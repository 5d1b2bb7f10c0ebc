use prt_core::CoreError;
use thiserror::Error;

/// Errors of Moving Basis Decomposition and its baselines.
#[derive(Debug, Clone, PartialEq, Error)]
#[non_exhaustive]
pub enum MbdError {
    /// The requested rank is zero or larger than the field's vector dimension.
    #[error("rank {rank} is invalid for {dim}-dimensional vectors (need 1..={dim})")]
    InvalidRank {
        /// The rank asked for.
        rank: usize,
        /// The field's vector dimension D.
        dim: usize,
    },
    /// A kernel family cannot be used (empty, or too coarse).
    #[error("{which} kernels are unusable: {why}")]
    InvalidKernels {
        /// "coefficient" or "basis".
        which: &'static str,
        /// What is wrong.
        why: String,
    },
    /// A kernel family does not cover the whole domain of the field.
    #[error("{which} kernels do not cover the field's domain: point {point:?} is uncovered")]
    KernelsDoNotCover {
        /// "coefficient" or "basis".
        which: &'static str,
        /// A point of the field's box where the family has no support.
        point: [f32; 3],
    },
    /// A tensor handed to a constructor has the wrong shape.
    #[error("{what} has shape {got:?}, expected {expected:?}")]
    ShapeMismatch {
        /// Which tensor.
        what: &'static str,
        /// The shape required.
        expected: Vec<usize>,
        /// The shape given.
        got: Vec<usize>,
    },
    /// An option is outside its valid range.
    #[error("invalid option {what}: {why}")]
    InvalidOption {
        /// The option.
        what: &'static str,
        /// Why it is invalid.
        why: String,
    },
    /// The solver produced a non-finite value (diverged); `what` names the quantity.
    #[error("solver diverged: non-finite {what} at iteration {iteration}")]
    Diverged {
        /// The quantity that became non-finite.
        what: &'static str,
        /// The iteration at which it happened.
        iteration: usize,
    },
    /// An iterative solve did not reach its tolerance within its iteration bound.
    #[error(
        "{what} did not converge: relative residual {relative_residual:.3e} after {iterations} iterations"
    )]
    NotConverged {
        /// The system.
        what: &'static str,
        /// Iterations run.
        iterations: usize,
        /// The relative residual reached.
        relative_residual: f64,
    },
    /// Serialised basis normal equations that do not fit the basis they are read for.
    #[error("malformed basis normal equations: {why}")]
    MalformedNormals {
        /// What is wrong.
        why: String,
    },
    /// An error of the shared vocabulary: non-finite input (naming where), empty field,
    /// cancellation, ...
    #[error(transparent)]
    Core(#[from] CoreError),
}

impl MbdError {
    /// Whether the work was cancelled through its `Progress` handle.
    pub fn is_cancelled(&self) -> bool {
        matches!(self, MbdError::Core(CoreError::Cancelled))
    }
}
