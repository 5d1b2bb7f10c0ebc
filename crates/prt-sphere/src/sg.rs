//! Spherical Gaussians `G(v) = μ exp(λ (p·v − 1))` (conventions.md), lobe sets, analytic inner
//! products and an irradiance approximation.
//!
//! Every closed form is written so that it stays finite and accurate for sharpness from 0 to
//! beyond 1e4: integrals use `expm1`, inner products use `|λ₁p₁ + λ₂p₂| − λ₁ − λ₂` computed
//! without cancellation (`1 − p₁·p₂ = |p₁ − p₂|²/2`), and nothing is ever `exp` of a positive
//! number larger than 0.
use glam::{DVec3, Vec3};
use ndarray::Array2;
use prt_core::SphericalBasis;

use crate::SphereError;

const TWO_PI: f64 = 2.0 * std::f64::consts::PI;

/// `(1 − e^{−2x}) / x`, accurate for all `x >= 0` (limit 2 at 0).
fn one_minus_exp_neg2x_over_x(x: f64) -> f64 {
    if x < 1e-12 {
        2.0 - 2.0 * x
    } else {
        -(-2.0 * x).exp_m1() / x
    }
}

/// `∫_S² exp(λ (p·v − 1)) dv = 2π (1 − e^{−2λ}) / λ` (4π at λ = 0).
pub fn sg_integral(sharpness: f64) -> f64 {
    TWO_PI * one_minus_exp_neg2x_over_x(sharpness)
}

/// `∫_S² G₁ G₂` for unit-amplitude lobes: `2π e^{r − λ₁ − λ₂} (1 − e^{−2r}) / r` with
/// `r = |λ₁ p₁ + λ₂ p₂|`. Axes are normalised first (so f32 axes give f64-accurate results).
pub fn sg_inner_product(p1: DVec3, l1: f64, p2: DVec3, l2: f64) -> f64 {
    let (p1, p2) = (p1.normalize(), p2.normalize());
    let r = (p1 * l1 + p2 * l2).length();
    let s = l1 + l2;
    // r − s = (r² − s²)/(r + s) = −2 λ₁ λ₂ (1 − p₁·p₂) / (r + s), with 1 − p₁·p₂ = |p₁ − p₂|²/2.
    let one_minus_dot = 0.5 * (p1 - p2).length_squared();
    let r_minus_s = if r + s > 0.0 {
        -2.0 * l1 * l2 * one_minus_dot / (r + s)
    } else {
        0.0
    };
    TWO_PI * r_minus_s.exp() * one_minus_exp_neg2x_over_x(r)
}

/// One spherical Gaussian lobe with an RGB amplitude.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SgLobe {
    /// Unit axis `p`.
    pub axis: Vec3,
    /// Sharpness `λ >= 0`.
    pub sharpness: f32,
    /// Amplitude `μ` per channel.
    pub amplitude: Vec3,
}

impl SgLobe {
    /// Evaluates the lobe at unit direction `dir`.
    pub fn eval(&self, dir: Vec3) -> Vec3 {
        self.amplitude * (self.sharpness * (self.axis.dot(dir) - 1.0)).exp()
    }

    /// `∫_S² G`, per channel.
    pub fn integral(&self) -> Vec3 {
        self.amplitude * sg_integral(self.sharpness as f64) as f32
    }

    /// Irradiance `∫ G(v) max(0, n·v) dv` at unit normal `n`.
    ///
    /// For `λ <= 16` it is exact: both functions are zonal, so the integral is the Legendre series
    /// `Σ_l e^{−λ} (2l+1) i_l(λ) A_l P_l(p·n)` (`i_l` the modified spherical Bessel function,
    /// `A_l` the clamped-cosine coefficients), summed until its terms vanish. Above, Hill's
    /// fitted approximation (S. Hill, in M. Pettineo's "SG Series" part 3, 2016), which is
    /// accurate to a few percent of the peak for sharp lobes and breaks down below λ ≈ 1.
    /// Never NaN for `λ` in `[0, ∞)`.
    pub fn irradiance(&self, normal: Vec3) -> Vec3 {
        let lambda = self.sharpness as f64;
        let mu_dot_n = (self.axis.dot(normal) as f64).clamp(-1.0, 1.0);
        let e = if lambda <= 16.0 {
            sg_irradiance_series(lambda, mu_dot_n)
        } else {
            let c0 = 0.36;
            let c1 = 1.0 / (4.0 * c0);
            let eml = (-lambda).exp();
            let em2l = eml * eml;
            let rl = 1.0 / lambda;
            let scale = 1.0 + 2.0 * em2l - rl;
            let bias = (eml - em2l) * rl - em2l;
            let x = (1.0 - scale).max(0.0).sqrt();
            let x0 = c0 * mu_dot_n;
            let x1 = c1 * x;
            let n = x0 + x1;
            let y = if x0.abs() <= x1 && x > 0.0 {
                n * n / x
            } else {
                mu_dot_n.clamp(0.0, 1.0)
            };
            (scale * y + bias) * sg_integral(lambda)
        };
        self.amplitude * e.max(0.0) as f32
    }

