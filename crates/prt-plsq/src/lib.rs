//! # prt-plsq — progressive least-squares encoding into sphere bases
//!
//! Fits the coefficients of any [`prt_core::SphericalBasis`] (spherical Gaussians, SH, ambient
//! cube/dice from `prt-sphere`) to a stream of radiance samples, one sample at a time, with no
//! stored samples and no matrix solve: Roughton, "Progressive Least-Squares Encoding for Linear
//! Bases", JCGT 9(1), 2020 (<http://jcgt.org/published/0009/01/02/>).
//!
//! ## Method
//! Least squares over the sphere solves `Σ_k b_k ∫B_i B_k = ∫B_i f`. Isolating `b_i`,
//! `b_i = ∫B_i (f − Σ_{k≠i} b_k B_k) / ∫B_i²`: both integrals are estimated by Monte Carlo in
//! lockstep as samples arrive, using the current estimates of the other coefficients. Per
//! sample `s` of value `f(s)` and weight `w` (total `W`): the residual
//! `Δ = f(s) − Σ_j b_j B_j(s)`; per basis function the running mean `I_i` of `B_i(s)²`; and the
//! step `b_i += α w B_i(s) Δ / (W I_i)` ([`Update::Residual`]; α is the paper's acceleration).
//! With Gauss-Seidel sweeps ([`Sweep::GaussSeidel`]) each basis function sees the residual
//! already reduced by the previous ones. [`Update::RunningAverage`] is the 2018 blog/Probulator
//! form. Options: non-negative projection, weighted samples (West's incremental weighted mean),
//! hemisphere mode (a zero sample opposite each true sample), 16-bit state (to show its bias).
//!
//! [`SgEncoder`] is the same encoder specialised for spherical Gaussians (structure of arrays,
//! vectorised `exp`, Gauss-Seidel as a prefix product); it is the one to use for speed.
//! [`BatchEncoder`] runs many independent encoders (lightmap texels, probes) in a blocked
//! structure-of-arrays layout in parallel; [`reference`](mod@reference) has the exact fits over the same samples;
//! [`probulator`] has Probulator's error definition ([`radiance_rmse`]) and lat-long frame.
//!
//! ```
//! use prt_plsq::{EncoderConfig, ProgressiveEncoder, reference};
//! use prt_sphere::{SgBasis, sampling::halton_sphere};
//! use prt_core::NoProgress;
//!
//! let basis = SgBasis::spiral(12, 6.0).unwrap();
//! let dirs = halton_sphere(2000);
//! let values: Vec<f32> = dirs.iter().map(|d| 1.0 + d.y.max(0.0)).collect();
//! let mut enc = ProgressiveEncoder::new(&basis, 1, EncoderConfig::paper()).unwrap();
//! enc.add_samples(&dirs, &values, None, &NoProgress).unwrap();
//! let ls = reference::least_squares_samples(&basis, &dirs, &values, 1).unwrap();
//! // The progressive fit approaches the least-squares fit over the same samples.
//! let (mut a, mut b) = ([0.0f32], 0.0f32);
//! enc.eval(glam::Vec3::Y, &mut a);
//! for (c, l) in ls.iter().zip(prt_sphere::spiral_axes(12)) {
//!     b += c * (6.0 * (l.dot(glam::Vec3::Y) - 1.0)).exp();
//! }
//! assert!((a[0] - b).abs() < 0.05 * b.abs());
//! ```
#![deny(missing_docs)]

mod batch;
mod encoder;
mod error;
mod fast;
pub mod probulator;
pub mod reference;

pub use batch::{BatchEncoder, LANES};
pub use encoder::{
    Denominator, EncoderConfig, Precision, ProgressiveEncoder, SampleOutcome, Sweep, Update,
    true_square_means,
};
pub use error::PlsqError;
pub use fast::{SgEncoder, exp_nonpositive};
pub use probulator::{LatLongFrame, radiance_rmse, sample_nearest};
