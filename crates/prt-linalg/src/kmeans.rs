//! k-means clustering: k-means++ seeding and Lloyd iterations on f32 data.

use ndarray::{Array2, ArrayView2};
use prt_core::Progress;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use rayon::prelude::*;

use crate::LinalgError;
use crate::backend::{self, Operand};

/// Rows per distance GEMM block.
const BLOCK_ROWS: usize = 256;
/// Upper bound on the number of row chunks (each holds `k x d` partial sums).
const MAX_CHUNKS: usize = 64;
/// Lower bound on the rows of a chunk.
const MIN_CHUNK_ROWS: usize = 2048;

/// Options of [`kmeans`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KMeansOptions {
    /// Maximum Lloyd iterations (assignment steps); at least 1 is always run.
    pub max_iters: usize,
    /// Stop when an iteration lowers the objective by less than `tol` times its value
    /// (0 runs until the assignments stop changing or `max_iters`).
    pub tol: f64,
    /// Seed of the k-means++ seeding.
    pub seed: u64,
}

impl Default for KMeansOptions {
    fn default() -> Self {
        Self {
            max_iters: 100,
            tol: 1e-6,
            seed: 0,
        }
    }
}

/// The result of [`kmeans`].
#[derive(Debug, Clone, PartialEq)]
pub struct KMeans {
    /// Cluster centres (`k x d`).
    pub centroids: Array2<f32>,
    /// Index of the nearest centroid of every row of the data.
    pub assignments: Vec<u32>,
    /// Sum over rows of the squared distance to their assigned centroid (f64, exact).
    pub objective: f64,
    /// The objective after each assignment step; never increases (up to rounding of the f32
    /// centroids, about `1e-12` relative).
    pub history: Vec<f64>,
}

/// Clusters the rows of `data` (`n x d`) into `k` groups minimising the sum of squared
/// distances to the group centroids.
///
/// Seeding is k-means++ (each next centre drawn with probability proportional to the squared
/// distance to the nearest chosen one). Each Lloyd iteration assigns every row to its nearest
/// centroid and moves each centroid to the mean of its rows (sums in f64). Distances come from a
/// blocked f32 GEMM, `|x|^2 - 2 x.c + |c|^2`; every centroid whose approximate distance is within
/// the rounding bound `d u (|x|^2 + |c|^2)` of the best is re-ranked by its exact f64 distance,
/// so cancellation never picks a farther centroid. An empty cluster is re-seeded at the row
/// farthest from its centroid (several empty clusters take the farthest rows in order), which
/// never increases the objective. Rows are split into fixed chunks and partial sums reduced in
/// chunk order: the same seed gives the same result on any thread count.
///
/// The returned `assignments` are the nearest-centroid labels of the returned `centroids`, and
/// `objective` is their cost. With fewer than `k` distinct rows some centroids coincide and
/// their clusters stay empty.
///
/// # Errors
/// [`LinalgError::Empty`] if `data` has no rows or columns, [`LinalgError::InvalidParameter`]
/// if `k` is 0, exceeds the number of rows or `u32::MAX`, or `tol` is negative or NaN,
/// [`LinalgError::NonFinite`] for NaN/Inf in `data`, [`LinalgError::Cancelled`].
pub fn kmeans(
    data: ArrayView2<'_, f32>,
    k: usize,
    opts: &KMeansOptions,
    progress: &dyn Progress,
) -> Result<KMeans, LinalgError> {
    let (n, d) = data.dim();
    if n == 0 || d == 0 {
        return Err(LinalgError::Empty { what: "data" });
    }
    if k == 0 || k > n || u32::try_from(k).is_err() {
        return Err(LinalgError::InvalidParameter {
            what: "k",
            why: format!("must be in 1..={n} (the number of rows), got {k}"),
        });
    }
    if opts.tol.is_nan() || opts.tol < 0.0 {
        return Err(LinalgError::InvalidParameter {
            what: "tol",
            why: format!("must be >= 0, got {}", opts.tol),
        });
    }
    let data = data.as_standard_layout();
    let x = data
        .as_slice()
        .ok_or_else(|| LinalgError::Backend("non-contiguous data".into()))?;
    let row_norms = squared_row_norms(x, d)?;

    progress.message("k-means: seeding");
    let mut centroids = seed_plus_plus(x, d, k, opts.seed, progress)?;

    let max_iters = opts.max_iters.max(1);
    progress.set_len(max_iters as u64);
    let mut assignments = vec![u32::MAX; n];
    let mut dists = vec![0.0f64; n];
    let mut history = Vec::new();
    for iter in 0..max_iters {
        let step = assign(
            x,
            d,
            &row_norms,
            &centroids,
            k,
            &mut assignments,
            &mut dists,
            progress,
        )?;
        history.push(step.objective);
        progress.inc(1);
        progress.message(&format!(
            "k-means iteration {iter}: objective {:.6e}",
            step.objective
        ));
        let prev = history.len().checked_sub(2).map(|i| history[i]);
        let stalled = prev.is_some_and(|p| p - step.objective <= opts.tol * p);
        if step.changed == 0 || stalled || iter + 1 == max_iters {
            break;
        }
        update_centroids(&mut centroids, x, &step, &dists, d, k);
        progress.check()?;
    }
    let objective = *history.last().unwrap_or(&0.0);
    Ok(KMeans {
        centroids: Array2::from_shape_vec((k, d), centroids)
            .map_err(|e| LinalgError::Backend(e.to_string()))?,
        assignments,
        objective,
        history,
    })
}

