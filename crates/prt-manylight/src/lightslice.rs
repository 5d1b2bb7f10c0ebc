use std::ops::Range;

use prt_core::{CoreError, DenseOracle, MatrixOracle, Progress};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;
use rayon::prelude::*;

use crate::cluster::split_until;
use crate::reduced::{check_requests, check_shape};
use crate::{ManyLightError, ReducedMatrix, cluster_columns, stratified_rows};

/// A [`MatrixOracle`] that can also evaluate a column on a contiguous range of rows only: what
/// LightSlice needs to render one slice of pixels with its own representatives.
///
/// Defined here rather than in prt-core because only LightSlice needs it. The default method
/// evaluates the whole column and copies the range (correct, but it costs a full column);
/// oracles that can do better override it.
pub trait SliceOracle: MatrixOracle {
    /// Writes rows `rows` of column `j` into `out` (`rows.len() * channels` floats).
    fn eval_col_range(
        &self,
        j: usize,
        rows: Range<usize>,
        out: &mut [f32],
    ) -> Result<(), CoreError> {
        let c = self.channels();
        if rows.end > self.rows() || rows.start > rows.end {
            return Err(CoreError::OutOfRange {
                what: "oracle row range end",
                index: rows.end,
                len: self.rows(),
            });
        }
        if out.len() != rows.len() * c {
            return Err(CoreError::LengthMismatch {
                what: "oracle column range output",
                expected: rows.len() * c,
                got: out.len(),
            });
        }
        let mut column = vec![0.0f32; self.rows() * c];
        self.eval_col(j, &mut column)?;
        out.copy_from_slice(&column[rows.start * c..rows.end * c]);
        Ok(())
    }
}

impl SliceOracle for DenseOracle {}

/// The knobs of [`light_slice`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LightSliceConfig {
    /// Slices: contiguous ranges of rows (pixels in scanline order), one sampled row each.
    pub slices: usize,
    /// Clusters of the global clustering, shared by all slices (at most `local_clusters`).
    pub global_clusters: usize,
    /// Clusters per slice after the local refinement: representative columns per slice.
    pub local_clusters: usize,
    /// Sampled rows used to refine a slice's clustering: its own and those of the nearest
    /// slices by index (at most `slices`).
    pub neighbours: usize,
    /// Random projections tried per cluster split.
    pub split_lines: usize,
    /// Seed of every random choice.
    pub seed: u64,
}

impl LightSliceConfig {
    /// `slices` slices and `local_clusters` clusters per slice, with `local_clusters / 2` global
    /// clusters, 8 neighbouring rows, 3 projections per split, seed 0.
    pub fn new(slices: usize, local_clusters: usize) -> Self {
        Self {
            slices,
            global_clusters: (local_clusters / 2).max(1),
            local_clusters,
            neighbours: 8,
            split_lines: 3,
            seed: 0,
        }
    }

    /// The same configuration with another seed.
    pub fn with_seed(self, seed: u64) -> Self {
        Self { seed, ..self }
    }
}

/// The result of [`light_slice`].
#[derive(Debug, Clone, PartialEq)]
pub struct LightSliceEstimate {
    /// The estimated image: `rows × channels` values, row-major.
    pub image: Vec<f32>,
    /// The sampled rows, one per slice.
    pub rows: Vec<usize>,
    /// Representative columns rendered per slice.
    pub clusters_per_slice: Vec<usize>,
    /// Matrix elements evaluated: `slices × cols` for the reduced matrix plus, per slice, its
    /// rows times its representatives.
    pub elements: u64,
}

