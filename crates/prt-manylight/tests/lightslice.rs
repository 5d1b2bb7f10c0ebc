//! LightSlice: exactness, unbiasedness, cost accounting, determinism and bad input.

use ndarray::Array2;
use prt_core::{DenseOracle, MatrixOracle, NoProgress};
use prt_manylight::{
    GatherGeometry, LightSliceConfig, LightSliceEstimate, ManyLightError, ReducedMatrix,
    ShadingGuide, SliceOracle, SliceSplit, SyntheticVplOracle, UnseenLights, VisibilityOracle,
    brute_force, light_slice, light_slice_guided,
};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

fn dense(rows: usize, cols: usize, seed: u64) -> DenseOracle {
    let mut rng = Pcg64Mcg::seed_from_u64(seed);
    let mut data = Array2::from_shape_fn((rows, cols * 3), |_| rng.random::<f32>());
    for j in (0..cols).step_by(5) {
        for c in 0..3 {
            data.column_mut(j * 3 + c).fill(0.0);
        }
    }
    DenseOracle::new(data, 3).unwrap()
}

/// Relative RMS error of an image against the exact one (prt-core's metric).
fn relative_error(a: &[f32], b: &[f32]) -> f64 {
    prt_core::metrics::relative_frobenius_error(a, b).unwrap()
}

#[test]
fn exact_when_every_slice_keeps_every_light_alone() {
    let oracle = dense(30, 20, 1);
    let exact = brute_force(&oracle, &NoProgress).unwrap();
    for slices in [1, 4, 30] {
        let config = LightSliceConfig {
            global_clusters: 5,
            ..LightSliceConfig::new(slices, 20)
        };
        let estimate = light_slice(&oracle, &config, &NoProgress).unwrap();
        assert!(estimate.clusters_per_slice.iter().all(|&c| c == 20));
        assert!(
            relative_error(&estimate.image, &exact) < 1e-6,
            "{slices} slices"
        );
    }
}

/// Mean over seeds within 5 standard errors of the exact total, and per pixel.
fn check_unbiased(oracle: &dyn SliceOracle, config: LightSliceConfig, runs: u64) {
    check_unbiased_with(oracle, runs, |seed| {
        light_slice(oracle, &config.with_seed(seed), &NoProgress).unwrap()
    });
}

/// [`check_unbiased`] for the estimates `run(seed)` of `oracle`'s column sum.
fn check_unbiased_with(
    oracle: &dyn SliceOracle,
    runs: u64,
    run: impl Fn(u64) -> LightSliceEstimate,
) {
    let exact = brute_force(oracle, &NoProgress).unwrap();
    let len = exact.len();
    let (mut sum, mut sum_sq) = (vec![0.0f64; len], vec![0.0f64; len]);
    let mut totals = Vec::new();
    for seed in 0..runs {
        let estimate = run(seed);
        for (k, &v) in estimate.image.iter().enumerate() {
            sum[k] += v as f64;
            sum_sq[k] += (v as f64).powi(2);
        }
        totals.push(estimate.image.iter().map(|&v| v as f64).sum::<f64>());
    }
    let n = runs as f64;
    let mean = totals.iter().sum::<f64>() / n;
    let var = totals.iter().map(|t| (t - mean).powi(2)).sum::<f64>() / (n - 1.0);
    let exact_total: f64 = exact.iter().map(|&v| v as f64).sum();
    assert!(var > 0.0);
    let z = (mean - exact_total) / (var / n).sqrt();
    assert!(z.abs() < 5.0, "mean {mean}, exact {exact_total}, z = {z}");
    for k in 0..len {
        let m = sum[k] / n;
        let v = (sum_sq[k] / n - m * m).max(0.0) * n / (n - 1.0);
        let tolerance = 5.0 * (v / n).sqrt() + 1e-5 * (1.0 + exact[k].abs() as f64);
        assert!(
            (m - exact[k] as f64).abs() < tolerance,
            "pixel value {k}: {m} vs {}",
            exact[k]
        );
    }
}

