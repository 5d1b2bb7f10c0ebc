use std::collections::BinaryHeap;
use std::ops::Range;

use prt_core::{MatrixOracle, Progress};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;
use rayon::prelude::*;

use crate::cluster::{ColumnSet, Queued, sampling_clustering, set_cost, split_set};
use crate::reduced::{check_requests, check_shape, eval_column};
use crate::{ManyLightError, ReducedMatrix, stratified_rows};

/// Columns evaluated together (in parallel) before they are accumulated in order.
const COLUMN_BATCH: usize = 32;

/// A zero-norm light inside a cluster with bright members is drawn as if its norm were this
/// fraction of the cluster's mean norm, so that no light has probability zero.
const ZERO_NORM_FLOOR: f64 = 1e-2;

/// The knobs of [`tensor_clustering`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TensorConfig {
    /// Rows (pixels) sampled in every frame.
    pub rows_per_frame: usize,
    /// Representative columns per frame on average: the budget is `columns_per_frame × frames`
    /// column evaluations (a cluster spanning `T` frames costs `|T|` of them).
    pub columns_per_frame: usize,
    /// Random projections tried per light split.
    pub split_lines: usize,
    /// Seed of every random choice.
    pub seed: u64,
}

impl TensorConfig {
    /// `rows_per_frame` rows and `columns_per_frame` columns per frame, 3 projections, seed 0.
    pub fn new(rows_per_frame: usize, columns_per_frame: usize) -> Self {
        Self {
            rows_per_frame,
            columns_per_frame,
            split_lines: 3,
            seed: 0,
        }
    }

    /// The same configuration with another seed.
    pub fn with_seed(self, seed: u64) -> Self {
        Self { seed, ..self }
    }
}

/// A rectangular cluster of the light × frame tensor: a set of lights over a range of frames,
/// rendered in every frame of the range by one representative light.
#[derive(Debug, Clone, PartialEq)]
pub struct TensorCluster {
    /// The lights, in increasing order.
    pub lights: Vec<u32>,
    /// The frames.
    pub frames: Range<usize>,
    /// The representative light.
    pub representative: usize,
    /// The factor its columns are scaled by (the inverse of its probability).
    pub weight: f64,
}

/// The result of [`tensor_clustering`].
#[derive(Debug, Clone, PartialEq)]
pub struct TensorEstimate {
    /// One image per frame: `rows × channels` values, row-major.
    pub images: Vec<Vec<f32>>,
    /// The sampled rows of every frame.
    pub rows: Vec<Vec<usize>>,
    /// The clusters.
    pub clusters: Vec<TensorCluster>,
    /// Splits in the light dimension made by the greedy stage.
    pub light_splits: usize,
    /// Splits in the time dimension made by the greedy stage.
    pub time_splits: usize,
    /// Matrix elements evaluated: the sampled rows of every frame plus, per cluster, one column
    /// of every frame it spans.
    pub elements: u64,
}

/// The reduced tensor: for every light, its reduced columns of all frames concatenated (frame
/// `t` at `t × frame_dim`), and the squared norm of each frame's part.
struct ReducedTensor {
    cols: usize,
    frames: usize,
    frame_dim: usize,
    data: Vec<f32>,
    frame_sq: Vec<f64>,
}

impl ReducedTensor {
    fn from_frames(frames: &[ReducedMatrix]) -> Self {
        let cols = frames[0].cols();
        let frame_dim = frames[0].dim();
        let count = frames.len();
        let dim = frame_dim * count;
        let mut data = vec![0.0f32; cols * dim];
        let mut frame_sq = vec![0.0f64; cols * count];
        data.par_chunks_mut(dim.max(1))
            .zip(frame_sq.par_chunks_mut(count))
            .enumerate()
            .for_each(|(j, (column, sq))| {
                for (t, frame) in frames.iter().enumerate() {
                    column[t * frame_dim..(t + 1) * frame_dim].copy_from_slice(frame.column(j));
                    sq[t] = frame.norms()[j] * frame.norms()[j];
                }
            });
        Self {
            cols,
            frames: count,
            frame_dim,
            data,
            frame_sq,
        }
    }

