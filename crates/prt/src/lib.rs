//! # prt — precomputed light transport
//!
//! A facade over the prt crates, in the way ripgrep's `grep` crate re-exports its parts: depend
//! on `prt` for everything, or on a single crate (`prt-sphere`, `prt-mbd`, ...) for one piece.
//! Each module below is the crate of the same name, enabled by the cargo feature of that name
//! (all on by default; all pure Rust).
//!
//! | module | feature | what it does |
//! |---|---|---|
//! | [`core`] | always | shared traits and types: kernels, sphere bases, grid fields, models, oracles, progress, metrics |
//! | `linalg` | `linalg` | eigen/SVD/Cholesky, PCA with f64 covariance, NNLS, k-means (faer; OpenBLAS with `lapack`) |
//! | `kernels` | `kernels` | hat grids, Shepard kernels, hybrid 2D × 3D kernels |
//! | `sphere` | `sphere` | spherical harmonics, spherical Gaussians, ambient cube/dice, sampling, environment maps |
//! | `plsq` | `plsq` | progressive least-squares encoding (Roughton 2020) and its references |
//! | `trace` | `trace` | glTF scenes, BVH ray queries, transfer-volume baking |
//! | `mbd` | `mbd` | Moving Basis Decomposition (Silvennoinen & Sloan) and the PCA-family baselines |
//! | `wavelet` | `wavelet` | Haar and Daubechies-4 wavelets, NWA, BI and PBI incremental relighting |
//! | `manylight` | `manylight` | many-light matrix sampling: row-column sampling and its successors |
//! | `texture` | `texture` | KTX2, EXR, Radiance HDR, DDS; quantisation; the MBD container |
//! | `bake` | `bake` | the main job: scene → transfer volume → MBD (+ baselines) → scores → container, and the container's reader |
//! | `export` | `export` | a bake lit by a sky, written as probe volumes Bevy, three.js and custom engines load |
//! | `render` | `render` | CPU renders of a scene lit by a transfer volume under a sky, and the scene mesh file |
//! | `shaders` | `shaders` | WGSL and GLSL ES 3.00 sources that render from the MBD container as written |
#![deny(missing_docs)]

pub use prt_core as core;

#[cfg(feature = "bake")]
pub use prt_bake as bake;
#[cfg(feature = "export")]
pub use prt_export as export;
#[cfg(feature = "kernels")]
pub use prt_kernels as kernels;
#[cfg(feature = "linalg")]
pub use prt_linalg as linalg;
#[cfg(feature = "manylight")]
pub use prt_manylight as manylight;
#[cfg(feature = "mbd")]
pub use prt_mbd as mbd;
#[cfg(feature = "plsq")]
pub use prt_plsq as plsq;
#[cfg(feature = "render")]
pub use prt_render as render;
#[cfg(feature = "shaders")]
pub use prt_shaders as shaders;
#[cfg(feature = "sphere")]
pub use prt_sphere as sphere;
#[cfg(feature = "texture")]
pub use prt_texture as texture;
#[cfg(feature = "trace")]
pub use prt_trace as trace;
#[cfg(feature = "wavelet")]
pub use prt_wavelet as wavelet;

/// The workspace README's Rust snippets, compiled and run as doc tests so they stay true.
#[doc = include_str!("../../../README.md")]
#[cfg(doctest)]
pub struct ReadmeDoctests;
