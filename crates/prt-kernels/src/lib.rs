//! # prt-kernels — spatial kernel families for precomputed light transport
//!
//! Moving Basis Decomposition (Silvennoinen & Sloan, "Moving Basis Decomposition for
//! Precomputed Light Transport", EGSR 2021) stores a field f(x) as
//! `f̂(x) = Σ_i φ_i(x) c_i · Σ_j ψ_j(x) B_j`: coefficients interpolated by one kernel family and
//! basis vectors by another. This crate provides the families, all implementing
//! [`prt_core::SpatialKernels`]:
//!
//! | type | kernels | non-zero at a point |
//! |---|---|---|
//! | [`HatGrid`] | tensor-product linear hats on a regular 1D, 2D or 3D grid | `2^d` |
//! | [`Shepard`] | normalised Wendland C2 kernels over scattered centres | data-dependent, bounded |
//! | [`HybridKernels`] | a 2D hat grid over the ground plane XZ, constant along Y | 4 |
//!
//! Every family is a partition of unity on its domain (non-negative weights summing to one).
//! Hat kernels additionally reproduce affine functions exactly: `Σ_i w_i(x) f(node_i) = f(x)`.
//!
//! ```
//! use glam::Vec3;
//! use prt_core::{Aabb, KernelWeights, SpatialKernels};
//! use prt_kernels::HatGrid;
//!
//! let grid = HatGrid::new([5, 5, 5], Aabb::UNIT).unwrap();
//! let mut w = KernelWeights::with_capacity(grid.max_support());
//! grid.eval(Vec3::new(0.1, 0.6, 0.9), &mut w).unwrap();
//! assert!((w.sum() - 1.0).abs() < 1e-6);
//! ```
#![deny(missing_docs)]

mod error;
mod hat;
mod hybrid;
mod shepard;

pub use error::KernelError;
pub use hat::{HatCorners, HatGrid, HatLocal};
pub use hybrid::HybridKernels;
pub use shepard::{Shepard, wendland_c2};