#[test]
fn skipping_unseen_lights_sums_exactly_the_seen_columns() {
    // Odd columns are spikes on one row each; with 5 slices of 40 rows most are unseen.
    let mut data = dense(40, 30, 3).data().clone();
    let mut rng = Pcg64Mcg::seed_from_u64(4);
    for j in (1..30).step_by(2) {
        let hit = rng.random_range(0..40);
        for i in 0..40 {
            for c in 0..3 {
                data[[i, j * 3 + c]] = if i == hit { 4.0 } else { 0.0 };
            }
        }
    }
    let oracle = DenseOracle::new(data.clone(), 3).unwrap();
    for seed in 0..3 {
        let config = LightSliceConfig::new(5, 30)
            .with_seed(seed)
            .with_unseen(UnseenLights::Skip);
        let estimate = light_slice(&oracle, &config, &NoProgress).unwrap();
        let seen: Vec<bool> = (0..30)
            .map(|j| {
                estimate
                    .rows
                    .iter()
                    .any(|&i| (0..3).any(|c| data[[i, j * 3 + c]] != 0.0))
            })
            .collect();
        let seen_count = seen.iter().filter(|&&s| s).count();
        assert!(
            seen_count < 25,
            "most spikes fall between the 5 sampled rows"
        );
        assert!(estimate.clusters_per_slice.iter().all(|&c| c == seen_count));
        assert_eq!(estimate.elements, (5 * 30 + 40 * seen_count) as u64);
        for i in 0..40 {
            for c in 0..3 {
                let want: f64 = (0..30)
                    .filter(|&j| seen[j])
                    .map(|j| data[[i, j * 3 + c]] as f64)
                    .sum();
                let got = estimate.image[i * 3 + c] as f64;
                assert!((got - want).abs() < 1e-4 * (1.0 + want), "{got} vs {want}");
            }
        }
    }
}

#[test]
fn unbiased_on_dense_and_vpl_like_matrices() {
    check_unbiased(&dense(24, 50, 2), LightSliceConfig::new(6, 8), 400);
    // 3000 runs: the weights 1/p are heavy-tailed here (a light with a small reduced norm can
    // dominate a pixel), so the sample variance needs many runs to be trusted; at 300 runs one
    // pixel's mean was 5.3 standard errors low, at 3000 every pixel is within 5.
    let oracle = SyntheticVplOracle::new(8, 8, 400, 3);
    check_unbiased(&oracle, LightSliceConfig::new(8, 24), 3000);
}

/// `dense` with its odd columns replaced by spikes (one non-zero row each): lights that most
/// sampled rows miss.
fn spiky(rows: usize, cols: usize, seed: u64) -> DenseOracle {
    let mut data = dense(rows, cols, seed).data().clone();
    let mut rng = Pcg64Mcg::seed_from_u64(seed + 100);
    for j in (1..cols).step_by(2) {
        let hit = rng.random_range(0..rows);
        for i in 0..rows {
            for c in 0..3 {
                data[[i, j * 3 + c]] = if i == hit { 4.0 + c as f32 } else { 0.0 };
            }
        }
    }
    DenseOracle::new(data, 3).unwrap()
}

#[test]
fn grouped_unseen_lights_stay_unbiased_within_the_budget() {
    let oracle = spiky(24, 50, 5);
    let config = LightSliceConfig::new(4, 12).with_unseen(UnseenLights::Groups(3));
    check_unbiased(&oracle, config, 400);
    let estimate = light_slice(&oracle, &config, &NoProgress).unwrap();
    assert!(estimate.clusters_per_slice.iter().all(|&c| c <= 12));
    let bad = |k| {
        light_slice(
            &oracle,
            &config.with_unseen(UnseenLights::Groups(k)),
            &NoProgress,
        )
    };
    assert_eq!(
        bad(0),
        Err(ManyLightError::ZeroSamples {
            what: "unseen light groups"
        })
    );
    assert_eq!(
        bad(13),
        Err(ManyLightError::TooMany {
            what: "unseen light groups",
            requested: 13,
            available: 12
        })
    );
}

#[test]
fn local_importance_stays_unbiased_and_exact() {
    let config = LightSliceConfig::new(6, 8).with_local_importance(true);
    check_unbiased(&dense(24, 50, 2), config, 400);
    let local = LightSliceConfig {
        neighbours: 2,
        ..LightSliceConfig::new(4, 12).with_local_importance(true)
    };
    check_unbiased(&spiky(24, 50, 6), local, 400);
    // One light per cluster: probability 1 from both halves of the mixture.
    let oracle = dense(30, 20, 1);
    let exact = brute_force(&oracle, &NoProgress).unwrap();
    let all = LightSliceConfig {
        global_clusters: 5,
        neighbours: 2,
        ..LightSliceConfig::new(6, 20).with_local_importance(true)
    };
    let estimate = light_slice(&oracle, &all, &NoProgress).unwrap();
    assert!(relative_error(&estimate.image, &exact) < 1e-6);
}

