use std::cmp::Ordering;
use std::collections::{BTreeMap, BinaryHeap};

use faer::{Accum, MatMut, MatRef, Par};
use prt_core::Progress;
use rand::Rng;
use rayon::prelude::*;

use crate::{ManyLightError, ReducedMatrix};

/// Columns per block of the assignment product (bounds its temporary memory).
const ASSIGN_BLOCK: usize = 1024;

/// A partition of the lights (columns) into clusters, each a list of column indices in
/// increasing order.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Clustering {
    clusters: Vec<Vec<u32>>,
}

impl Clustering {
    /// The clusters.
    pub fn clusters(&self) -> &[Vec<u32>] {
        &self.clusters
    }

    /// Number of clusters.
    pub fn len(&self) -> usize {
        self.clusters.len()
    }

    /// Whether there are no clusters.
    pub fn is_empty(&self) -> bool {
        self.clusters.is_empty()
    }

    /// Replaces the clusters of unseen lights (all reduced norms zero) by `groups` groups of
    /// consecutive lights; see [`regroup_unseen`].
    pub(crate) fn regroup_unseen(&mut self, norms: &[f64], groups: usize) {
        regroup_unseen(&mut self.clusters, norms, groups);
    }

    /// The total cost, the sum of [`cluster_cost`] over the clusters.
    pub fn cost(&self, reduced: &ReducedMatrix) -> f64 {
        self.clusters.iter().map(|c| cluster_cost(reduced, c)).sum()
    }
}

/// The clustering cost of one cluster (Hasan et al. 2007, eq. 4):
/// `Σ_{i<j} ‖ρ_i‖ ‖ρ_j‖ ‖ρ̂_i − ρ̂_j‖²` over its pairs of reduced columns, where `ρ̂ = ρ/‖ρ‖`.
///
/// It is the expected squared error, on the sampled rows, of estimating the cluster's sum by
/// one column drawn proportionally to its norm, and is computed in `O(|C| · dim)` through
/// the identity `Σ_{i<j} a_i a_j ‖ρ̂_i − ρ̂_j‖² = (Σ a_i)² − ‖Σ ρ_i‖²` (with `a = ‖ρ‖`), in f64.
/// Zero columns contribute nothing. Column indices out of range are ignored.
pub fn cluster_cost(reduced: &ReducedMatrix, members: &[u32]) -> f64 {
    set_cost(reduced, members)
}

/// Replaces the clusters whose members all have a zero norm (unseen lights) by
/// `max(groups, clusters removed)` groups (at most one per light) of consecutive light
/// indices, appended after the other clusters, which keep their order. Nothing changes when
/// there are no such clusters.
pub(crate) fn regroup_unseen(clusters: &mut Vec<Vec<u32>>, norms: &[f64], groups: usize) {
    let before = clusters.len();
    let mut unseen: Vec<u32> = Vec::new();
    clusters.retain(|c| {
        let zero = c.iter().all(|&j| norms[j as usize] == 0.0);
        if zero {
            unseen.extend_from_slice(c);
        }
        !zero
    });
    if unseen.is_empty() {
        return;
    }
    unseen.sort_unstable();
    let len = unseen.len();
    let k = groups.max(before - clusters.len()).min(len);
    clusters.extend((0..k).map(|g| unseen[g * len / k..(g + 1) * len / k].to_vec()));
}

/// Reduced columns as the clustering sees them: the columns of a [`ReducedMatrix`], or of a
/// tensor restricted to a range of frames.
pub(crate) trait ColumnSet: Sync {
    /// Number of columns.
    fn cols(&self) -> usize;
    /// Length of a column.
    fn dim(&self) -> usize;
    /// Column `j` (empty when out of range).
    fn column(&self, j: usize) -> &[f32];
    /// `‖column(j)‖` (0 when out of range).
    fn norm(&self, j: usize) -> f64;
}

impl ColumnSet for ReducedMatrix {
    fn cols(&self) -> usize {
        ReducedMatrix::cols(self)
    }
    fn dim(&self) -> usize {
        ReducedMatrix::dim(self)
    }
    fn column(&self, j: usize) -> &[f32] {
        ReducedMatrix::column(self, j)
    }
    fn norm(&self, j: usize) -> f64 {
        self.norms().get(j).copied().unwrap_or(0.0)
    }
}