    /// `∫ G₁ G₂`, per channel.
    pub fn inner_product(&self, other: &SgLobe) -> Vec3 {
        let s = sg_inner_product(
            self.axis.as_dvec3(),
            self.sharpness as f64,
            other.axis.as_dvec3(),
            other.sharpness as f64,
        );
        self.amplitude * other.amplitude * s as f32
    }
}

/// Probulator's spiral ("Vogel's sphere") of `n` axes: axis `i` has
/// `z = lerp(1 − 1/n, 1/n − 1, i/(n−1))`, azimuth `i π (3 − √5)`, radius `√(1 − z²)`, given
/// literally as `(r cos φ, r sin φ, z)` (for `n = 1`, `t = 1/2`).
pub fn spiral_axes(n: usize) -> Vec<Vec3> {
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    (0..n)
        .map(|i| {
            let nf = n as f64;
            let t = if n > 1 { i as f64 / (nf - 1.0) } else { 0.5 };
            let z = (1.0 - 1.0 / nf) + ((1.0 / nf - 1.0) - (1.0 - 1.0 / nf)) * t;
            let r = (1.0 - z * z).max(0.0).sqrt();
            let phi = golden * i as f64;
            DVec3::new(r * phi.cos(), r * phi.sin(), z)
                .normalize()
                .as_vec3()
        })
        .collect()
}

/// Fibonacci sphere of `n` axes around +Y: `y_i = 1 − (2i + 1)/n`, azimuth `i π (3 − √5)`.
pub fn fibonacci_axes(n: usize) -> Vec<Vec3> {
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    (0..n)
        .map(|i| {
            let y = 1.0 - (2 * i + 1) as f64 / n as f64;
            let r = (1.0 - y * y).max(0.0).sqrt();
            let phi = golden * i as f64;
            DVec3::new(r * phi.cos(), y, r * phi.sin()).as_vec3()
        })
        .collect()
}

/// The 12 vertices of the regular icosahedron `(±1, ±t, 0)`, `(0, ±1, ±t)`, `(±t, 0, ±1)` with
/// `t = 1/φ`, normalised, in the order of Probulator's ambient dice.
pub fn icosahedral_axes() -> Vec<Vec3> {
    let t = 0.618_033_988_749_894_9_f64;
    [
        (1.0, t, 0.0),
        (-1.0, t, 0.0),
        (1.0, -t, 0.0),
        (-1.0, -t, 0.0),
        (0.0, 1.0, t),
        (0.0, -1.0, t),
        (0.0, 1.0, -t),
        (0.0, -1.0, -t),
        (t, 0.0, 1.0),
        (-t, 0.0, 1.0),
        (t, 0.0, -1.0),
        (-t, 0.0, -1.0),
    ]
    .iter()
    .map(|&(x, y, z)| DVec3::new(x, y, z).normalize().as_vec3())
    .collect()
}

/// A set of spherical Gaussian lobes (axes and sharpness; amplitudes are the coefficients) as
/// a [`SphericalBasis`].
#[derive(Debug, Clone, PartialEq)]
pub struct SgBasis {
    axes: Vec<Vec3>,
    sharpness: Vec<f32>,
    label: String,
}

impl SgBasis {
    /// Lobes with the given unit axes and sharpness (one per axis). Errors: no lobes, a
    /// non-finite or non-unit axis (|1 − |p|| > 1e-3), a sharpness that is negative, NaN or
    /// infinite.
    pub fn new(
        axes: Vec<Vec3>,
        sharpness: Vec<f32>,
        label: impl Into<String>,
    ) -> Result<Self, SphereError> {
        if axes.is_empty() {
            return Err(SphereError::invalid(
                "lobe count",
                "at least one lobe is needed",
            ));
        }
        if sharpness.len() != axes.len() {
            return Err(SphereError::LengthMismatch {
                what: "sharpness",
                expected: axes.len(),
                got: sharpness.len(),
            });
        }
        for (i, a) in axes.iter().enumerate() {
            if !a.is_finite() {
                return Err(SphereError::NonFinite {
                    what: "lobe axis",
                    index: i,
                });
            }
            if (a.length() - 1.0).abs() > 1e-3 {
                return Err(SphereError::invalid(
                    "lobe axis",
                    format!("axis {i} is not a unit vector"),
                ));
            }
        }
        for (i, &l) in sharpness.iter().enumerate() {
            if !l.is_finite() {
                return Err(SphereError::NonFinite {
                    what: "lobe sharpness",
                    index: i,
                });
            }
            if l < 0.0 {
                return Err(SphereError::invalid(
                    "lobe sharpness",
                    format!("lobe {i} has λ = {l} < 0"),
                ));
            }
        }
        let axes = axes.into_iter().map(|a| a.normalize()).collect();
        Ok(Self {
            axes,
            sharpness,
            label: label.into(),
        })
    }

