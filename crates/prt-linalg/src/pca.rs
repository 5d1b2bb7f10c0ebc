//! Principal component analysis of f32 data with f64 accumulation.

use ndarray::{Array1, Array2, ArrayView2, Axis, s};
use prt_core::Progress;
use rand::SeedableRng;
use rand_pcg::Pcg64;
use rayon::prelude::*;

use crate::backend::{self, Operand, Real};
use crate::synthetic::gaussian_matrix;
use crate::{LinalgError, sym_eig, thin_svd};

/// Rows per GEMM block: big enough for an efficient kernel, small enough to stay in L2.
const BLOCK_ROWS: usize = 256;
/// Upper bound on the number of row chunks of a reduction (each holds its own partial sum).
const MAX_CHUNKS: usize = 64;
/// Lower bound on the rows of a chunk, so small inputs are not split into tiny jobs.
const MIN_CHUNK_ROWS: usize = 8192;

/// How [`Pca::fit`] finds the principal subspace.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum PcaMethod {
    /// Exact: the `d x d` covariance, then a symmetric eigendecomposition. The centred rows
    /// are multiplied in blocks of 1024 by an f32 GEMM (twice the f64 throughput) and the block
    /// products summed in f64, so rounding grows like `sqrt(1024) u` per block rather than with
    /// `n` (the loss of scikit-learn's all-f32 `covariance_eigh`). Cost `n d^2 / 2` FMAs,
    /// independent of the rank.
    #[default]
    Covariance,
    /// As [`PcaMethod::Covariance`] with the block products in f64 too: about twice the time,
    /// for data whose columns need more than f32 products can give.
    CovarianceF64,
    /// Randomized range finder with power iterations (Halko, Martinsson & Tropp 2011): cost
    /// about `(2 q + 2) n d (rank + oversample)`; accuracy improves geometrically with `q`.
    Randomized {
        /// Extra sketch columns beyond the rank (10 is the usual choice).
        oversample: usize,
        /// Power (subspace) iterations `q`; 1-2 suffice for decaying spectra.
        power_iters: usize,
        /// Seed of the Gaussian test matrix.
        seed: u64,
    },
}

/// Options of [`Pca::fit`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct PcaOptions {
    /// The algorithm.
    pub method: PcaMethod,
}

/// A fitted rank-`k` PCA: `x ~ mean + coeffs * components`.
#[derive(Debug, Clone, PartialEq)]
pub struct Pca {
    /// Per-column mean of the data (`d`).
    pub mean: Array1<f32>,
    /// Principal directions as orthonormal rows (`rank x d`), by decreasing variance; each row's
    /// entry of largest magnitude is positive.
    pub components: Array2<f32>,
    /// Variance along each component (eigenvalues of the covariance, divided by `n - 1`).
    pub explained_variance: Array1<f64>,
    /// Total variance of the data (trace of the covariance, divided by `n - 1`).
    pub total_variance: f64,
}

/// Fixed row chunks of a reduction over `n` rows: the same for every thread count.
fn chunk_ranges(n: usize) -> Vec<std::ops::Range<usize>> {
    let rows = n
        .div_ceil(MAX_CHUNKS)
        .max(MIN_CHUNK_ROWS)
        .next_multiple_of(BLOCK_ROWS);
    (0..n)
        .step_by(rows)
        .map(|start| start..(start + rows).min(n))
        .collect()
}

/// Runs `map` on every chunk in parallel and sums the results in chunk order (deterministic).
fn ordered_reduce<A: Send>(
    n: usize,
    progress: &dyn Progress,
    map: impl Fn(std::ops::Range<usize>) -> Result<A, LinalgError> + Sync,
    mut add: impl FnMut(&mut A, A),
) -> Result<Option<A>, LinalgError> {
    let parts: Vec<Result<A, LinalgError>> = chunk_ranges(n)
        .into_par_iter()
        .map(|range| {
            progress.check()?;
            let rows = range.len() as u64;
            let part = map(range)?;
            progress.inc(rows);
            Ok(part)
        })
        .collect();
    let mut total: Option<A> = None;
    for part in parts {
        let part = part?;
        match total.as_mut() {
            Some(t) => add(t, part),
            None => total = Some(part),
        }
    }
    Ok(total)
}

fn add_into(acc: &mut [f64], part: Vec<f64>) {
    for (a, p) in acc.iter_mut().zip(part) {
        *a += p;
    }
}

