use prt_core::{CoreError, DenseOracle, MatrixOracle, Progress};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;
use rayon::prelude::*;

use crate::cluster::{regroup_unseen, split_until};
use crate::reduced::{check_requests, check_shape};
use crate::{ManyLightError, ReducedMatrix, UnseenLights, VisibilityOracle, cluster_columns};

/// A [`MatrixOracle`] that LightSlice can slice: it evaluates a column on a subset of rows
/// only, and may tell where each row's gather point is so that slices group pixels of similar
/// position and normal.
///
/// Defined here rather than in prt-core because only LightSlice needs it. The default
/// `eval_col_rows` evaluates the whole column and copies the rows (correct, but it costs a full
/// column); oracles that can do better override it. The default `gather_point` is `None`: the
/// slices are then contiguous row ranges.
pub trait SliceOracle: MatrixOracle {
    /// Writes column `j` at `rows` (in that order) into `out` (`rows.len() * channels` floats).
    fn eval_col_rows(&self, j: usize, rows: &[usize], out: &mut [f32]) -> Result<(), CoreError> {
        let c = self.channels();
        if let Some(&bad) = rows.iter().find(|&&i| i >= self.rows()) {
            return Err(CoreError::OutOfRange {
                what: "oracle row",
                index: bad,
                len: self.rows(),
            });
        }
        if out.len() != rows.len() * c {
            return Err(CoreError::LengthMismatch {
                what: "oracle column rows output",
                expected: rows.len() * c,
                got: out.len(),
            });
        }
        let mut column = vec![0.0f32; self.rows() * c];
        self.eval_col(j, &mut column)?;
        for (dst, &i) in out.chunks_exact_mut(c).zip(rows) {
            dst.copy_from_slice(&column[i * c..(i + 1) * c]);
        }
        Ok(())
    }

    /// The gather point of row `i` (pixel): its position and unit normal, or `None` when the
    /// oracle has no geometry for it (a pixel that sees nothing, or an abstract matrix).
    fn gather_point(&self, i: usize) -> Option<GatherGeometry> {
        let _ = i;
        None
    }
}

/// Where a row's pixel is: the position and unit normal of its gather point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GatherGeometry {
    /// World-space position.
    pub position: [f32; 3],
    /// Unit normal.
    pub normal: [f32; 3],
}

impl SliceOracle for DenseOracle {}

/// The knobs of [`light_slice`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LightSliceConfig {
    /// Slices: groups of rows (pixels) of similar gather-point position and normal (contiguous
    /// row ranges for an oracle without geometry), one sampled row each.
    pub slices: usize,
    /// Clusters of the global clustering, shared by all slices (at most `local_clusters`).
    pub global_clusters: usize,
    /// Clusters per slice after the local refinement: representative columns per slice.
    pub local_clusters: usize,
    /// Sampled rows used to refine a slice's clustering: its own and those of the nearest
    /// slices (by the distance between slice centroids; at most `slices`).
    pub neighbours: usize,
    /// Random projections tried per cluster split.
    pub split_lines: usize,
    /// Seed of every random choice.
    pub seed: u64,
    /// The treatment of lights that no sampled row sees (as in row-column sampling).
    pub unseen: UnseenLights,
    /// Draw each slice's representatives from the even mixture of two probabilities, the
    /// members' norms over the slice's local rows and over all sampled rows, instead of the
    /// latter alone: the local rows say which lights matter to this slice, the global norms
    /// bound every weight to twice the global draw's (still unbiased).
    pub local_importance: bool,
    /// Percent (0–100) of the representatives' element budget (`local_clusters` × pixels)
    /// handed out to the slices in proportion to their brightness — the mean, over the sampled
    /// rows of the slice and its `neighbours`, of the row's exact pixel value (the sum of its
    /// elements over every light and channel) — instead of equally. 0 (the default) gives every
    /// slice `local_clusters` representatives, as the paper does. See [`light_slice`], step 4.
    pub adaptive_percent: u32,
    /// Which slice the median splits cut next ([`SliceSplit`]).
    pub split: SliceSplit,
    /// Percent (0–99) of each representative draw made uniformly over the cluster's members
    /// (a defensive mixture: no weight exceeds `100 / percent` times the cluster's size; still
    /// unbiased). 0 (the default) draws by the norms alone, as the paper does.
    pub defensive_percent: u32,
    /// Part of each seen cluster's draw made by the lights' unshadowed shading on probe pixels
    /// of the slice ([`ShadingGuide`]; only with [`light_slice_guided`]). `None` (the default)
    /// draws by the sampled rows alone, as the paper does.
    pub shading_guide: Option<ShadingGuide>,
}

