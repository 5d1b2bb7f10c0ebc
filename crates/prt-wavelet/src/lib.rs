//! # prt-wavelet — wavelets and incremental relighting
//!
//! Haar and Daubechies-4 wavelets, non-linear and incremental wavelet approximation of changing
//! lighting, and a wavelet-domain relighting engine, reproducing Overbeck's thesis "Exploiting
//! Temporal Coherence for Pre-computation Based Rendering" (Columbia, 2009; EGSR 2006 paper with
//! Ben-Artzi, Ramamoorthi and Grinspun) on top of Ng, Ramamoorthi and Hanrahan's "All-Frequency
//! Shadows Using Non-linear Wavelet Lighting Approximation" (SIGGRAPH 2003).
//!
//! | item | what it is |
//! |---|---|
//! | [`haar_forward`], [`Haar2d`] | orthonormal Haar: 1D multilevel, 2D non-standard decomposition |
//! | [`CubemapHaar`], [`CubemapLayout`] | a cube map as one coefficient vector, band and area weight per coefficient; level × face × tile bands |
//! | [`Cubemap::from_lat_long`] | area-averaged resampling of a rotated `prt_sphere::LatLongMap` onto cube faces |
//! | [`Daubechies4`] | PyWavelets' `db2` with `mode='periodization'`, multilevel, orthonormal |
//! | [`Approximator`] | NWA, BI and PBI (exhaustive, L1-test and dealer band strategies) |
//! | [`ShApproximator`] | PBI for spherical-harmonic lighting with tolerance-driven band filling |
//! | [`sequence`] | lighting sequences: rotation about +Y with a stop frame, interpolation |
//! | [`analysis`] | per-frame area-weighted L1, terms per band per frame, spatio-temporal band energy |
//! | [`brdf`] | 256-bin BRDF curves (Beckmann, free-hand) edited with BI in Daubechies-4, and on an image: per-pixel curve transport, incremental image updates |
//! | [`Relighter`], [`SparseTransport`] | `B = T L` with quantised, row-truncated wavelet transport and per-band partial images |
//! | [`BrdfFactorisation`] | a BRDF as `K` in-out products (SVD on a paraboloid hemisphere grid): glossy transport under a changing view (thesis §7.2) |
//! | [`CpcaModel`], [`CpcaRelighter`] | clustered-PCA transport relit in two incremental stages: projections from the lighting update, BI on the points' weights (thesis §7.3) |
//! | [`TransportParts`] | a sparse transport in its stored form, for files ([`SparseTransport::to_parts`], [`SparseTransport::from_parts`]) |
//!
//! ## The method
//! Lighting `L` (a cube map, 6 × n × n texels per channel) is Haar-transformed face by face.
//! All-frequency relighting computes `B = T L` with a sparse wavelet-domain transport `T`, and
//! its cost is proportional to the number of lighting terms used, so `L` is approximated with
//! `k` terms per frame. NWA keeps the `k` largest coefficients; BI spends the `k` terms on the
//! largest coefficients of the *difference* to last frame's approximation; PBI decides per
//! wavelet level whether the difference or the lighting itself is sparser, because coarse
//! levels are temporally coherent under motion and fine levels are not. See [`Approximator`].
//!
//! ```
//! use prt_wavelet::{Approximator, BandStrategy, Cubemap, CubemapHaar, CubemapLayout, Policy, Weighting};
//!
//! // A 1-channel 8 × 8 cube map with one bright texel on +Y.
//! let mut texels = vec![0.1f32; 6 * 64];
//! texels[2 * 64 + 3 * 8 + 4] = 50.0;
//! let map = Cubemap::new(8, 1, texels)?;
//! let mut coeffs = map.into_data();
//! CubemapHaar::new(8)?.forward(&mut coeffs)?;
//!
//! let layout = CubemapLayout::new(8)?;
//! let mut pbi = Approximator::for_cubemap(&layout, 1, Weighting::Area, 10, Policy::PerBand(BandStrategy::L1Test))?;
//! // Static lighting: PBI converges to the exact coefficients within ⌈non-zeros / k⌉ frames.
//! for _ in 0..((6 + 7) / 10 + 1) {
//!     pbi.step(&coeffs)?;
//! }
//! assert_eq!(pbi.approximation(), &coeffs[..]);
//! # Ok::<(), prt_wavelet::WaveletError>(())
//! ```
//!
//! ## Lighting from lat-long maps
//! Maps are `prt-sphere`'s [`prt_sphere::LatLongMap`] and cube faces follow its conventions
//! (`prt_sphere::envmap::cube_to_direction`: +X, −X, +Y, −Y, +Z, −Z, Vulkan orientation), but
//! [`Cubemap::from_lat_long`] does not call `LatLongMap::to_cubemap`: that takes one bilinear
//! lookup at each texel centre, and a light smaller than a cube texel is then seen only while a
//! centre falls near it. Under rotation such a light blinks (probulator_grace on 64 × 64 faces:
//! total energy 4.4 to 10.9 across frames of a 1°/frame rotation), which is temporal
//! incoherence of the resampling, not of the lighting, and defeats incremental updates. Here
//! each texel is the solid-angle-weighted mean of `samples × samples` lookups
//! ([`Cubemap::default_samples`]: about four per lat-long texel, 4 × 4 to 16 × 16); the energy
//! then stays within 1%.
//!
//! Errors are [`WaveletError`]s: sizes that are not powers of two, mismatched faces or buffers,
//! and non-finite lighting (naming the face, texel and channel) are reported, never panicked on.
#![deny(missing_docs)]

pub mod analysis;
mod approx;
pub mod brdf;
mod cpca;
mod cubemap;
mod daubechies;
mod error;
mod haar;
mod relight;
pub mod sequence;
mod sh;
mod view;

pub use approx::{Approximator, BandMode, BandStrategy, FrameUpdate, Policy, Term, Weighting};
pub use cpca::{CpcaModel, CpcaRelighter, CpcaWork, PointUpdate};
pub use cubemap::{Cubemap, CubemapHaar, CubemapLayout, texel_solid_angles};
pub use daubechies::Daubechies4;
pub use error::WaveletError;
pub use haar::{Haar2d, band_of_2d, haar_forward, haar_inverse};
pub use relight::{Relighter, SparseTransport, TransportParts};
pub use sh::ShApproximator;
pub use view::{
    BrdfFactorisation, FactorisationConfig, local_frame, paraboloid_coordinates,
    paraboloid_direction,
};
