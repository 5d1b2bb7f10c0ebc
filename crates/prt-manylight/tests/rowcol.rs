//! Row-column sampling: exactness, unbiasedness, clustering laws, determinism and bad input.

use std::sync::atomic::{AtomicU64, Ordering};

use ndarray::Array2;
use proptest::prelude::*;
use prt_core::{AtomicProgress, CoreError, DenseOracle, MatrixOracle, NoProgress};
use prt_manylight::{
    ManyLightError, ReducedMatrix, RowColumnConfig, SyntheticVplOracle, UnseenLights, brute_force,
    cluster_columns, cluster_cost, row_column_sampling, split_cluster, stratified_rows,
};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

/// A non-negative `rows × cols` RGB matrix of rank `rank` (or full rank with `rank = 0`), with
/// every 7th column zero.
fn dense(rows: usize, cols: usize, rank: usize, seed: u64) -> DenseOracle {
    let mut rng = Pcg64Mcg::seed_from_u64(seed);
    let data = if rank == 0 {
        Array2::from_shape_fn((rows, cols * 3), |_| rng.random::<f32>())
    } else {
        let u = Array2::from_shape_fn((rows, rank), |_| rng.random::<f32>());
        let v = Array2::from_shape_fn((rank, cols * 3), |_| rng.random::<f32>());
        u.dot(&v)
    };
    let mut data = data;
    for j in (0..cols).step_by(7) {
        for c in 0..3 {
            data.column_mut(j * 3 + c).fill(0.0);
        }
    }
    DenseOracle::new(data, 3).unwrap()
}

fn total(image: &[f32]) -> f64 {
    image.iter().map(|&v| v as f64).sum()
}

#[test]
fn exact_when_every_light_is_its_own_cluster() {
    for (oracle, rows) in [
        (dense(40, 30, 3, 1), 5),
        (dense(40, 30, 0, 2), 40),
        (dense(1, 1, 0, 3), 1),
    ] {
        let exact = brute_force(&oracle, &NoProgress).unwrap();
        let cols = oracle.cols();
        for seed in 0..3 {
            let config = RowColumnConfig::new(rows, cols).with_seed(seed);
            let estimate = row_column_sampling(&oracle, &config, &NoProgress).unwrap();
            assert_eq!(estimate.clustering.len(), cols);
            assert!(estimate.representatives.iter().all(|r| r.weight == 1.0));
            for (a, b) in estimate.image.iter().zip(&exact) {
                assert!((a - b).abs() <= 1e-5 * (1.0 + b.abs()), "{a} vs {b}");
            }
        }
    }
}

#[test]
fn brute_force_is_the_column_sum() {
    let oracle = dense(9, 13, 0, 4);
    let image = brute_force(&oracle, &NoProgress).unwrap();
    let data = oracle.data();
    for i in 0..9 {
        for c in 0..3 {
            let want: f64 = (0..13).map(|j| data[[i, j * 3 + c]] as f64).sum();
            assert!((image[i * 3 + c] as f64 - want).abs() < 1e-5);
        }
    }
}

/// The estimator is unbiased given any rows and clustering, so the mean over seeds converges to
/// the exact image. Tolerance: 5 standard errors of the mean, estimated from the samples.
fn check_unbiased(oracle: &dyn MatrixOracle, config: RowColumnConfig, runs: u64) {
    let exact = brute_force(oracle, &NoProgress).unwrap();
    let len = exact.len();
    let mut sum = vec![0.0f64; len];
    let mut sum_sq = vec![0.0f64; len];
    let mut totals = Vec::new();
    for seed in 0..runs {
        let estimate = row_column_sampling(oracle, &config.with_seed(seed), &NoProgress).unwrap();
        for (k, &v) in estimate.image.iter().enumerate() {
            sum[k] += v as f64;
            sum_sq[k] += (v as f64).powi(2);
        }
        totals.push(total(&estimate.image));
    }
    let n = runs as f64;
    let mean_total = totals.iter().sum::<f64>() / n;
    let var_total = totals.iter().map(|t| (t - mean_total).powi(2)).sum::<f64>() / (n - 1.0);
    let exact_total = total(&exact);
    let z = (mean_total - exact_total) / (var_total / n).sqrt();
    assert!(var_total > 0.0, "the estimate should vary with the seed");
    assert!(
        z.abs() < 5.0,
        "total: mean {mean_total}, exact {exact_total}, z = {z}"
    );
    // Per pixel and channel: 5 standard errors, plus f32 rounding of the images.
    let mut worst: f64 = 0.0;
    for k in 0..len {
        let mean = sum[k] / n;
        let var = (sum_sq[k] / n - mean * mean).max(0.0) * n / (n - 1.0);
        let tolerance = 5.0 * (var / n).sqrt() + 1e-5 * (1.0 + exact[k].abs() as f64);
        let dev = (mean - exact[k] as f64).abs();
        worst = worst.max(dev / tolerance);
    }
    assert!(
        worst < 1.0,
        "a pixel's mean is {worst} tolerances away from the exact value"
    );
}