/// Unshadowed shading as a guide for LightSlice's representative draws (an extension of the
/// paper; see [`light_slice_guided`]).
///
/// Every element is bounded by its unshadowed shading, `0 ≤ M(i, j) ≤ S(i, j)` per channel
/// (visibility is in `[0, 1]`), and the shading costs no shadow ray. A light whose reduced
/// column is tiny (the sampled rows barely see it) but which lights the slice's other pixels
/// strongly gets a tiny probability from the rows and a huge weight; its shading on those
/// pixels gives it a probability in proportion to what it can contribute there.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub struct ShadingGuide {
    /// Percent (0–99) of each seen cluster's draw proportional to the members' shading norm on
    /// the slice's probe pixels, `u_j = (Σ_{i∈probes} Σ_c S(i, j, c)²)^½`; the rest is the
    /// row-based draw, which keeps every seen light's probability positive (so the estimate
    /// stays unbiased). 0 gives the unguided estimator, bit for bit.
    pub percent: u32,
    /// Probe pixels per slice (at least 1): the slice's sampled row, then repeatedly the pixel
    /// farthest (in the 6-D slicing space) from those already chosen. A slice of at most this
    /// many pixels probes all of them; the weighted column of a representative is then bounded
    /// by `100 / percent` times its cluster's shading norm over the slice.
    pub probes: usize,
    /// Draws per slice among the globally unseen lights (zero on every sampled row), with
    /// [`UnseenLights::Skip`] only: proportional to their shading norms on the probes, each
    /// weighted by `1 / (draws · p_j)`, out of the slice's cluster budget (the seen lights get
    /// that many clusters fewer; none are taken from a slice whose probes no unseen light
    /// reaches). Unbiased for the unseen lights that some probe of the slice sees (all those
    /// that light the slice when every pixel is probed); the others are skipped, as `Skip`
    /// skips every unseen light. 0 (the default): `Skip` as it is.
    pub unseen_draws: usize,
}

impl ShadingGuide {
    /// `percent` of each seen cluster's draw by the shading on `probes` pixels per slice
    /// (`usize::MAX`: every pixel), no unseen draws.
    pub fn new(percent: u32, probes: usize) -> Self {
        Self {
            percent,
            probes,
            unseen_draws: 0,
        }
    }

    /// The same guide with `draws` draws per slice among the unseen lights
    /// ([`ShadingGuide::unseen_draws`]).
    pub fn with_unseen_draws(self, draws: usize) -> Self {
        Self {
            unseen_draws: draws,
            ..self
        }
    }
}

