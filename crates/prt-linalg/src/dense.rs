//! Small dense decompositions and solvers: symmetric eigen, thin SVD, Cholesky, LDLT, least
//! squares. Inputs are validated (shape, emptiness, NaN/Inf) before reaching the backend.

use ndarray::{Array1, Array2, ArrayView2, Axis};

use crate::{LinalgError, backend};

/// Returns `Err(NonFinite)` naming the first (row-major) non-finite entry of `a`.
pub(crate) fn check_finite<T: Copy + Into<f64>>(
    what: &'static str,
    a: ArrayView2<'_, T>,
) -> Result<(), LinalgError> {
    match a.iter().position(|v| !(*v).into().is_finite()) {
        Some(index) => Err(LinalgError::NonFinite { what, index }),
        None => Ok(()),
    }
}

fn check_nonempty<T>(what: &'static str, a: ArrayView2<'_, T>) -> Result<(), LinalgError> {
    if a.is_empty() {
        Err(LinalgError::Empty { what })
    } else {
        Ok(())
    }
}

fn check_square<T>(what: &'static str, a: ArrayView2<'_, T>) -> Result<(), LinalgError> {
    if a.nrows() != a.ncols() {
        return Err(LinalgError::ShapeMismatch {
            what,
            expected: a.nrows(),
            got: a.ncols(),
        });
    }
    Ok(())
}

fn check_ridge(ridge: f64) -> Result<(), LinalgError> {
    if !(ridge.is_finite() && ridge >= 0.0) {
        return Err(LinalgError::InvalidParameter {
            what: "ridge",
            why: format!("must be finite and >= 0, got {ridge}"),
        });
    }
    Ok(())
}

/// Flips the sign of `vectors` column `j` (and of `partner` column `j`, if given) so that the
/// entry of largest magnitude is positive: a deterministic sign, identical across backends.
fn canonical_signs(vectors: &mut Array2<f64>, mut partner: Option<&mut Array2<f64>>) {
    for j in 0..vectors.ncols() {
        let col = vectors.column(j);
        let mut best = 0.0f64;
        for &v in col.iter() {
            if v.abs() > best.abs() {
                best = v;
            }
        }
        if best < 0.0 {
            vectors.column_mut(j).mapv_inplace(|v| -v);
            if let Some(p) = partner.as_deref_mut() {
                p.column_mut(j).mapv_inplace(|v| -v);
            }
        }
    }
}

/// A symmetric eigendecomposition `a = vectors * diag(values) * vectors^T`.
#[derive(Debug, Clone, PartialEq)]
pub struct SymEig {
    /// Eigenvalues, in descending order.
    pub values: Array1<f64>,
    /// Orthonormal eigenvectors as columns, in the order of `values`; each column's entry of
    /// largest magnitude is positive.
    pub vectors: Array2<f64>,
}

/// Eigendecomposition of the symmetric matrix `a`.
///
/// Only the lower triangle of `a` is read (the upper is assumed to mirror it). Eigenvalues come
/// out descending, eigenvectors with a deterministic sign (largest entry positive).
///
/// # Errors
/// [`LinalgError::Empty`] for a 0 x 0 matrix, [`LinalgError::ShapeMismatch`] if `a` is not
/// square, [`LinalgError::NonFinite`] for NaN/Inf in the lower triangle,
/// [`LinalgError::NoConvergence`] if the backend's QR iteration fails (not seen in practice).
pub fn sym_eig(a: ArrayView2<'_, f64>) -> Result<SymEig, LinalgError> {
    check_square("a is square", a)?;
    check_nonempty("a", a)?;
    let n = a.nrows();
    for i in 0..n {
        for j in 0..=i {
            if !a[[i, j]].is_finite() {
                return Err(LinalgError::NonFinite {
                    what: "a",
                    index: i * n + j,
                });
            }
        }
    }
    let (ascending, vectors) = backend::eigh(a)?;
    let values = Array1::from_iter(ascending.iter().rev().copied());
    let mut vectors = vectors.slice(ndarray::s![.., ..;-1]).to_owned();
    canonical_signs(&mut vectors, None);
    Ok(SymEig { values, vectors })
}

/// A thin singular value decomposition `a = u * diag(s) * vt`.
#[derive(Debug, Clone, PartialEq)]
pub struct Svd {
    /// Left singular vectors, `m x min(m, n)`, orthonormal columns.
    pub u: Array2<f64>,
    /// Singular values, non-negative and descending.
    pub s: Array1<f64>,
    /// Right singular vectors as rows, `min(m, n) x n`, orthonormal rows; each row's entry of
    /// largest magnitude is positive.
    pub vt: Array2<f64>,
}