/// A `rows × cols` RGB matrix whose odd columns are spikes (one non-zero row each) over a
/// dense low-rank background in the even columns.
fn spiky(rows: usize, cols: usize, seed: u64) -> DenseOracle {
    let mut data = dense(rows, cols, 2, seed).data().clone();
    let mut rng = Pcg64Mcg::seed_from_u64(seed + 100);
    for j in (1..cols).step_by(2) {
        let hit = rng.random_range(0..rows);
        for i in 0..rows {
            for c in 0..3 {
                data[[i, j * 3 + c]] = if i == hit { 5.0 + c as f32 } else { 0.0 };
            }
        }
    }
    DenseOracle::new(data, 3).unwrap()
}

#[test]
fn skipping_unseen_lights_sums_exactly_the_seen_columns() {
    let oracle = spiky(40, 30, 11);
    let data = oracle.data().clone();
    for seed in 0..4 {
        let config = RowColumnConfig::new(6, 30).with_seed(seed);
        let sample = row_column_sampling(&oracle, &config, &NoProgress).unwrap();
        let skip = row_column_sampling(
            &oracle,
            &config.with_unseen(UnseenLights::Skip),
            &NoProgress,
        )
        .unwrap();
        assert_eq!(sample.rows, skip.rows);
        let seen: Vec<bool> = (0..30)
            .map(|j| {
                sample
                    .rows
                    .iter()
                    .any(|&i| (0..3).any(|c| data[[i, j * 3 + c]] != 0.0))
            })
            .collect();
        let unseen = seen.iter().filter(|&&s| !s).count();
        assert!(unseen > 5, "the spikes should mostly fall between 6 rows");
        assert_eq!((sample.unseen_lights, skip.unseen_lights), (unseen, unseen));
        // One light per cluster: Sample is exact; Skip drops exactly the unseen columns, and
        // evaluates no column for them.
        assert_eq!(skip.representatives.len(), 30 - unseen);
        assert_eq!(skip.elements, (6 * 30 + (30 - unseen) * 40) as u64);
        for i in 0..40 {
            for c in 0..3 {
                let all: f64 = (0..30).map(|j| data[[i, j * 3 + c]] as f64).sum();
                let seen_sum: f64 = (0..30)
                    .filter(|&j| seen[j])
                    .map(|j| data[[i, j * 3 + c]] as f64)
                    .sum();
                assert!((sample.image[i * 3 + c] as f64 - all).abs() < 1e-4 * (1.0 + all));
                assert!((skip.image[i * 3 + c] as f64 - seen_sum).abs() < 1e-4 * (1.0 + seen_sum));
            }
        }
    }
}

#[test]
fn skipping_unseen_lights_is_unbiased_when_every_row_is_sampled() {
    let oracle = spiky(12, 40, 12);
    let config = RowColumnConfig::new(12, 9).with_unseen(UnseenLights::Skip);
    check_unbiased(&oracle, config, 400);
}