fn chunk_rows(n: usize) -> usize {
    n.div_ceil(MAX_CHUNKS)
        .max(MIN_CHUNK_ROWS)
        .next_multiple_of(BLOCK_ROWS)
}

/// `|x_i|^2` in f64 for every row, failing on the first non-finite entry.
fn squared_row_norms(x: &[f32], d: usize) -> Result<Vec<f64>, LinalgError> {
    let norms: Vec<f64> = x
        .par_chunks(d)
        .map(|row| row.iter().map(|&v| f64::from(v).powi(2)).sum())
        .collect();
    if let Some(i) = norms.iter().position(|v| !v.is_finite()) {
        let j = x[i * d..(i + 1) * d]
            .iter()
            .position(|v| !v.is_finite())
            .unwrap_or(0);
        return Err(LinalgError::NonFinite {
            what: "data",
            index: i * d + j,
        });
    }
    Ok(norms)
}

/// Writes `half_norms - dots` into `scores` and returns its minimum (eight lanes, so the loop
/// vectorises).
fn scores_and_min(half_norms: &[f32], dots: &[f32], scores: &mut [f32]) -> f32 {
    let mut lanes = [f32::INFINITY; 8];
    let lanes_of = scores
        .chunks_exact_mut(8)
        .zip(half_norms.chunks_exact(8))
        .zip(dots.chunks_exact(8));
    for ((s, h), p) in lanes_of {
        for l in 0..8 {
            s[l] = h[l] - p[l];
            lanes[l] = lanes[l].min(s[l]);
        }
    }
    let done = scores.len() / 8 * 8;
    let mut lowest = lanes.iter().fold(f32::INFINITY, |m, &v| m.min(v));
    for j in done..scores.len() {
        scores[j] = half_norms[j] - dots[j];
        lowest = lowest.min(scores[j]);
    }
    lowest
}

/// Exact squared distance in f64 (eight independent partial sums, so it vectorises).
fn exact_dist(a: &[f32], b: &[f32]) -> f64 {
    let mut acc = [0.0f64; 8];
    let (ca, cb) = (a.chunks_exact(8), b.chunks_exact(8));
    let tail: f64 = ca
        .remainder()
        .iter()
        .zip(cb.remainder())
        .map(|(&p, &q)| (f64::from(p) - f64::from(q)).powi(2))
        .sum();
    for (pa, pb) in ca.zip(cb) {
        for l in 0..8 {
            let diff = f64::from(pa[l]) - f64::from(pb[l]);
            acc[l] += diff * diff;
        }
    }
    acc.iter().sum::<f64>() + tail
}