    fn view(&self, frames: Range<usize>) -> FrameView<'_> {
        FrameView {
            tensor: self,
            frames,
        }
    }
}

/// The reduced tensor restricted to a range of frames: each light's concatenated reduced
/// columns over those frames (a contiguous part of its tensor column).
struct FrameView<'a> {
    tensor: &'a ReducedTensor,
    frames: Range<usize>,
}

impl ColumnSet for FrameView<'_> {
    fn cols(&self) -> usize {
        self.tensor.cols
    }

    fn dim(&self) -> usize {
        self.frames.len() * self.tensor.frame_dim
    }

    fn column(&self, j: usize) -> &[f32] {
        let t = self.tensor;
        let start = j * t.frames * t.frame_dim;
        t.data
            .get(start + self.frames.start * t.frame_dim..start + self.frames.end * t.frame_dim)
            .unwrap_or(&[])
    }

    fn norm(&self, j: usize) -> f64 {
        let t = self.tensor;
        t.frame_sq
            .get(j * t.frames + self.frames.start..j * t.frames + self.frames.end)
            .map_or(0.0, |sq| sq.iter().sum::<f64>().sqrt())
    }
}

/// The best cut of `members` over `frames` in time: the frame `k` where
/// `cost([start, k)) + cost([k, end))` is least (ties to the earliest), with that cost. `None`
/// for a single frame. The sum never exceeds the cost over all of `frames`: the norm of a light
/// over the range is the Euclidean norm of its norms over the halves (Minkowski), and the
/// squared norm of the sum splits exactly.
fn best_time_split(
    tensor: &ReducedTensor,
    members: &[u32],
    frames: &Range<usize>,
) -> Option<(usize, f64)> {
    if frames.len() < 2 {
        return None;
    }
    let fd = tensor.frame_dim;
    let f = frames.len();
    // ‖Σ_C ρ^t‖² per frame, and each member's prefix sums of squared frame norms.
    let mut sum_sq = vec![0.0f64; f];
    let mut sum = vec![0.0f64; fd];
    for (k, t) in frames.clone().enumerate() {
        sum.fill(0.0);
        for &j in members {
            let start = (j as usize * tensor.frames + t) * fd;
            for (s, &v) in sum.iter_mut().zip(&tensor.data[start..start + fd]) {
                *s += v as f64;
            }
        }
        sum_sq[k] = sum.iter().map(|s| s * s).sum();
    }
    let prefix: Vec<Vec<f64>> = members
        .iter()
        .map(|&j| {
            let mut running = 0.0;
            let base = j as usize * tensor.frames;
            std::iter::once(0.0)
                .chain(frames.clone().map(|t| {
                    running += tensor.frame_sq[base + t];
                    running
                }))
                .collect()
        })
        .collect();
    let total_sum_sq: f64 = sum_sq.iter().sum();
    let mut left_sum_sq = 0.0;
    let mut best: Option<(usize, f64)> = None;
    for cut in 1..f {
        left_sum_sq += sum_sq[cut - 1];
        let (mut left_norm, mut right_norm) = (0.0f64, 0.0f64);
        for p in &prefix {
            left_norm += p[cut].sqrt();
            right_norm += (p[f] - p[cut]).max(0.0).sqrt();
        }
        let cost = (left_norm * left_norm - left_sum_sq).max(0.0)
            + (right_norm * right_norm - (total_sum_sq - left_sum_sq)).max(0.0);
        if best.is_none_or(|(_, c)| cost < c) {
            best = Some((frames.start + cut, cost));
        }
    }
    best
}

