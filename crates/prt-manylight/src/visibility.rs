use std::collections::BinaryHeap;

use faer::{Accum, MatMut, MatRef, Par};
use prt_core::{CoreError, MatrixOracle, Progress};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;
use rayon::prelude::*;

use crate::cluster::{BestCut, Queued};
use crate::reduced::{check_requests, check_shape};
use crate::{ManyLightError, stratified_rows};

/// Pixels shaded together in the final gather (one parallel task each).
const PIXEL_BATCH: usize = 64;

/// A [`MatrixOracle`] whose elements factor into an unshadowed shading term and a visibility
/// term, `M(i, j) = S(i, j) · V(i, j)`: shading is cheap (no shadow ray), visibility is the
/// expensive part. What visibility clustering needs.
pub trait VisibilityOracle: MatrixOracle {
    /// The unshadowed contribution `S(i, j)` of light `j` to pixel `i` into `out`
    /// (`channels()` values).
    fn shading(&self, i: usize, j: usize, out: &mut [f32]) -> Result<(), CoreError>;
    /// The visibility `V(i, j)` in `[0, 1]` between pixel `i` and light `j` (a shadow ray).
    fn visibility(&self, i: usize, j: usize) -> Result<f32, CoreError>;
}

/// How [`visibility_clustering`] groups the lights.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum VisibilityClusterMethod {
    /// Divisive: the cluster of largest visibility error is split in two along random
    /// projections of the visibility vectors, at the cut of least total error.
    Split,
    /// The divisive clustering refined by `iterations` rounds of weighted k-means (Lloyd) on
    /// the visibility vectors.
    KMeans {
        /// Lloyd iterations after the divisive start.
        iterations: usize,
    },
}

/// The knobs of [`visibility_clustering`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct VisibilityConfig {
    /// Rows (pixels) sampled to measure visibility.
    pub rows: usize,
    /// Clusters, hence representatives whose visibility is traced for every pixel.
    pub columns: usize,
    /// How the clusters are formed.
    pub method: VisibilityClusterMethod,
    /// Random projections tried per split.
    pub split_lines: usize,
    /// Seed of every random choice.
    pub seed: u64,
}

impl VisibilityConfig {
    /// `rows` sampled rows, `columns` clusters, divisive clustering, 3 projections, seed 0.
    pub fn new(rows: usize, columns: usize) -> Self {
        Self {
            rows,
            columns,
            method: VisibilityClusterMethod::Split,
            split_lines: 3,
            seed: 0,
        }
    }

    /// The same configuration with another clustering method.
    pub fn with_method(self, method: VisibilityClusterMethod) -> Self {
        Self { method, ..self }
    }

    /// The same configuration with another seed.
    pub fn with_seed(self, seed: u64) -> Self {
        Self { seed, ..self }
    }
}

/// The result of [`visibility_clustering`].
#[derive(Debug, Clone, PartialEq)]
pub struct VisibilityEstimate {
    /// The estimated image: `rows × channels` values, row-major.
    pub image: Vec<f32>,
    /// The sampled rows.
    pub rows: Vec<usize>,
    /// The light clusters, each in increasing order.
    pub clusters: Vec<Vec<u32>>,
    /// The representative light of each cluster.
    pub representatives: Vec<usize>,
    /// The weighted L2 error of the visibility approximation on the sampled rows,
    /// `Σ_C Σ_i Σ_{j∈C} w_ij (V_ij − V_i,rep)²` (`w` = shading summed over channels).
    pub visibility_error: f64,
    /// Visibility evaluations (shadow rays) counted as row-column sampling counts elements:
    /// `rows × cols` for the sampled rows plus `rows_total` per cluster.
    pub elements: u64,
    /// Unshadowed shading evaluations: the sampled rows plus every pixel against every light.
    pub shading_evaluations: u64,
}

/// The sampled rows' visibility vectors: for light `j`, `vis[j·r + k]` is `V(rows[k], j)` and
/// `weight[j·r + k]` the shading summed over channels (`V` is 0 where the weight is).
struct Features {
    r: usize,
    vis: Vec<f32>,
    weight: Vec<f32>,
}

impl Features {
    fn vis(&self, j: u32) -> &[f32] {
        &self.vis[j as usize * self.r..(j as usize + 1) * self.r]
    }

    fn weight(&self, j: u32) -> &[f32] {
        &self.weight[j as usize * self.r..(j as usize + 1) * self.r]
    }

