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
    /// A primitive is unusable: no positions, an attribute naming a missing accessor, or morph
    /// targets that do not match its vertices.
    #[error("mesh '{mesh}' primitive {primitive}: {why}")]
    BadPrimitive {
        /// Mesh name (or `#index`).
        mesh: String,
        /// Primitive index inside the mesh.
        primitive: usize,
        /// What is wrong.
        why: String,
    },
    /// An accessor cannot be read as what it is used for: wrong type or component type, count
    /// 0, a stride below its element size, data past its buffer view or buffer, an index past
    /// the vertex count.
    #[error("glTF accessor {accessor} ({used_as}): {why}")]
    BadAccessor {
        /// Accessor index in the document.
        accessor: usize,
        /// What it was read as, e.g. "mesh 'box' primitive 0 POSITION".
        used_as: String,
        /// What is wrong.
        why: String,
    },
    /// The node hierarchy is not a set of disjoint trees (a cycle, or a node with two parents).
    #[error("glTF node {node}: {why}")]
    BadNode {
        /// Node index in the document.
        node: usize,
        /// What is wrong.
        why: String,
    },
    /// The document needs an extension that changes how geometry is stored or placed (Draco or
    /// meshopt compression, GPU instancing), which the loader cannot read: it is required, or
    /// used without a complete fallback.
    #[error(
        "glTF extension {name} is not supported and the geometry cannot be read without it \
         (it compresses or instances meshes); export without it"
    )]
    UnsupportedExtension {
        /// The extension's name.
        name: String,
    },
    /// Loading failed after gathering warnings, which may explain the failure.
    #[error("{error} (warnings before it: {})", warnings.join("; "))]
    WithWarnings {
        /// The failure.
        error: Box<TraceError>,
        /// The warnings gathered before it.
        warnings: Vec<String>,
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
    /// A bake in which no voxel is valid: each is inside geometry (its probe rays see back faces)
    /// or outside the scene bounds plus margin. The message names the knobs of
    /// [`crate::BakeOptions`]; front ends name their own flags for them.
    #[error(
        "no valid voxel: {invalid} of {voxels} are inside geometry and {skipped} outside the scene; \
         grow the margin (BakeOptions::margin) or the grid bounds (BakeOptions::bounds) so that \
         voxels lie in open space"
    )]
    NoValidVoxels {
        /// Voxels in the grid.
        voxels: usize,
        /// Voxels inside geometry.
        invalid: usize,
        /// Voxels outside the scene bounds plus margin.
        skipped: usize,
    },
    /// A bake or scene option is out of range.
    #[error("invalid {what}: {why}")]
    InvalidOption {
        /// The option.
        what: &'static str,
        /// Why.
        why: String,
    },
    /// A per-pixel transport file is malformed.
    #[error("bad pixel-transport file {path}: {why}")]
    BadTransportFile {
        /// The file.
        path: PathBuf,
        /// The first thing found wrong.
        why: String,
    },
    /// An error of the wavelet transport (prt-wavelet).
    #[error(transparent)]
    Wavelet(#[from] prt_wavelet::WaveletError),
    /// An error of the shared vocabulary, including [`CoreError::Cancelled`].
    #[error(transparent)]
    Core(#[from] CoreError),
}

impl TraceError {
    /// The failure without the warnings [`TraceError::WithWarnings`] attaches, and those
    /// warnings (empty for any other error).
    pub fn without_warnings(&self) -> (&TraceError, &[String]) {
        match self {
            TraceError::WithWarnings { error, warnings } => (error, warnings),
            other => (other, &[]),
        }
    }

    /// Whether the work was cancelled through its [`prt_core::Progress`] handle.
    pub fn is_cancelled(&self) -> bool {
        matches!(self, TraceError::Core(CoreError::Cancelled))
    }
}