/// Row `i` of `data` as a slice: borrowed when the row is contiguous (the usual row-major
/// input), else copied into `scratch`. Slices let the per-element loops vectorise.
fn row_slice<'a>(data: ArrayView2<'a, f32>, i: usize, scratch: &'a mut Vec<f32>) -> &'a [f32] {
    let row = data.index_axis_move(Axis(0), i);
    match row.to_slice() {
        Some(slice) => slice,
        None => {
            scratch.clear();
            scratch.extend(row.iter());
            scratch
        }
    }
}

/// Writes rows `range` of `data`, minus `mean`, into `out` (row-major) as `T`.
fn centered_rows<T: Copy + 'static>(
    data: ArrayView2<'_, f32>,
    mean: &[f64],
    range: std::ops::Range<usize>,
    out: &mut Vec<T>,
    cast: impl Fn(f64) -> T,
) {
    let d = mean.len();
    out.clear();
    out.resize(range.len() * d, cast(0.0));
    let mut scratch = Vec::new();
    for (i, dst) in range.zip(out.chunks_exact_mut(d)) {
        let row = row_slice(data, i, &mut scratch);
        for ((o, &x), &m) in dst.iter_mut().zip(row).zip(mean) {
            *o = cast(f64::from(x) - m);
        }
    }
}

impl Pca {
    /// Fits a rank-`rank` PCA to the `n x d` matrix `data` (one sample per row).
    ///
    /// Extremes: constant data gives zero explained and total variance (components are then an
    /// arbitrary orthonormal set, no NaN); a single row likewise; `rank == d` keeps everything
    /// (residual zero up to rounding). Works in three passes over the data (mean, covariance or
    /// sketch passes), reporting rows done through `progress` and honouring its cancellation.
    ///
    /// # Errors
    /// [`LinalgError::Empty`] if `data` has no rows or columns, [`LinalgError::InvalidRank`] if
    /// `rank` is 0 or above `d`, [`LinalgError::NonFinite`] naming the first NaN/Inf of `data`,
    /// [`LinalgError::Cancelled`].
    pub fn fit(
        data: ArrayView2<'_, f32>,
        rank: usize,
        opts: &PcaOptions,
        progress: &dyn Progress,
    ) -> Result<Pca, LinalgError> {
        let (n, d) = data.dim();
        if n == 0 || d == 0 {
            return Err(LinalgError::Empty { what: "data" });
        }
        if rank == 0 || rank > d {
            return Err(LinalgError::InvalidRank { rank, max: d });
        }
        let mean = column_mean(data, progress)?;
        let (explained, components, total_variance) = match opts.method {
            PcaMethod::Covariance => covariance_pca(data, &mean, rank, false, progress)?,
            PcaMethod::CovarianceF64 => covariance_pca(data, &mean, rank, true, progress)?,
            PcaMethod::Randomized {
                oversample,
                power_iters,
                seed,
            } => randomized_pca(data, &mean, rank, oversample, power_iters, seed, progress)?,
        };
        Ok(Pca {
            mean: mean.iter().map(|&m| m as f32).collect(),
            components,
            explained_variance: explained,
            total_variance,
        })
    }

    /// Number of components.
    pub fn rank(&self) -> usize {
        self.components.nrows()
    }

    /// Dimension of the data.
    pub fn dim(&self) -> usize {
        self.components.ncols()
    }

    /// Variance of the fitted data left unexplained: `total_variance - sum(explained_variance)`,
    /// clamped at zero.
    pub fn residual_variance(&self) -> f64 {
        (self.total_variance - self.explained_variance.sum()).max(0.0)
    }

    fn check_input(&self, x: ArrayView2<'_, f32>, what: &'static str) -> Result<(), LinalgError> {
        if x.ncols() != self.dim() {
            return Err(LinalgError::ShapeMismatch {
                what: "columns of x",
                expected: self.dim(),
                got: x.ncols(),
            });
        }
        crate::dense::check_finite(what, x)
    }

    /// Coefficients (`n x rank`) of the rows of `x` (`n x d`): `(x - mean) components^T`.
    ///
    /// # Errors
    /// [`LinalgError::ShapeMismatch`] if `x` does not have `d` columns, [`LinalgError::NonFinite`]
    /// for NaN/Inf in `x`.
    pub fn project(&self, x: ArrayView2<'_, f32>) -> Result<Array2<f32>, LinalgError> {
        self.check_input(x, "x")?;
        let centered = &x - &self.mean.view().insert_axis(Axis(0));
        Ok(centered.dot(&self.components.t()))
    }