/// [`cluster_cost`] on any [`ColumnSet`].
pub(crate) fn set_cost(reduced: &impl ColumnSet, members: &[u32]) -> f64 {
    if members.len() < 2 {
        // No pairs; the formula would return rounding noise.
        return 0.0;
    }
    let mut sum = vec![0.0f64; reduced.dim()];
    let mut total_norm = 0.0;
    for &j in members {
        total_norm += reduced.norm(j as usize);
        for (s, &v) in sum.iter_mut().zip(reduced.column(j as usize)) {
            *s += v as f64;
        }
    }
    let sum_sq: f64 = sum.iter().map(|s| s * s).sum();
    (total_norm * total_norm - sum_sq).max(0.0)
}

/// Splits a cluster in two along random projections (the divide-and-conquer step of Hasan et
/// al. 2007, §4.2): the normalised reduced columns are projected onto `lines` random directions;
/// along each, the members are sorted and cut where the two halves' total cost is smallest;
/// the best cut over all directions wins (ties go to the most balanced cut).
///
/// The halves' total cost never exceeds the cluster's (the pairs across the cut are dropped
/// from a sum of non-negative terms), so splitting never increases the clustering cost. A
/// cluster of zero columns is cut into two halves by index. Returns `None` for fewer than two
/// members.
pub fn split_cluster(
    reduced: &ReducedMatrix,
    members: &[u32],
    lines: usize,
    rng: &mut impl Rng,
) -> Option<(Vec<u32>, Vec<u32>)> {
    split_set(reduced, members, lines, rng)
}

/// [`split_cluster`] on any [`ColumnSet`].
pub(crate) fn split_set(
    reduced: &impl ColumnSet,
    members: &[u32],
    lines: usize,
    rng: &mut impl Rng,
) -> Option<(Vec<u32>, Vec<u32>)> {
    let n = members.len();
    if n < 2 {
        return None;
    }
    let norms: Vec<f64> = members.iter().map(|&j| reduced.norm(j as usize)).collect();
    let total_norm: f64 = norms.iter().sum();
    if total_norm <= 0.0 {
        let (a, b) = members.split_at(n / 2);
        return Some((a.to_vec(), b.to_vec()));
    }
    let dim = reduced.dim();
    let mut total = vec![0.0f64; dim];
    for &j in members {
        for (t, &v) in total.iter_mut().zip(reduced.column(j as usize)) {
            *t += v as f64;
        }
    }
    let total_sq: f64 = total.iter().map(|t| t * t).sum();
    let dot_total: Vec<f64> = members
        .iter()
        .map(|&j| {
            reduced
                .column(j as usize)
                .iter()
                .zip(&total)
                .map(|(&v, t)| v as f64 * t)
                .sum()
        })
        .collect();

    let mut best = BestCut::default();
    let mut partial = vec![0.0f64; dim];
    for _ in 0..lines.max(1) {
        let direction: Vec<f32> = (0..dim).map(|_| rng.random_range(-1.0f32..1.0)).collect();
        let projection: Vec<f64> = members
            .iter()
            .zip(&norms)
            .map(|(&j, &a)| {
                let dot: f64 = reduced
                    .column(j as usize)
                    .iter()
                    .zip(&direction)
                    .map(|(&v, &g)| v as f64 * g as f64)
                    .sum();
                if a > 0.0 { dot / a } else { 0.0 }
            })
            .collect();
        let mut order: Vec<usize> = (0..n).collect();
        order.sort_by(|&x, &y| projection[x].total_cmp(&projection[y]).then(x.cmp(&y)));
        // Sweep the cut from left to right, keeping the left half's sums: its norm sum, ‖S‖² and
        // S·T, from which both halves' costs follow in O(1) per step.
        partial.fill(0.0);
        let (mut left_norm, mut left_sq, mut left_dot_total) = (0.0f64, 0.0f64, 0.0f64);
        for (k, &x) in order.iter().enumerate().take(n - 1) {
            let column = reduced.column(members[x] as usize);
            let cross: f64 = partial.iter().zip(column).map(|(s, &v)| s * v as f64).sum();
            left_sq += 2.0 * cross + norms[x] * norms[x];
            for (s, &v) in partial.iter_mut().zip(column) {
                *s += v as f64;
            }
            left_norm += norms[x];
            left_dot_total += dot_total[x];
            let right_norm = total_norm - left_norm;
            let right_sq = total_sq - 2.0 * left_dot_total + left_sq;
            let cost = (left_norm * left_norm - left_sq).max(0.0)
                + (right_norm * right_norm - right_sq).max(0.0);
            best.offer(cost, k + 1, n);
        }
        best.end_order(&order);
    }
    best.split(members)
}

