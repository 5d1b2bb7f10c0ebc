use prt_core::CoreError;
use thiserror::Error;

/// Everything that can go wrong in prt-linalg.
#[derive(Debug, Clone, PartialEq, Error)]
#[non_exhaustive]
pub enum LinalgError {
    /// An input held NaN or an infinity.
    #[error("non-finite value in {what} at flat (row-major) index {index}")]
    NonFinite {
        /// Which argument held the value ("a", "b", "data", ...).
        what: &'static str,
        /// Row-major flat index of the first offending value.
        index: usize,
    },
    /// Two dimensions that must agree did not (or a matrix that must be square was not).
    #[error("shape mismatch in {what}: expected {expected}, got {got}")]
    ShapeMismatch {
        /// What was checked ("rows of b", "columns of x", "a is square", ...).
        what: &'static str,
        /// The size required.
        expected: usize,
        /// The size given.
        got: usize,
    },
    /// Cholesky met a non-positive pivot: the (ridged) matrix is not positive definite.
    #[error("matrix is not positive definite (pivot {pivot})")]
    NotPositiveDefinite {
        /// Index of the first non-positive pivot.
        pivot: usize,
    },
    /// A symmetric indefinite factorization met an exactly singular matrix.
    #[error("matrix is singular")]
    Singular,
    /// An input had no rows or no columns.
    #[error("{what} is empty")]
    Empty {
        /// What was empty.
        what: &'static str,
    },
    /// A requested rank was 0 or above the largest possible one.
    #[error("invalid rank {rank}: must be in 1..={max}")]
    InvalidRank {
        /// The rank asked for.
        rank: usize,
        /// The largest valid rank.
        max: usize,
    },
    /// A scalar parameter was out of its valid range.
    #[error("invalid {what}: {why}")]
    InvalidParameter {
        /// The parameter.
        what: &'static str,
        /// Why it is invalid.
        why: String,
    },
    /// An iterative method did not converge within its iteration budget.
    #[error("{what} did not converge within {iterations} iterations")]
    NoConvergence {
        /// The method.
        what: &'static str,
        /// Iterations spent.
        iterations: usize,
    },
    /// The work was cancelled through its [`prt_core::Progress`] handle.
    #[error("cancelled")]
    Cancelled,
    /// The numerical backend (faer or LAPACK) reported a failure not covered above.
    #[error("backend failure: {0}")]
    Backend(String),
}

impl From<CoreError> for LinalgError {
    fn from(e: CoreError) -> Self {
        match e {
            CoreError::Cancelled => LinalgError::Cancelled,
            CoreError::NonFinite { what, index } => LinalgError::NonFinite { what, index },
            CoreError::Empty { what } => LinalgError::Empty { what },
            other => LinalgError::Backend(other.to_string()),
        }
    }
}