/// k-means++ seeding: `k x d` row-major centroids.
fn seed_plus_plus(
    x: &[f32],
    d: usize,
    k: usize,
    seed: u64,
    progress: &dyn Progress,
) -> Result<Vec<f32>, LinalgError> {
    let n = x.len() / d;
    let mut rng = Pcg64::seed_from_u64(seed);
    let mut centroids = Vec::with_capacity(k * d);
    let first = rng.random_range(0..n);
    centroids.extend_from_slice(&x[first * d..(first + 1) * d]);
    let mut min_dist: Vec<f64> = x
        .par_chunks(d)
        .map(|row| exact_dist(row, &centroids[..d]))
        .collect();
    let chunk = chunk_rows(n);
    for _ in 1..k {
        progress.check()?;
        // Ordered sum over fixed chunks: the same total on any thread count.
        let total: f64 = min_dist
            .par_chunks(chunk)
            .map(|c| c.iter().sum::<f64>())
            .collect::<Vec<_>>()
            .iter()
            .sum();
        let pick = if total > 0.0 {
            let target = rng.random::<f64>() * total;
            let mut cum = 0.0;
            let mut pick = None;
            for (i, &w) in min_dist.iter().enumerate() {
                cum += w;
                if w > 0.0 {
                    pick = Some(i);
                    if cum > target {
                        break;
                    }
                }
            }
            pick.unwrap_or(0)
        } else {
            // Every row coincides with a chosen centre: any row duplicates one.
            rng.random_range(0..n)
        };
        let start = centroids.len();
        centroids.extend_from_slice(&x[pick * d..(pick + 1) * d]);
        let c = &centroids[start..];
        min_dist
            .par_iter_mut()
            .zip(x.par_chunks(d))
            .for_each(|(m, row)| {
                *m = m.min(exact_dist(row, c));
            });
    }
    Ok(centroids)
}

/// What an assignment step leaves for the update step.
struct AssignStep {
    objective: f64,
    changed: usize,
    sums: Vec<f64>,
    counts: Vec<u64>,
}

