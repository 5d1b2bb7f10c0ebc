//! ndarray-linalg (LAPACK) + OpenBLAS implementation of the backend kernels.

use ndarray::linalg::general_mat_mul;
use ndarray::{Array2, ArrayView2, ArrayViewMut2, Axis};
use ndarray_linalg::{
    Eigh, FactorizeC, FactorizeH, JobSvd, QR, SVDDC, SolveC, SolveH, UPLO,
    error::LinalgError as LapackError,
};

use super::{Op, Operand, Real, SvdParts};
use crate::LinalgError;

fn view<'a, T: Real>(o: &Operand<'a, T>) -> ArrayView2<'a, T> {
    // The slice length was sized by the caller for these dimensions.
    let m = ArrayView2::from_shape((o.rows, o.cols), o.data)
        .unwrap_or_else(|_| unreachable!("operand slice does not match its shape"));
    match o.op {
        Op::N => m,
        Op::T => m.reversed_axes(),
    }
}

fn backend_error(e: LapackError) -> LinalgError {
    LinalgError::Backend(e.to_string())
}

/// `dst (m x n, row-major) (+)= a * b` through BLAS `?gemm` (`lower_only` computes the full
/// product: the upper triangle is simply not read by the caller).
pub(crate) fn gemm<T: Real>(
    dst: &mut [T],
    accumulate: bool,
    a: Operand<'_, T>,
    b: Operand<'_, T>,
    _lower_only: bool,
    _parallel: bool,
) {
    let (m, _) = a.shape();
    let (_, n) = b.shape();
    let mut c = ArrayViewMut2::from_shape((m, n), dst)
        .unwrap_or_else(|_| unreachable!("destination slice does not match its shape"));
    let beta = if accumulate { T::one() } else { T::zero() };
    general_mat_mul(T::one(), &view(&a), &view(&b), beta, &mut c);
}

/// Eigenvalues (ascending) and eigenvectors (columns) of a symmetric matrix (LAPACK `dsyevd`),
/// reading its lower triangle.
pub(crate) fn eigh(a: ArrayView2<'_, f64>) -> Result<(Vec<f64>, Array2<f64>), LinalgError> {
    let (values, vectors) =
        a.to_owned()
            .eigh(UPLO::Lower)
            .map_err(|_| LinalgError::NoConvergence {
                what: "symmetric eigendecomposition",
                iterations: 0,
            })?;
    Ok((values.to_vec(), vectors))
}

/// Thin SVD `a = u diag(s) vt` with `s` descending (LAPACK `dgesdd`).
pub(crate) fn svd_thin(a: ArrayView2<'_, f64>) -> Result<SvdParts, LinalgError> {
    let (u, s, vt) = a
        .to_owned()
        .svddc(JobSvd::Some)
        .map_err(|_| LinalgError::NoConvergence {
            what: "thin SVD",
            iterations: 0,
        })?;
    match (u, vt) {
        (Some(u), Some(vt)) => Ok((u, s.to_vec(), vt)),
        _ => Err(LinalgError::Backend(
            "gesdd returned no singular vectors".into(),
        )),
    }
}

fn solve_columns(
    b: ArrayView2<'_, f64>,
    mut solve: impl FnMut(&ndarray::Array1<f64>) -> Result<ndarray::Array1<f64>, LinalgError>,
) -> Result<Array2<f64>, LinalgError> {
    let mut x = Array2::zeros(b.raw_dim());
    for (j, col) in b.axis_iter(Axis(1)).enumerate() {
        x.column_mut(j).assign(&solve(&col.to_owned())?);
    }
    Ok(x)
}

/// Solves `a x = b` for symmetric positive definite `a` (lower triangle read) by Cholesky
/// (LAPACK `dpotrf`).
pub(crate) fn llt_solve(
    a: ArrayView2<'_, f64>,
    b: ArrayView2<'_, f64>,
) -> Result<Array2<f64>, LinalgError> {
    let factor = a.to_owned().factorizec(UPLO::Lower).map_err(|e| match e {
        LapackError::Lapack(lax::error::Error::LapackComputationalFailure { return_code })
            if return_code > 0 =>
        {
            LinalgError::NotPositiveDefinite {
                pivot: return_code as usize - 1,
            }
        }
        other => backend_error(other),
    })?;
    solve_columns(b, |col| factor.solvec(col).map_err(backend_error))
}

/// Solves `a x = b` for symmetric (possibly indefinite) `a` by Bunch-Kaufman (LAPACK
/// `dsytrf`); an exactly singular `a` gives [`LinalgError::Singular`].
pub(crate) fn lblt_solve(
    a: ArrayView2<'_, f64>,
    b: ArrayView2<'_, f64>,
) -> Result<Array2<f64>, LinalgError> {
    // ndarray-linalg factors the upper triangle; mirror the lower one into it.
    let n = a.nrows();
    let sym = Array2::from_shape_fn((n, n), |(i, j)| if i >= j { a[[i, j]] } else { a[[j, i]] });
    let singular = |e: LapackError| match e {
        LapackError::Lapack(lax::error::Error::LapackComputationalFailure { return_code })
            if return_code > 0 =>
        {
            LinalgError::Singular
        }
        other => backend_error(other),
    };
    let factor = sym.factorizeh().map_err(singular)?;
    solve_columns(b, |col| factor.solveh(col).map_err(singular))
}

/// The thin `Q` factor (`rows x min(rows, cols)`, orthonormal columns) of a matrix (LAPACK
/// `dgeqrf` + `dorgqr`).
pub(crate) fn thin_q(a: ArrayView2<'_, f64>) -> Array2<f64> {
    match a.to_owned().qr() {
        Ok((q, _)) => q,
        // Householder QR of a finite matrix cannot fail; keep the shape if LAPACK says otherwise.
        Err(_) => Array2::eye(a.nrows()).slice_move(ndarray::s![.., ..a.nrows().min(a.ncols())]),
    }
}