/// The order in which [`light_slice`] cuts the pixels into slices (step 1).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[non_exhaustive]
pub enum SliceSplit {
    /// The slice with the most pixels first (ties to the lowest index): slices of equal size
    /// (within a factor 2), whatever their geometry.
    #[default]
    Largest,
    /// The slice of largest spread first: the sum over its pixels of the squared distance of
    /// their 6-D features (position and weighted normal) to the slice's centroid, as in
    /// variance-based median cut. Slices over varied geometry (curved surfaces, edges, far
    /// walls) are cut finer and get more sampled rows; flat, near ones stay larger.
    Spread,
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
            unseen: UnseenLights::Sample,
            local_importance: false,
            adaptive_percent: 0,
            split: SliceSplit::Largest,
            defensive_percent: 0,
            shading_guide: None,
        }
    }

    /// The same configuration with `percent` of each seen cluster's draw guided by the
    /// unshadowed shading on `probes` pixels per slice ([`ShadingGuide`];
    /// [`light_slice_guided`] only).
    pub fn with_shading_guide(self, percent: u32, probes: usize) -> Self {
        self.with_guide(ShadingGuide::new(percent, probes))
    }

    /// The same configuration with the shading guide `guide`.
    pub fn with_guide(self, guide: ShadingGuide) -> Self {
        Self {
            shading_guide: Some(guide),
            ..self
        }
    }

    /// The same configuration with `percent` of the representative draws uniform
    /// ([`LightSliceConfig::defensive_percent`]).
    pub fn with_defensive_percent(self, percent: u32) -> Self {
        Self {
            defensive_percent: percent,
            ..self
        }
    }

    /// The same configuration with another slicing order ([`SliceSplit`]).
    pub fn with_split(self, split: SliceSplit) -> Self {
        Self { split, ..self }
    }

    /// The same configuration with `percent` of the representatives' budget spread over the
    /// slices by brightness ([`LightSliceConfig::adaptive_percent`]).
    pub fn with_adaptive_percent(self, percent: u32) -> Self {
        Self {
            adaptive_percent: percent,
            ..self
        }
    }

    /// The same configuration with or without the local rows in the representatives'
    /// probability ([`LightSliceConfig::local_importance`]).
    pub fn with_local_importance(self, local_importance: bool) -> Self {
        Self {
            local_importance,
            ..self
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

/// The result of [`light_slice`].
#[derive(Debug, Clone, PartialEq)]
pub struct LightSliceEstimate {
    /// The estimated image: `rows × channels` values, row-major.
    pub image: Vec<f32>,
    /// The sampled rows, one per slice.
    pub rows: Vec<usize>,
    /// The rows of every slice, each in increasing order.
    pub slices: Vec<Vec<usize>>,
    /// Representative columns rendered per slice (without the skipped clusters of unseen lights
    /// with [`UnseenLights::Skip`]); `local_clusters` at most in every slice unless
    /// [`LightSliceConfig::adaptive_percent`] is positive.
    pub clusters_per_slice: Vec<usize>,
    /// Matrix elements evaluated: `slices × cols` for the reduced matrix plus, per slice, its
    /// rows times its representatives (at most `local_clusters × rows` in all). The shading
    /// guide's evaluations are not elements (no shadow ray) and are not counted here.
    pub elements: u64,
    /// Unshadowed shading evaluations of the [`ShadingGuide`] (no shadow rays): per slice, its
    /// probe pixels times the seen lights. 0 without a guide (or at 0%).
    pub shading_evaluations: u64,
}

/// Weight of the unit normal against the position (scaled to a unit bounding-box diagonal)
/// in the slicing and neighbour distances: opposite normals are as far apart as points 0.6
/// diagonals apart.
const NORMAL_WEIGHT: f32 = 0.3;

/// LightSlice (Ou and Pellacini, "LightSlice: Matrix Slice Sampling for the Many-Lights
/// Problem", SIGGRAPH Asia 2011).
///
/// 1. **Slices**: the pixels are cut into `slices` groups of similar gather-point geometry by
///    median splits (largest slice first, or with [`SliceSplit::Spread`] the slice of largest
///    spread; along the axis of largest extent) in the 6-D space of
///    position (scaled to a unit bounding-box diagonal) and normal (weighted by 0.3). Pixels
///    without a gather point form a slice of their own; an oracle without any geometry is cut
///    into contiguous row ranges. One row per slice is drawn uniformly, giving the reduced
///    matrix.
/// 2. **Global clustering** of the lights into `global_clusters` clusters ([`cluster_columns`])
///    on all sampled rows.
/// 3. **Local refinement**: for each slice, the global clusters are split further
///    ([`crate::split_cluster`], highest cost first) on the rows of the `neighbours` slices
///    whose centroids are nearest to its own (itself included), up to `local_clusters`: each
///    slice gets the clustering that fits its part of the image. The clusters of globally
///    unseen lights (zero on every sampled row) are left whole unless the seen lights are all
///    alone: split by index at cost 0, they would otherwise take the seen lights' clusters.
/// 4. **Budget per slice**: every slice refines to `local_clusters` clusters, or, with
///    [`LightSliceConfig::adaptive_percent`] `= q`, to `(1 − q/100) · local_clusters` plus its
///    share of the other `q/100` of the representatives' elements (`local_clusters × rows`),
///    in proportion to its pixels times its brightness `b_s` (the mean exact pixel value of the
///    sampled rows of the slice and its neighbours): `q/100 · local_clusters · rows · b_s /
///    Σ_t |t| b_t` more clusters. Slices whose share exceeds what they can use (every seen
///    light alone with `Skip`, every light alone otherwise) hand the rest to the others; no
///    slice gets fewer than `global_clusters`. The error of a slice falls about as `1/k` with
///    its `k` clusters and scales with its brightness, so this moves columns to the bright
///    slices that carry most of the error (an extension of the paper, off by default; the
///    estimate stays unbiased: it changes the clusters, not the draws).
/// 5. Each local cluster draws one representative proportionally to its reduced norm over all
///    sampled rows (uniformly in a cluster of zero columns, which [`UnseenLights::Skip`] skips
///    instead), as the authors' implementation does — the local rows decide the clusters, the
///    global norms are the robust importance — and the slice's pixels of its column, scaled by
///    the inverse probability, are added to the slice. With
///    [`LightSliceConfig::defensive_percent`] that share of the probability is uniform over the
///    cluster's members, which bounds the weights.
///
/// With [`UnseenLights::Groups`], each slice cuts the globally unseen lights into that many
/// groups of consecutive lights (out of its `local_clusters`), one uniform draw each.
///
/// Unbiased given the rows and clusterings with [`UnseenLights::Sample`] and
/// [`UnseenLights::Groups`] (every light has a
/// non-zero probability and its inverse as weight; with `Skip`, unbiased for the seen lights'
/// columns); exact when `local_clusters == cols`. The cost is
/// `slices × cols + local_clusters × rows` elements, the same as row-column sampling with
/// `slices` rows and `local_clusters` columns, but the clusters adapt to each slice. Slices are
/// processed in parallel, each with its own generator derived from the seed, so a seed gives
/// the same image on any number of threads.
///
/// Errors: an empty matrix, zero or too many slices / clusters, `global_clusters` above
/// `local_clusters`, `adaptive_percent` above 100 or `defensive_percent` above 99
/// ([`ManyLightError::TooMany`]), zero neighbours, non-finite elements, oracle failures,
/// cancellation; a [`LightSliceConfig::shading_guide`], which needs the unshadowed shading of
/// [`light_slice_guided`] ([`ManyLightError::NeedsShading`]).
pub fn light_slice(
    oracle: &dyn SliceOracle,
    config: &LightSliceConfig,
    progress: &dyn Progress,
) -> Result<LightSliceEstimate, ManyLightError> {
    if config.shading_guide.is_some() {
        return Err(ManyLightError::NeedsShading {
            what: "LightSlice's shading guide",
        });
    }
    slice_sample(oracle, None, config, progress)
}

/// [`light_slice`] on an oracle that also gives the unshadowed shading `S(i, j)` of every
/// element ([`VisibilityOracle::shading`], no shadow ray), for the [`ShadingGuide`] of
/// [`LightSliceConfig::shading_guide`] (an extension of the paper; without a guide the result
/// is [`light_slice`]'s).
///
/// With a guide of `percent` `= 100 α` and `probes` `= P`, each slice evaluates the shading of
/// every seen light (non-zero reduced column) on `P` probe pixels of the slice — its sampled row
/// and then, repeatedly, the pixel farthest in the slicing space from those chosen, or every
/// pixel of a slice of at most `P` — giving `u_j = (Σ_{i∈probes} Σ_c S(i, j, c)²)^½`. A seen
/// cluster `C` then draws its representative with probability
/// `p_j = (1 − α) q_j + α u_j / Σ_C u` (before the defensive share), where `q_j` is the
/// row-based probability of step 5 (the global norms, or their mixture with the local ones);
/// a cluster whose members all have `u = 0` draws by `q` alone. Every seen light keeps
/// `p_j ≥ (1 − α) q_j > 0`, so the estimate is unbiased exactly as without the guide; what
/// changes is the tail: a light that the sampled rows barely see (tiny `q_j`) but that
/// lights other pixels of the slice gets probability from its shading there, and since
/// `M ≤ S` element-wise its weighted column on the probes is at most `Σ_C u / α`. Unseen
/// lights are treated as [`LightSliceConfig::unseen`] says, or, with
/// [`ShadingGuide::unseen_draws`] `= k` and [`UnseenLights::Skip`], by `k` draws per slice
/// among them proportional to their shading norms on the same probes, out of the slice's
/// cluster budget (unbiased for the unseen lights that a probe sees).
///
/// The element count ([`LightSliceEstimate::elements`]) is identical to [`light_slice`]'s;
/// the shading evaluations (`P` or the slice's pixels, times the seen lights, per slice) are
/// counted apart in [`LightSliceEstimate::shading_evaluations`].
///
/// ```
/// use prt_core::NoProgress;
/// use prt_manylight::{LightSliceConfig, SliceSplit, SyntheticVplOracle, UnseenLights};
/// use prt_manylight::{light_slice, light_slice_guided};
///
/// let oracle = SyntheticVplOracle::new(32, 32, 2000, 1);
/// let config = LightSliceConfig::new(16, 100)
///     .with_split(SliceSplit::Spread)
///     .with_unseen(UnseenLights::Skip);
/// let plain = light_slice(&oracle, &config, &NoProgress).unwrap();
/// let guided = light_slice_guided(&oracle, &config.with_shading_guide(30, 8), &NoProgress).unwrap();
/// assert_eq!(guided.elements, plain.elements); // the same shadow rays
/// assert!(guided.shading_evaluations > 0 && plain.shading_evaluations == 0);
/// ```
///
/// Errors: those of [`light_slice`] (but not [`ManyLightError::NeedsShading`]), a guide
/// percent above 99, unseen draws without [`UnseenLights::Skip`] or not below
/// `local_clusters` ([`ManyLightError::TooMany`]), zero probes
/// ([`ManyLightError::ZeroSamples`]), a non-finite shading value
/// ([`ManyLightError::NonFinite`]).
pub fn light_slice_guided<O: SliceOracle + VisibilityOracle>(
    oracle: &O,
    config: &LightSliceConfig,
    progress: &dyn Progress,
) -> Result<LightSliceEstimate, ManyLightError> {
    slice_sample(oracle, Some(oracle), config, progress)
}

/// [`light_slice`], with the shading of `shading` (the same matrix) for the guide.
fn slice_sample(
    oracle: &dyn SliceOracle,
    shading: Option<&dyn VisibilityOracle>,
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
    if config.adaptive_percent > 100 {
        return Err(ManyLightError::TooMany {
            what: "adaptive percent",
            requested: config.adaptive_percent as usize,
            available: 100,
        });
    }
    if config.defensive_percent > 99 {
        return Err(ManyLightError::TooMany {
            what: "defensive percent",
            requested: config.defensive_percent as usize,
            available: 99,
        });
    }
    let defensive = config.defensive_percent as f64 / 100.0;
    // The guide at 0% is no guide: nothing evaluated, the unguided draws bit for bit.
    let guide = match (config.shading_guide, shading) {
        (Some(g), _) if g.percent > 99 => {
            return Err(ManyLightError::TooMany {
                what: "shading guide percent",
                requested: g.percent as usize,
                available: 99,
            });
        }
        (Some(g), _) if g.probes == 0 => {
            return Err(ManyLightError::ZeroSamples {
                what: "shading probe",
            });
        }
        (Some(g), _) if g.unseen_draws > 0 && config.unseen != UnseenLights::Skip => {
            return Err(ManyLightError::TooMany {
                what: "unseen draws (only with UnseenLights::Skip)",
                requested: g.unseen_draws,
                available: 0,
            });
        }
        (Some(g), _) if g.unseen_draws >= config.local_clusters => {
            return Err(ManyLightError::TooMany {
                what: "unseen draws",
                requested: g.unseen_draws,
                available: config.local_clusters - 1,
            });
        }
        (Some(g), Some(shading)) if g.percent > 0 || g.unseen_draws > 0 => Some((g, shading)),
        _ => None,
    };
    config.unseen.check(config.local_clusters)?;
    let mut rng = Pcg64Mcg::seed_from_u64(config.seed);
    progress.message("lightslice: slices");
    let Slicing {
        slices,
        centroids,
        features,
    } = make_slices(oracle, config.slices, config.split);
    let rows: Vec<usize> = slices
        .iter()
        .map(|s| s[rng.random_range(0..s.len())])
        .collect();
    progress.message("lightslice: reduced matrix");
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
    let unseen = global_norms.iter().filter(|&&a| a == 0.0).count();
    let groups = config
        .unseen
        .groups(unseen, m - unseen, config.local_clusters);
    let window = config.neighbours.min(slices.len());
    let neighbourhoods: Vec<Vec<usize>> = (0..slices.len())
        .map(|s| nearest(&centroids, s, window))
        .collect();
    let budgets = if config.adaptive_percent == 0 {
        vec![config.local_clusters; slices.len()]
    } else {
        // What a slice can use: every light alone, or with Skip every seen light alone plus
        // the one (skipped) cluster of unseen lights.
        let usable = if config.unseen == UnseenLights::Skip {
            m - unseen + usize::from(unseen > 0)
        } else {
            m
        };
        let totals = row_totals(&reduced);
        let brightness: Vec<f64> = neighbourhoods
            .iter()
            .map(|near| near.iter().map(|&t| totals[t]).sum::<f64>() / near.len() as f64)
            .collect();
        let sizes: Vec<usize> = slices.iter().map(Vec::len).collect();
        allocate_clusters(
            &sizes,
            &brightness,
            config.local_clusters,
            config.adaptive_percent,
            config.global_clusters.max(groups),
            usable.max(config.global_clusters.max(groups)),
        )
    };

    // The global clusters with a seen light, and those of unseen lights only: every slice
    // starts from copies of both.
    let (seen_global, unseen_global): (Vec<Vec<u32>>, Vec<Vec<u32>>) = global
        .clusters()
        .iter()
        .cloned()
        .partition(|c| c.iter().any(|&j| global_norms[j as usize] > 0.0));
    let seen_lights: Vec<u32> = seen_global.iter().flatten().copied().collect();
    let unseen_lights: Vec<u32> = unseen_global.iter().flatten().copied().collect();

    progress.message("lightslice: slices");
    progress.set_len(slices.len() as u64);
    let rendered: Vec<(Vec<f32>, usize, u64)> = slices
        .par_iter()
        .enumerate()
        .map(|(s, pixels)| {
            progress.check()?;
            let mut rng = Pcg64Mcg::seed_from_u64(
                slice_seed.wrapping_add((s as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)),
            );
            let local = reduced.select_rows(&neighbourhoods[s]);
            // The guide's shading norms on the probes: of the seen lights for their draws, of
            // the unseen ones for the unseen draws (which only happen if one of them is lit).
            let shaded = match guide {
                Some((g, shading)) => {
                    let probes = probe_pixels(pixels, reduced.rows()[s], &features, g.probes);
                    let lights: Vec<u32> = [
                        (g.percent > 0, &seen_lights),
                        (g.unseen_draws > 0, &unseen_lights),
                    ]
                    .into_iter()
                    .filter(|(wanted, _)| *wanted)
                    .flat_map(|(_, lights)| lights.iter().copied())
                    .collect();
                    let norms = shading_norms(shading, &probes, &lights, m, channels)?;
                    Some((g, norms, (probes.len() * lights.len()) as u64))
                }
                None => None,
            };
            let unseen_total: f64 = shaded.as_ref().map_or(0.0, |(g, u, _)| {
                if g.unseen_draws > 0 {
                    unseen_lights.iter().map(|&j| u[j as usize]).sum()
                } else {
                    0.0
                }
            });
            let unseen_draws = match &shaded {
                Some((g, _, _)) if unseen_total > 0.0 => g.unseen_draws,
                _ => 0,
            };
            let local_budget = (budgets[s] + 1 - groups).saturating_sub(unseen_draws);
            // The local rows refine the seen lights' clusters first: the globally unseen lights
            // are zero on every sampled row, so splitting them (by index, at cost 0) would take
            // clusters from the seen lights. They are split only with what the seen lights
            // cannot use (all alone), and follow the seen clusters.
            let (mut clusters, mut unseen_clusters) = (seen_global.clone(), unseen_global.clone());
            split_until(
                &local,
                &mut clusters,
                local_budget.saturating_sub(unseen_clusters.len()),
                config.split_lines,
                &mut rng,
                progress,
            )?;
            split_until(
                &local,
                &mut unseen_clusters,
                local_budget.saturating_sub(clusters.len()),
                config.split_lines,
                &mut rng,
                progress,
            )?;
            clusters.append(&mut unseen_clusters);
            if let UnseenLights::Groups(_) = config.unseen {
                regroup_unseen(&mut clusters, global_norms, groups);
            }
            let mut acc = vec![0.0f64; pixels.len() * channels];
            let mut column = vec![0.0f32; pixels.len() * channels];
            let mut rendered = 0;
            let local_norms = config.local_importance.then(|| local.norms());
            let guide_norms = shaded
                .as_ref()
                .map(|(g, u, _)| (u.as_slice(), g.percent as f64 / 100.0));
            let mut draws: Vec<(usize, f64)> = Vec::with_capacity(clusters.len() + unseen_draws);
            for members in &clusters {
                let (j, weight) = pick(
                    members,
                    global_norms,
                    local_norms,
                    guide_norms,
                    defensive,
                    &mut rng,
                );
                if config.unseen == UnseenLights::Skip && global_norms[j] == 0.0 {
                    continue;
                }
                draws.push((j, weight));
            }
            if let Some((_, u, _)) = &shaded {
                for _ in 0..unseen_draws {
                    let j = draw(&unseen_lights, u, unseen_total, rng.random::<f64>());
                    draws.push((j, unseen_total / (unseen_draws as f64 * u[j])));
                }
            }
            for (j, weight) in draws {
                rendered += 1;
                oracle.eval_col_rows(j, pixels, &mut column)?;
                if let Some(k) = column.iter().position(|v| !v.is_finite()) {
                    return Err(ManyLightError::NonFinite {
                        row: pixels[k / channels],
                        col: j,
                        channel: k % channels,
                    });
                }
                for (a, &v) in acc.iter_mut().zip(&column) {
                    *a += weight * v as f64;
                }
            }
            progress.inc(1);
            Ok((
                acc.into_iter().map(|a| a as f32).collect(),
                rendered,
                shaded.map_or(0, |(_, _, evaluations)| evaluations),
            ))
        })
        .collect::<Result<_, ManyLightError>>()?;
    let mut image = vec![0.0f32; n * channels];
    let mut elements = (slices.len() * m) as u64;
    let mut shading_evaluations = 0;
    let mut clusters_per_slice = Vec::with_capacity(slices.len());
    for (pixels, (values, clusters, shaded)) in slices.iter().zip(rendered) {
        shading_evaluations += shaded;
        for (&i, v) in pixels.iter().zip(values.chunks_exact(channels)) {
            image[i * channels..(i + 1) * channels].copy_from_slice(v);
        }
        elements += (pixels.len() * clusters) as u64;
        clusters_per_slice.push(clusters);
    }
    Ok(LightSliceEstimate {
        image,
        rows: reduced.rows().to_vec(),
        slices,
        clusters_per_slice,
        elements,
        shading_evaluations,
    })
}

/// Up to `count` probe pixels of a slice: its sampled row, then repeatedly the pixel farthest
/// from those chosen in the slicing space `features` (ties to the lowest row); every pixel when
/// the slice has at most `count`.
fn probe_pixels(
    pixels: &[usize],
    sampled: usize,
    features: &[[f32; 6]],
    count: usize,
) -> Vec<usize> {
    if pixels.len() <= count {
        return pixels.to_vec();
    }
    let distance = |a: usize, b: usize| -> f32 {
        features[a]
            .iter()
            .zip(&features[b])
            .map(|(x, y)| (x - y) * (x - y))
            .sum()
    };
    let mut probes = vec![sampled];
    let mut nearest: Vec<f32> = pixels.iter().map(|&i| distance(i, sampled)).collect();
    while probes.len() < count {
        let Some(k) = (0..pixels.len())
            .filter(|&k| nearest[k] > 0.0)
            .max_by(|&a, &b| nearest[a].total_cmp(&nearest[b]).then(b.cmp(&a)))
        else {
            break;
        };
        let chosen = pixels[k];
        probes.push(chosen);
        for (d, &i) in nearest.iter_mut().zip(pixels) {
            *d = d.min(distance(i, chosen));
        }
    }
    probes
}

/// The shading norm of each of `lights` over the `probes`, `(Σ_i Σ_c S(i, j, c)²)^½`, in a
/// vector indexed by light (`cols` long; zero for the other lights).
fn shading_norms(
    shading: &dyn VisibilityOracle,
    probes: &[usize],
    lights: &[u32],
    cols: usize,
    channels: usize,
) -> Result<Vec<f64>, ManyLightError> {
    let mut norms = vec![0.0f64; cols];
    let mut value = vec![0.0f32; channels];
    for &j in lights {
        let j = j as usize;
        let mut sum = 0.0f64;
        for &i in probes {
            shading.shading(i, j, &mut value)?;
            for (channel, &v) in value.iter().enumerate() {
                if !v.is_finite() {
                    return Err(ManyLightError::NonFinite {
                        row: i,
                        col: j,
                        channel,
                    });
                }
                sum += v as f64 * v as f64;
            }
        }
        norms[j] = sum.sqrt();
    }
    Ok(norms)
}

/// The exact pixel value of every sampled row: the sum of its elements over all lights and
/// channels (zero columns skipped), in the order of [`ReducedMatrix::rows`].
fn row_totals(reduced: &ReducedMatrix) -> Vec<f64> {
    let channels = reduced.channels();
    let mut totals = vec![0.0f64; reduced.rows().len()];
    for (j, &norm) in reduced.norms().iter().enumerate() {
        if norm == 0.0 {
            continue;
        }
        for (t, element) in totals
            .iter_mut()
            .zip(reduced.column(j).chunks_exact(channels))
        {
            *t += element.iter().map(|&v| v as f64).sum::<f64>();
        }
    }
    totals
}

/// Clusters per slice (see [`light_slice`], step 4): `(100 − percent)%` of `clusters` each,
/// plus `percent%` of the element budget `clusters × Σ sizes` in proportion to `size × brightness`,
/// each slice between `floor` (taken out of the equal part first) and `cap` (the share above a
/// cap goes to the other slices, by the same proportion). Equal shares when no slice is
/// brighter than zero. Never more elements (`Σ size × clusters`) than the equal split, rounding
/// down.
fn allocate_clusters(
    sizes: &[usize],
    brightness: &[f64],
    clusters: usize,
    percent: u32,
    floor: usize,
    cap: usize,
) -> Vec<usize> {
    let base =
        (clusters as f64 * (100 - percent.min(100)) as f64 / 100.0).max(floor.min(clusters) as f64);
    let total: f64 = sizes.iter().map(|&s| s as f64).sum();
    let weights: Vec<f64> = brightness
        .iter()
        .map(|&b| if b.is_finite() && b > 0.0 { b } else { 0.0 })
        .collect();
    let mut share: Vec<f64> = vec![base; sizes.len()];
    let mut left = clusters as f64 * total - base * total;
    let mut open: Vec<bool> = vec![true; sizes.len()];
    // Water-filling: hand out what is left by weight among the slices under their cap, until
    // nothing is left or no weighted slice is open (then the rest is spread equally, capped).
    while left > 1e-9 * clusters as f64 * total {
        let weight: f64 = (0..sizes.len())
            .filter(|&s| open[s])
            .map(|s| sizes[s] as f64 * weights[s])
            .sum();
        let equal: f64 = (0..sizes.len())
            .filter(|&s| open[s])
            .map(|s| sizes[s] as f64)
            .sum();
        if equal == 0.0 {
            break;
        }
        let mut spilled = 0.0;
        for s in 0..sizes.len() {
            if !open[s] {
                continue;
            }
            // Extra clusters for slice s: its part of the elements left, over its pixels.
            let extra = if weight > 0.0 {
                left * weights[s] / weight
            } else {
                left / equal
            };
            share[s] += extra;
            if share[s] >= cap as f64 {
                spilled += (share[s] - cap as f64) * sizes[s] as f64;
                share[s] = cap as f64;
                open[s] = false;
            }
        }
        left = spilled;
    }
    share
        .into_iter()
        // The tolerance keeps a share that sums to a whole number of clusters from losing one
        // to rounding (a slice capped by the water-filling gets exactly its cap).
        .map(|k| ((k + 1e-6).floor() as usize).clamp(floor.min(cap), cap))
        .collect()
}

/// Cuts the rows into `count` slices (fewer only if there are fewer rows). See [`light_slice`],
/// step 1.
fn make_slices(oracle: &dyn SliceOracle, count: usize, split: SliceSplit) -> Slicing {
    let n = oracle.rows();
    let geometry: Vec<Option<GatherGeometry>> = (0..n).map(|i| oracle.gather_point(i)).collect();
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for g in geometry.iter().flatten() {
        for a in 0..3 {
            lo[a] = lo[a].min(g.position[a]);
            hi[a] = hi[a].max(g.position[a]);
        }
    }
    let diagonal = (0..3)
        .map(|a| (hi[a] - lo[a]).max(0.0).powi(2))
        .sum::<f32>()
        .sqrt();
    let scale = if diagonal > 0.0 && diagonal.is_finite() {
        1.0 / diagonal
    } else {
        1.0
    };
    let any_geometry = geometry.iter().any(Option::is_some);
    let features: Vec<[f32; 6]> = geometry
        .iter()
        .enumerate()
        .map(|(i, g)| match g {
            Some(g) => {
                let p = g.position.map(|x| if x.is_finite() { x } else { 0.0 });
                let nrm = g.normal.map(|x| if x.is_finite() { x } else { 0.0 });
                [
                    (p[0] - lo[0]) * scale,
                    (p[1] - lo[1]) * scale,
                    (p[2] - lo[2]) * scale,
                    nrm[0] * NORMAL_WEIGHT,
                    nrm[1] * NORMAL_WEIGHT,
                    nrm[2] * NORMAL_WEIGHT,
                ]
            }
            None => [i as f32 / n as f32, 0.0, 0.0, 0.0, 0.0, 0.0],
        })
        .collect();
    let mut slices: Vec<Vec<usize>> = if any_geometry {
        let (with, without): (Vec<usize>, Vec<usize>) =
            (0..n).partition(|&i| geometry[i].is_some());
        [with, without]
            .into_iter()
            .filter(|s| !s.is_empty())
            .collect()
    } else {
        vec![(0..n).collect()]
    };
    // Largest (or most spread) slice first, then lowest index; the rows without geometry are
    // never split.
    let splittable = |s: &Vec<usize>| !any_geometry || geometry[s[0]].is_some();
    let priority = |rows: &[usize]| -> f64 {
        match split {
            SliceSplit::Largest => rows.len() as f64,
            SliceSplit::Spread => {
                let mut mean = [0.0f64; 6];
                for &i in rows {
                    for (m, &f) in mean.iter_mut().zip(&features[i]) {
                        *m += f as f64;
                    }
                }
                let mean = mean.map(|m| m / rows.len().max(1) as f64);
                rows.iter()
                    .map(|&i| {
                        features[i]
                            .iter()
                            .zip(&mean)
                            .map(|(&f, m)| (f as f64 - m).powi(2))
                            .sum::<f64>()
                    })
                    .sum()
            }
        }
    };
    let mut priorities: Vec<f64> = slices.iter().map(|s| priority(s)).collect();
    while slices.len() < count {
        let Some(k) = (0..slices.len())
            .filter(|&k| slices[k].len() >= 2 && splittable(&slices[k]))
            .max_by(|&a, &b| priorities[a].total_cmp(&priorities[b]).then(b.cmp(&a)))
        else {
            break;
        };
        let mut rows = std::mem::take(&mut slices[k]);
        let axis = (0..6)
            .max_by(|&a, &b| {
                let extent = |x: usize| {
                    let (mut l, mut h) = (f32::INFINITY, f32::NEG_INFINITY);
                    for &i in &rows {
                        l = l.min(features[i][x]);
                        h = h.max(features[i][x]);
                    }
                    h - l
                };
                extent(a).total_cmp(&extent(b)).then(b.cmp(&a))
            })
            .unwrap_or(0);
        rows.sort_by(|&a, &b| {
            features[a][axis]
                .total_cmp(&features[b][axis])
                .then(a.cmp(&b))
        });
        let right = rows.split_off(rows.len() / 2);
        priorities[k] = priority(&rows);
        priorities.push(priority(&right));
        slices[k] = rows;
        slices.push(right);
    }
    for s in &mut slices {
        s.sort_unstable();
    }
    slices.sort_unstable_by_key(|s| s[0]);
    let centroids = slices
        .iter()
        .map(|s| {
            let mut c = [0.0f64; 6];
            for &i in s {
                for (a, &f) in c.iter_mut().zip(&features[i]) {
                    *a += f as f64;
                }
            }
            c.map(|a| (a / s.len() as f64) as f32)
        })
        .collect();
    Slicing {
        slices,
        centroids,
        features,
    }
}

/// What [`make_slices`] returns: the slices (rows in increasing order), their centroids and
/// every row's features in the 6-D slicing space.
struct Slicing {
    slices: Vec<Vec<usize>>,
    centroids: Vec<[f32; 6]>,
    features: Vec<[f32; 6]>,
}

/// The `window` slices whose centroids are nearest to slice `s`'s (itself first; ties to the
/// lower index), as positions into the sampled rows.
fn nearest(centroids: &[[f32; 6]], s: usize, window: usize) -> Vec<usize> {
    let d = |t: usize| -> f32 {
        centroids[s]
            .iter()
            .zip(&centroids[t])
            .map(|(a, b)| (a - b) * (a - b))
            .sum()
    };
    let mut order: Vec<(f32, usize)> = (0..centroids.len()).map(|t| (d(t), t)).collect();
    order.sort_by(|a, b| {
        a.0.total_cmp(&b.0)
            .then((a.1 != s).cmp(&(b.1 != s)))
            .then(a.1.cmp(&b.1))
    });
    order.into_iter().take(window).map(|(_, t)| t).collect()
}

/// A representative of `members` drawn proportionally to its norm over all sampled rows
/// (uniformly in a cluster of zero columns), or, with `local` norms whose sum over the cluster
/// is positive, from the even mixture of that and the draw proportional to the local norms;
/// with probability `defensive` the draw is uniform over the members instead (a defensive
/// mixture). With `guide` norms `u` whose sum over the cluster is positive and its share `α`,
/// the non-defensive draw is by `u` with probability `α` and as above otherwise. Returned with
/// the inverse of its probability. Local clusters only split global ones, and the global
/// clustering keeps zero columns apart, so a cluster is either all zero or all positive
/// (globally; a local norm is zero only where the global one is or the local rows miss the
/// light).
fn pick(
    members: &[u32],
    norms: &[f64],
    local: Option<&[f64]>,
    guide: Option<(&[f64], f64)>,
    defensive: f64,
    rng: &mut impl Rng,
) -> (usize, f64) {
    let total: f64 = members.iter().map(|&j| norms[j as usize]).sum();
    if total <= 0.0 {
        let k = rng.random_range(0..members.len());
        return (members[k] as usize, members.len() as f64);
    }
    let sum_over = |v: &[f64]| members.iter().map(|&j| v[j as usize]).sum::<f64>();
    let guide = guide
        .map(|(u, alpha)| (u, sum_over(u), alpha))
        .filter(|&(_, sum, alpha)| sum > 0.0 && alpha > 0.0);
    let local = local.map(|l| (l, sum_over(l))).filter(|&(_, t)| t > 0.0);
    let size = members.len() as f64;
    // One uniform number picks the uniform draw (below `defensive`), then the guide (the next
    // `α` of the rest), then the row-based distribution (first half: global) and the light
    // within it.
    let u = rng.random::<f64>();
    let j = if u < defensive {
        members[((u / defensive * size) as usize).min(members.len() - 1)] as usize
    } else {
        let u = (u - defensive) / (1.0 - defensive);
        match guide {
            Some((g, sum, alpha)) if u < alpha => draw(members, g, sum, u / alpha),
            _ => {
                let u = match guide {
                    Some((_, _, alpha)) => (u - alpha) / (1.0 - alpha),
                    None => u,
                };
                match local {
                    Some((l, t)) if u >= 0.5 => draw(members, l, t, 2.0 * u - 1.0),
                    Some(_) => draw(members, norms, total, 2.0 * u),
                    None => draw(members, norms, total, u),
                }
            }
        }
    };
    let rows = match local {
        Some((l, t)) => 0.5 * norms[j] / total + 0.5 * l[j] / t,
        None => norms[j] / total,
    };
    let weight = match guide {
        Some((g, sum, alpha)) => {
            1.0 / ((1.0 - defensive) * ((1.0 - alpha) * rows + alpha * g[j] / sum)
                + defensive / size)
        }
        None if local.is_none() && defensive == 0.0 => total / norms[j],
        None => 1.0 / ((1.0 - defensive) * rows + defensive / size),
    };
    (j, weight)
}

/// The member drawn proportionally to `weights` (whose sum over `members` is `sum > 0`) by the
/// uniform number `u` in `[0, 1)`: the first member whose running sum exceeds `u · sum`
/// (members of zero weight are never drawn).
fn draw(members: &[u32], weights: &[f64], sum: f64, u: f64) -> usize {
    let target = u * sum;
    let mut running = 0.0;
    let mut pick = members[0];
    for &j in members {
        let a = weights[j as usize];
        if a > 0.0 {
            pick = j;
            running += a;
            if target < running {
                break;
            }
        }
    }
    pick as usize
}