    /// Per-row sums over `members`: `Σ w`, `Σ w V`, `Σ w V²`.
    fn moments(&self, members: &[u32]) -> Moments {
        let mut m = Moments::zero(self.r);
        for &j in members {
            m.add(self.weight(j), self.vis(j));
        }
        m
    }

    /// `Σ_i Σ_{j∈C} w_ij (V_ij − V̄_i)²`, the error of approximating each member's visibility by
    /// the cluster's weighted mean visibility per row.
    fn error(&self, members: &[u32]) -> f64 {
        self.moments(members).error()
    }
}

/// Per-row weighted moments of a set of visibility vectors.
struct Moments {
    w: Vec<f64>,
    wv: Vec<f64>,
    wv2: Vec<f64>,
}

impl Moments {
    fn zero(r: usize) -> Self {
        Self {
            w: vec![0.0; r],
            wv: vec![0.0; r],
            wv2: vec![0.0; r],
        }
    }

    fn add(&mut self, weight: &[f32], vis: &[f32]) {
        for k in 0..self.w.len() {
            let (w, v) = (weight[k] as f64, vis[k] as f64);
            self.w[k] += w;
            self.wv[k] += w * v;
            self.wv2[k] += w * v * v;
        }
    }

    /// `Σ_i (Σ w V² − (Σ w V)² / Σ w)`: the weighted variance around the mean, summed.
    fn error(&self) -> f64 {
        self.error_minus(None)
    }

    /// The error of these moments minus `other` (a subset), or of these alone.
    fn error_minus(&self, other: Option<&Moments>) -> f64 {
        let mut e = 0.0;
        for k in 0..self.w.len() {
            let (mut w, mut wv, mut wv2) = (self.w[k], self.wv[k], self.wv2[k]);
            if let Some(o) = other {
                w -= o.w[k];
                wv -= o.wv[k];
                wv2 -= o.wv2[k];
            }
            if w > 0.0 {
                e += (wv2 - wv * wv / w).max(0.0);
            }
        }
        e
    }
}

/// Splits `members` in two along random projections of their visibility vectors, cutting
/// where the halves' total error is least (ties to the most balanced cut). Splitting never
/// raises the error: a weighted variance around the mean is at most the variance around any
/// other value. `None` for fewer than two members.
fn split_visibility(
    features: &Features,
    members: &[u32],
    lines: usize,
    rng: &mut impl Rng,
) -> Option<(Vec<u32>, Vec<u32>)> {
    let n = members.len();
    if n < 2 {
        return None;
    }
    let total = features.moments(members);
    let mut best = BestCut::default();
    for _ in 0..lines.max(1) {
        let direction: Vec<f32> = (0..features.r)
            .map(|_| rng.random_range(-1.0f32..1.0))
            .collect();
        let projection: Vec<f64> = members
            .iter()
            .map(|&j| {
                let (v, w) = (features.vis(j), features.weight(j));
                (0..features.r)
                    .map(|k| {
                        if w[k] > 0.0 {
                            (v[k] * direction[k]) as f64
                        } else {
                            0.0
                        }
                    })
                    .sum()
            })
            .collect();
        let mut order: Vec<usize> = (0..n).collect();
        order.sort_by(|&x, &y| projection[x].total_cmp(&projection[y]).then(x.cmp(&y)));
        let mut left = Moments::zero(features.r);
        for (k, &x) in order.iter().enumerate().take(n - 1) {
            let j = members[x];
            left.add(features.weight(j), features.vis(j));
            let cost = left.error() + total.error_minus(Some(&left));
            best.offer(cost, k + 1, n);
        }
        best.end_order(&order);
    }
    best.split(members)
}

/// Divisive clustering into `count` clusters: the cluster of largest error (then the largest)
/// is split until there are `count` clusters or only singletons.
fn divisive(
    features: &Features,
    cols: usize,
    count: usize,
    lines: usize,
    rng: &mut impl Rng,
    progress: &dyn Progress,
) -> Result<Vec<Vec<u32>>, ManyLightError> {
    let mut clusters = vec![(0..cols as u32).collect::<Vec<u32>>()];
    let mut queue = BinaryHeap::from([Queued {
        cost: features.error(&clusters[0]),
        size: cols,
        id: 0,
    }]);
    while clusters.len() < count {
        let Some(top) = queue.pop() else { break };
        if top.size < 2 {
            continue;
        }
        progress.check()?;
        let members = std::mem::take(&mut clusters[top.id]);
        let Some((a, b)) = split_visibility(features, &members, lines, rng) else {
            clusters[top.id] = members;
            continue;
        };
        let new_id = clusters.len();
        for (id, part) in [(top.id, &a), (new_id, &b)] {
            queue.push(Queued {
                cost: features.error(part),
                size: part.len(),
                id,
            });
        }
        clusters[top.id] = a;
        clusters.push(b);
    }
    Ok(clusters)
}