#[test]
fn error_falls_with_more_slices_and_clusters() {
    let oracle = SyntheticVplOracle::new(24, 24, 3000, 4);
    let exact = brute_force(&oracle, &NoProgress).unwrap();
    let mean_error = |slices, clusters| {
        (0..6u64)
            .map(|seed| {
                let config = LightSliceConfig::new(slices, clusters).with_seed(seed);
                relative_error(
                    &light_slice(&oracle, &config, &NoProgress).unwrap().image,
                    &exact,
                )
            })
            .sum::<f64>()
            / 6.0
    };
    let coarse = mean_error(4, 16);
    let fine = mean_error(32, 300);
    assert!(fine < 0.5 * coarse, "{coarse} -> {fine}");
}

#[test]
fn elements_are_counted_per_slice() {
    let oracle = SyntheticVplOracle::new(10, 10, 500, 5);
    let config = LightSliceConfig::new(7, 30);
    let estimate = light_slice(&oracle, &config, &NoProgress).unwrap();
    assert_eq!(estimate.rows.len(), 7);
    assert!(estimate.clusters_per_slice.iter().all(|&c| c == 30));
    // 7 sampled rows of 500 lights, then 30 representatives on each slice's pixels (100 in all).
    assert_eq!(estimate.elements, 7 * 500 + 30 * 100);
    assert_eq!(oracle.elements_evaluated(), estimate.elements);
}

#[test]
fn same_seed_same_image_on_any_thread_count() {
    let oracle = SyntheticVplOracle::new(16, 16, 2000, 6);
    let config = LightSliceConfig::new(16, 40).with_seed(9);
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| light_slice(&oracle, &config, &NoProgress).unwrap())
    };
    assert_eq!(run(1), run(3));
}

#[test]
fn bad_input_is_a_typed_error() {
    let oracle = dense(10, 20, 7);
    let run = |config: LightSliceConfig| light_slice(&oracle, &config, &NoProgress);
    assert_eq!(
        run(LightSliceConfig::new(0, 5)),
        Err(ManyLightError::ZeroSamples { what: "slices" })
    );
    assert_eq!(
        run(LightSliceConfig::new(11, 5)),
        Err(ManyLightError::TooMany {
            what: "slices",
            requested: 11,
            available: 10
        })
    );
    assert_eq!(
        run(LightSliceConfig::new(5, 21)),
        Err(ManyLightError::TooMany {
            what: "local clusters",
            requested: 21,
            available: 20
        })
    );
    assert_eq!(
        run(LightSliceConfig {
            global_clusters: 6,
            ..LightSliceConfig::new(5, 5)
        }),
        Err(ManyLightError::TooMany {
            what: "global clusters",
            requested: 6,
            available: 5
        })
    );
    assert_eq!(
        run(LightSliceConfig {
            neighbours: 0,
            ..LightSliceConfig::new(5, 5)
        }),
        Err(ManyLightError::ZeroSamples { what: "neighbours" })
    );
    let empty = DenseOracle::new(Array2::zeros((0, 3)), 3).unwrap();
    assert_eq!(
        light_slice(&empty, &LightSliceConfig::new(1, 1), &NoProgress),
        Err(ManyLightError::EmptyMatrix {
            what: "rows (pixels)"
        })
    );
    // The default row evaluation checks its rows and output.
    let mut out = vec![0.0f32; 9];
    assert!(oracle.eval_col_rows(0, &[8, 9, 10], &mut out).is_err());
    assert!(oracle.eval_col_rows(0, &[7, 8], &mut out).is_err());
    assert!(oracle.eval_col_rows(0, &[9, 7, 8], &mut out).is_ok());
    assert_eq!(out[0], oracle.data()[[9, 0]]);
    assert_eq!(out[3], oracle.data()[[7, 0]]);
}

