use thiserror::Error;

/// Errors shared by the traits of prt-core.
///
/// Crates that implement the traits map their own failures onto these kinds where they fit and
/// keep richer error types of their own for everything else.
#[derive(Debug, Clone, PartialEq, Error)]
#[non_exhaustive]
pub enum CoreError {
    /// A value that must be finite was NaN or infinite.
    #[error("non-finite value in {what} at index {index}")]
    NonFinite {
        /// What held the value (for example "field data", "query point").
        what: &'static str,
        /// Flat index of the offending value inside `what`.
        index: usize,
    },
    /// Two lengths that must agree did not.
    #[error("length mismatch in {what}: expected {expected}, got {got}")]
    LengthMismatch {
        /// What was being checked.
        what: &'static str,
        /// The length required.
        expected: usize,
        /// The length given.
        got: usize,
    },
    /// A point lies where no kernel of a kernel family has support.
    #[error("point ({}, {}, {}) is covered by no kernel", point[0], point[1], point[2])]
    Uncovered {
        /// The query point.
        point: [f32; 3],
    },
    /// An object that must not be empty was (zero voxels, zero dimensions, zero rows, ...).
    #[error("{what} is empty")]
    Empty {
        /// What was empty.
        what: &'static str,
    },
    /// An index was outside its range.
    #[error("{what} index {index} out of range 0..{len}")]
    OutOfRange {
        /// What was indexed.
        what: &'static str,
        /// The index given.
        index: usize,
        /// The length of the indexed range.
        len: usize,
    },
    /// A parameter was outside its valid range.
    #[error("invalid {what}: {why}")]
    Invalid {
        /// The parameter.
        what: &'static str,
        /// Why it is invalid.
        why: String,
    },
    /// The work was cancelled through a [`crate::Progress`] handle.
    #[error("cancelled")]
    Cancelled,
}

impl CoreError {
    /// Returns `Err(NonFinite)` naming the first non-finite value of `values`, if any.
    pub fn check_finite(what: &'static str, values: &[f32]) -> Result<(), CoreError> {
        match values.iter().position(|v| !v.is_finite()) {
            Some(index) => Err(CoreError::NonFinite { what, index }),
            None => Ok(()),
        }
    }
}