/// Many-light animation rendering by tensor clustering (Hašan, Velázquez-Armendáriz,
/// Pellacini and Bala, "Tensor Clustering for Rendering Many-Light Animations", EGSR 2008).
///
/// The frames are the slices of a pixels × lights × frames tensor: `frames[t]` is the matrix
/// of frame `t`, all with the same lights (columns) and channels. The algorithm
/// 1. samples `rows_per_frame` stratified rows in every frame; a light's reduced column over a
///    range of frames is the concatenation of its reduced columns in those frames;
/// 2. lights whose reduced columns are zero in every frame form one cluster; the others are
///    clustered over the whole sequence by the sampling clustering of row-column sampling into
///    about `2/3 · columns_per_frame` clusters spanning all frames;
/// 3. greedy refinement: the rectangular cluster (lights × frame range) of highest cost
///    ([`crate::cluster_cost`] of its concatenated reduced columns) is split either in lights
///    (random projections, as [`crate::split_cluster`]) or in time (the cut frame of least
///    cost), whichever lowers the cost more. A light split of a cluster spanning `|T|` frames
///    costs `|T|` more column evaluations; a cluster whose light split no longer fits the
///    budget of `columns_per_frame × frames` evaluations is final, as is one no split improves;
/// 4. every cluster draws one representative proportionally to its norm over the cluster's
///    frames (a zero-norm member of a cluster with bright ones as if its norm were 1% of the
///    cluster's mean, uniformly in an all-zero cluster), and its column, scaled by the inverse
///    probability, is added to every frame the cluster spans — the same light across frames,
///    which keeps the animation free of flicker.
///
/// Unbiased given the rows and the clustering (every light has a non-zero probability and the
/// inverse as weight). With `columns_per_frame == cols` every light is its own cluster over all
/// frames and the result is exact. A seed gives the same images on any number of threads.
///
/// Errors: no frames ([`ManyLightError::EmptyMatrix`]), frames with different columns or
/// channels ([`ManyLightError::ShapeMismatch`]), an empty matrix, zero or too many rows /
/// columns, non-finite elements, oracle failures, cancellation.
pub fn tensor_clustering(
    frames: &[&dyn MatrixOracle],
    config: &TensorConfig,
    progress: &dyn Progress,
) -> Result<TensorEstimate, ManyLightError> {
    let Some(first) = frames.first() else {
        return Err(ManyLightError::EmptyMatrix { what: "frames" });
    };
    for (t, frame) in frames.iter().enumerate() {
        check_shape(*frame)?;
        if frame.cols() != first.cols() || frame.channels() != first.channels() {
            return Err(ManyLightError::ShapeMismatch {
                frame: t,
                cols: frame.cols(),
                channels: frame.channels(),
                expected_cols: first.cols(),
                expected_channels: first.channels(),
            });
        }
    }
    let m = first.cols();
    let min_rows = frames.iter().map(|f| f.rows()).min().unwrap_or(0);
    check_requests(&[
        ("row", "rows", config.rows_per_frame, min_rows),
        ("column", "columns", config.columns_per_frame, m),
    ])?;
    let count = frames.len();
    let mut rng = Pcg64Mcg::seed_from_u64(config.seed);
    progress.message("tensor clustering: reduced tensor");
    let mut rows = Vec::with_capacity(count);
    let mut reduced = Vec::with_capacity(count);
    for frame in frames {
        let sampled = stratified_rows(frame.rows(), config.rows_per_frame, &mut rng);
        rows.push(sampled.clone());
        reduced.push(ReducedMatrix::sample(*frame, sampled, progress)?);
    }
    let tensor = ReducedTensor::from_frames(&reduced);
    drop(reduced);
    progress.message("tensor clustering: clustering");
    let (clusters, light_splits, time_splits) =
        cluster_tensor(&tensor, config, &mut rng, progress)?;
    let clusters = pick_representatives(&tensor, clusters, &mut rng);
    progress.message("tensor clustering: representative columns");
    let images = accumulate(frames, &clusters, progress)?;
    let elements = frames
        .iter()
        .map(|f| (config.rows_per_frame * f.cols()) as u64)
        .sum::<u64>()
        + clusters
            .iter()
            .flat_map(|c| c.frames.clone())
            .map(|t| frames[t].rows() as u64)
            .sum::<u64>();
    Ok(TensorEstimate {
        images,
        rows,
        clusters,
        light_splits,
        time_splits,
        elements,
    })
}

/// A rectangular cluster before its representative is drawn: lights and frames.
type Block = (Vec<u32>, Range<usize>);

