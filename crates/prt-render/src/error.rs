//! What can go wrong while rendering or reading a scene mesh.

use prt_core::CoreError;
use prt_texture::TextureError;
use prt_trace::TraceError;

/// An error of [`render`](crate::render) or of building a [`RelitVolume`](crate::RelitVolume).
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

/// An error of writing or reading a scene mesh file ([`read_mesh`](crate::read_mesh),
/// [`decode_mesh`](crate::decode_mesh), [`write_mesh`](crate::write_mesh)).
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum MeshError {
    /// Reading the file failed.
    #[error("cannot read the mesh file: {0}")]
    Io(#[from] std::io::Error),
    /// Writing the file failed.
    #[error("cannot write the mesh file: {0}")]
    Write(#[from] TextureError),
    /// The file does not start with the mesh magic.
    #[error("not a prt scene mesh (bad magic)")]
    BadMagic,
    /// A version this reader does not know.
    #[error("scene mesh version {0} is not supported (this reader knows version 1)")]
    UnsupportedVersion(u32),
    /// A size above the reader's limits.
    #[error("{what} is {value}, above the limit {limit}")]
    TooLarge {
        /// What was too large.
        what: &'static str,
        /// Its value.
        value: u64,
        /// The limit.
        limit: u64,
    },
    /// The file ends inside `what`.
    #[error("the file ends inside {what}")]
    Truncated {
        /// The section being read.
        what: &'static str,
    },
    /// Bytes after the last section.
    #[error("{0} bytes after the last section")]
    TrailingBytes(usize),
    /// A NaN or infinite value.
    #[error("non-finite value in {what} {index}")]
    NonFinite {
        /// The section.
        what: &'static str,
        /// Index of the record in it.
        index: usize,
    },
    /// An index that points outside its table.
    #[error("{what} {index} refers to entry {value} of {len}")]
    OutOfRange {
        /// What holds the index.
        what: &'static str,
        /// Which record.
        index: usize,
        /// The index found.
        value: u64,
        /// The table's length.
        len: usize,
    },
    /// A triangle whose vertices disagree on the material.
    #[error("triangle {0} has vertices of different materials")]
    MixedMaterials(usize),
    /// A name that is not UTF-8.
    #[error("the name of {what} {index} is not UTF-8")]
    BadName {
        /// Material or camera.
        what: &'static str,
        /// Which one.
        index: usize,
    },
    /// A value the format does not allow (flag bits, a non-positive field of view, ...).
    #[error("invalid {what} {index}: {why}")]
    Invalid {
        /// The section.
        what: &'static str,
        /// Which record.
        index: usize,
        /// Why.
        why: String,
    },
    /// The scene cannot be written in this format, or rebuilt from the file.
    #[error(transparent)]
    Scene(#[from] TraceError),
}
