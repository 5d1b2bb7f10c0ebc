//! BRDF editing with basic incremental updates in Daubechies-4 (Overbeck's chapter 4, after
//! Ben-Artzi, Overbeck and Ramamoorthi, "Real-time BRDF editing in complex lighting", 2006).
//!
//! A 1D BRDF curve (here the microfacet distribution `D(θ_h)` sampled in 256 bins of
//! `θ_h ∈ [0, π/2)`) is edited interactively; each frame spends `k` Daubechies-4 terms on the
//! largest coefficients of the difference between the edited curve and the current
//! approximation. Because terms are assigned exactly and never chosen twice while the curve is
//! static, the approximation is exact (up to the f32 transform) at most `⌈256 / k⌉` frames after
//! the edits stop: 9 frames at 30 terms.

use crate::WaveletError;
use crate::approx::{Approximator, Policy};
use crate::daubechies::Daubechies4;

/// The Beckmann microfacet distribution `D(θ_h) = exp(−tan²θ_h / m²) / (π m² cos⁴θ_h)` of
/// roughness `m` (Cook and Torrance 1982) at the centres of `bins` bins over `[0, π/2)`.
/// Errors if `m` is not finite and positive or `bins` is zero.
pub fn beckmann_curve(roughness: f32, bins: usize) -> Result<Vec<f32>, WaveletError> {
    if !(roughness.is_finite() && roughness > 0.0) || bins == 0 {
        return Err(WaveletError::Invalid {
            what: "Beckmann curve",
            why: format!("roughness {roughness} must be finite and positive, bins {bins} non-zero"),
        });
    }
    let m2 = roughness as f64 * roughness as f64;
    Ok((0..bins)
        .map(|i| {
            let theta = (i as f64 + 0.5) / bins as f64 * std::f64::consts::FRAC_PI_2;
            let (c, t) = (theta.cos(), theta.tan());
            ((-t * t / m2).exp() / (std::f64::consts::PI * m2 * c.powi(4))) as f32
        })
        .collect())
}

/// A free-hand edit: adds a raised-cosine stroke of height `delta` and half-width `radius` bins
/// centred on bin `centre` to `curve` (values are clamped at 0, as a BRDF cannot be negative).
pub fn brush_stroke(curve: &mut [f32], centre: f32, radius: f32, delta: f32) {
    let r = radius.max(1e-3);
    for (i, v) in curve.iter_mut().enumerate() {
        let d = (i as f32 - centre).abs() / r;
        if d < 1.0 {
            *v = (*v + delta * 0.5 * (1.0 + (std::f32::consts::PI * d).cos())).max(0.0);
        }
    }
}

/// An interactive curve editor: BI with `k` Daubechies-4 terms per frame.
#[derive(Debug, Clone)]
pub struct CurveEditor {
    transform: Daubechies4,
    approximator: Approximator,
    coefficients: Vec<f32>,
    curve: Vec<f32>,
}

impl CurveEditor {
    /// An editor for curves of `bins` samples (a power of two >= 2), `terms` per frame.
    pub fn new(bins: usize, terms: usize) -> Result<Self, WaveletError> {
        let transform = Daubechies4::new(bins)?;
        let approximator = Approximator::new(
            vec![0; bins],
            vec![1.0; bins],
            1,
            terms,
            Policy::Incremental,
        )?;
        Ok(Self {
            transform,
            approximator,
            coefficients: vec![0.0; bins],
            curve: vec![0.0; bins],
        })
    }

    /// One frame towards the edited curve `target`; returns the displayed (approximated) curve.
    /// Errors on a length mismatch or a non-finite sample.
    pub fn step(&mut self, target: &[f32]) -> Result<&[f32], WaveletError> {
        WaveletError::check_len("BRDF curve", self.coefficients.len(), target.len())?;
        WaveletError::check_finite("BRDF curve", target)?;
        self.coefficients.copy_from_slice(target);
        self.transform.forward(&mut self.coefficients)?;
        self.approximator.step(&self.coefficients)?;
        self.curve
            .copy_from_slice(self.approximator.approximation());
        self.transform.inverse(&mut self.curve)?;
        Ok(&self.curve)
    }

    /// The displayed curve of the last frame.
    pub fn curve(&self) -> &[f32] {
        &self.curve
    }
}
