use prt_core::{MatrixOracle, Progress};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;
use rayon::prelude::*;

use crate::reduced::{check_requests, check_shape, eval_column};
use crate::{Clustering, ManyLightError, ReducedMatrix, cluster_columns, stratified_rows};

/// Columns evaluated together (in parallel) before they are accumulated in order.
const COLUMN_BATCH: usize = 32;

/// What [`row_column_sampling`] does with *unseen* lights, whose reduced column is zero (no
/// sampled row sees them).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[non_exhaustive]
pub enum UnseenLights {
    /// Keep them in clusters of their own, each represented by one light drawn uniformly and
    /// weighted by the cluster's size: the estimate stays unbiased, but one unseen light that
    /// does light part of the image is then scaled by the number of unseen lights (tens of
    /// thousands in a scene whose view sees a small part of the lit geometry), a heavy tail.
    #[default]
    Sample,
    /// Never draw them, as the paper's estimator does (a representative is drawn with
    /// probability `‖ρ_j‖ / Σ_C ‖ρ‖`, zero for an unseen light): the image then estimates,
    /// without bias, the sum of the *seen* lights' columns and misses the unseen lights'
    /// contribution (light that reaches only pixels between the sampled rows). Exact in
    /// expectation when every non-zero column is seen, e.g. when all rows are sampled.
    Skip,
    /// Like `Sample`, but the unseen lights are cut into `k` groups of consecutive light
    /// indices (fewer if there are fewer unseen lights), each represented by one light drawn
    /// uniformly and weighted by the group's size: still unbiased, with about `1/k` of the
    /// variance of `Sample`'s single draw (stratified sampling of the unseen lights). The groups
    /// come out of the column budget: the seen lights get `k − 1` clusters fewer. Worth it when
    /// many lights are unseen and some of them light small parts of the image (Sponza at 400
    /// rows: 92% of the lights unseen, the expected error of `Sample`'s one draw 2.7× that of
    /// all the seen clusters together). `Groups(1)` samples like `Sample`; `k` must be at least 1 and at
    /// most the column (cluster) budget, and the seen lights keep at least one cluster.
    Groups(usize),
}

impl UnseenLights {
    /// Checks the group count of [`UnseenLights::Groups`] against the column budget.
    pub(crate) fn check(self, columns: usize) -> Result<(), ManyLightError> {
        match self {
            UnseenLights::Groups(0) => Err(ManyLightError::ZeroSamples {
                what: "unseen light groups",
            }),
            UnseenLights::Groups(k) if k > columns => Err(ManyLightError::TooMany {
                what: "unseen light groups",
                requested: k,
                available: columns,
            }),
            _ => Ok(()),
        }
    }

    /// The groups of `unseen` unseen lights in a budget of `columns` clusters, of which the
    /// `seen` lights keep at least one: the clustering is asked for `columns − groups + 1`
    /// clusters (it keeps one for the unseen lights), then [`UnseenLights::Groups`] regroups
    /// them. 1 for the other variants.
    pub(crate) fn groups(self, unseen: usize, seen: usize, columns: usize) -> usize {
        match self {
            UnseenLights::Groups(k) if unseen > 0 => {
                k.min(unseen).min(columns - usize::from(seen > 0)).max(1)
            }
            _ => 1,
        }
    }
}

/// The knobs of [`row_column_sampling`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RowColumnConfig {
    /// Rows (pixels) sampled, one per stratum of the row range. The paper's settings are
    /// 100–900.
    pub rows: usize,
    /// Clusters of lights, hence full columns evaluated (one representative per cluster). The
    /// paper's settings are 200–1800.
    pub columns: usize,
    /// Random projections tried per cluster split (the best cut wins).
    pub split_lines: usize,
    /// Seed of every random choice (rows, centres, projections, representatives).
    pub seed: u64,
    /// The treatment of lights that no sampled row sees.
    pub unseen: UnseenLights,
}

impl RowColumnConfig {
    /// `rows` sampled rows and `columns` clusters, 3 projections per split, seed 0.
    pub fn new(rows: usize, columns: usize) -> Self {
        Self {
            rows,
            columns,
            split_lines: 3,
            seed: 0,
            unseen: UnseenLights::Sample,
        }
    }

    /// The same configuration with another seed.
    pub fn with_seed(self, seed: u64) -> Self {
        Self { seed, ..self }
    }

    /// The same configuration with another treatment of unseen lights.
    pub fn with_unseen(self, unseen: UnseenLights) -> Self {
        Self { unseen, ..self }
    }
}