#[test]
fn unbiased_on_low_rank_and_full_rank_matrices() {
    check_unbiased(&dense(24, 60, 2, 5), RowColumnConfig::new(4, 8), 400);
    check_unbiased(&dense(24, 60, 0, 6), RowColumnConfig::new(6, 10), 400);
    // Spikes that most rows miss: unseen lights are sampled uniformly, still unbiased.
    check_unbiased(&spiky(24, 60, 7), RowColumnConfig::new(4, 10), 400);
}

#[test]
fn unbiased_on_a_vpl_like_matrix() {
    let oracle = SyntheticVplOracle::new(8, 8, 400, 7);
    check_unbiased(&oracle, RowColumnConfig::new(8, 24), 300);
}

#[test]
fn error_falls_as_rows_and_columns_grow() {
    let oracle = SyntheticVplOracle::new(24, 24, 3000, 8);
    let exact = brute_force(&oracle, &NoProgress).unwrap();
    let rms = |image: &[f32]| {
        let num: f64 = image
            .iter()
            .zip(&exact)
            .map(|(&a, &b)| (a as f64 - b as f64).powi(2))
            .sum();
        let den: f64 = exact.iter().map(|&b| (b as f64).powi(2)).sum();
        (num / den).sqrt()
    };
    let mean_error = |rows: usize, columns: usize| {
        (0..6u64)
            .map(|seed| {
                let config = RowColumnConfig::new(rows, columns).with_seed(seed);
                rms(&row_column_sampling(&oracle, &config, &NoProgress)
                    .unwrap()
                    .image)
            })
            .sum::<f64>()
            / 6.0
    };
    let coarse = mean_error(4, 16);
    let fine = mean_error(32, 300);
    assert!(fine < 0.5 * coarse, "relative RMS error {coarse} -> {fine}");
    assert!(
        fine < 0.1,
        "relative RMS error {fine} at 32 rows / 300 columns"
    );
}

#[test]
fn same_seed_same_image_on_any_thread_count() {
    let oracle = SyntheticVplOracle::new(16, 16, 3000, 9);
    let config = RowColumnConfig::new(20, 60).with_seed(42);
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| row_column_sampling(&oracle, &config, &NoProgress).unwrap())
    };
    let one = run(1);
    let three = run(3);
    assert_eq!(one, three);
    let other = row_column_sampling(&oracle, &config.with_seed(43), &NoProgress).unwrap();
    assert_ne!(one.image, other.image);
}

#[test]
fn elements_are_counted() {
    let oracle = SyntheticVplOracle::new(10, 10, 500, 10);
    let estimate = row_column_sampling(&oracle, &RowColumnConfig::new(7, 30), &NoProgress).unwrap();
    assert_eq!(
        estimate.elements,
        7 * 500 + estimate.representatives.len() as u64 * 100
    );
    assert_eq!(oracle.elements_evaluated(), estimate.elements);
    assert_eq!(estimate.representatives.len(), 30);
    let sizes: usize = estimate
        .representatives
        .iter()
        .map(|r| r.cluster_size)
        .sum();
    assert_eq!(sizes, 500);
}