/// Thin SVD of the `m x n` matrix `a`.
///
/// # Errors
/// [`LinalgError::Empty`] if `a` has no rows or no columns, [`LinalgError::NonFinite`] for
/// NaN/Inf, [`LinalgError::NoConvergence`] if the backend fails to converge.
pub fn thin_svd(a: ArrayView2<'_, f64>) -> Result<Svd, LinalgError> {
    check_nonempty("a", a)?;
    check_finite("a", a)?;
    let (mut u, s, vt) = backend::svd_thin(a)?;
    let mut v = vt.reversed_axes();
    canonical_signs(&mut v, Some(&mut u));
    Ok(Svd {
        u,
        s: Array1::from(s),
        vt: v.reversed_axes().as_standard_layout().into_owned(),
    })
}

fn check_system(a: ArrayView2<'_, f64>, b: ArrayView2<'_, f64>) -> Result<(), LinalgError> {
    check_square("a is square", a)?;
    check_nonempty("a", a)?;
    if b.nrows() != a.nrows() {
        return Err(LinalgError::ShapeMismatch {
            what: "rows of b",
            expected: a.nrows(),
            got: b.nrows(),
        });
    }
    check_finite("a", a)?;
    check_finite("b", b)
}

fn ridged(a: ArrayView2<'_, f64>, ridge: f64) -> Array2<f64> {
    let mut a = a.to_owned();
    a.diag_mut().mapv_inplace(|d| d + ridge);
    a
}

/// Solves `(a + ridge I) x = b` for symmetric positive definite `a + ridge I` by Cholesky.
///
/// Only the lower triangle of `a` is read. `b` may have any number of columns (zero included).
///
/// # Errors
/// [`LinalgError::NotPositiveDefinite`] when a pivot is not positive (for a semidefinite `a`,
/// pass `ridge > 0` or use [`ldlt_solve`] / [`lstsq`]); shape, emptiness and NaN/Inf errors as
/// usual; [`LinalgError::InvalidParameter`] for a negative or non-finite `ridge`.
pub fn cholesky_solve(
    a: ArrayView2<'_, f64>,
    b: ArrayView2<'_, f64>,
    ridge: f64,
) -> Result<Array2<f64>, LinalgError> {
    check_system(a, b)?;
    check_ridge(ridge)?;
    backend::llt_solve(ridged(a, ridge).view(), b)
}

/// Solves `(a + ridge I) x = b` for symmetric, possibly indefinite `a` by a Bunch-Kaufman
/// (pivoted `L B L^T`) factorization, which needs no positive definiteness.
///
/// Only the lower triangle of `a` is read.
///
/// # Errors
/// [`LinalgError::Singular`] when the factorization meets an exactly singular pivot (the
/// solution would be infinite or NaN); nearly singular systems give large but finite answers,
/// so use [`lstsq`] when `a` may be rank deficient. Other errors as for [`cholesky_solve`].
pub fn ldlt_solve(
    a: ArrayView2<'_, f64>,
    b: ArrayView2<'_, f64>,
    ridge: f64,
) -> Result<Array2<f64>, LinalgError> {
    check_system(a, b)?;
    check_ridge(ridge)?;
    let x = backend::lblt_solve(ridged(a, ridge).view(), b)?;
    if x.iter().any(|v| !v.is_finite()) {
        return Err(LinalgError::Singular);
    }
    Ok(x)
}

/// Minimises `||a x - b||^2 + ridge ||x||^2` for the `m x n` matrix `a` and `m x r` right-hand
/// sides `b`, returning `x` (`n x r`).
///
/// Solved through the thin SVD of `a` (never the normal equations), so it is stable for
/// ill-conditioned `a`: `x = V diag(s / (s^2 + ridge)) U^T b`. With `ridge = 0`, singular values
/// below `max(m, n) * eps * s_max` are treated as zero, which gives the minimum-norm solution for
/// rank-deficient or underdetermined problems (numpy's `lstsq` convention).
///
/// # Errors
/// Shape, emptiness and NaN/Inf errors; [`LinalgError::InvalidParameter`] for a negative or
/// non-finite `ridge`.
pub fn lstsq(
    a: ArrayView2<'_, f64>,
    b: ArrayView2<'_, f64>,
    ridge: f64,
) -> Result<Array2<f64>, LinalgError> {
    check_nonempty("a", a)?;
    if b.nrows() != a.nrows() {
        return Err(LinalgError::ShapeMismatch {
            what: "rows of b",
            expected: a.nrows(),
            got: b.nrows(),
        });
    }
    check_finite("a", a)?;
    check_finite("b", b)?;
    check_ridge(ridge)?;
    let (u, s, vt) = backend::svd_thin(a)?;
    let s_max = s.first().copied().unwrap_or(0.0);
    let cutoff = a.nrows().max(a.ncols()) as f64 * f64::EPSILON * s_max;
    let mut utb = u.t().dot(&b);
    for (mut row, &si) in utb.axis_iter_mut(Axis(0)).zip(&s) {
        let scale = if ridge > 0.0 {
            si / (si * si + ridge)
        } else if si > cutoff {
            1.0 / si
        } else {
            0.0
        };
        row.mapv_inplace(|v| v * scale);
    }
    Ok(vt.t().dot(&utb))
}