    /// Rows `mean + coeffs components` (`n x d`) for coefficients `coeffs` (`n x rank`).
    ///
    /// # Errors
    /// [`LinalgError::ShapeMismatch`] if `coeffs` does not have `rank` columns,
    /// [`LinalgError::NonFinite`] for NaN/Inf in `coeffs`.
    pub fn reconstruct(&self, coeffs: ArrayView2<'_, f32>) -> Result<Array2<f32>, LinalgError> {
        if coeffs.ncols() != self.rank() {
            return Err(LinalgError::ShapeMismatch {
                what: "columns of coeffs",
                expected: self.rank(),
                got: coeffs.ncols(),
            });
        }
        crate::dense::check_finite("coeffs", coeffs)?;
        let mut out = coeffs.dot(&self.components);
        out += &self.mean.view().insert_axis(Axis(0));
        Ok(out)
    }

    /// Sum over the rows of `x` of the squared distance to their rank-`k` reconstruction
    /// (accumulated in f64). On the fitted data this is `(n - 1) * residual_variance()` up to
    /// rounding: the optimal rank-`k` residual of the centred data (Eckart-Young).
    ///
    /// # Errors
    /// As [`Pca::project`].
    pub fn residual_energy(&self, x: ArrayView2<'_, f32>) -> Result<f64, LinalgError> {
        self.check_input(x, "x")?;
        let comps = self.components.mapv(f64::from);
        let rows: Vec<f64> = (0..x.nrows())
            .into_par_iter()
            .map(|i| {
                let row = x.row(i);
                let c: Vec<f64> = row
                    .iter()
                    .zip(&self.mean)
                    .map(|(&v, &m)| f64::from(v) - f64::from(m))
                    .collect();
                let coeffs: Vec<f64> = comps
                    .rows()
                    .into_iter()
                    .map(|p| p.iter().zip(&c).map(|(a, b)| a * b).sum())
                    .collect();
                let mut err = 0.0;
                for (j, &cj) in c.iter().enumerate() {
                    let recon: f64 = coeffs
                        .iter()
                        .enumerate()
                        .map(|(k, &a)| a * comps[[k, j]])
                        .sum();
                    err += (cj - recon) * (cj - recon);
                }
                err
            })
            .collect();
        Ok(rows.iter().sum())
    }
}

/// Column means in f64 (fixed chunks, ordered reduction), failing on the first NaN/Inf.
fn column_mean(
    data: ArrayView2<'_, f32>,
    progress: &dyn Progress,
) -> Result<Vec<f64>, LinalgError> {
    let (n, d) = data.dim();
    progress.message("PCA: mean");
    progress.set_len(n as u64);
    let sums = ordered_reduce(
        n,
        progress,
        |range| {
            let rows = data.slice(s![range.clone(), ..]);
            let mut sum = vec![0.0f64; d];
            let mut scratch = Vec::new();
            for i in 0..rows.nrows() {
                for (acc, &v) in sum.iter_mut().zip(row_slice(rows, i, &mut scratch)) {
                    *acc += f64::from(v);
                }
            }
            // Sums of finite f32 values cannot overflow in f64: a non-finite sum means NaN/Inf.
            if sum.iter().any(|v| !v.is_finite())
                && let Some(index) = rows.iter().position(|v| !v.is_finite())
            {
                return Err(LinalgError::NonFinite {
                    what: "data",
                    index: range.start * d + index,
                });
            }
            Ok(sum)
        },
        |a, b| add_into(a, b),
    )?
    .unwrap_or_else(|| vec![0.0; d]);
    Ok(sums.into_iter().map(|s| s / n as f64).collect())
}

type PcaParts = (Array1<f64>, Array2<f32>, f64);