/// Random reduced matrices from DenseOracles, with zero columns.
fn reduced_strategy() -> impl Strategy<Value = ReducedMatrix> {
    (2usize..12, 2usize..40, 0usize..4, any::<u64>()).prop_map(|(rows, cols, rank, seed)| {
        let oracle = dense(rows, cols, rank, seed);
        let r = (rows / 2).max(1);
        ReducedMatrix::sample(&oracle, (0..r).collect(), &NoProgress).unwrap()
    })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    /// One row per stratum, inside it: sorted, distinct, in range.
    #[test]
    fn stratified_rows_fall_in_their_strata(total in 1usize..5000, frac in 0.0f64..1.0, seed in any::<u64>()) {
        let count = 1 + ((total - 1) as f64 * frac) as usize;
        let rows = stratified_rows(total, count, &mut Pcg64Mcg::seed_from_u64(seed));
        prop_assert_eq!(rows.len(), count);
        for (s, &r) in rows.iter().enumerate() {
            prop_assert!(r >= s * total / count && r < (s + 1) * total / count, "row {r} stratum {s}");
        }
        prop_assert!(stratified_rows(0, 3, &mut Pcg64Mcg::seed_from_u64(seed)).is_empty());
    }

    /// The O(n) cost formula equals the definition over pairs.
    #[test]
    fn cost_matches_pairwise_definition(reduced in reduced_strategy()) {
        let members: Vec<u32> = (0..reduced.cols() as u32).collect();
        let norms = reduced.norms();
        let mut want = 0.0f64;
        for i in 0..members.len() {
            for j in i + 1..members.len() {
                let (a, b) = (norms[i], norms[j]);
                if a == 0.0 || b == 0.0 {
                    continue;
                }
                let d2: f64 = reduced.column(i).iter().zip(reduced.column(j))
                    .map(|(&x, &y)| (x as f64 / a - y as f64 / b).powi(2)).sum();
                want += a * b * d2;
            }
        }
        let got = cluster_cost(&reduced, &members);
        // The formula subtracts two sums of size (Σa)²: f64 cancellation is relative to that.
        let scale = norms.iter().sum::<f64>().powi(2);
        prop_assert!((got - want).abs() <= 1e-9 * (1.0 + want) + 1e-10 * scale,
            "formula {got}, pairs {want}");
    }

    /// A split partitions the members and never increases the cost.
    #[test]
    fn split_never_increases_cost(reduced in reduced_strategy(), seed in any::<u64>(), lines in 1usize..4) {
        let members: Vec<u32> = (0..reduced.cols() as u32).collect();
        let mut rng = Pcg64Mcg::seed_from_u64(seed);
        let (a, b) = split_cluster(&reduced, &members, lines, &mut rng).unwrap();
        prop_assert!(!a.is_empty() && !b.is_empty());
        let mut all: Vec<u32> = a.iter().chain(&b).copied().collect();
        all.sort_unstable();
        prop_assert_eq!(&all, &members);
        let before = cluster_cost(&reduced, &members);
        let after = cluster_cost(&reduced, &a) + cluster_cost(&reduced, &b);
        prop_assert!(after <= before * (1.0 + 1e-9) + 1e-9, "{before} -> {after}");
    }

    /// A clustering covers every light once, has the requested size when possible, and more
    /// clusters never cost more than fewer on the same rows (top-down splits only lower it).
    #[test]
    fn clustering_is_a_partition(reduced in reduced_strategy(), count in 1usize..40, seed in any::<u64>()) {
        let mut rng = Pcg64Mcg::seed_from_u64(seed);
        let clustering = cluster_columns(&reduced, count, 2, &mut rng, &NoProgress).unwrap();
        let mut all: Vec<u32> = clustering.clusters().iter().flatten().copied().collect();
        all.sort_unstable();
        prop_assert_eq!(all, (0..reduced.cols() as u32).collect::<Vec<_>>());
        prop_assert!(clustering.clusters().iter().all(|c| !c.is_empty()));
        let has_zero = reduced.norms().contains(&0.0);
        let has_positive = reduced.norms().iter().any(|&a| a > 0.0);
        let floor = if has_zero && has_positive { 2 } else { 1 };
        prop_assert_eq!(clustering.len(), count.min(reduced.cols()).max(floor));
        // No cluster mixes zero and non-zero reduced columns.
        for c in clustering.clusters() {
            let zeros = c.iter().filter(|&&j| reduced.norms()[j as usize] == 0.0).count();
            prop_assert!(zeros == 0 || zeros == c.len());
        }
    }
}

/// An oracle that returns NaN at one element.
struct Poisoned {
    inner: DenseOracle,
    at: (usize, usize),
    calls: AtomicU64,
}

impl MatrixOracle for Poisoned {
    fn rows(&self) -> usize {
        self.inner.rows()
    }
    fn cols(&self) -> usize {
        self.inner.cols()
    }
    fn channels(&self) -> usize {
        3
    }
    fn eval_row(&self, i: usize, out: &mut [f32]) -> Result<(), CoreError> {
        self.calls.fetch_add(1, Ordering::Relaxed);
        self.inner.eval_row(i, out)?;
        if i == self.at.0 {
            out[self.at.1 * 3 + 1] = f32::NAN;
        }
        Ok(())
    }
    fn eval_col(&self, j: usize, out: &mut [f32]) -> Result<(), CoreError> {
        self.inner.eval_col(j, out)?;
        if j == self.at.1 {
            out[self.at.0 * 3 + 1] = f32::NAN;
        }
        Ok(())
    }
    fn elements_evaluated(&self) -> u64 {
        self.inner.elements_evaluated()
    }
}