/// One representative light: the full column evaluated for its cluster and its weight.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Representative {
    /// The column (light) index.
    pub column: usize,
    /// The factor the column is scaled by: `Σ_C ‖ρ‖ / ‖ρ_rep‖` (or `|C|` for a cluster of
    /// zero reduced columns, whose representative is drawn uniformly).
    pub weight: f64,
    /// Number of lights in the cluster.
    pub cluster_size: usize,
}

/// The result of [`row_column_sampling`].
#[derive(Debug, Clone, PartialEq)]
pub struct RowColumnEstimate {
    /// The estimated image, the sum of all columns: `rows × channels` values, row-major.
    pub image: Vec<f32>,
    /// The sampled rows.
    pub rows: Vec<usize>,
    /// The light clusters.
    pub clustering: Clustering,
    /// The total [`crate::cluster_cost`] of the clustering on the sampled rows.
    pub clustering_cost: f64,
    /// One representative per cluster, in cluster order (none for the clusters of unseen
    /// lights with [`UnseenLights::Skip`]).
    pub representatives: Vec<Representative>,
    /// Matrix elements evaluated: `rows × cols` for the reduced matrix plus `rows_total`
    /// per representative.
    pub elements: u64,
    /// Lights whose reduced column is zero (seen by no sampled row).
    pub unseen_lights: usize,
}

/// Many-light rendering by matrix row-column sampling (Hasan, Pellacini and Bala, "Matrix
/// Row-Column Sampling for the Many-Light Problem", SIGGRAPH 2007).
///
/// The image is the sum of the columns of the pixels × lights matrix. The algorithm
/// 1. evaluates `config.rows` rows, one drawn uniformly in each stratum of the row range
///    ([`stratified_rows`]), giving the reduced columns `ρ_j` ([`ReducedMatrix`]);
/// 2. clusters the lights by their reduced columns ([`cluster_columns`]): sampling clustering
///    then top-down splits by random projection, minimising `Σ ‖ρ_i‖‖ρ_j‖‖ρ̂_i − ρ̂_j‖²`;
/// 3. draws one representative per cluster with probability `‖ρ_j‖ / Σ_C ‖ρ‖` and adds its
///    full column scaled by `Σ_C ‖ρ‖ / ‖ρ_j‖`. Unseen lights (zero reduced columns) are clustered
///    apart; with [`UnseenLights::Sample`] (the default) each of their clusters draws uniformly
///    and scales by its size, with [`UnseenLights::Groups`] they are cut into that many groups
///    of consecutive lights, each drawing uniformly, and with [`UnseenLights::Skip`] (the
///    paper's estimator) they are never drawn and cost no column.
///
/// Given the rows and the clustering, the estimate is unbiased with [`UnseenLights::Sample`]
/// and [`UnseenLights::Groups`]:
/// every light has a non-zero probability of representing its cluster and its weight is the
/// inverse of that probability. With [`UnseenLights::Skip`] it is an unbiased estimate of the
/// seen lights' columns only. With `columns == cols` every cluster is one light of weight 1 and
/// the result is exact (a skipped unseen light then has a zero column on the sampled rows, which
/// are all rows when `rows == rows_total`).
///
/// Work is `rows × cols + columns × rows_total` element evaluations (`elements` in the result),
/// rows and columns evaluated in parallel. The result depends only on the oracle and the
/// config: the same seed gives the same image on any number of threads (fixed batches,
/// accumulation in order, in f64).
///
/// Errors: an empty matrix, zero rows or columns requested, more than the matrix has
/// ([`ManyLightError::TooMany`]), a non-finite element, oracle failures, cancellation.
pub fn row_column_sampling(
    oracle: &dyn MatrixOracle,
    config: &RowColumnConfig,
    progress: &dyn Progress,
) -> Result<RowColumnEstimate, ManyLightError> {
    check_shape(oracle)?;
    let (n, m, channels) = (oracle.rows(), oracle.cols(), oracle.channels());
    check_requests(&[
        ("row", "rows", config.rows, n),
        ("column", "columns", config.columns, m),
    ])?;
    config.unseen.check(config.columns)?;
    let mut rng = Pcg64Mcg::seed_from_u64(config.seed);
    progress.message("row-column sampling: reduced matrix");
    let rows = stratified_rows(n, config.rows, &mut rng);
    let reduced = ReducedMatrix::sample(oracle, rows, progress)?;
    let unseen_lights = reduced.norms().iter().filter(|&&a| a == 0.0).count();
    progress.message("row-column sampling: clustering");
    let groups = config
        .unseen
        .groups(unseen_lights, m - unseen_lights, config.columns);
    let mut clustering = cluster_columns(
        &reduced,
        config.columns + 1 - groups,
        config.split_lines,
        &mut rng,
        progress,
    )?;
    if let UnseenLights::Groups(_) = config.unseen {
        clustering.regroup_unseen(reduced.norms(), groups);
    }
    let clustering_cost = clustering.cost(&reduced);
    let mut representatives = pick_representatives(&reduced, &clustering, &mut rng);
    if config.unseen == UnseenLights::Skip {
        // Drawn after every other choice, so that Skip and Sample share rows, clusters and the
        // seen clusters' representatives for a seed.
        representatives.retain(|r| reduced.norms()[r.column] > 0.0);
    }
    progress.message("row-column sampling: representative columns");
    let image = accumulate_columns(oracle, &representatives, progress)?;
    let elements = (reduced.rows().len() * m) as u64 + (representatives.len() * n) as u64;
    debug_assert_eq!(image.len(), n * channels);
    Ok(RowColumnEstimate {
        image,
        rows: reduced.rows().to_vec(),
        clustering,
        clustering_cost,
        representatives,
        elements,
        unseen_lights,
    })
}

