use thiserror::Error;

/// Errors of prt-plsq.
#[derive(Debug, Clone, PartialEq, Error)]
#[non_exhaustive]
pub enum PlsqError {
    /// A value that must be finite was NaN or infinite.
    #[error("non-finite value in {what} at index {index}")]
    NonFinite {
        /// What held the value ("sample value", "sample direction", "sample weight", ...).
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
    /// A parameter was outside its valid range.
    #[error("invalid {what}: {why}")]
    Invalid {
        /// The parameter.
        what: &'static str,
        /// Why it is invalid.
        why: String,
    },
    /// The total sample weight was zero: there is nothing to fit and the coefficients were left
    /// untouched.
    #[error("total sample weight is zero; coefficients left untouched")]
    ZeroTotalWeight,
    /// A Gram or normal-equations matrix was singular to working precision.
    #[error("{what} is singular to working precision: {why}")]
    Singular {
        /// Which matrix.
        what: &'static str,
        /// The solver's message.
        why: String,
    },
    /// The work was cancelled through a `Progress` handle.
    #[error("cancelled")]
    Cancelled,
}

impl PlsqError {
    pub(crate) fn check_finite(what: &'static str, values: &[f32]) -> Result<(), PlsqError> {
        match values.iter().position(|v| !v.is_finite()) {
            Some(index) => Err(PlsqError::NonFinite { what, index }),
            None => Ok(()),
        }
    }

    /// `channels` values per sample and, when given, one weight per sample.
    pub(crate) fn check_sample_lengths(
        samples: usize,
        values: &[f32],
        channels: usize,
        weights: Option<&[f32]>,
    ) -> Result<(), PlsqError> {
        if values.len() != samples * channels {
            return Err(PlsqError::LengthMismatch {
                what: "sample values",
                expected: samples * channels,
                got: values.len(),
            });
        }
        if let Some(w) = weights
            && w.len() != samples
        {
            return Err(PlsqError::LengthMismatch {
                what: "sample weights",
                expected: samples,
                got: w.len(),
            });
        }
        Ok(())
    }

    pub(crate) fn invalid(what: &'static str, why: impl Into<String>) -> PlsqError {
        PlsqError::Invalid {
            what,
            why: why.into(),
        }
    }
}
