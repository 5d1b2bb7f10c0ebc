//! Reference fits over the same samples as the progressive encoder: naive projection, least
//! squares through the exact Gram matrix, least squares over the sample set, non-negative least
//! squares over the sample set (prt-linalg's Lawson-Hanson `nnls_gram`).
use glam::Vec3;
use ndarray::Array2;
use prt_core::SphericalBasis;

use crate::PlsqError;

fn check_samples(dirs: &[Vec3], values: &[f32], channels: usize) -> Result<(), PlsqError> {
    if channels == 0 {
        return Err(PlsqError::invalid("channel count", "must be at least 1"));
    }
    if values.len() != dirs.len() * channels {
        return Err(PlsqError::LengthMismatch {
            what: "sample values",
            expected: dirs.len() * channels,
            got: values.len(),
        });
    }
    if dirs.is_empty() {
        return Err(PlsqError::ZeroTotalWeight);
    }
    PlsqError::check_finite("sample value", values)?;
    if let Some(i) = dirs.iter().position(|d| !d.is_finite()) {
        return Err(PlsqError::NonFinite {
            what: "sample direction",
            index: i,
        });
    }
    Ok(())
}

/// `(A^T A, A^T b)` of the sample set in f64 (`A` is samples × basis).
fn normal_equations<B: SphericalBasis + ?Sized>(
    basis: &B,
    dirs: &[Vec3],
    values: &[f32],
    channels: usize,
) -> (Array2<f64>, Array2<f64>) {
    let k = basis.len();
    let mut ata = Array2::<f64>::zeros((k, k));
    let mut atb = Array2::<f64>::zeros((k, channels));
    let mut b = vec![0.0f32; k];
    for (s, d) in dirs.iter().enumerate() {
        basis.eval(*d, &mut b);
        for i in 0..k {
            let bi = b[i] as f64;
            for j in i..k {
                ata[[i, j]] += bi * b[j] as f64;
            }
            for c in 0..channels {
                atb[[i, c]] += bi * values[s * channels + c] as f64;
            }
        }
    }
    for i in 0..k {
        for j in 0..i {
            ata[[i, j]] = ata[[j, i]];
        }
    }
    (ata, atb)
}

/// Errors unless `m` (symmetric positive semidefinite) is positive definite to working
/// precision: its smallest eigenvalue must exceed `n · 1e-12` times the largest (so that a
/// Cholesky solve cannot silently return noise from a rounding-level pivot).
pub fn check_nonsingular(what: &'static str, m: &Array2<f64>) -> Result<(), PlsqError> {
    let eig = prt_linalg::sym_eig(m.view()).map_err(|e| PlsqError::Singular {
        what,
        why: e.to_string(),
    })?;
    let max = eig.values.iter().fold(0.0f64, |a, &v| a.max(v));
    let min = eig.values.iter().fold(f64::INFINITY, |a, &v| a.min(v));
    if max.is_nan() || max <= 0.0 || min <= m.nrows() as f64 * 1e-12 * max {
        return Err(PlsqError::Singular {
            what,
            why: format!("eigenvalues span [{min:e}, {max:e}]"),
        });
    }
    Ok(())
}

fn to_coeffs(x: &Array2<f64>) -> Vec<f32> {
    x.iter().map(|&v| v as f32).collect()
}

/// Solves `a x = b` for a symmetric positive definite `a` (checked with
/// [`check_nonsingular`] first), naming `what` in the error.
fn solve_spd(
    what: &'static str,
    a: &Array2<f64>,
    b: &Array2<f64>,
) -> Result<Array2<f64>, PlsqError> {
    check_nonsingular(what, a)?;
    prt_linalg::cholesky_solve(a.view(), b.view(), 0.0).map_err(|e| PlsqError::Singular {
        what,
        why: e.to_string(),
    })
}

/// Naive projection: `c_i = scale_i / N Σ_s f(s) B_i(s)` (for SH, `scale = 4π` gives the exact
/// Monte Carlo projection; Probulator's SG "naive" fit uses [`probulator_sg_naive_scale`]).
pub fn naive_projection<B: SphericalBasis + ?Sized>(
    basis: &B,
    dirs: &[Vec3],
    values: &[f32],
    channels: usize,
    scale: f64,
) -> Result<Vec<f32>, PlsqError> {
    check_samples(dirs, values, channels)?;
    let (_, atb) = normal_equations(basis, dirs, values, channels);
    Ok(to_coeffs(&(atb * (scale / dirs.len() as f64))))
}