/// With gather-point geometry, slices are compact groups of pixels (here square tiles of the
/// synthetic floor), not scanline segments; without it, contiguous row ranges. Both partition
/// the rows.
#[test]
fn slices_follow_the_geometry_and_partition_the_rows() {
    let oracle = SyntheticVplOracle::new(16, 16, 200, 8);
    let estimate = light_slice(&oracle, &LightSliceConfig::new(16, 10), &NoProgress).unwrap();
    let mut seen = vec![0; 256];
    for (slice, &row) in estimate.slices.iter().zip(&estimate.rows) {
        assert!(slice.contains(&row), "the sampled row lies in its slice");
        assert_eq!(slice.len(), 16);
        let span = |f: fn(usize) -> usize| {
            let v: Vec<usize> = slice.iter().map(|&i| f(i)).collect();
            v.iter().max().unwrap() - v.iter().min().unwrap()
        };
        assert_eq!((span(|i| i % 16), span(|i| i / 16)), (3, 3), "{slice:?}");
        slice.iter().for_each(|&i| seen[i] += 1);
    }
    assert!(seen.iter().all(|&s| s == 1));

    let abstract_matrix = dense(20, 10, 9);
    let estimate =
        light_slice(&abstract_matrix, &LightSliceConfig::new(4, 5), &NoProgress).unwrap();
    let ranges: Vec<Vec<usize>> = (0..4).map(|s| (s * 5..(s + 1) * 5).collect()).collect();
    assert_eq!(estimate.slices, ranges);
}

#[test]
fn selected_rows_equal_a_reduced_matrix_sampled_on_them() {
    // Every fifth column of `dense` is zero: those skip the copy and must stay zero.
    let oracle = dense(40, 25, 3);
    let rows = vec![3, 17, 8, 39, 0, 22];
    let reduced = ReducedMatrix::sample(&oracle, rows.clone(), &NoProgress).unwrap();
    for positions in [vec![0, 2, 5], vec![4, 1], vec![5, 4, 3, 2, 1, 0], vec![]] {
        let selected = reduced.select_rows(&positions);
        let picked: Vec<usize> = positions.iter().map(|&p| rows[p]).collect();
        assert_eq!(selected.rows(), picked.as_slice());
        assert_eq!(selected.cols(), 25);
        if picked.is_empty() {
            assert!(selected.norms().iter().all(|&a| a == 0.0));
            continue;
        }
        let direct = ReducedMatrix::sample(&oracle, picked, &NoProgress).unwrap();
        assert_eq!(selected, direct, "positions {positions:?}");
        assert!((0..25).step_by(5).all(|j| selected.norms()[j] == 0.0));
        assert!(selected.norms()[1] > 0.0);
    }
    // Positions out of range are skipped.
    assert_eq!(reduced.select_rows(&[1, 6, 99]).rows(), &[17]);
}

#[test]
fn unseen_lights_leave_the_local_budget_to_the_seen_ones() {
    // Every light is a spike (one non-zero row, same colour): on a slice's own row every
    // cluster costs 0, so only the order of the splits decides who gets the clusters.
    let (rows, cols) = (24, 100);
    let mut rng = Pcg64Mcg::seed_from_u64(9);
    let mut data = Array2::<f32>::zeros((rows, cols * 3));
    for j in 0..cols {
        let hit = rng.random_range(0..rows);
        for c in 0..3 {
            data[[hit, j * 3 + c]] = 4.0 + c as f32;
        }
    }
    let oracle = DenseOracle::new(data, 3).unwrap();
    let config = LightSliceConfig {
        neighbours: 1,
        global_clusters: 3,
        ..LightSliceConfig::new(6, 10)
    }
    .with_unseen(UnseenLights::Skip);
    for seed in 0..4 {
        let estimate = light_slice(&oracle, &config.with_seed(seed), &NoProgress).unwrap();
        let seen = (0..cols)
            .filter(|&j| {
                estimate
                    .rows
                    .iter()
                    .any(|&i| oracle.data()[[i, j * 3]] != 0.0)
            })
            .count();
        assert!(seen >= 10 && seen < cols, "{seen} seen lights");
        // All but the one cluster of unseen lights are rendered, in every slice.
        assert!(
            estimate.clusters_per_slice.iter().all(|&c| c == 9),
            "seed {seed}: {:?}",
            estimate.clusters_per_slice
        );
    }
}

/// `dense` with its first `bright` rows scaled by 20: slices over them are the bright ones.
fn half_bright(rows: usize, cols: usize, bright: usize) -> DenseOracle {
    let mut data = dense(rows, cols, 12).data().clone();
    for i in 0..bright {
        data.row_mut(i).mapv_inplace(|v| 20.0 * v);
    }
    DenseOracle::new(data, 3).unwrap()
}