#[test]
fn bad_input_is_a_typed_error() {
    let empty_lights = DenseOracle::new(Array2::zeros((4, 0)), 3).unwrap();
    let empty_pixels = DenseOracle::new(Array2::zeros((0, 6)), 3).unwrap();
    let ok = dense(10, 20, 0, 11);
    let run = |o: &dyn MatrixOracle, r, c| {
        row_column_sampling(o, &RowColumnConfig::new(r, c), &NoProgress)
    };
    assert_eq!(
        run(&empty_lights, 1, 1),
        Err(ManyLightError::EmptyMatrix {
            what: "columns (lights)"
        })
    );
    assert_eq!(
        run(&empty_pixels, 1, 1),
        Err(ManyLightError::EmptyMatrix {
            what: "rows (pixels)"
        })
    );
    assert_eq!(
        brute_force(&empty_lights, &NoProgress),
        Err(ManyLightError::EmptyMatrix {
            what: "columns (lights)"
        })
    );
    assert_eq!(
        run(&ok, 0, 5),
        Err(ManyLightError::ZeroSamples { what: "row" })
    );
    assert_eq!(
        run(&ok, 5, 0),
        Err(ManyLightError::ZeroSamples { what: "column" })
    );
    let grouped = |k| {
        let config = RowColumnConfig::new(5, 8).with_unseen(UnseenLights::Groups(k));
        row_column_sampling(&ok, &config, &NoProgress)
    };
    assert_eq!(
        grouped(0),
        Err(ManyLightError::ZeroSamples {
            what: "unseen light groups"
        })
    );
    assert_eq!(
        grouped(9),
        Err(ManyLightError::TooMany {
            what: "unseen light groups",
            requested: 9,
            available: 8
        })
    );
    assert!(grouped(8).is_ok());
    assert_eq!(
        run(&ok, 11, 5),
        Err(ManyLightError::TooMany {
            what: "rows",
            requested: 11,
            available: 10
        })
    );
    assert_eq!(
        run(&ok, 5, 21),
        Err(ManyLightError::TooMany {
            what: "columns",
            requested: 21,
            available: 20
        })
    );
    assert_eq!(
        ReducedMatrix::sample(&ok, vec![3, 10], &NoProgress),
        Err(ManyLightError::TooMany {
            what: "rows",
            requested: 11,
            available: 10
        })
    );
    // A NaN element met in a sampled row, in a representative column, and by brute force.
    let poisoned = Poisoned {
        inner: dense(10, 20, 0, 12),
        at: (4, 6),
        calls: AtomicU64::new(0),
    };
    let nan = ManyLightError::NonFinite {
        row: 4,
        col: 6,
        channel: 1,
    };
    assert_eq!(run(&poisoned, 10, 5), Err(nan.clone()));
    assert_eq!(brute_force(&poisoned, &NoProgress), Err(nan.clone()));
    // With clusters = lights every column is evaluated: whether the NaN is met in the sampled
    // row or in its column, the error names the element.
    let by_column = row_column_sampling(
        &poisoned,
        &RowColumnConfig::new(1, 20).with_seed(1),
        &NoProgress,
    );
    assert!(matches!(
        by_column,
        Err(ManyLightError::NonFinite {
            row: 4,
            col: 6,
            channel: 1
        })
    ));
    assert!(poisoned.calls.load(Ordering::Relaxed) > 0);
}

