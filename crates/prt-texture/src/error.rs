use std::path::PathBuf;

use thiserror::Error;

/// Everything that can go wrong while encoding, writing or reading a texture.
///
/// Readers never panic on malformed input: every inconsistency of a file maps onto one of these
/// kinds, with enough context (`what`) to find the offending field.
#[derive(Debug, Error)]
#[non_exhaustive]
pub enum TextureError {
    /// An operating-system I/O failure, with the file involved.
    #[error("I/O error on {path}: {source}")]
    Io {
        /// The file being read or written.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
    /// The input ended before a structure that it announces.
    #[error("truncated {what}: needs {needed} bytes, {available} available")]
    Truncated {
        /// The structure being read.
        what: &'static str,
        /// Bytes required.
        needed: u64,
        /// Bytes present.
        available: u64,
    },
    /// A size, count or dimension exceeds the reader's [`crate::Limits`] or the format's range.
    #[error("{what} = {value} exceeds the limit {limit}")]
    TooLarge {
        /// The quantity.
        what: &'static str,
        /// Its value in the file or request.
        value: u64,
        /// The limit it broke.
        limit: u64,
    },
    /// The input is structurally invalid.
    #[error("malformed {what}: {why}")]
    Malformed {
        /// The structure at fault.
        what: &'static str,
        /// What is wrong with it.
        why: String,
    },
    /// The input is valid but uses a feature this crate does not implement.
    #[error("unsupported {what}: {why}")]
    Unsupported {
        /// The feature.
        what: &'static str,
        /// Details.
        why: String,
    },
    /// A value that must be finite was NaN or infinite.
    #[error("non-finite value in {what} at index {index}")]
    NonFinite {
        /// The array holding the value.
        what: &'static str,
        /// Flat index of the value.
        index: usize,
    },
    /// A finite value lies outside what the target encoding can represent.
    #[error("value {value} in {what} at index {index} is outside the representable range")]
    OutOfRange {
        /// The array holding the value.
        what: &'static str,
        /// Flat index of the value.
        index: usize,
        /// The value.
        value: f32,
    },
    /// Two lengths that must agree do not.
    #[error("length mismatch in {what}: expected {expected}, got {got}")]
    LengthMismatch {
        /// What was checked.
        what: &'static str,
        /// Length required.
        expected: usize,
        /// Length given.
        got: usize,
    },
    /// A caller's parameter is invalid (zero size, wrong channel count, ...).
    #[error("invalid {what}: {why}")]
    Invalid {
        /// The parameter.
        what: &'static str,
        /// Why.
        why: String,
    },
    /// The OpenEXR codec reported an error.
    #[error("OpenEXR: {0}")]
    Exr(String),
    /// The DDS codec reported an error.
    #[error("DDS: {0}")]
    Dds(String),
    /// A JSON manifest could not be parsed or produced.
    #[error("manifest JSON: {0}")]
    Json(String),
}

impl TextureError {
    /// Returns `Err(NonFinite)` naming the first non-finite value of `values`.
    pub fn check_finite(what: &'static str, values: &[f32]) -> Result<(), TextureError> {
        match values.iter().position(|v| !v.is_finite()) {
            Some(index) => Err(TextureError::NonFinite { what, index }),
            None => Ok(()),
        }
    }

    pub(crate) fn io(path: &std::path::Path, source: std::io::Error) -> Self {
        TextureError::Io {
            path: path.to_path_buf(),
            source,
        }
    }

    pub(crate) fn malformed(what: &'static str, why: impl Into<String>) -> Self {
        TextureError::Malformed {
            what,
            why: why.into(),
        }
    }

    pub(crate) fn invalid(what: &'static str, why: impl Into<String>) -> Self {
        TextureError::Invalid {
            what,
            why: why.into(),
        }
    }
}