#[test]
fn adaptive_budget_moves_clusters_to_bright_slices_within_the_budget() {
    let (rows, cols, slices, clusters) = (40, 60, 8, 12);
    let oracle = half_bright(rows, cols, 20);
    let equal = LightSliceConfig {
        neighbours: 1,
        global_clusters: 4,
        ..LightSliceConfig::new(slices, clusters)
    };
    for seed in 0..3 {
        let config = equal.with_adaptive_percent(75).with_seed(seed);
        let estimate = light_slice(&oracle, &config, &NoProgress).unwrap();
        // Contiguous slices of 5 rows: the first four are the bright ones.
        let per_slice = &estimate.clusters_per_slice;
        let (bright, dim) = per_slice.split_at(4);
        assert!(
            bright.iter().min() > dim.iter().max(),
            "seed {seed}: {per_slice:?}"
        );
        // 25% of 12 each, and at least the 4 global clusters.
        assert!(dim.iter().all(|&k| k >= 4), "{per_slice:?}");
        // No more representative elements than the equal split (5 rows per slice).
        let spent: usize = per_slice.iter().map(|&k| 5 * k).sum();
        assert!(spent <= clusters * rows, "{spent}");
        assert!(
            spent + slices * 5 >= clusters * rows,
            "{spent}: budget left unused"
        );
        assert_eq!(estimate.elements, (slices * cols + spent) as u64);
        // The equal split gives every slice the same count.
        let same = light_slice(&oracle, &equal.with_seed(seed), &NoProgress).unwrap();
        assert!(same.clusters_per_slice.iter().all(|&k| k == clusters));
    }
    // Every slice capped at one light per cluster: the bright ones' surplus goes to the dim
    // ones until all have every light alone, and the image is exact.
    let exact = brute_force(&oracle, &NoProgress).unwrap();
    let all = LightSliceConfig {
        neighbours: 1,
        global_clusters: 4,
        ..LightSliceConfig::new(slices, cols)
    }
    .with_adaptive_percent(60);
    let estimate = light_slice(&oracle, &all, &NoProgress).unwrap();
    assert!(estimate.clusters_per_slice.iter().all(|&k| k == cols));
    assert!(relative_error(&estimate.image, &exact) < 1e-6);
    assert_eq!(
        light_slice(&oracle, &equal.with_adaptive_percent(101), &NoProgress),
        Err(ManyLightError::TooMany {
            what: "adaptive percent",
            requested: 101,
            available: 100
        })
    );
}

#[test]
fn adaptive_budget_stays_unbiased() {
    let config = LightSliceConfig::new(6, 8).with_adaptive_percent(50);
    check_unbiased(&half_bright(24, 50, 8), config, 400);
    let local = LightSliceConfig {
        neighbours: 2,
        ..LightSliceConfig::new(4, 12).with_adaptive_percent(100)
    };
    check_unbiased(&spiky(24, 50, 6), local, 400);
}

/// A dense matrix whose first half of pixels sit on one spot (x ≈ 100) and whose second half spread
/// along a line.
struct TwoRegions(DenseOracle);

impl MatrixOracle for TwoRegions {
    fn rows(&self) -> usize {
        self.0.rows()
    }
    fn cols(&self) -> usize {
        self.0.cols()
    }
    fn channels(&self) -> usize {
        self.0.channels()
    }
    fn eval_row(&self, i: usize, out: &mut [f32]) -> Result<(), prt_core::CoreError> {
        self.0.eval_row(i, out)
    }
    fn eval_col(&self, j: usize, out: &mut [f32]) -> Result<(), prt_core::CoreError> {
        self.0.eval_col(j, out)
    }
    fn elements_evaluated(&self) -> u64 {
        self.0.elements_evaluated()
    }
}

impl SliceOracle for TwoRegions {
    fn gather_point(&self, i: usize) -> Option<GatherGeometry> {
        let half = self.rows() / 2;
        let x = if i < half {
            100.0 + 1e-3 * i as f32
        } else {
            (i - half) as f32
        };
        Some(GatherGeometry {
            position: [x, 0.0, 0.0],
            normal: [0.0, 0.0, 1.0],
        })
    }
}

#[test]
fn spread_slicing_cuts_varied_geometry_finer() {
    let oracle = TwoRegions(dense(64, 10, 13));
    let in_spread_half = |slices: &[Vec<usize>]| slices.iter().filter(|s| s[0] >= 32).count();
    let largest = light_slice(&oracle, &LightSliceConfig::new(8, 5), &NoProgress).unwrap();
    assert_eq!(in_spread_half(&largest.slices), 4);
    let config = LightSliceConfig::new(8, 5).with_split(SliceSplit::Spread);
    let spread = light_slice(&oracle, &config, &NoProgress).unwrap();
    assert_eq!(in_spread_half(&spread.slices), 7, "{:?}", spread.slices);
    let mut seen = vec![0; 64];
    for (slice, &row) in spread.slices.iter().zip(&spread.rows) {
        assert!(slice.contains(&row));
        slice.iter().for_each(|&i| seen[i] += 1);
    }
    assert!(seen.iter().all(|&s| s == 1));
}

