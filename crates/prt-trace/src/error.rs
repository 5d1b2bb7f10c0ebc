use std::path::PathBuf;

use prt_core::CoreError;
use thiserror::Error;

/// Everything that can go wrong while loading a scene, building its BVH or baking transport.
#[derive(Debug, Error)]
#[non_exhaustive]
pub enum TraceError {
    /// A file could not be read.
    #[error("cannot read {path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
    /// A cache file could not be written (it is written to a temporary file and renamed, so a
    /// failure leaves no partial file under its name).
    #[error("cannot write {path}")]
    Write {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        #[source]
        source: prt_texture::TextureError,
    },
    /// The glTF document is malformed (JSON, GLB container, or a failed validation).
    #[error("malformed glTF {path}: {message}")]
    Gltf {
        /// The file.
        path: PathBuf,
        /// What the parser or validator reported.
        message: String,
    },
    /// A buffer referenced by the glTF document could not be loaded.
    #[error("glTF buffer {index} ('{uri}') cannot be loaded: {message}")]
    Buffer {
        /// Buffer index in the document.
        index: usize,
        /// Its URI (`<GLB BIN chunk>` for the binary chunk).
        uri: String,
        /// Why.
        message: String,
    },
    /// An image referenced by a material could not be read (only when textures are decoded).
    #[error("glTF image {index} ('{uri}') cannot be loaded: {message}")]
    Image {
        /// Image index in the document.
        index: usize,
        /// Its URI.
        uri: String,
        /// Why.
        message: String,
    },
    /// A primitive uses a mode other than `TRIANGLES`.
    #[error("mesh '{mesh}' primitive {primitive}: mode {mode} is not supported (only triangles)")]
    UnsupportedMode {
        /// Mesh name (or `#index`).
        mesh: String,
        /// Primitive index inside the mesh.
        primitive: usize,
        /// The mode found.
        mode: String,
    },
    /// A primitive is unusable: no positions, or an index past the vertex count.
    #[error("mesh '{mesh}' primitive {primitive}: {why}")]
    BadPrimitive {
        /// Mesh name (or `#index`).
        mesh: String,
        /// Primitive index inside the mesh.
        primitive: usize,
        /// What is wrong.
        why: String,
    },
    /// A vertex position (after the node transform) is NaN or infinite.
    #[error("non-finite position in {what}, triangle {triangle}")]
    NonFinitePosition {
        /// Where: a mesh and primitive, or "triangles" for [`crate::Scene::from_triangles`].
        what: String,
        /// Triangle index within `what`.
        triangle: usize,
    },
    /// A size limit of [`crate::LoadOptions`] was exceeded.
    #[error("{what}: {got} exceeds the limit {limit}")]
    Limit {
        /// What was counted.
        what: &'static str,
        /// The limit.
        limit: u64,
        /// The amount found.
        got: u64,
    },
    /// The scene has no triangles, so there is nothing to bound a bake by or trace against.
    #[error("the scene has no triangles (give explicit bounds to bake an empty scene)")]
    EmptyScene,
    /// A bake or scene option is out of range.
    #[error("invalid {what}: {why}")]
    InvalidOption {
        /// The option.
        what: &'static str,
        /// Why.
        why: String,
    },
    /// An error of the shared vocabulary, including [`CoreError::Cancelled`].
    #[error(transparent)]
    Core(#[from] CoreError),
}

impl TraceError {
    /// Whether the work was cancelled through its [`prt_core::Progress`] handle.
    pub fn is_cancelled(&self) -> bool {
        matches!(self, TraceError::Core(CoreError::Cancelled))
    }
}