/// One representative per cluster, drawn proportionally to the reduced norms (uniformly in a
/// cluster of zero columns), with the inverse-probability weight.
fn pick_representatives(
    reduced: &ReducedMatrix,
    clustering: &Clustering,
    rng: &mut impl Rng,
) -> Vec<Representative> {
    let norms = reduced.norms();
    clustering
        .clusters()
        .iter()
        .map(|members| {
            let total: f64 = members.iter().map(|&j| norms[j as usize]).sum();
            let (column, weight) = if total > 0.0 {
                let u = rng.random::<f64>() * total;
                let mut running = 0.0;
                // The last member of positive norm catches rounding at the top end.
                let mut pick = members[0] as usize;
                for &j in members {
                    let a = norms[j as usize];
                    if a > 0.0 {
                        pick = j as usize;
                        running += a;
                        if u < running {
                            break;
                        }
                    }
                }
                (pick, total / norms[pick])
            } else {
                let k = rng.random_range(0..members.len());
                (members[k] as usize, members.len() as f64)
            };
            Representative {
                column,
                weight,
                cluster_size: members.len(),
            }
        })
        .collect()
}

/// `Σ_rep weight × column(rep)`, columns evaluated in parallel batches and accumulated in
/// order in f64.
fn accumulate_columns(
    oracle: &dyn MatrixOracle,
    representatives: &[Representative],
    progress: &dyn Progress,
) -> Result<Vec<f32>, ManyLightError> {
    let len = oracle.rows() * oracle.channels();
    let mut image = vec![0.0f64; len];
    progress.set_len(representatives.len() as u64);
    for batch in representatives.chunks(COLUMN_BATCH) {
        progress.check()?;
        let columns: Vec<Result<Vec<f32>, ManyLightError>> = batch
            .par_iter()
            .map(|rep| {
                let mut column = vec![0.0f32; len];
                eval_column(oracle, rep.column, &mut column)?;
                Ok(column)
            })
            .collect();
        for (rep, column) in batch.iter().zip(columns) {
            for (acc, &v) in image.iter_mut().zip(&column?) {
                *acc += rep.weight * v as f64;
            }
        }
        progress.inc(batch.len() as u64);
    }
    Ok(image.into_iter().map(|v| v as f32).collect())
}

/// The exact image (the sum of all columns) at `rows × cols` element evaluations: the
/// reference that row-column sampling approximates. Rows are evaluated in parallel and each
/// pixel summed in f64, in column order.
pub fn brute_force(
    oracle: &dyn MatrixOracle,
    progress: &dyn Progress,
) -> Result<Vec<f32>, ManyLightError> {
    check_shape(oracle)?;
    let (n, m, channels) = (oracle.rows(), oracle.cols(), oracle.channels());
    let mut image = vec![0.0f32; n * channels];
    progress.set_len(n as u64);
    image
        .par_chunks_mut(channels)
        .enumerate()
        .try_for_each_init(
            || vec![0.0f32; m * channels],
            |row, (i, pixel)| {
                progress.check()?;
                oracle.eval_row(i, row)?;
                let mut sum = vec![0.0f64; channels];
                for (j, element) in row.chunks_exact(channels).enumerate() {
                    for (c, (s, &v)) in sum.iter_mut().zip(element).enumerate() {
                        if !v.is_finite() {
                            return Err(ManyLightError::NonFinite {
                                row: i,
                                col: j,
                                channel: c,
                            });
                        }
                        *s += v as f64;
                    }
                }
                for (p, s) in pixel.iter_mut().zip(sum) {
                    *p = s as f32;
                }
                progress.inc(1);
                Ok(())
            },
        )?;
    Ok(image)
}