/// The best cut over several sorted orders of a cluster's members: the lowest cost, then the most
/// balanced, the first found on ties. Only the winning cut of each order is copied.
#[derive(Debug, Default)]
pub(crate) struct BestCut {
    best: Option<(f64, usize)>,
    improved_at: Option<usize>,
    left: Vec<usize>,
}

impl BestCut {
    /// Offers the cut that leaves the first `cut` of `n` members of the current order on the left.
    pub(crate) fn offer(&mut self, cost: f64, cut: usize, n: usize) {
        let imbalance = cut.abs_diff(n - cut);
        let better = match self.best {
            None => true,
            Some((c, b)) => match cost.total_cmp(&c) {
                Ordering::Less => true,
                Ordering::Equal => imbalance < b,
                Ordering::Greater => false,
            },
        };
        if better {
            self.best = Some((cost, imbalance));
            self.improved_at = Some(cut);
        }
    }

    /// Ends the current order: keeps its positions on the left if one of its cuts won.
    pub(crate) fn end_order(&mut self, order: &[usize]) {
        if let Some(cut) = self.improved_at.take() {
            self.left.clear();
            self.left.extend_from_slice(&order[..cut]);
        }
    }

    /// Splits `members` by the winning cut (left, right); `None` if no cut was offered.
    pub(crate) fn split(self, members: &[u32]) -> Option<(Vec<u32>, Vec<u32>)> {
        self.best?;
        let mut in_left = vec![false; members.len()];
        for &x in &self.left {
            in_left[x] = true;
        }
        let (mut a, mut b) = (Vec::new(), Vec::new());
        for (x, &j) in members.iter().enumerate() {
            if in_left[x] { a.push(j) } else { b.push(j) }
        }
        Some((a, b))
    }
}

/// A cluster in the splitting queue: highest cost first, then the largest, then the oldest.
#[derive(Debug, PartialEq)]
pub(crate) struct Queued {
    pub(crate) cost: f64,
    pub(crate) size: usize,
    pub(crate) id: usize,
}

impl Eq for Queued {}

impl Ord for Queued {
    fn cmp(&self, other: &Self) -> Ordering {
        self.cost
            .total_cmp(&other.cost)
            .then(self.size.cmp(&other.size))
            .then(other.id.cmp(&self.id))
    }
}

impl PartialOrd for Queued {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}

/// Clusters the columns of `reduced` into `count` clusters (Hasan et al. 2007, §4.2):
///
/// 1. **Sampling clustering** to about `2/3 · count` clusters: centres are drawn with
///    probability proportional to `α_i = Σ_k ‖ρ_i‖‖ρ_k‖ (1 − ρ̂_i·ρ̂_k)` (a column's cost
///    against all others), each weighted by the inverse of its probability, and every column
///    joins the centre `k` minimising `w_k ‖ρ_k‖ (1 − ρ̂_i·ρ̂_k)`, the weighted pair cost (one
///    matrix product per block of columns).
/// 2. **Top-down splitting**: the cluster of highest [`cluster_cost`] is split with
///    [`split_cluster`] until there are `count` clusters or no cluster can be split.
///
/// Columns whose reduced column is zero carry no information about their direction; they are
/// kept apart in clusters of their own, so that a representative drawn uniformly among them
/// keeps the estimate unbiased. When zero and non-zero columns both exist the result has at
/// least two clusters, even if `count` is 1. With `count >= cols` every column ends alone.
pub fn cluster_columns(
    reduced: &ReducedMatrix,
    count: usize,
    lines: usize,
    rng: &mut impl Rng,
    progress: &dyn Progress,
) -> Result<Clustering, ManyLightError> {
    let clusters = cluster_set(reduced, count, lines, rng, progress)?;
    Ok(Clustering { clusters })
}