/// Weighted Lloyd iterations: every light joins the cluster whose per-row weighted mean
/// visibility `μ` is nearest in `Σ_i w_ij (V_ij − μ_i)²`; the means are then recomputed.
/// Clusters that empty are dropped. Distances come from two matrix products per block of
/// lights (sequential products, blocks in parallel, so the result is thread-count independent).
fn kmeans(
    features: &Features,
    mut clusters: Vec<Vec<u32>>,
    iterations: usize,
    progress: &dyn Progress,
) -> Result<Vec<Vec<u32>>, ManyLightError> {
    let r = features.r;
    let cols = features.vis.len() / r.max(1);
    for _ in 0..iterations {
        progress.check()?;
        let k = clusters.len();
        // Means μ (r × k) and their squares, column-major.
        let mut mean = vec![0.0f32; r * k];
        for (c, members) in clusters.iter().enumerate() {
            let m = features.moments(members);
            for i in 0..r {
                mean[c * r + i] = if m.w[i] > 0.0 {
                    (m.wv[i] / m.w[i]) as f32
                } else {
                    0.0
                };
            }
        }
        let mean_sq: Vec<f32> = mean.iter().map(|v| v * v).collect();
        let mean_ref = MatRef::from_column_major_slice(&mean, r, k);
        let mean_sq_ref = MatRef::from_column_major_slice(&mean_sq, r, k);
        let assignment: Vec<u32> = (0..cols as u32)
            .collect::<Vec<u32>>()
            .par_chunks(1024)
            .flat_map_iter(|block| {
                let b = block.len();
                let mut wv = vec![0.0f32; r * b];
                let mut w = vec![0.0f32; r * b];
                for (x, &j) in block.iter().enumerate() {
                    for i in 0..r {
                        w[x * r + i] = features.weight(j)[i];
                        wv[x * r + i] = features.weight(j)[i] * features.vis(j)[i];
                    }
                }
                // d(j, c) = Σ w μ² − 2 Σ w V μ (+ Σ w V², the same for every c).
                let mut cross = vec![0.0f32; k * b];
                let mut square = vec![0.0f32; k * b];
                let wv_ref = MatRef::from_column_major_slice(&wv, r, b);
                let w_ref = MatRef::from_column_major_slice(&w, r, b);
                faer::linalg::matmul::matmul(
                    MatMut::from_column_major_slice_mut(&mut cross, k, b),
                    Accum::Replace,
                    mean_ref.transpose(),
                    wv_ref,
                    1.0f32,
                    Par::Seq,
                );
                faer::linalg::matmul::matmul(
                    MatMut::from_column_major_slice_mut(&mut square, k, b),
                    Accum::Replace,
                    mean_sq_ref.transpose(),
                    w_ref,
                    1.0f32,
                    Par::Seq,
                );
                (0..b)
                    .map(|x| {
                        let mut arg = 0u32;
                        let mut min = f32::INFINITY;
                        for c in 0..k {
                            let d = square[x * k + c] - 2.0 * cross[x * k + c];
                            if d < min {
                                min = d;
                                arg = c as u32;
                            }
                        }
                        arg
                    })
                    .collect::<Vec<u32>>()
            })
            .collect();
        let mut next = vec![Vec::new(); k];
        for (j, &c) in assignment.iter().enumerate() {
            next[c as usize].push(j as u32);
        }
        next.retain(|c| !c.is_empty());
        if next == clusters {
            break;
        }
        clusters = next;
    }
    Ok(clusters)
}

/// The member whose visibility vector is nearest to the cluster's weighted mean,
/// `argmin_r Σ_i W_i (V_ir − V̄_i)²` (`W_i = Σ_j w_ij`): it minimises the cluster's L2 error
/// `Σ_i Σ_j w_ij (V_ij − V_ir)² = Σ_i Σ_j w_ij (V_ij − V̄_i)² + Σ_i W_i (V̄_i − V_ir)²`. Ties go
/// to the lowest index. Returns the representative and that error.
fn representative(features: &Features, members: &[u32]) -> (usize, f64) {
    let m = features.moments(members);
    let spread = m.error();
    let mut best = (members[0] as usize, f64::INFINITY);
    for &j in members {
        let v = features.vis(j);
        let off: f64 = (0..features.r)
            .filter(|&i| m.w[i] > 0.0)
            .map(|i| {
                let d = v[i] as f64 - m.wv[i] / m.w[i];
                m.w[i] * d * d
            })
            .sum();
        if off < best.1 {
            best = (j as usize, off);
        }
    }
    (best.0, spread + best.1)
}