#[test]
fn defensive_draws_stay_unbiased_and_exact() {
    let config = LightSliceConfig::new(6, 8).with_defensive_percent(30);
    check_unbiased(&spiky(24, 50, 6), config, 400);
    let mixed = LightSliceConfig {
        neighbours: 2,
        ..LightSliceConfig::new(4, 12)
            .with_defensive_percent(50)
            .with_local_importance(true)
    };
    check_unbiased(&dense(24, 50, 2), mixed, 400);
    let oracle = dense(30, 20, 1);
    let exact = brute_force(&oracle, &NoProgress).unwrap();
    let all = LightSliceConfig {
        global_clusters: 5,
        ..LightSliceConfig::new(6, 20).with_defensive_percent(99)
    };
    let estimate = light_slice(&oracle, &all, &NoProgress).unwrap();
    assert!(relative_error(&estimate.image, &exact) < 1e-6);
    assert_eq!(
        light_slice(&oracle, &all.with_defensive_percent(100), &NoProgress),
        Err(ManyLightError::TooMany {
            what: "defensive percent",
            requested: 100,
            available: 99
        })
    );
}

/// A synthetic VPL matrix (its sphere's shadow makes shading and elements differ).
fn shaded_vpls(width: usize, lights: usize, seed: u64) -> SyntheticVplOracle {
    SyntheticVplOracle::new(width, width, lights, seed)
}

#[test]
fn shading_guide_stays_unbiased() {
    let oracle = shaded_vpls(8, 400, 3);
    // Few probes (the pdf misses pixels), and every pixel probed (8 slices of 8 pixels).
    for (percent, probes) in [(50, 3), (90, usize::MAX)] {
        let config = LightSliceConfig::new(8, 24).with_shading_guide(percent, probes);
        check_unbiased_with(&oracle, 1200, |seed| {
            light_slice_guided(&oracle, &config.with_seed(seed), &NoProgress).unwrap()
        });
    }
}

#[test]
fn shading_guide_at_zero_percent_is_the_unguided_estimator() {
    let oracle = shaded_vpls(12, 600, 4);
    for split in [SliceSplit::Largest, SliceSplit::Spread] {
        let config = LightSliceConfig::new(9, 40)
            .with_split(split)
            .with_unseen(UnseenLights::Skip)
            .with_defensive_percent(10)
            .with_seed(5);
        let plain = light_slice(&oracle, &config, &NoProgress).unwrap();
        let unguided = light_slice_guided(&oracle, &config, &NoProgress).unwrap();
        let zero =
            light_slice_guided(&oracle, &config.with_shading_guide(0, 8), &NoProgress).unwrap();
        assert_eq!(plain, unguided);
        assert_eq!(plain, zero);
        assert_eq!(zero.shading_evaluations, 0);
        let guided =
            light_slice_guided(&oracle, &config.with_shading_guide(50, 8), &NoProgress).unwrap();
        assert_ne!(guided.image, plain.image, "the guide changes the draws");
    }
}

#[test]
fn shading_guide_keeps_the_element_budget_and_counts_its_shading() {
    let oracle = shaded_vpls(16, 800, 6);
    for (unseen, probes) in [(UnseenLights::Skip, 5), (UnseenLights::Sample, usize::MAX)] {
        let config = LightSliceConfig::new(10, 50)
            .with_split(SliceSplit::Spread)
            .with_unseen(unseen)
            .with_seed(2);
        let plain = light_slice(&oracle, &config, &NoProgress).unwrap();
        oracle.reset_count();
        let guided =
            light_slice_guided(&oracle, &config.with_shading_guide(60, probes), &NoProgress)
                .unwrap();
        assert_eq!(guided.elements, plain.elements);
        assert_eq!(guided.clusters_per_slice, plain.clusters_per_slice);
        assert_eq!(
            oracle.elements_evaluated(),
            guided.elements,
            "shading is not counted"
        );
        let reduced = ReducedMatrix::sample(&oracle, guided.rows.clone(), &NoProgress).unwrap();
        let seen = reduced.norms().iter().filter(|&&a| a > 0.0).count();
        assert!(seen > 0 && seen < 800);
        let probed: usize = guided.slices.iter().map(|s| s.len().min(probes)).sum();
        assert_eq!(guided.shading_evaluations, (probed * seen) as u64);
    }
}