#[test]
fn cancellation_stops_the_work() {
    let oracle = SyntheticVplOracle::new(16, 16, 1000, 13);
    let progress = AtomicProgress::new();
    progress.cancel();
    assert_eq!(
        row_column_sampling(&oracle, &RowColumnConfig::new(64, 100), &progress),
        Err(ManyLightError::Cancelled)
    );
    assert_eq!(
        brute_force(&oracle, &progress),
        Err(ManyLightError::Cancelled)
    );
    // Cancelled once the reduced matrix is done (8 rows = one batch): stops in the clustering.
    let progress = AtomicProgress::cancel_after(1);
    assert_eq!(
        row_column_sampling(&oracle, &RowColumnConfig::new(8, 100), &progress),
        Err(ManyLightError::Cancelled)
    );
    assert_eq!(progress.last_message(), "row-column sampling: clustering");
    // Cancelled after the first batch of 16 rows out of 64: stops in the reduced matrix.
    let progress = AtomicProgress::cancel_after(1);
    assert_eq!(
        row_column_sampling(&oracle, &RowColumnConfig::new(64, 100), &progress),
        Err(ManyLightError::Cancelled)
    );
    assert_eq!(
        progress.last_message(),
        "row-column sampling: reduced matrix"
    );
    assert_eq!(progress.position(), 16);
}

/// Relative RMS error of an image against the exact one (prt-core's metric).
fn relative_error(a: &[f32], b: &[f32]) -> f64 {
    prt_core::metrics::relative_frobenius_error(a, b).unwrap()
}

#[test]
fn identical_lights_are_one_exact_cluster() {
    // Every column the same: any representative times the cluster size is the exact sum.
    let column: Vec<f32> = (0..20 * 3).map(|k| 0.1 + (k % 7) as f32).collect();
    let data = Array2::from_shape_fn((20, 50 * 3), |(i, jc)| column[i * 3 + jc % 3]);
    let oracle = DenseOracle::new(data, 3).unwrap();
    let exact = brute_force(&oracle, &NoProgress).unwrap();
    let estimate = row_column_sampling(&oracle, &RowColumnConfig::new(3, 10), &NoProgress).unwrap();
    assert!(estimate.clustering_cost < 1e-6 * total(&exact).powi(2));
    assert!(relative_error(&estimate.image, &exact) < 1e-6);
}

#[test]
fn a_single_bright_light_among_dark_ones_is_exact() {
    let mut data = Array2::<f32>::zeros((30, 40 * 3));
    for i in 0..30 {
        for c in 0..3 {
            data[[i, 17 * 3 + c]] = 1.0 + i as f32;
        }
    }
    let oracle = DenseOracle::new(data, 3).unwrap();
    let exact = brute_force(&oracle, &NoProgress).unwrap();
    for (rows, columns) in [(1, 1), (5, 2), (30, 40)] {
        let config = RowColumnConfig::new(rows, columns).with_seed(3);
        let estimate = row_column_sampling(&oracle, &config, &NoProgress).unwrap();
        assert_eq!(
            relative_error(&estimate.image, &exact),
            0.0,
            "{rows} / {columns}"
        );
        // The dark lights are never mixed with the bright one.
        assert!(
            estimate
                .clustering
                .clusters()
                .iter()
                .any(|c| c == &vec![17])
        );
    }
}

#[test]
fn huge_dynamic_range_stays_finite_and_exact_at_full_clustering() {
    // Columns scaled from 1e-6 to 1e6.
    let mut rng = Pcg64Mcg::seed_from_u64(14);
    let data = Array2::from_shape_fn((12, 25 * 3), |(_, jc)| {
        rng.random::<f32>() * 10f32.powi((jc / 3) as i32 % 13 - 6)
    });
    let oracle = DenseOracle::new(data, 3).unwrap();
    let exact = brute_force(&oracle, &NoProgress).unwrap();
    let full = row_column_sampling(&oracle, &RowColumnConfig::new(4, 25), &NoProgress).unwrap();
    assert!(relative_error(&full.image, &exact) < 1e-6);
    let coarse = row_column_sampling(&oracle, &RowColumnConfig::new(4, 5), &NoProgress).unwrap();
    assert!(coarse.image.iter().all(|v| v.is_finite()));
    assert!(
        coarse
            .representatives
            .iter()
            .all(|r| r.weight.is_finite() && r.weight >= 1.0)
    );
}