/// Assigns every row to its nearest centroid; returns per-cluster sums and the objective.
fn assign(
    x: &[f32],
    d: usize,
    row_norms: &[f64],
    centroids: &[f32],
    k: usize,
    assignments: &mut [u32],
    dists: &mut [f64],
    progress: &dyn Progress,
) -> Result<AssignStep, LinalgError> {
    let n = row_norms.len();
    let chunk = chunk_rows(n);
    let centroid_norms: Vec<f64> = centroids
        .chunks(d)
        .map(|c| c.iter().map(|&v| f64::from(v).powi(2)).sum())
        .collect();
    let half_norms: Vec<f32> = centroid_norms.iter().map(|c| (0.5 * c) as f32).collect();
    let max_norm = centroid_norms.iter().fold(0.0f64, |m, &v| m.max(v));
    // Rounding bound of the f32 score |c|^2/2 - x.c, relative to |x|^2 + |c|^2: gamma_d for the
    // dot product of length d, plus a few units for the conversions and the subtraction.
    let bound = (d + 8) as f64 * f64::from(f32::EPSILON) / 2.0;
    let parts: Vec<Result<AssignStep, LinalgError>> = assignments
        .par_chunks_mut(chunk)
        .zip(dists.par_chunks_mut(chunk))
        .enumerate()
        .map(|(c, (labels, dist))| {
            progress.check()?;
            let first = c * chunk;
            let mut part = AssignStep {
                objective: 0.0,
                changed: 0,
                sums: vec![0.0; k * d],
                counts: vec![0; k],
            };
            let mut dots = vec![0.0f32; BLOCK_ROWS * k];
            let mut scores = vec![0.0f32; k];
            for b in (0..labels.len()).step_by(BLOCK_ROWS) {
                let rows = BLOCK_ROWS.min(labels.len() - b);
                let block = &x[(first + b) * d..(first + b + rows) * d];
                backend::gemm(
                    &mut dots[..rows * k],
                    false,
                    Operand::n(block, rows, d),
                    Operand::t(centroids, k, d),
                    false,
                    false,
                );
                for r in 0..rows {
                    let i = b + r;
                    let xx = row_norms[first + i];
                    // |x - c|^2 / 2 - |x|^2 / 2 = |c|^2 / 2 - x.c, approximately; every centroid
                    // within the rounding bound of the best is ranked by its exact distance.
                    let lowest =
                        scores_and_min(&half_norms, &dots[r * k..(r + 1) * k], &mut scores);
                    let threshold = f64::from(lowest) + bound * (xx + max_norm);
                    let row = &block[r * d..(r + 1) * d];
                    let (mut best, mut best_dist) = (0, f64::INFINITY);
                    for (j, &score) in scores.iter().enumerate() {
                        if f64::from(score) <= threshold {
                            let e = exact_dist(row, &centroids[j * d..(j + 1) * d]);
                            if e < best_dist {
                                (best, best_dist) = (j, e);
                            }
                        }
                    }
                    if labels[i] != best as u32 {
                        part.changed += 1;
                        labels[i] = best as u32;
                    }
                    dist[i] = best_dist;
                    part.objective += best_dist;
                    part.counts[best] += 1;
                    for (s, &v) in part.sums[best * d..(best + 1) * d].iter_mut().zip(row) {
                        *s += f64::from(v);
                    }
                }
            }
            Ok(part)
        })
        .collect();
    let mut total: Option<AssignStep> = None;
    for part in parts {
        let part = part?;
        match total.as_mut() {
            None => total = Some(part),
            Some(t) => {
                t.objective += part.objective;
                t.changed += part.changed;
                for (a, b) in t.sums.iter_mut().zip(&part.sums) {
                    *a += b;
                }
                for (a, b) in t.counts.iter_mut().zip(&part.counts) {
                    *a += b;
                }
            }
        }
    }
    total.ok_or(LinalgError::Empty { what: "data" })
}

/// Moves centroids to their cluster means and re-seeds empty clusters at the farthest rows.
fn update_centroids(
    centroids: &mut [f32],
    x: &[f32],
    step: &AssignStep,
    dists: &[f64],
    d: usize,
    k: usize,
) {
    let empty: Vec<usize> = (0..k).filter(|&j| step.counts[j] == 0).collect();
    for j in 0..k {
        if step.counts[j] > 0 {
            let inv = 1.0 / step.counts[j] as f64;
            for (c, &s) in centroids[j * d..(j + 1) * d]
                .iter_mut()
                .zip(&step.sums[j * d..(j + 1) * d])
            {
                *c = (s * inv) as f32;
            }
        }
    }
    if empty.is_empty() {
        return;
    }
    // Farthest rows first (ties: lower index), one per empty cluster.
    let mut order: Vec<usize> = (0..dists.len()).collect();
    order.sort_by(|&a, &b| dists[b].total_cmp(&dists[a]).then(a.cmp(&b)));
    for (&j, &i) in empty.iter().zip(&order) {
        centroids[j * d..(j + 1) * d].copy_from_slice(&x[i * d..(i + 1) * d]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn empty_clusters_are_reseeded_at_the_farthest_rows() {
        let x = [0.0f32, 10.0, 3.0, 7.0];
        let mut centroids = vec![1.0f32, 50.0, 60.0];
        // Clusters 1 and 2 received no rows; rows 1 (distance 81) and 3 (36) are the farthest.
        let step = AssignStep {
            objective: 0.0,
            changed: 0,
            sums: vec![20.0, 0.0, 0.0],
            counts: vec![4, 0, 0],
        };
        let dists = [1.0, 81.0, 4.0, 36.0];
        update_centroids(&mut centroids, &x, &step, &dists, 1, 3);
        assert_eq!(centroids, vec![5.0, 10.0, 7.0]);
    }
}