#[test]
fn shading_guide_is_exact_when_every_light_is_alone() {
    let oracle = shaded_vpls(6, 20, 7);
    let exact = brute_force(&oracle, &NoProgress).unwrap();
    let config = LightSliceConfig {
        global_clusters: 5,
        ..LightSliceConfig::new(4, 20).with_shading_guide(99, 2)
    };
    let estimate = light_slice_guided(&oracle, &config, &NoProgress).unwrap();
    assert!(estimate.clusters_per_slice.iter().all(|&c| c == 20));
    assert!(estimate.shading_evaluations > 0);
    assert!(relative_error(&estimate.image, &exact) < 1e-6);
}

#[test]
fn shading_guide_bad_input_is_a_typed_error() {
    let oracle = shaded_vpls(6, 20, 7);
    let config = LightSliceConfig::new(4, 10);
    assert_eq!(
        light_slice_guided(&oracle, &config.with_shading_guide(100, 4), &NoProgress),
        Err(ManyLightError::TooMany {
            what: "shading guide percent",
            requested: 100,
            available: 99
        })
    );
    assert_eq!(
        light_slice_guided(&oracle, &config.with_shading_guide(50, 0), &NoProgress),
        Err(ManyLightError::ZeroSamples {
            what: "shading probe"
        })
    );
    assert_eq!(
        light_slice(&oracle, &config.with_shading_guide(50, 4), &NoProgress),
        Err(ManyLightError::NeedsShading {
            what: "LightSlice's shading guide"
        })
    );
    let draws = config.with_guide(ShadingGuide::new(50, 4).with_unseen_draws(2));
    assert_eq!(
        light_slice_guided(&oracle, &draws, &NoProgress),
        Err(ManyLightError::TooMany {
            what: "unseen draws (only with UnseenLights::Skip)",
            requested: 2,
            available: 0
        })
    );
    let skip = config.with_unseen(UnseenLights::Skip);
    assert_eq!(
        light_slice_guided(
            &oracle,
            &skip.with_guide(ShadingGuide::new(50, 4).with_unseen_draws(10)),
            &NoProgress
        ),
        Err(ManyLightError::TooMany {
            what: "unseen draws",
            requested: 10,
            available: 9
        })
    );
}

/// A matrix with its unshadowed shading: `M = S · V`, `S` dense and positive, `V` one for the
/// even lights and, for the odd ones, on a single random row (a light that reaches one pixel,
/// which the sampled rows mostly miss).
struct Spikes {
    shading: Array2<f32>,
    visible: Array2<f32>,
}

impl Spikes {
    fn new(rows: usize, cols: usize, seed: u64) -> Self {
        let mut rng = Pcg64Mcg::seed_from_u64(seed);
        let shading = Array2::from_shape_fn((rows, cols * 3), |_| rng.random::<f32>() + 0.1);
        let mut visible = Array2::from_elem((rows, cols), 1.0f32);
        for j in (1..cols).step_by(2) {
            let hit = rng.random_range(0..rows);
            for i in 0..rows {
                visible[[i, j]] = if i == hit { 1.0 } else { 0.0 };
            }
        }
        Self { shading, visible }
    }
}

impl MatrixOracle for Spikes {
    fn rows(&self) -> usize {
        self.visible.nrows()
    }
    fn cols(&self) -> usize {
        self.visible.ncols()
    }
    fn channels(&self) -> usize {
        3
    }
    fn eval_row(&self, i: usize, out: &mut [f32]) -> Result<(), prt_core::CoreError> {
        for (j, o) in out.chunks_exact_mut(3).enumerate() {
            self.shading(i, j, o)?;
            o.iter_mut().for_each(|v| *v *= self.visible[[i, j]]);
        }
        Ok(())
    }
    fn eval_col(&self, j: usize, out: &mut [f32]) -> Result<(), prt_core::CoreError> {
        for (i, o) in out.chunks_exact_mut(3).enumerate() {
            self.shading(i, j, o)?;
            o.iter_mut().for_each(|v| *v *= self.visible[[i, j]]);
        }
        Ok(())
    }
    fn elements_evaluated(&self) -> u64 {
        0
    }
}

impl SliceOracle for Spikes {}

