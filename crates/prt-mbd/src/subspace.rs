//! Uncentred principal subspaces (truncated SVD of a block of rows), shared by MBD's
//! initialisation and the PCA-family baselines.

use ndarray::{Array2, ArrayView2, Axis, linalg::general_mat_mul, s};
use prt_linalg::sym_eig;
use rayon::prelude::*;

use crate::MbdError;

/// Rows per f32 Gram block before it is added to the f64 total: short enough that f32 rounding
/// stays at the level of one product, long enough for an efficient matrix product.
const GRAM_BLOCK: usize = 256;

/// Rows per parallel task of [`gram_columns`]: fixed, so the f64 sums run in the same order on
/// any number of threads.
const GRAM_TASK: usize = 64 * GRAM_BLOCK;

/// `XᵀX` (`d × d`) accumulated in f64 from f32 products of `GRAM_BLOCK`-row blocks, tasks of
/// `GRAM_TASK` rows in parallel and their totals added in order.
pub(crate) fn gram_columns(x: ArrayView2<'_, f32>) -> Array2<f64> {
    let d = x.ncols();
    let task_totals: Vec<Array2<f64>> = x
        .axis_chunks_iter(Axis(0), GRAM_TASK)
        .into_par_iter()
        .map(|task| {
            let mut total = Array2::<f64>::zeros((d, d));
            let mut block = Array2::<f32>::zeros((d, d));
            for chunk in task.axis_chunks_iter(Axis(0), GRAM_BLOCK) {
                general_mat_mul(1.0, &chunk.t(), &chunk, 0.0, &mut block);
                total.zip_mut_with(&block, |t, &b| *t += b as f64);
            }
            total
        })
        .collect();
    let mut total = Array2::<f64>::zeros((d, d));
    for task in &task_totals {
        total += task;
    }
    total
}

/// The `rank` leading right singular vectors of `x` (rows of the result, `rank × d`,
/// orthonormal): the uncentred rank-`rank` principal subspace, i.e. the basis of the best
/// rank-`rank` approximation of the rows (Eckart-Young).
///
/// Works through the smaller of the two Gram matrices (`d × d`, or `n × n` when there are fewer
/// rows than columns), accumulated in f64. When the rows span fewer than `rank` dimensions
/// (a zero block, fewer rows than `rank`), the remaining vectors are completed from the
/// eigenvectors of the Gram matrix's null space, so the result is always orthonormal.
pub(crate) fn principal_subspace(
    x: ArrayView2<'_, f32>,
    rank: usize,
) -> Result<Array2<f32>, MbdError> {
    let (n, d) = x.dim();
    if rank == 0 || rank > d {
        return Err(MbdError::InvalidRank { rank, dim: d });
    }
    if n >= d || n == 0 {
        let gram = gram_columns(x);
        match sym_eig(gram.view()) {
            Ok(eig) => Ok(eig.vectors.slice(s![.., ..rank]).t().mapv(|v| v as f32)),
            Err(_) => subspace_by_svd(x, rank),
        }
    } else {
        // Gram of the rows: X Xᵀ = U Σ² Uᵀ, and the right singular vectors are Xᵀ U / σ.
        let xd = x.mapv(|v| v as f64);
        let gram = xd.dot(&xd.t());
        let Ok(eig) = sym_eig(gram.view()) else {
            return subspace_by_svd(x, rank);
        };
        let mut out = Array2::<f64>::zeros((rank, d));
        let mut filled = 0;
        let s_max = eig.values.first().copied().unwrap_or(0.0).max(0.0);
        for (k, &value) in eig.values.iter().enumerate() {
            if filled == rank || value <= s_max * 1e-12 || value <= 0.0 {
                break;
            }
            let v = xd.t().dot(&eig.vectors.column(k)) / value.sqrt();
            out.row_mut(filled).assign(&v);
            filled += 1;
        }
        complete_orthonormal(&mut out, filled);
        Ok(out.mapv(|v| v as f32))
    }
}

/// The fallback when the eigensolver of the Gram matrix does not converge (seen on blocks of a
/// traced Sponza volume that are nearly all invalid, zero voxels): the right singular vectors
/// of `x` itself, completed to an orthonormal set where `x` has fewer than `rank` directions.
fn subspace_by_svd(x: ArrayView2<'_, f32>, rank: usize) -> Result<Array2<f32>, MbdError> {
    let d = x.ncols();
    let xd = x.mapv(|v| v as f64);
    let svd = prt_linalg::thin_svd(xd.view()).map_err(|e| linalg_error("principal subspace", e))?;
    let mut out = Array2::<f64>::zeros((rank, d));
    let s_max = svd.s.first().copied().unwrap_or(0.0);
    let mut filled = 0;
    for (k, &sigma) in svd.s.iter().enumerate() {
        if filled == rank || sigma <= s_max * 1e-6 || sigma <= 0.0 {
            break;
        }
        out.row_mut(filled).assign(&svd.vt.row(k));
        filled += 1;
    }
    complete_orthonormal(&mut out, filled);
    Ok(out.mapv(|v| v as f32))
}

