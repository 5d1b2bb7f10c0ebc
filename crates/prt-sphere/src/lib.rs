//! # prt-sphere — sphere bases, sampling and environment maps
//!
//! The linear bases over the unit sphere that prt encodes lighting and transport in, each a
//! [`prt_core::SphericalBasis`] with an exact (or quadrature) Gram matrix:
//!
//! | basis | functions | Gram |
//! |---|---|---|
//! | [`ShBasis`] | real orthonormal spherical harmonics, any order ([`sh`]) | identity |
//! | [`SgBasis`] | spherical Gaussians on Probulator's spiral, Fibonacci or icosahedral axes ([`sg`]) | analytic |
//! | [`AmbientCube`] | six clamped cos² lobes (Valve 2004) | analytic |
//! | [`AmbientDiceSrbf`] | ambient dice, SRBF variant (Iwanicki & Sloan 2017) | quadrature |
//! | [`AmbientDiceBezier`] | ambient dice, hybrid cubic Bezier variant (36 functions) | quadrature |
//!
//! plus SH rotation of any order (Ivanic & Ruedenberg 1996) and zonal convolution with the
//! clamped cosine (Ramamoorthi & Hanrahan 2001), sphere point sets ([`sampling`]) and
//! lat-long / cube environment maps with exact texel solid angles ([`envmap`]), and [`Sky`]:
//! distant lighting as order-3 SH per colour channel, the input that lights a transfer volume.
//!
//! Conventions (prt's conventions.md): right-handed, +Y up; SH polar axis = +Y with the
//! explicit polynomials listed in [`sh`]; SG `G(v) = μ exp(λ (p·v − 1))`; lat-long texel
//! centres `θ = 2πu`, `φ = πv`, `dir = (sin φ sin θ, cos φ, −sin φ cos θ)`.
//!
//! ```
//! use prt_sphere::{ShBasis, SgBasis, sg_integral};
//! use prt_core::SphericalBasis;
//! use glam::Vec3;
//!
//! let sh = ShBasis::new(3).unwrap(); // bands 0..2, 9 functions
//! let mut y = [0.0f32; 9];
//! sh.eval(Vec3::Y, &mut y);
//! assert!((y[2] - 0.488603).abs() < 1e-5); // Y_1^0 = 0.488603 y
//!
//! let sg = SgBasis::spiral(12, 6.0).unwrap();
//! let g = sg.gram();
//! // The diagonal is ∫ G² = 2π (1 − e^{−4λ}) / (2λ), exactly.
//! assert!((g[[0, 0]] - sg_integral(12.0)).abs() < 1e-12);
//! ```
#![deny(missing_docs)]

mod ambient;
pub mod envmap;
mod error;
pub mod sampling;
pub mod sg;
pub mod sh;
mod sky;

pub use ambient::{AmbientCube, AmbientDiceBezier, AmbientDiceSrbf, quadrature_gram};
pub use envmap::{CubeMap, LatLongMap};
pub use error::SphereError;
pub use sg::{
    SgBasis, SgLobe, fibonacci_axes, icosahedral_axes, sg_inner_product, sg_integral, spiral_axes,
};
pub use sh::{ShBasis, ShRotation, eval_sh, eval_sh_f64, sh_index, sh_len};
pub use sky::{SKY_SH, Sky, SunSky};