    /// Probulator's default: `n` lobes on its spiral, all of sharpness `lambda`.
    pub fn spiral(n: usize, lambda: f32) -> Result<Self, SphereError> {
        Self::new(
            spiral_axes(n),
            vec![lambda; n],
            format!("SG {n} spiral λ={lambda}"),
        )
    }

    /// `n` lobes on a Fibonacci sphere, all of sharpness `lambda`.
    pub fn fibonacci(n: usize, lambda: f32) -> Result<Self, SphereError> {
        Self::new(
            fibonacci_axes(n),
            vec![lambda; n],
            format!("SG {n} Fibonacci λ={lambda}"),
        )
    }

    /// 12 lobes on the icosahedron's vertices, all of sharpness `lambda`.
    pub fn icosahedral(lambda: f32) -> Result<Self, SphereError> {
        Self::new(
            icosahedral_axes(),
            vec![lambda; 12],
            format!("SG 12 icosahedral λ={lambda}"),
        )
    }

    /// The lobe axes.
    pub fn axes(&self) -> &[Vec3] {
        &self.axes
    }

    /// The lobe sharpness values.
    pub fn sharpness(&self) -> &[f32] {
        &self.sharpness
    }

    /// `∫ B_i²` per lobe (exact).
    pub fn square_integrals(&self) -> Vec<f64> {
        self.sharpness
            .iter()
            .map(|&l| sg_integral(2.0 * l as f64))
            .collect()
    }

    /// The lobes with amplitudes `coeffs` (`len` rows of `channels = 3`).
    pub fn lobes(&self, rgb: &[Vec3]) -> Result<Vec<SgLobe>, SphereError> {
        if rgb.len() != self.axes.len() {
            return Err(SphereError::LengthMismatch {
                what: "amplitudes",
                expected: self.axes.len(),
                got: rgb.len(),
            });
        }
        Ok(self
            .axes
            .iter()
            .zip(&self.sharpness)
            .zip(rgb)
            .map(|((&axis, &sharpness), &amplitude)| SgLobe {
                axis,
                sharpness,
                amplitude,
            })
            .collect())
    }
}

impl SphericalBasis for SgBasis {
    fn len(&self) -> usize {
        self.axes.len()
    }

    fn eval(&self, dir: Vec3, out: &mut [f32]) {
        for ((o, a), &l) in out[..self.axes.len()]
            .iter_mut()
            .zip(&self.axes)
            .zip(&self.sharpness)
        {
            *o = (l * (a.dot(dir) - 1.0)).exp();
        }
    }

    fn gram(&self) -> Array2<f64> {
        let n = self.axes.len();
        Array2::from_shape_fn((n, n), |(i, j)| {
            sg_inner_product(
                self.axes[i].as_dvec3(),
                self.sharpness[i] as f64,
                self.axes[j].as_dvec3(),
                self.sharpness[j] as f64,
            )
        })
    }

    fn name(&self) -> String {
        self.label.clone()
    }
}

/// Exact irradiance of a unit SG of sharpness `lambda` at cosine `t` between axis and normal, by
/// its Legendre series (converges fast for moderate λ; used for λ <= 4).
fn sg_irradiance_series(lambda: f64, t: f64) -> f64 {
    let mut sum = 0.0;
    let (mut p_prev, mut p) = (1.0, t); // P_0, P_1
    for l in 0..64usize {
        let pl = if l == 0 { 1.0 } else { p };
        let a = crate::sh::clamped_cosine_coefficient(l);
        if a != 0.0 {
            let term =
                (-lambda).exp() * (2 * l + 1) as f64 * spherical_bessel_i(l, lambda) * a * pl;
            sum += term;
            if l > 2 && term.abs() < 1e-16 * sum.abs() {
                break;
            }
        }
        if l >= 1 {
            let lf = l as f64;
            let next = ((2.0 * lf + 1.0) * t * p - lf * p_prev) / (lf + 1.0);
            p_prev = p;
            p = next;
        }
    }
    sum
}

/// Modified spherical Bessel function of the first kind `i_l(x)` by its power series (x >= 0,
/// all terms positive, so accurate for the x <= 16 it is used at).
fn spherical_bessel_i(l: usize, x: f64) -> f64 {
    // i_l(x) = x^l / (2l+1)!! Σ_k (x²/2)^k / (k! (2l+3)(2l+5)...(2l+2k+1))
    let mut lead = 1.0;
    for k in 0..l {
        lead *= x / (2 * k + 3) as f64;
    }
    let mut term = 1.0;
    let mut sum = 1.0;
    let half_x2 = 0.5 * x * x;
    for k in 1..200 {
        term *= half_x2 / (k as f64 * (2 * l + 2 * k + 1) as f64);
        sum += term;
        if term < 1e-17 * sum {
            break;
        }
    }
    lead * sum
}