/// Visibility clustering: every light's unshadowed shading is computed for every pixel, but
/// visibility only from one representative per cluster of lights,
/// `Î(i) = Σ_C V(i, r_C) Σ_{j∈C} S(i, j)`.
///
/// This is the visibility approximation of many-light methods that cluster lights for shadows
/// only (Davidovič et al., "Combining Global and Local Virtual Lights for Detailed Glossy
/// Illumination", SIGGRAPH Asia 2010; "Scalability with Many Lights II", SIGGRAPH 2012 course):
/// 1. `rows` stratified rows are evaluated in full, giving for every light its visibility
///    vector `V_ij` on the sampled pixels and weights `w_ij` (shading summed over channels);
/// 2. the lights are clustered to minimise the weighted L2 error of the visibility
///    approximation, `Σ_C Σ_i Σ_{j∈C} w_ij (V_ij − V̄_iC)²`: divisively (splits along random
///    projections, [`VisibilityClusterMethod::Split`]) or divisively then by weighted k-means
///    ([`VisibilityClusterMethod::KMeans`]);
/// 3. each cluster's representative is the member nearest to the cluster's mean visibility;
///    its visibility is traced for every pixel and multiplies the cluster's summed shading.
///
/// Unlike row-column sampling this is a deterministic approximation, not an unbiased estimate:
/// the error is that of the visibility approximation only. It is exact when every cluster is
/// one light (`columns == cols`) and whenever visibility is constant within each cluster (for
/// example an unoccluded scene, at any number of clusters). Shadow rays are counted in
/// `elements` as row-column sampling counts elements; the gather also costs
/// `rows_total × cols` shading evaluations (no shadow rays). A seed gives the same image on any
/// number of threads.
///
/// Errors: an empty matrix, zero or too many rows / columns, non-finite shading or visibility,
/// oracle failures, cancellation.
pub fn visibility_clustering(
    oracle: &dyn VisibilityOracle,
    config: &VisibilityConfig,
    progress: &dyn Progress,
) -> Result<VisibilityEstimate, ManyLightError> {
    check_shape(oracle)?;
    let (n, m) = (oracle.rows(), oracle.cols());
    check_requests(&[
        ("row", "rows", config.rows, n),
        ("column", "columns", config.columns, m),
    ])?;
    let mut rng = Pcg64Mcg::seed_from_u64(config.seed);
    progress.message("visibility clustering: sampled rows");
    let rows = stratified_rows(n, config.rows, &mut rng);
    let features = sample_features(oracle, &rows, progress)?;
    progress.message("visibility clustering: clustering");
    let clusters = if config.columns >= m {
        (0..m as u32).map(|j| vec![j]).collect()
    } else {
        let split = divisive(
            &features,
            m,
            config.columns,
            config.split_lines,
            &mut rng,
            progress,
        )?;
        match config.method {
            VisibilityClusterMethod::Split => split,
            VisibilityClusterMethod::KMeans { iterations } => {
                kmeans(&features, split, iterations, progress)?
            }
        }
    };
    let picked: Vec<(usize, f64)> = clusters
        .par_iter()
        .map(|c| representative(&features, c))
        .collect();
    let representatives: Vec<usize> = picked.iter().map(|p| p.0).collect();
    let visibility_error = picked.iter().map(|p| p.1).sum();
    progress.message("visibility clustering: gather");
    let image = gather(oracle, &clusters, &representatives, progress)?;
    Ok(VisibilityEstimate {
        image,
        elements: (rows.len() * m + clusters.len() * n) as u64,
        shading_evaluations: (rows.len() * m + n * m) as u64,
        rows,
        clusters,
        representatives,
        visibility_error,
    })
}

