//! faer implementation of the backend kernels.

use faer::linalg::matmul::triangular::BlockStructure;
use faer::linalg::solvers::Solve;
use faer::{Accum, Mat, MatMut, MatRef, Par, Side};
use ndarray::{Array2, ArrayView2};

use super::{Op, Operand, Real, SvdParts};
use crate::LinalgError;

fn view<'a, T: Real>(o: &Operand<'a, T>) -> MatRef<'a, T> {
    let m = MatRef::from_row_major_slice(o.data, o.rows, o.cols);
    match o.op {
        Op::N => m,
        Op::T => m.transpose(),
    }
}

fn to_faer(a: ArrayView2<'_, f64>) -> Mat<f64> {
    Mat::from_fn(a.nrows(), a.ncols(), |i, j| a[[i, j]])
}

fn to_ndarray(m: MatRef<'_, f64>) -> Array2<f64> {
    Array2::from_shape_fn((m.nrows(), m.ncols()), |(i, j)| m[(i, j)])
}

/// `dst (m x n, row-major) (+)= a * b`. With `lower_only` only the lower triangle of `dst` is
/// written (a symmetric rank-k update at half the cost). `parallel` lets the kernel use the
/// rayon pool; callers that already run in parallel pass `false`.
pub(crate) fn gemm<T: Real>(
    dst: &mut [T],
    accumulate: bool,
    a: Operand<'_, T>,
    b: Operand<'_, T>,
    lower_only: bool,
    parallel: bool,
) {
    let (m, k) = a.shape();
    let (_, n) = b.shape();
    let dst = MatMut::from_row_major_slice_mut(dst, m, n);
    let accum = if accumulate {
        Accum::Add
    } else {
        Accum::Replace
    };
    let par = if parallel { Par::rayon(0) } else { Par::Seq };
    let (lhs, rhs) = (view(&a), view(&b));
    debug_assert_eq!(lhs.ncols(), k);
    if lower_only {
        faer::linalg::matmul::triangular::matmul(
            dst,
            BlockStructure::TriangularLower,
            accum,
            lhs,
            BlockStructure::Rectangular,
            rhs,
            BlockStructure::Rectangular,
            T::one_impl(),
            par,
        );
    } else {
        faer::linalg::matmul::matmul(dst, accum, lhs, rhs, T::one_impl(), par);
    }
}

/// Eigenvalues (ascending) and eigenvectors (columns) of a symmetric matrix, reading its lower
/// triangle.
pub(crate) fn eigh(a: ArrayView2<'_, f64>) -> Result<(Vec<f64>, Array2<f64>), LinalgError> {
    let m = to_faer(a);
    let e = m
        .self_adjoint_eigen(Side::Lower)
        .map_err(|_| LinalgError::NoConvergence {
            what: "symmetric eigendecomposition",
            iterations: 0,
        })?;
    let s = e.S().column_vector();
    let values = (0..s.nrows()).map(|i| s[i]).collect();
    Ok((values, to_ndarray(e.U())))
}

/// Thin SVD `a = u diag(s) vt` with `s` descending.
pub(crate) fn svd_thin(a: ArrayView2<'_, f64>) -> Result<SvdParts, LinalgError> {
    let m = to_faer(a);
    let svd = m.thin_svd().map_err(|_| LinalgError::NoConvergence {
        what: "thin SVD",
        iterations: 0,
    })?;
    let s = svd.S().column_vector();
    let values = (0..s.nrows()).map(|i| s[i]).collect();
    let vt = to_ndarray(svd.V().transpose());
    Ok((to_ndarray(svd.U()), values, vt))
}

/// Solves `a x = b` for symmetric positive definite `a` (lower triangle read) by Cholesky.
pub(crate) fn llt_solve(
    a: ArrayView2<'_, f64>,
    b: ArrayView2<'_, f64>,
) -> Result<Array2<f64>, LinalgError> {
    let llt = to_faer(a).llt(Side::Lower).map_err(|e| match e {
        faer::linalg::cholesky::llt::factor::LltError::NonPositivePivot { index } => {
            LinalgError::NotPositiveDefinite { pivot: index }
        }
    })?;
    let mut x = to_faer(b);
    llt.solve_in_place(x.as_mut());
    Ok(to_ndarray(x.as_ref()))
}

/// Solves `a x = b` for symmetric (possibly indefinite) `a` by Bunch-Kaufman `L B L^T`.
/// Singularity shows as non-finite entries, which the caller checks.
pub(crate) fn lblt_solve(
    a: ArrayView2<'_, f64>,
    b: ArrayView2<'_, f64>,
) -> Result<Array2<f64>, LinalgError> {
    let lblt = to_faer(a).lblt(Side::Lower);
    let mut x = to_faer(b);
    lblt.solve_in_place(x.as_mut());
    Ok(to_ndarray(x.as_ref()))
}

/// The thin `Q` factor (`rows x min(rows, cols)`, orthonormal columns) of a row-major matrix.
pub(crate) fn thin_q(a: ArrayView2<'_, f64>) -> Array2<f64> {
    let run = || to_ndarray(to_faer(a).qr().compute_thin_Q().as_ref());
    // faer's QR takes its parallelism from the current rayon pool, and on tall, skinny sketches
    // (262144 x 26) its parallel path was 5x slower than the sequential one on 2 threads:
    // run it in a one-thread pool.
    match rayon::ThreadPoolBuilder::new().num_threads(1).build() {
        Ok(pool) => pool.install(run),
        Err(_) => run(),
    }
}
