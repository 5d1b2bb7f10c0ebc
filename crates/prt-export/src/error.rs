use prt_core::CoreError;
use prt_sphere::SphereError;
use prt_texture::TextureError;
use prt_trace::TraceError;
use thiserror::Error;

/// What can go wrong while lighting a bake or writing an export.
#[derive(Debug, Error)]
#[non_exhaustive]
pub enum ExportError {
    /// Reading or writing a texture or file failed.
    #[error(transparent)]
    Texture(#[from] TextureError),
    /// A sky was refused (non-finite coefficient, bad parameter).
    #[error(transparent)]
    Sphere(#[from] SphereError),
    /// A field, kernel evaluation or cancellation error.
    #[error(transparent)]
    Core(#[from] CoreError),
    /// A lit volume that does not fit its grid, or a transfer volume that cannot be lit.
    #[error(transparent)]
    Trace(#[from] TraceError),
    /// An input that does not fit the export (shape, dimension, parameter).
    #[error("invalid {what}: {why}")]
    Invalid {
        /// What was checked.
        what: &'static str,
        /// Why it was refused.
        why: String,
    },
    /// A sky JSON document that is not one of the accepted shapes.
    #[error("sky JSON: {0}")]
    SkyJson(String),
}

impl ExportError {
    pub(crate) fn invalid(what: &'static str, why: impl Into<String>) -> ExportError {
        ExportError::Invalid {
            what,
            why: why.into(),
        }
    }
}
