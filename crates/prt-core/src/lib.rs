//! # prt-core — the shared vocabulary of prt
//!
//! prt is a toolkit for precomputed light transport. Its crates (ray tracing, sphere bases,
//! Moving Basis Decomposition, wavelets, many-light sampling, texture formats) meet only through
//! the small set of traits and value types defined here, in the way ripgrep's crates meet through
//! `grep-matcher`. This crate knows no file format, no ray tracer and no basis in particular.
//!
//! | item | what it is | implemented by |
//! |---|---|---|
//! | [`SpatialKernels`] | a family of kernels over R³, evaluated sparsely | hat grids, Shepard kernels (`prt-kernels`) |
//! | [`SphericalBasis`] | a linear basis of functions on the unit sphere | SH, SG sets, ambient cube/dice (`prt-sphere`) |
//! | [`GridField`] | a dense 3D grid of D-vectors with trilinear sampling | transfer volumes (`prt-trace`), MBD targets |
//! | [`FieldModel`] / [`Compressor`] | a compressed reconstruction f̂(x) and what fits it | MBD and the PCA family (`prt-mbd`) |
//! | [`MatrixOracle`] | a matrix evaluated a row or a column at a time | the pixel × light matrix (`prt-trace`) |
//! | [`Progress`] | progress reporting and cancellation for long work | the CLI's progress bars, [`NoProgress`] |
//! | [`metrics`] | RMSE, relative MSE, Frobenius error, area-weighted L1 | used by every crate's evaluation |
//!
//! ## Conventions
//! Right-handed, +Y up, metres (glTF). Storage is `f32`; every sum that grows with the data
//! (metrics here, covariances elsewhere) is accumulated in `f64`. Non-finite input is a typed
//! [`CoreError`] naming where it was found, never a silent NaN out.
//!
//! ```
//! use prt_core::{Aabb, GridField};
//! use glam::Vec3;
//!
//! // A 2-dimensional field on a 4×4×4 grid over the unit cube: f(x) = (x.x, 2 x.y + 1).
//! let field = GridField::from_fn([4, 4, 4], Aabb::new(Vec3::ZERO, Vec3::ONE), 2, |p, out| {
//!     out[0] = p.x;
//!     out[1] = 2.0 * p.y + 1.0;
//! })
//! .unwrap();
//! let mut v = [0.0; 2];
//! field.sample(Vec3::new(0.5, 0.5, 0.5), &mut v).unwrap();
//! // Trilinear interpolation reproduces affine fields exactly between voxel centres.
//! assert!((v[0] - 0.5).abs() < 1e-6 && (v[1] - 2.0).abs() < 1e-6);
//! ```
#![deny(missing_docs)]

mod aabb;
mod error;
mod field;
mod kernels;
pub mod metrics;
mod model;
mod oracle;
mod progress;
mod sphere;

pub use aabb::Aabb;
pub use error::CoreError;
pub use field::{GridField, TrilinearWeights};
pub use kernels::{KernelWeights, SpatialKernels};
pub use model::{Compressor, FieldModel, resample_to_grid};
pub use oracle::{DenseOracle, MatrixOracle};
pub use progress::{AtomicProgress, NoProgress, Progress};
pub use sphere::SphericalBasis;

/// Re-exported so that implementers and users of the traits agree on the vector type.
pub use glam;
/// Re-exported so that implementers and users of [`GridField`] agree on the array type.
pub use ndarray;