/// Fills rows `filled..` of `basis` (whose first `filled` rows are orthonormal) with unit
/// vectors orthogonal to all previous rows, by Gram-Schmidt on the standard basis.
fn complete_orthonormal(basis: &mut Array2<f64>, mut filled: usize) {
    let (rank, d) = basis.dim();
    let mut e = 0;
    while filled < rank && e < d {
        let mut v = ndarray::Array1::<f64>::zeros(d);
        v[e] = 1.0;
        for _ in 0..2 {
            for k in 0..filled {
                let row = basis.row(k);
                let p = row.dot(&v);
                v.scaled_add(-p, &row);
            }
        }
        let norm = v.dot(&v).sqrt();
        if norm > 1e-6 {
            basis.row_mut(filled).assign(&(v / norm));
            filled += 1;
        }
        e += 1;
    }
}

pub(crate) fn linalg_error(what: &'static str, e: prt_linalg::LinalgError) -> MbdError {
    MbdError::InvalidOption {
        what,
        why: e.to_string(),
    }
}

/// Cholesky factorisation in place of the small symmetric positive definite `n × n` row-major
/// matrix `a` (lower factor written over the lower triangle). Returns false if a pivot is not
/// positive. Used per kernel in hot loops, where a general solver's allocations would dominate.
pub(crate) fn cholesky_in_place(a: &mut [f64], n: usize) -> bool {
    for j in 0..n {
        let mut diag = a[j * n + j];
        for k in 0..j {
            diag -= a[j * n + k] * a[j * n + k];
        }
        if diag <= 0.0 || !diag.is_finite() {
            return false;
        }
        let diag = diag.sqrt();
        a[j * n + j] = diag;
        for i in j + 1..n {
            let mut v = a[i * n + j];
            for k in 0..j {
                v -= a[i * n + k] * a[j * n + k];
            }
            a[i * n + j] = v / diag;
        }
    }
    true
}

/// Solves `L Lᵀ x = b` in place for `cols` right-hand sides stored as the columns of the
/// `n × cols` row-major `b`, with `a` from [`cholesky_in_place`].
pub(crate) fn cholesky_solve_in_place(a: &[f64], b: &mut [f64], n: usize, cols: usize) {
    for i in 0..n {
        for k in 0..i {
            let f = a[i * n + k];
            for c in 0..cols {
                b[i * cols + c] -= f * b[k * cols + c];
            }
        }
        let d = a[i * n + i];
        b[i * cols..(i + 1) * cols].iter_mut().for_each(|v| *v /= d);
    }
    for i in (0..n).rev() {
        for k in i + 1..n {
            let f = a[k * n + i];
            for c in 0..cols {
                b[i * cols + c] -= f * b[k * cols + c];
            }
        }
        let d = a[i * n + i];
        b[i * cols..(i + 1) * cols].iter_mut().for_each(|v| *v /= d);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_pcg::Pcg64Mcg;

    /// `BᵀB` of orthonormal rows `b`: the projector onto their span.
    fn projector(b: &Array2<f32>) -> Array2<f64> {
        let b = b.mapv(f64::from);
        b.t().dot(&b)
    }

    #[test]
    fn the_svd_fallback_finds_the_same_subspace() {
        let mut rng = Pcg64Mcg::seed_from_u64(3);
        // Tall (more rows than columns) and wide blocks, both with many zero rows as in a
        // traced volume's invalid voxels, and rank-deficient (3 directions, rank 5 asked).
        for (n, d) in [(60, 12), (12, 40)] {
            let directions: Vec<f32> = (0..3 * d).map(|_| rng.random::<f32>() - 0.5).collect();
            let mut x = Array2::<f32>::zeros((n, d));
            for mut row in x.rows_mut().into_iter().skip(n / 2) {
                let c: [f32; 3] = [rng.random(), rng.random(), rng.random()];
                for (k, v) in row.iter_mut().enumerate() {
                    *v = (0..3).map(|j| c[j] * directions[j * d + k]).sum();
                }
            }
            let by_eig = principal_subspace(x.view(), 3).unwrap();
            let by_svd = subspace_by_svd(x.view(), 3).unwrap();
            let gap = (projector(&by_eig) - projector(&by_svd)).mapv(f64::abs);
            assert!(gap.iter().all(|&g| g < 1e-4), "n = {n}, d = {d}");
            // Asked for more than the block holds: completed to an orthonormal set.
            let five = subspace_by_svd(x.view(), 5).unwrap().mapv(f64::from);
            let gram = five.dot(&five.t());
            for i in 0..5 {
                for j in 0..5 {
                    let expected = if i == j { 1.0 } else { 0.0 };
                    assert!((gram[[i, j]] - expected).abs() < 1e-5, "{gram}");
                }
            }
        }
    }
}