/// Step 1: shading weights and visibility of every light on the sampled rows.
fn sample_features(
    oracle: &dyn VisibilityOracle,
    rows: &[usize],
    progress: &dyn Progress,
) -> Result<Features, ManyLightError> {
    let (m, channels) = (oracle.cols(), oracle.channels());
    let r = rows.len();
    progress.set_len(r as u64);
    let per_row: Vec<Vec<(f32, f32)>> = rows
        .par_iter()
        .map(|&i| {
            progress.check()?;
            let mut s = vec![0.0f32; channels];
            let row = (0..m)
                .map(|j| {
                    oracle.shading(i, j, &mut s)?;
                    check_values(&s, i, j)?;
                    let w: f32 = s.iter().map(|v| v.abs()).sum();
                    let v = if w > 0.0 {
                        let v = oracle.visibility(i, j)?;
                        check_values(&[v], i, j)?;
                        v
                    } else {
                        0.0
                    };
                    Ok((w, v))
                })
                .collect::<Result<Vec<_>, ManyLightError>>()?;
            progress.inc(1);
            Ok(row)
        })
        .collect::<Result<_, ManyLightError>>()?;
    let mut vis = vec![0.0f32; m * r];
    let mut weight = vec![0.0f32; m * r];
    for (k, row) in per_row.iter().enumerate() {
        for (j, &(w, v)) in row.iter().enumerate() {
            weight[j * r + k] = w;
            vis[j * r + k] = v;
        }
    }
    Ok(Features { r, vis, weight })
}

fn check_values(values: &[f32], row: usize, col: usize) -> Result<(), ManyLightError> {
    match values.iter().position(|v| !v.is_finite()) {
        Some(channel) => Err(ManyLightError::NonFinite { row, col, channel }),
        None => Ok(()),
    }
}

/// Step 3: `Î(i) = Σ_C V(i, r_C) Σ_{j∈C} S(i, j)`, pixels in parallel batches, each pixel summed
/// in cluster order in f64 (visibility traced only where the cluster's shading is non-zero).
fn gather(
    oracle: &dyn VisibilityOracle,
    clusters: &[Vec<u32>],
    representatives: &[usize],
    progress: &dyn Progress,
) -> Result<Vec<f32>, ManyLightError> {
    let (n, channels) = (oracle.rows(), oracle.channels());
    let mut image = vec![0.0f32; n * channels];
    progress.set_len(n.div_ceil(PIXEL_BATCH) as u64);
    image
        .par_chunks_mut(PIXEL_BATCH * channels)
        .enumerate()
        .try_for_each(|(b, block)| {
            progress.check()?;
            let mut s = vec![0.0f32; channels];
            let mut sum = vec![0.0f64; channels];
            let mut pixel = vec![0.0f64; channels];
            for (x, out) in block.chunks_exact_mut(channels).enumerate() {
                let i = b * PIXEL_BATCH + x;
                pixel.fill(0.0);
                for (members, &rep) in clusters.iter().zip(representatives) {
                    sum.fill(0.0);
                    for &j in members {
                        oracle.shading(i, j as usize, &mut s)?;
                        check_values(&s, i, j as usize)?;
                        for (a, &v) in sum.iter_mut().zip(&s) {
                            *a += v as f64;
                        }
                    }
                    if sum.iter().any(|&v| v != 0.0) {
                        let v = oracle.visibility(i, rep)?;
                        check_values(&[v], i, rep)?;
                        for (p, a) in pixel.iter_mut().zip(&sum) {
                            *p += v as f64 * a;
                        }
                    }
                }
                for (o, p) in out.iter_mut().zip(&pixel) {
                    *o = *p as f32;
                }
            }
            progress.inc(1);
            Ok::<(), ManyLightError>(())
        })?;
    Ok(image)
}

#[cfg(test)]
mod tests {
    use super::{Features, split_visibility};
    use proptest::prelude::*;
    use rand::{Rng, SeedableRng};
    use rand_pcg::Pcg64Mcg;

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]

        /// A split never raises the visibility error.
        #[test]
        fn split_never_raises_the_error(
            cols in 2usize..20,
            r in 1usize..6,
            seed in 0u64..1000,
        ) {
            let mut rng = Pcg64Mcg::seed_from_u64(seed);
            let vis = (0..cols * r).map(|_| rng.random_range(0..2u8) as f32).collect();
            let weight = (0..cols * r).map(|_| rng.random_range(0.0f32..2.0)).collect();
            let features = Features { r, vis, weight };
            let members: Vec<u32> = (0..cols as u32).collect();
            let whole = features.error(&members);
            let (a, b) = split_visibility(&features, &members, 2, &mut rng).unwrap();
            prop_assert_eq!(a.len() + b.len(), cols);
            let parts = features.error(&a) + features.error(&b);
            prop_assert!(parts <= whole + 1e-9 * (1.0 + whole), "{} > {}", parts, whole);
        }
    }
}