/// Stages 2 and 3 of [`tensor_clustering`]: the clusters, and the numbers of light and time
/// splits.
fn cluster_tensor(
    tensor: &ReducedTensor,
    config: &TensorConfig,
    rng: &mut impl Rng,
    progress: &dyn Progress,
) -> Result<(Vec<Block>, usize, usize), ManyLightError> {
    let all = 0..tensor.frames;
    let whole = tensor.view(all.clone());
    if config.columns_per_frame >= tensor.cols {
        let singletons = (0..tensor.cols as u32).map(|j| (vec![j], all.clone()));
        return Ok((singletons.collect(), 0, 0));
    }
    let (positive, zero): (Vec<u32>, Vec<u32>) =
        (0..tensor.cols as u32).partition(|&j| whole.norm(j as usize) > 0.0);
    let mut clusters: Vec<Block> = Vec::new();
    if !zero.is_empty() {
        clusters.push((zero, all.clone()));
    }
    if !positive.is_empty() {
        let budget = config
            .columns_per_frame
            .saturating_sub(clusters.len())
            .max(1);
        let initial = (2 * budget).div_ceil(3).max(1);
        let groups = if initial >= positive.len() {
            positive.iter().map(|&j| vec![j]).collect()
        } else {
            sampling_clustering(&whole, &positive, initial, rng, progress)?
        };
        clusters.extend(groups.into_iter().map(|g| (g, all.clone())));
    }
    let budget = config.columns_per_frame * tensor.frames;
    let mut used: usize = clusters.iter().map(|(_, f)| f.len()).sum();
    let costs: Vec<f64> = clusters
        .par_iter()
        .map(|(c, f)| set_cost(&tensor.view(f.clone()), c))
        .collect();
    let mut queue: BinaryHeap<Queued> = costs
        .into_iter()
        .enumerate()
        .map(|(id, cost)| Queued {
            cost,
            size: clusters[id].0.len(),
            id,
        })
        .collect();
    let (mut light_splits, mut time_splits) = (0, 0);
    while let Some(top) = queue.pop() {
        if top.size < 2 || top.cost <= 0.0 {
            // Nothing left to gain from this cluster (and the rest cost no more).
            continue;
        }
        progress.check()?;
        let (members, frames) = clusters[top.id].clone();
        let view = tensor.view(frames.clone());
        let in_lights = split_set(&view, &members, config.split_lines, rng).map(|(a, b)| {
            let cost = set_cost(&view, &a) + set_cost(&view, &b);
            (a, b, cost)
        });
        let in_time = best_time_split(tensor, &members, &frames);
        let light_gain = in_lights.as_ref().map_or(0.0, |(_, _, c)| top.cost - c);
        let time_gain = in_time.map_or(0.0, |(_, c)| top.cost - c);
        let mut parts = Vec::new();
        let affordable = used + frames.len() <= budget;
        match (in_time, in_lights) {
            (Some((cut, _)), _) if time_gain > light_gain && time_gain > 0.0 => {
                parts.push((members.clone(), frames.start..cut));
                parts.push((members, cut..frames.end));
                time_splits += 1;
            }
            (_, Some((a, b, _))) if light_gain > 0.0 && affordable => {
                used += frames.len();
                parts.push((a, frames.clone()));
                parts.push((b, frames));
                light_splits += 1;
            }
            _ => {}
        }
        // An empty `parts` leaves the cluster final.
        for (k, part) in parts.into_iter().enumerate() {
            let id = if k == 0 { top.id } else { clusters.len() };
            let cost = set_cost(&tensor.view(part.1.clone()), &part.0);
            let size = part.0.len();
            if k == 0 {
                clusters[id] = part;
            } else {
                clusters.push(part);
            }
            queue.push(Queued { cost, size, id });
        }
    }
    Ok((clusters, light_splits, time_splits))
}