#[test]
fn grouped_unseen_lights_stay_unbiased() {
    let config = RowColumnConfig::new(4, 10).with_unseen(UnseenLights::Groups(4));
    check_unbiased(&spiky(24, 60, 7), config, 400);
}

#[test]
fn grouped_unseen_lights_are_consecutive_groups_within_the_budget() {
    let oracle = spiky(40, 61, 13);
    // (requested groups, seed, groups): 20 of a 20-cluster budget leaves the seen lights one.
    for (k, seed, groups) in [(1, 0, 1), (3, 1, 3), (7, 2, 7), (20, 3, 19)] {
        let config = RowColumnConfig::new(5, 20)
            .with_seed(seed)
            .with_unseen(UnseenLights::Groups(k));
        let estimate = row_column_sampling(&oracle, &config, &NoProgress).unwrap();
        let reduced = ReducedMatrix::sample(&oracle, estimate.rows.clone(), &NoProgress).unwrap();
        let unseen: Vec<&Vec<u32>> = estimate
            .clustering
            .clusters()
            .iter()
            .filter(|c| c.iter().all(|&j| reduced.norms()[j as usize] == 0.0))
            .collect();
        assert!(
            estimate.unseen_lights > 20,
            "most spikes fall between 5 rows"
        );
        assert_eq!(unseen.len(), groups, "groups of unseen lights");
        let (small, large) = unseen.iter().fold((usize::MAX, 0), |(s, l), c| {
            (s.min(c.len()), l.max(c.len()))
        });
        assert!(large - small <= 1, "group sizes {small}..{large}");
        for c in &unseen {
            assert!(c.windows(2).all(|w| w[0] < w[1]));
        }
        let mut all: Vec<u32> = unseen.iter().flat_map(|c| c.iter().copied()).collect();
        all.sort_unstable();
        assert!(all.windows(2).all(|w| w[0] < w[1]) && all.len() == estimate.unseen_lights);
        // A partition of all lights, one representative per cluster, within the budget.
        let members: usize = estimate.clustering.clusters().iter().map(Vec::len).sum();
        assert_eq!(members, 61);
        assert!(estimate.representatives.len() <= 20);
        assert_eq!(estimate.representatives.len(), estimate.clustering.len());
        assert_eq!(
            estimate.elements,
            (5 * 61 + estimate.representatives.len() * 40) as u64
        );
    }
}

/// Mean squared error over `runs` seeds, and its standard error.
fn mean_squared_error(oracle: &dyn MatrixOracle, config: RowColumnConfig, runs: u64) -> (f64, f64) {
    let exact = brute_force(oracle, &NoProgress).unwrap();
    let errors: Vec<f64> = (0..runs)
        .map(|seed| {
            let estimate =
                row_column_sampling(oracle, &config.with_seed(seed), &NoProgress).unwrap();
            estimate
                .image
                .iter()
                .zip(&exact)
                .map(|(&a, &b)| (a as f64 - b as f64).powi(2))
                .sum()
        })
        .collect();
    let n = runs as f64;
    let mean = errors.iter().sum::<f64>() / n;
    let var = errors.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / (n - 1.0);
    (mean, (var / n).sqrt())
}

#[test]
fn grouped_unseen_lights_lower_the_error_when_unseen_lights_dominate_it() {
    // 100 spikes, 4 rows of 48: about 92 spikes unseen, each lighting one pixel. One uniform
    // draw scales one spike by ~92; eight groups scale eight spikes by ~12 each.
    let oracle = spiky(48, 200, 21);
    let sample = mean_squared_error(&oracle, RowColumnConfig::new(4, 20), 300);
    let grouped = mean_squared_error(
        &oracle,
        RowColumnConfig::new(4, 20).with_unseen(UnseenLights::Groups(8)),
        300,
    );
    // Both within 4 standard errors of their means; the grouped error at most half.
    assert!(
        grouped.0 + 4.0 * grouped.1 < 0.5 * (sample.0 - 4.0 * sample.1),
        "sample {sample:?}, grouped {grouped:?}"
    );
}
