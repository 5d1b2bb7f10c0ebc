use prt_core::CoreError;
use thiserror::Error;

/// Errors of prt-wavelet.
#[derive(Debug, Clone, PartialEq, Error)]
#[non_exhaustive]
pub enum WaveletError {
    /// A signal or image side length that must be a power of two (and at least the minimum) was not.
    #[error("{what} has length {len}, which is not a power of two >= {min}")]
    NotPowerOfTwo {
        /// What was measured ("signal", "face side", ...).
        what: &'static str,
        /// The length given.
        len: usize,
        /// The smallest length accepted.
        min: usize,
    },
    /// Two lengths that must agree did not (a buffer of the wrong size, a face of the wrong size).
    #[error("length mismatch in {what}: expected {expected}, got {got}")]
    LengthMismatch {
        /// What was checked.
        what: &'static str,
        /// The length required.
        expected: usize,
        /// The length given.
        got: usize,
    },
    /// A lighting texel was NaN or infinite.
    #[error("non-finite lighting at face {face}, texel ({x}, {y}), channel {channel}")]
    NonFiniteTexel {
        /// Cube face (0..6, order +X, -X, +Y, -Y, +Z, -Z).
        face: usize,
        /// Column of the texel.
        x: usize,
        /// Row of the texel.
        y: usize,
        /// Colour channel.
        channel: usize,
    },
    /// A value that must be finite was not (outside cubemaps: signals, coefficients, matrices).
    #[error("non-finite value in {what} at index {index}")]
    NonFinite {
        /// What held the value.
        what: &'static str,
        /// Flat index of the value.
        index: usize,
    },
    /// A parameter was outside its valid range.
    #[error("invalid {what}: {why}")]
    Invalid {
        /// The parameter.
        what: &'static str,
        /// Why it is invalid.
        why: String,
    },
    /// The work was cancelled through a [`prt_core::Progress`] handle.
    #[error("cancelled")]
    Cancelled,
    /// An error of the shared core (metrics, progress).
    #[error(transparent)]
    Core(#[from] CoreError),
}

impl WaveletError {
    /// `Err(NonFinite)` naming the first non-finite value of `values`.
    pub(crate) fn check_finite(what: &'static str, values: &[f32]) -> Result<(), WaveletError> {
        match values.iter().position(|v| !v.is_finite()) {
            Some(index) => Err(WaveletError::NonFinite { what, index }),
            None => Ok(()),
        }
    }

    pub(crate) fn check_len(
        what: &'static str,
        expected: usize,
        got: usize,
    ) -> Result<(), WaveletError> {
        if expected == got {
            Ok(())
        } else {
            Err(WaveletError::LengthMismatch {
                what,
                expected,
                got,
            })
        }
    }

    pub(crate) fn check_pow2(
        what: &'static str,
        len: usize,
        min: usize,
    ) -> Result<(), WaveletError> {
        if len >= min && len.is_power_of_two() {
            Ok(())
        } else {
            Err(WaveletError::NotPowerOfTwo { what, len, min })
        }
    }
}