/// One representative per cluster, drawn proportionally to the norms over its frames.
fn pick_representatives(
    tensor: &ReducedTensor,
    clusters: Vec<Block>,
    rng: &mut impl Rng,
) -> Vec<TensorCluster> {
    clusters
        .into_iter()
        .map(|(lights, frames)| {
            let view = tensor.view(frames.clone());
            let norms: Vec<f64> = lights.iter().map(|&j| view.norm(j as usize)).collect();
            let positive: f64 = norms.iter().sum();
            let (representative, weight) = if positive > 0.0 {
                let floor = ZERO_NORM_FLOOR * positive / lights.len() as f64;
                let sampled: Vec<f64> = norms
                    .iter()
                    .map(|&a| if a > 0.0 { a } else { floor })
                    .collect();
                let total: f64 = sampled.iter().sum();
                let u = rng.random::<f64>() * total;
                let mut running = 0.0;
                let mut pick = lights.len() - 1;
                for (k, &a) in sampled.iter().enumerate() {
                    running += a;
                    if u < running {
                        pick = k;
                        break;
                    }
                }
                (lights[pick] as usize, total / sampled[pick])
            } else {
                let k = rng.random_range(0..lights.len());
                (lights[k] as usize, lights.len() as f64)
            };
            TensorCluster {
                lights,
                frames,
                representative,
                weight,
            }
        })
        .collect()
}

/// Adds every cluster's weighted representative column to each frame it spans: columns in
/// parallel batches, accumulated in cluster and frame order in f64.
fn accumulate(
    frames: &[&dyn MatrixOracle],
    clusters: &[TensorCluster],
    progress: &dyn Progress,
) -> Result<Vec<Vec<f32>>, ManyLightError> {
    let mut images: Vec<Vec<f64>> = frames
        .iter()
        .map(|f| vec![0.0; f.rows() * f.channels()])
        .collect();
    let jobs: Vec<(usize, usize, f64)> = clusters
        .iter()
        .flat_map(|c| c.frames.clone().map(|t| (t, c.representative, c.weight)))
        .collect();
    progress.set_len(jobs.len() as u64);
    for batch in jobs.chunks(COLUMN_BATCH) {
        progress.check()?;
        let columns: Vec<Result<Vec<f32>, ManyLightError>> = batch
            .par_iter()
            .map(|&(t, j, _)| {
                let mut column = vec![0.0f32; images[t].len()];
                eval_column(frames[t], j, &mut column)?;
                Ok(column)
            })
            .collect();
        for (&(t, _, weight), column) in batch.iter().zip(columns) {
            for (acc, &v) in images[t].iter_mut().zip(&column?) {
                *acc += weight * v as f64;
            }
        }
        progress.inc(batch.len() as u64);
    }
    Ok(images
        .into_iter()
        .map(|image| image.into_iter().map(|v| v as f32).collect())
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn tensor(cols: usize, frames: usize, fd: usize, values: &[f32]) -> ReducedTensor {
        let data: Vec<f32> = values
            .iter()
            .copied()
            .cycle()
            .take(cols * frames * fd)
            .collect();
        let frame_sq = (0..cols * frames)
            .map(|k| {
                data[k * fd..(k + 1) * fd]
                    .iter()
                    .map(|&v| v as f64 * v as f64)
                    .sum()
            })
            .collect();
        ReducedTensor {
            cols,
            frames,
            frame_dim: fd,
            data,
            frame_sq,
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]

        /// A time split never raises the cost, and its reported cost is the halves' costs.
        #[test]
        fn time_split_never_raises_the_cost(
            values in proptest::collection::vec(0.0f32..4.0, 1..40),
            cols in 2usize..9,
            frames in 2usize..7,
            fd in 1usize..4,
        ) {
            let t = tensor(cols, frames, fd, &values);
            let members: Vec<u32> = (0..cols as u32).collect();
            let all = 0..frames;
            let whole = set_cost(&t.view(all.clone()), &members);
            let (cut, cost) = best_time_split(&t, &members, &all).unwrap();
            let halves = set_cost(&t.view(0..cut), &members) + set_cost(&t.view(cut..frames), &members);
            prop_assert!(cost <= whole * (1.0 + 1e-9) + 1e-9, "{cost} > {whole}");
            prop_assert!((cost - halves).abs() <= 1e-6 * (1.0 + whole), "{cost} vs {halves}");
        }
    }
}