/// Lower triangle of `x_c^T x_c` (f64, row-major `d x d`) for the centred data: the product of
/// each block of [`COV_BLOCK_ROWS`] rows is a GEMM in `T`, the blocks are summed in f64 in a
/// fixed order.
fn lower_gram<T: Real>(
    data: ArrayView2<'_, f32>,
    mean: &[f64],
    progress: &dyn Progress,
    cast: impl Fn(f64) -> T + Sync,
) -> Result<Vec<f64>, LinalgError> {
    let (n, d) = data.dim();
    Ok(ordered_reduce(
        n,
        progress,
        |range| {
            let mut acc = vec![0.0f64; d * d];
            let mut part = vec![T::ZERO; d * d];
            let mut block = Vec::with_capacity(COV_BLOCK_ROWS * d);
            for start in range.clone().step_by(COV_BLOCK_ROWS) {
                let rows = (start..(start + COV_BLOCK_ROWS).min(range.end)).len();
                centered_rows(data, mean, start..start + rows, &mut block, &cast);
                let (lhs, rhs) = (Operand::t(&block, rows, d), Operand::n(&block, rows, d));
                backend::gemm(&mut part, false, lhs, rhs, true, false);
                for (i, (acc_row, part_row)) in acc
                    .chunks_exact_mut(d)
                    .zip(part.chunks_exact(d))
                    .enumerate()
                {
                    for (a, &p) in acc_row[..=i].iter_mut().zip(&part_row[..=i]) {
                        *a += p.to_f64();
                    }
                }
            }
            Ok(acc)
        },
        |a, b| add_into(a, b),
    )?
    .unwrap_or_else(|| vec![0.0; d * d]))
}

/// Rows per covariance block: the span of each f32 partial sum in [`PcaMethod::Covariance`].
const COV_BLOCK_ROWS: usize = 1024;

fn covariance_pca(
    data: ArrayView2<'_, f32>,
    mean: &[f64],
    rank: usize,
    f64_products: bool,
    progress: &dyn Progress,
) -> Result<PcaParts, LinalgError> {
    let (n, d) = data.dim();
    progress.message("PCA: covariance");
    progress.set_len(n as u64);
    let lower = if f64_products {
        lower_gram::<f64>(data, mean, progress, |v| v)?
    } else {
        lower_gram::<f32>(data, mean, progress, |v| v as f32)?
    };
    let denom = (n.max(2) - 1) as f64;
    let cov = Array2::from_shape_fn((d, d), |(i, j)| {
        let (i, j) = if i >= j { (i, j) } else { (j, i) };
        lower[i * d + j] / denom
    });
    let total_variance = cov.diag().sum();
    let eig = sym_eig(cov.view())?;
    let explained = eig.values.slice(s![..rank]).mapv(|v| v.max(0.0));
    let components = eig.vectors.slice(s![.., ..rank]).t().mapv(|v| v as f32);
    Ok((explained, components, total_variance))
}

/// `x_c * omega` (`n x l`, f64) for the centred data, block by block in parallel.
fn sketch(
    data: ArrayView2<'_, f32>,
    mean: &[f64],
    omega: &Array2<f64>,
    progress: &dyn Progress,
) -> Result<Array2<f64>, LinalgError> {
    let (n, d) = data.dim();
    let l = omega.ncols();
    let omega32: Vec<f32> = omega.iter().map(|&v| v as f32).collect();
    let mut y = vec![0.0f32; n * l];
    y.par_chunks_mut(BLOCK_ROWS * l)
        .enumerate()
        .try_for_each(|(b, out)| {
            progress.check()?;
            let start = b * BLOCK_ROWS;
            let rows = out.len() / l;
            let mut block = Vec::with_capacity(rows * d);
            centered_rows(data, mean, start..start + rows, &mut block, |v| v as f32);
            backend::gemm(
                out,
                false,
                Operand::n(&block, rows, d),
                Operand::n(&omega32, d, l),
                false,
                false,
            );
            progress.inc(rows as u64);
            Ok::<(), LinalgError>(())
        })?;
    Array2::from_shape_vec((n, l), y.into_iter().map(f64::from).collect())
        .map_err(|e| LinalgError::Backend(e.to_string()))
}