/// [`cluster_columns`] on any [`ColumnSet`], returning the clusters.
pub(crate) fn cluster_set(
    reduced: &impl ColumnSet,
    count: usize,
    lines: usize,
    rng: &mut impl Rng,
    progress: &dyn Progress,
) -> Result<Vec<Vec<u32>>, ManyLightError> {
    let (positive, zero): (Vec<u32>, Vec<u32>) =
        (0..reduced.cols() as u32).partition(|&j| reduced.norm(j as usize) > 0.0);
    let mut clusters: Vec<Vec<u32>> = Vec::new();
    if !zero.is_empty() {
        clusters.push(zero);
    }
    if !positive.is_empty() {
        let budget = count.saturating_sub(clusters.len()).max(1);
        let initial = (2 * budget).div_ceil(3).max(1);
        if initial >= positive.len() {
            clusters.extend(positive.iter().map(|&j| vec![j]));
        } else {
            progress.check()?;
            clusters.extend(sampling_clustering(
                reduced, &positive, initial, rng, progress,
            )?);
        }
    }
    split_until(reduced, &mut clusters, count, lines, rng, progress)?;
    Ok(clusters)
}

/// The top-down stage: splits the cluster of highest [`cluster_cost`] on `reduced` with
/// [`split_cluster`] until there are `count` clusters or only singletons are left.
pub(crate) fn split_until(
    reduced: &impl ColumnSet,
    clusters: &mut Vec<Vec<u32>>,
    count: usize,
    lines: usize,
    rng: &mut impl Rng,
    progress: &dyn Progress,
) -> Result<(), ManyLightError> {
    progress.check()?;
    let costs: Vec<f64> = clusters.par_iter().map(|c| set_cost(reduced, c)).collect();
    let mut queue: BinaryHeap<Queued> = costs
        .into_iter()
        .enumerate()
        .map(|(id, cost)| Queued {
            cost,
            size: clusters[id].len(),
            id,
        })
        .collect();
    while clusters.len() < count {
        let Some(top) = queue.pop() else { break };
        if top.size < 2 {
            // Singletons cannot split; they leave the queue for good.
            continue;
        }
        progress.check()?;
        let members = std::mem::take(&mut clusters[top.id]);
        let Some((left, right)) = split_set(reduced, &members, lines, rng) else {
            clusters[top.id] = members;
            continue;
        };
        let new_id = clusters.len();
        queue.push(Queued {
            cost: set_cost(reduced, &left),
            size: left.len(),
            id: top.id,
        });
        queue.push(Queued {
            cost: set_cost(reduced, &right),
            size: right.len(),
            id: new_id,
        });
        clusters[top.id] = left;
        clusters.push(right);
    }
    Ok(())
}

