//! Error metrics shared by every crate's evaluation.
//!
//! All sums are accumulated in `f64`. Inputs of different lengths are a
//! [`CoreError::LengthMismatch`]; a non-finite value is a [`CoreError::NonFinite`] naming the
//! slice ("approximation", "reference" or "weights") and the index. Empty inputs give 0 for
//! absolute metrics; relative metrics of an all-zero reference are defined as 0 when the
//! approximation is also zero and `f64::INFINITY` otherwise (documented rather than NaN).

use crate::CoreError;

fn check(approx: &[f32], reference: &[f32]) -> Result<(), CoreError> {
    if approx.len() != reference.len() {
        return Err(CoreError::LengthMismatch {
            what: "metric inputs",
            expected: reference.len(),
            got: approx.len(),
        });
    }
    CoreError::check_finite("approximation", approx)?;
    CoreError::check_finite("reference", reference)
}

/// Sum of squared differences, in f64.
pub fn squared_error(approx: &[f32], reference: &[f32]) -> Result<f64, CoreError> {
    check(approx, reference)?;
    Ok(approx
        .iter()
        .zip(reference)
        .map(|(&a, &b)| {
            let d = a as f64 - b as f64;
            d * d
        })
        .sum())
}

/// Root mean squared error `sqrt(Σ (a - b)² / n)`; 0 for empty input.
pub fn rmse(approx: &[f32], reference: &[f32]) -> Result<f64, CoreError> {
    let se = squared_error(approx, reference)?;
    Ok(if approx.is_empty() {
        0.0
    } else {
        (se / approx.len() as f64).sqrt()
    })
}

/// Relative mean squared error `Σ (a - b)² / Σ b²` (the MBD paper's error measure).
pub fn relative_mse(approx: &[f32], reference: &[f32]) -> Result<f64, CoreError> {
    let se = squared_error(approx, reference)?;
    let energy: f64 = reference.iter().map(|&b| (b as f64) * (b as f64)).sum();
    Ok(ratio(se, energy))
}

/// Frobenius norm of the difference `sqrt(Σ (a - b)²)` (the slices are the matrices' entries).
pub fn frobenius_error(approx: &[f32], reference: &[f32]) -> Result<f64, CoreError> {
    Ok(squared_error(approx, reference)?.sqrt())
}

/// Relative Frobenius error `‖A − B‖_F / ‖B‖_F`.
pub fn relative_frobenius_error(approx: &[f32], reference: &[f32]) -> Result<f64, CoreError> {
    Ok(relative_mse(approx, reference)?.sqrt())
}

/// Area-weighted L1 error `Σ w |a − b| / Σ w` (Overbeck's lighting error, with `w` the texel
/// solid angles). Weights must be non-negative and finite; zero total weight gives 0.
pub fn area_weighted_l1(
    approx: &[f32],
    reference: &[f32],
    weights: &[f32],
) -> Result<f64, CoreError> {
    check(approx, reference)?;
    if weights.len() != approx.len() {
        return Err(CoreError::LengthMismatch {
            what: "metric weights",
            expected: approx.len(),
            got: weights.len(),
        });
    }
    CoreError::check_finite("weights", weights)?;
    if let Some(index) = weights.iter().position(|&w| w < 0.0) {
        return Err(CoreError::Invalid {
            what: "metric weights",
            why: format!("weight {index} is negative"),
        });
    }
    let mut num = 0.0f64;
    let mut den = 0.0f64;
    for ((&a, &b), &w) in approx.iter().zip(reference).zip(weights) {
        num += w as f64 * (a as f64 - b as f64).abs();
        den += w as f64;
    }
    Ok(ratio(num, den))
}

fn ratio(num: f64, den: f64) -> f64 {
    if den > 0.0 {
        num / den
    } else if num == 0.0 {
        0.0
    } else {
        f64::INFINITY
    }
}
