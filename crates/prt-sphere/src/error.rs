use thiserror::Error;

/// Errors of prt-sphere.
#[derive(Debug, Clone, PartialEq, Error)]
#[non_exhaustive]
pub enum SphereError {
    /// A value that must be finite was NaN or infinite.
    #[error("non-finite value in {what} at index {index}")]
    NonFinite {
        /// What held the value ("texel", "coefficient", "sample value", ...).
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
    /// A parameter was outside its valid range (order 0, no lobes, sharpness <= 0, ...).
    #[error("invalid {what}: {why}")]
    Invalid {
        /// The parameter.
        what: &'static str,
        /// Why it is invalid.
        why: String,
    },
}

impl SphereError {
    /// `Err(NonFinite)` naming the first non-finite value of `values`, if any.
    pub fn check_finite(what: &'static str, values: &[f32]) -> Result<(), SphereError> {
        match values.iter().position(|v| !v.is_finite()) {
            Some(index) => Err(SphereError::NonFinite { what, index }),
            None => Ok(()),
        }
    }

    pub(crate) fn invalid(what: &'static str, why: impl Into<String>) -> SphereError {
        SphereError::Invalid {
            what,
            why: why.into(),
        }
    }
}