impl VisibilityOracle for Spikes {
    fn shading(&self, i: usize, j: usize, out: &mut [f32]) -> Result<(), prt_core::CoreError> {
        for (c, o) in out.iter_mut().enumerate() {
            *o = self.shading[[i, j * 3 + c]];
        }
        Ok(())
    }
    fn visibility(&self, i: usize, j: usize) -> Result<f32, prt_core::CoreError> {
        Ok(self.visible[[i, j]])
    }
}

#[test]
fn unseen_draws_with_every_pixel_probed_are_unbiased_within_the_budget() {
    let oracle = Spikes::new(40, 30, 8);
    let skip = LightSliceConfig::new(5, 12).with_unseen(UnseenLights::Skip);
    // The guide for the unseen lights alone (0% for the seen ones), every pixel probed: a light
    // that no probe sees lights no pixel of the slice, so nothing is skipped.
    let config = skip.with_guide(ShadingGuide::new(0, usize::MAX).with_unseen_draws(3));
    check_unbiased_with(&oracle, 1000, |seed| {
        light_slice_guided(&oracle, &config.with_seed(seed), &NoProgress).unwrap()
    });
    let plain = light_slice(&oracle, &skip.with_seed(1), &NoProgress).unwrap();
    let drawn = light_slice_guided(&oracle, &config.with_seed(1), &NoProgress).unwrap();
    assert_eq!(drawn.elements, plain.elements);
    let reduced = ReducedMatrix::sample(&oracle, drawn.rows.clone(), &NoProgress).unwrap();
    let unseen = reduced.norms().iter().filter(|&&a| a == 0.0).count();
    assert!(unseen > 5, "most spikes fall between the 5 sampled rows");
    assert_eq!(drawn.shading_evaluations, (40 * unseen) as u64);
    // Skip alone misses the unseen spikes: its mean is far off, the draws' is not.
    let exact: f64 = brute_force(&oracle, &NoProgress)
        .unwrap()
        .iter()
        .map(|&v| v as f64)
        .sum();
    let mean = |guided: bool| {
        (0..200u64)
            .map(|seed| {
                let e = if guided {
                    light_slice_guided(&oracle, &config.with_seed(seed), &NoProgress)
                } else {
                    light_slice(&oracle, &skip.with_seed(seed), &NoProgress)
                };
                e.unwrap().image.iter().map(|&v| v as f64).sum::<f64>()
            })
            .sum::<f64>()
            / 200.0
    };
    let (skipped, drawn) = (mean(false), mean(true));
    assert!(
        (drawn - exact).abs() < 0.25 * (skipped - exact).abs(),
        "exact {exact}, Skip {skipped}, unseen draws {drawn}"
    );
}

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig::with_cases(24))]

    /// The guide never costs elements: exactly `light_slice`'s without unseen draws, at most
    /// theirs with them (a slice whose probes no unseen light reaches makes none); at 0% and no
    /// unseen draws it is `light_slice` itself; the shading count is probes × lights shaded.
    #[test]
    fn shading_guide_keeps_the_budget(
        slices in 1usize..12,
        clusters in 4usize..40,
        percent in 0u32..100,
        probes in 1usize..20,
        draws in 0usize..4,
        seed in 0u64..1000,
    ) {
        let oracle = shaded_vpls(8, 200, 11);
        let config = LightSliceConfig::new(slices, clusters)
            .with_unseen(UnseenLights::Skip)
            .with_split(SliceSplit::Spread)
            .with_seed(seed);
        let plain = light_slice(&oracle, &config, &NoProgress).unwrap();
        let guide = ShadingGuide::new(percent, probes).with_unseen_draws(draws);
        let guided = light_slice_guided(&oracle, &config.with_guide(guide), &NoProgress).unwrap();
        proptest::prop_assert!(guided.elements <= plain.elements);
        if draws == 0 {
            proptest::prop_assert_eq!(guided.elements, plain.elements);
        }
        if percent == 0 && draws == 0 {
            proptest::prop_assert_eq!(&guided, &plain);
        }
        let reduced = ReducedMatrix::sample(&oracle, guided.rows.clone(), &NoProgress).unwrap();
        let seen = reduced.norms().iter().filter(|&&a| a > 0.0).count();
        let shaded = usize::from(percent > 0) * seen + usize::from(draws > 0) * (200 - seen);
        let probed: usize = guided.slices.iter().map(|s| s.len().min(probes)).sum();
        proptest::prop_assert_eq!(guided.shading_evaluations, (probed * shaded) as u64);
    }
}