/// Probulator's normalisation of the naive SG projection, `4λ² / ((1 − e^{−2λ}) n)` (its source
/// notes "there is no solid basis for this").
pub fn probulator_sg_naive_scale(lambda: f64, lobe_count: usize) -> f64 {
    4.0 * lambda * lambda / ((1.0 - (-2.0 * lambda).exp()) * lobe_count as f64)
}

/// Least squares through the exact Gram matrix: `G c = (4π/N) Σ_s f(s) B(s)`.
pub fn least_squares_gram<B: SphericalBasis + ?Sized>(
    basis: &B,
    dirs: &[Vec3],
    values: &[f32],
    channels: usize,
) -> Result<Vec<f32>, PlsqError> {
    check_samples(dirs, values, channels)?;
    let (_, atb) = normal_equations(basis, dirs, values, channels);
    let moments = atb * (4.0 * std::f64::consts::PI / dirs.len() as f64);
    let g = basis.gram();
    let x = solve_spd("Gram matrix", &g, &moments)?;
    Ok(to_coeffs(&x))
}

/// Least squares over the sample set: `min Σ_s |f(s) − Σ_i c_i B_i(s)|²` (normal equations in
/// f64, Cholesky).
pub fn least_squares_samples<B: SphericalBasis + ?Sized>(
    basis: &B,
    dirs: &[Vec3],
    values: &[f32],
    channels: usize,
) -> Result<Vec<f32>, PlsqError> {
    check_samples(dirs, values, channels)?;
    let (ata, atb) = normal_equations(basis, dirs, values, channels);
    let x = solve_spd("sample normal equations", &ata, &atb)?;
    Ok(to_coeffs(&x))
}

/// Non-negative least squares over the sample set, per channel.
pub fn nnls_samples<B: SphericalBasis + ?Sized>(
    basis: &B,
    dirs: &[Vec3],
    values: &[f32],
    channels: usize,
) -> Result<Vec<f32>, PlsqError> {
    check_samples(dirs, values, channels)?;
    let (ata, atb) = normal_equations(basis, dirs, values, channels);
    check_nonsingular("sample normal equations", &ata)?;
    let k = basis.len();
    let mut out = vec![0.0f32; k * channels];
    for c in 0..channels {
        let sol =
            prt_linalg::nnls_gram(ata.view(), atb.column(c)).map_err(|e| PlsqError::Singular {
                what: "sample normal equations",
                why: e.to_string(),
            })?;
        for i in 0..k {
            out[i * channels + c] = sol.x[i] as f32;
        }
    }
    Ok(out)
}

/// Least squares of a whole lat-long map (RGB) through the Gram matrix: `G c = Σ_texels
/// ω_t f_t B(d_t)` with exact texel solid angles `ω_t` and texel-centre directions `d_t`
/// expressed in `frame` (Probulator fits ambient dice this way). Moments in f64.
///
/// Errors: a Gram matrix that is singular to working precision.
pub fn least_squares_map<B: SphericalBasis + ?Sized>(
    basis: &B,
    map: &prt_sphere::LatLongMap,
    frame: crate::LatLongFrame,
) -> Result<Vec<f32>, PlsqError> {
    let k = basis.len();
    let mut moments = Array2::<f64>::zeros((k, 3));
    let mut b = vec![0.0f32; k];
    for y in 0..map.height() {
        let omega = map.texel_solid_angle(y);
        for x in 0..map.width() {
            basis.eval(frame.from_conventions(map.direction(x, y)), &mut b);
            let t = map.texel(x, y).to_array();
            for i in 0..k {
                if b[i] == 0.0 {
                    continue;
                }
                for c in 0..3 {
                    moments[[i, c]] += b[i] as f64 * t[c] as f64 * omega;
                }
            }
        }
    }
    let x = solve_spd("Gram matrix", &basis.gram(), &moments)?;
    Ok(to_coeffs(&x))
}