/// `q^T x_c` (`l x d`, f64) for an `n x l` matrix `q`: f32 GEMM per block, f64 across blocks.
fn project_rows(
    data: ArrayView2<'_, f32>,
    mean: &[f64],
    q: &Array2<f64>,
    progress: &dyn Progress,
) -> Result<Array2<f64>, LinalgError> {
    let (n, d) = data.dim();
    let l = q.ncols();
    let acc = ordered_reduce(
        n,
        progress,
        |range| {
            let mut acc = vec![0.0f64; l * d];
            let mut part = vec![0.0f32; l * d];
            let mut block = Vec::with_capacity(BLOCK_ROWS * d);
            for start in range.clone().step_by(BLOCK_ROWS) {
                let rows = (start..(start + BLOCK_ROWS).min(range.end)).len();
                centered_rows(data, mean, start..start + rows, &mut block, |v| v as f32);
                let qb: Vec<f32> = q
                    .slice(s![start..start + rows, ..])
                    .iter()
                    .map(|&v| v as f32)
                    .collect();
                backend::gemm(
                    &mut part,
                    false,
                    Operand::t(&qb, rows, l),
                    Operand::n(&block, rows, d),
                    false,
                    false,
                );
                for (a, &p) in acc.iter_mut().zip(&part) {
                    *a += f64::from(p);
                }
            }
            Ok(acc)
        },
        |a, b| add_into(a, b),
    )?
    .unwrap_or_else(|| vec![0.0; l * d]);
    Array2::from_shape_vec((l, d), acc).map_err(|e| LinalgError::Backend(e.to_string()))
}

fn randomized_pca(
    data: ArrayView2<'_, f32>,
    mean: &[f64],
    rank: usize,
    oversample: usize,
    power_iters: usize,
    seed: u64,
    progress: &dyn Progress,
) -> Result<PcaParts, LinalgError> {
    let (n, d) = data.dim();
    let l = (rank + oversample).min(d).min(n.max(rank));
    progress.message("PCA: randomized sketch");
    progress.set_len(((2 * power_iters + 3) * n) as u64);
    let total_variance = centered_sum_of_squares(data, mean, progress)? / (n.max(2) - 1) as f64;
    let mut omega = gaussian_matrix(d, l, &mut Pcg64::seed_from_u64(seed));
    let mut q = backend::thin_q(sketch(data, mean, &omega, progress)?.view());
    for _ in 0..power_iters {
        let z = project_rows(data, mean, &q, progress)?; // l x d
        omega = backend::thin_q(z.t());
        q = backend::thin_q(sketch(data, mean, &omega, progress)?.view());
    }
    let b = project_rows(data, mean, &q, progress)?; // l x d: the data in the found basis
    let svd = thin_svd(b.view())?;
    let denom = (n.max(2) - 1) as f64;
    let k = rank.min(svd.s.len());
    let mut explained = Array1::zeros(rank);
    explained
        .slice_mut(s![..k])
        .assign(&svd.s.slice(s![..k]).mapv(|v| v * v / denom));
    let mut components = Array2::zeros((rank, d));
    components
        .slice_mut(s![..k, ..])
        .assign(&svd.vt.slice(s![..k, ..]).mapv(|v| v as f32));
    if k < rank {
        // More components than the sketch can hold (rank > n): complete the basis exactly.
        complete_orthonormal_rows(&mut components, k);
    }
    Ok((explained, components, total_variance))
}

/// Sum of squared centred entries (f64, ordered reduction).
fn centered_sum_of_squares(
    data: ArrayView2<'_, f32>,
    mean: &[f64],
    progress: &dyn Progress,
) -> Result<f64, LinalgError> {
    Ok(ordered_reduce(
        data.nrows(),
        progress,
        |range| {
            Ok(data
                .slice(s![range, ..])
                .rows()
                .into_iter()
                .map(|row| {
                    row.iter()
                        .zip(mean)
                        .map(|(&v, &m)| (f64::from(v) - m).powi(2))
                        .sum::<f64>()
                })
                .sum::<f64>())
        },
        |a, b| *a += b,
    )?
    .unwrap_or(0.0))
}

/// Fills rows `k..` of `rows` with unit vectors orthogonal to all earlier rows (Gram-Schmidt
/// over the standard basis).
fn complete_orthonormal_rows(rows: &mut Array2<f32>, k: usize) {
    let d = rows.ncols();
    let mut filled = k;
    for e in 0..d {
        if filled == rows.nrows() {
            break;
        }
        let mut v = vec![0.0f64; d];
        v[e] = 1.0;
        for r in 0..filled {
            let dot: f64 = (0..d).map(|j| f64::from(rows[[r, j]]) * v[j]).sum();
            for j in 0..d {
                v[j] -= dot * f64::from(rows[[r, j]]);
            }
        }
        let norm = v.iter().map(|x| x * x).sum::<f64>().sqrt();
        if norm > 0.5 {
            for j in 0..d {
                rows[[filled, j]] = (v[j] / norm) as f32;
            }
            filled += 1;
        }
    }
}