/// LightSlice (Ou and Pellacini, "LightSlice: Matrix Slice Sampling for the Many-Lights
/// Problem", SIGGRAPH Asia 2011), on contiguous row ranges as slices.
///
/// 1. The rows are cut into `slices` contiguous slices and one row is drawn in each
///    ([`stratified_rows`]), giving the reduced matrix.
/// 2. A global clustering of the lights into `global_clusters` clusters
///    ([`cluster_columns`]) on all sampled rows.
/// 3. For each slice, the global clusters are refined by top-down splits
///    ([`crate::split_cluster`]) on the rows of the `neighbours` nearest slices only, up to
///    `local_clusters`: each slice gets the clustering that fits its own part of the image.
/// 4. Each local cluster draws one representative with probability
///    `½ a_j^local / Σ a^local + ½ a_j^global / Σ a^global` (`a` = reduced norms; the global
///    half keeps every light of a non-zero global cluster possible, uniform in a cluster of
///    zero columns), and the slice's rows of its column, scaled by the inverse probability,
///    are added to the slice's pixels.
///
/// Unbiased given the rows and clusterings (every light has a non-zero probability and its
/// inverse as weight); exact when `local_clusters == cols`. The cost is
/// `slices × cols + local_clusters × rows` elements, the same as row-column sampling with
/// `slices` rows and `local_clusters` columns, but the clusters adapt to each slice. Slices are
/// processed in parallel, each with its own generator derived from the seed, so a seed gives
/// the same image on any number of threads.
///
/// Errors: an empty matrix, zero or too many slices / clusters, `global_clusters` above
/// `local_clusters` ([`ManyLightError::TooMany`]), zero neighbours, non-finite elements, oracle
/// failures, cancellation.
pub fn light_slice(
    oracle: &dyn SliceOracle,
    config: &LightSliceConfig,
    progress: &dyn Progress,
) -> Result<LightSliceEstimate, ManyLightError> {
    check_shape(oracle)?;
    let (n, m, channels) = (oracle.rows(), oracle.cols(), oracle.channels());
    check_requests(&[
        ("slices", "slices", config.slices, n),
        ("local clusters", "local clusters", config.local_clusters, m),
        (
            "global clusters",
            "global clusters",
            config.global_clusters,
            config.local_clusters,
        ),
        ("neighbours", "neighbours", config.neighbours, usize::MAX),
    ])?;
    let mut rng = Pcg64Mcg::seed_from_u64(config.seed);
    progress.message("lightslice: reduced matrix");
    let rows = stratified_rows(n, config.slices, &mut rng);
    let reduced = ReducedMatrix::sample(oracle, rows, progress)?;
    progress.message("lightslice: global clustering");
    let global = cluster_columns(
        &reduced,
        config.global_clusters,
        config.split_lines,
        &mut rng,
        progress,
    )?;
    let slice_seed: u64 = rng.random();
    let global_norms = reduced.norms();

    // The image cut into the slices' disjoint row ranges.
    let bounds: Vec<Range<usize>> = (0..config.slices)
        .map(|s| {
            let lo = (s as u128 * n as u128 / config.slices as u128) as usize;
            let hi = ((s as u128 + 1) * n as u128 / config.slices as u128) as usize;
            lo..hi
        })
        .collect();
    let mut image = vec![0.0f32; n * channels];
    let mut parts: Vec<&mut [f32]> = Vec::with_capacity(config.slices);
    let mut rest = image.as_mut_slice();
    for range in &bounds {
        let (part, tail) = rest.split_at_mut(range.len() * channels);
        parts.push(part);
        rest = tail;
    }
    progress.message("lightslice: slices");
    progress.set_len(config.slices as u64);
    let window = config.neighbours.min(config.slices);
    let clusters_per_slice: Vec<usize> = parts
        .into_par_iter()
        .enumerate()
        .map(|(s, part)| {
            progress.check()?;
            let mut rng = Pcg64Mcg::seed_from_u64(
                slice_seed.wrapping_add((s as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)),
            );
            // The `window` slices nearest to s by index, clamped at the ends.
            let first = s.saturating_sub(window / 2).min(config.slices - window);
            let positions: Vec<usize> = (first..first + window).collect();
            let local = reduced.select_rows(&positions);
            let mut clusters = global.clusters().to_vec();
            split_until(
                &local,
                &mut clusters,
                config.local_clusters,
                config.split_lines,
                &mut rng,
                progress,
            )?;
            let range = bounds[s].clone();
            let mut acc = vec![0.0f64; part.len()];
            let mut column = vec![0.0f32; part.len()];
            for members in &clusters {
                let (j, weight) = pick_mixture(members, local.norms(), global_norms, &mut rng);
                oracle.eval_col_range(j, range.clone(), &mut column)?;
                if let Some(k) = column.iter().position(|v| !v.is_finite()) {
                    return Err(ManyLightError::NonFinite {
                        row: range.start + k / channels,
                        col: j,
                        channel: k % channels,
                    });
                }
                for (a, &v) in acc.iter_mut().zip(&column) {
                    *a += weight * v as f64;
                }
            }
            for (p, a) in part.iter_mut().zip(acc) {
                *p = a as f32;
            }
            progress.inc(1);
            Ok(clusters.len())
        })
        .collect::<Result<_, ManyLightError>>()?;
    let elements = (config.slices * m) as u64
        + bounds
            .iter()
            .zip(&clusters_per_slice)
            .map(|(r, &c)| (r.len() * c) as u64)
            .sum::<u64>();
    Ok(LightSliceEstimate {
        image,
        rows: reduced.rows().to_vec(),
        clusters_per_slice,
        elements,
    })
}

/// A representative of `members` drawn with probability
/// `½ local_j / Σ local + ½ global_j / Σ global` (one half alone when the other total is 0,
/// uniform when both are), and the inverse of that probability.
fn pick_mixture(
    members: &[u32],
    local: &[f64],
    global: &[f64],
    rng: &mut impl Rng,
) -> (usize, f64) {
    let total_local: f64 = members.iter().map(|&j| local[j as usize]).sum();
    let total_global: f64 = members.iter().map(|&j| global[j as usize]).sum();
    let (wl, wg) = match (total_local > 0.0, total_global > 0.0) {
        (true, true) => (0.5 / total_local, 0.5 / total_global),
        (true, false) => (1.0 / total_local, 0.0),
        (false, true) => (0.0, 1.0 / total_global),
        (false, false) => {
            let k = rng.random_range(0..members.len());
            return (members[k] as usize, members.len() as f64);
        }
    };
    let probability = |j: u32| wl * local[j as usize] + wg * global[j as usize];
    let u: f64 = rng.random();
    let mut running = 0.0;
    let mut pick = members[0];
    for &j in members {
        let p = probability(j);
        if p > 0.0 {
            pick = j;
            running += p;
            if u < running {
                break;
            }
        }
    }
    (pick as usize, 1.0 / probability(pick))
}