/// Stage 1 of [`cluster_columns`] over the non-zero columns `positive`; returns the non-empty
/// clusters.
pub(crate) fn sampling_clustering(
    reduced: &impl ColumnSet,
    positive: &[u32],
    centres: usize,
    rng: &mut impl Rng,
    progress: &dyn Progress,
) -> Result<Vec<Vec<u32>>, ManyLightError> {
    let dim = reduced.dim();
    // Norms by column index (only those of `positive` are read).
    let mut norms = vec![0.0f64; reduced.cols()];
    for &j in positive {
        norms[j as usize] = reduced.norm(j as usize);
    }
    let mut total = vec![0.0f64; dim];
    for &j in positive {
        for (t, &v) in total.iter_mut().zip(reduced.column(j as usize)) {
            *t += v as f64;
        }
    }
    let total_norm: f64 = positive.iter().map(|&j| norms[j as usize]).sum();
    // α_i = a_i Σa − ρ_i · Σρ.
    let alpha: Vec<f64> = positive
        .par_iter()
        .map(|&j| {
            let dot: f64 = reduced
                .column(j as usize)
                .iter()
                .zip(&total)
                .map(|(&v, t)| v as f64 * t)
                .sum();
            (norms[j as usize] * total_norm - dot).max(0.0)
        })
        .collect();
    let alpha_sum: f64 = alpha.iter().sum();
    if alpha_sum <= 0.0 {
        // All columns point the same way: one cluster costs nothing.
        return Ok(vec![positive.to_vec()]);
    }
    let mut cumulative = Vec::with_capacity(alpha.len());
    let mut running = 0.0;
    for &a in &alpha {
        running += a;
        cumulative.push(running);
    }
    // Centre weights w_k = Σ over its draws of 1 / p_k, keyed by position in `positive`.
    let mut weights: BTreeMap<usize, f64> = BTreeMap::new();
    for _ in 0..centres {
        let u = rng.random::<f64>() * running;
        let k = cumulative.partition_point(|&c| c <= u).min(alpha.len() - 1);
        if alpha[k] > 0.0 {
            *weights.entry(k).or_insert(0.0) += alpha_sum / alpha[k];
        }
    }
    let centre_list: Vec<(usize, f64)> = weights.into_iter().collect();
    let k_count = centre_list.len();
    // Centre matrix: columns w_k ρ_k (dim × K, column-major), and w_k ‖ρ_k‖.
    let mut centre_matrix = vec![0.0f32; dim * k_count];
    let mut centre_scale = vec![0.0f64; k_count];
    for (c, &(k, w)) in centre_list.iter().enumerate() {
        let j = positive[k] as usize;
        for (dst, &v) in centre_matrix[c * dim..(c + 1) * dim]
            .iter_mut()
            .zip(reduced.column(j))
        {
            *dst = (v as f64 * w) as f32;
        }
        centre_scale[c] = w * norms[j];
    }
    let centres_ref = MatRef::from_column_major_slice(&centre_matrix, dim, k_count);
    // Assign each column to the centre of least weighted pair cost w_k (a_k a_i − ρ_k·ρ_i)
    // (the common factor a_i dropped after dividing), blocks in parallel, one sequential
    // product per block so that the result does not depend on the thread count.
    progress.set_len(positive.len().div_ceil(ASSIGN_BLOCK) as u64);
    let assignment: Vec<Vec<u32>> = positive
        .par_chunks(ASSIGN_BLOCK)
        .map(|block| {
            progress.check()?;
            let mut gathered = vec![0.0f32; dim * block.len()];
            for (b, &j) in block.iter().enumerate() {
                gathered[b * dim..(b + 1) * dim].copy_from_slice(reduced.column(j as usize));
            }
            let columns = MatRef::from_column_major_slice(&gathered, dim, block.len());
            let mut products = vec![0.0f32; k_count * block.len()];
            let dst = MatMut::from_column_major_slice_mut(&mut products, k_count, block.len());
            faer::linalg::matmul::matmul(
                dst,
                Accum::Replace,
                centres_ref.transpose(),
                columns,
                1.0f32,
                Par::Seq,
            );
            let mut best = Vec::with_capacity(block.len());
            for (b, &j) in block.iter().enumerate() {
                let a = norms[j as usize];
                let dots = &products[b * k_count..(b + 1) * k_count];
                let mut arg = 0u32;
                let mut min = f64::INFINITY;
                for (c, (&dot, &scale)) in dots.iter().zip(&centre_scale).enumerate() {
                    let d = scale * a - dot as f64;
                    if d < min {
                        min = d;
                        arg = c as u32;
                    }
                }
                best.push(arg);
            }
            progress.inc(1);
            Ok(best)
        })
        .collect::<Result<_, ManyLightError>>()?;
    let mut clusters = vec![Vec::new(); k_count];
    for (&j, &c) in positive.iter().zip(assignment.iter().flatten()) {
        clusters[c as usize].push(j);
    }
    clusters.retain(|c| !c.is_empty());
    Ok(clusters)
}
