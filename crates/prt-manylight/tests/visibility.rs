//! Visibility clustering: exactness (clusters = lights, unoccluded scenes), error against
//! budget, the k-means variant, determinism and bad input.

use prt_core::metrics::relative_frobenius_error;
use prt_core::{CoreError, MatrixOracle, NoProgress};
use prt_manylight::{
    ManyLightError, SyntheticVplOracle, VisibilityClusterMethod, VisibilityConfig,
    VisibilityOracle, brute_force, visibility_clustering,
};

const KMEANS: VisibilityClusterMethod = VisibilityClusterMethod::KMeans { iterations: 5 };

fn error(oracle: &SyntheticVplOracle, config: VisibilityConfig) -> f64 {
    let exact = brute_force(oracle, &NoProgress).unwrap();
    let estimate = visibility_clustering(oracle, &config, &NoProgress).unwrap();
    relative_frobenius_error(&estimate.image, &exact).unwrap()
}

#[test]
fn exact_when_every_light_is_its_own_cluster() {
    let oracle = SyntheticVplOracle::new(8, 8, 300, 1);
    for method in [VisibilityClusterMethod::Split, KMEANS] {
        let config = VisibilityConfig::new(5, 300).with_method(method);
        let estimate = visibility_clustering(&oracle, &config, &NoProgress).unwrap();
        assert_eq!(estimate.clusters.len(), 300);
        assert_eq!(estimate.visibility_error, 0.0);
        let exact = brute_force(&oracle, &NoProgress).unwrap();
        for (a, b) in estimate.image.iter().zip(&exact) {
            assert!((a - b).abs() <= 1e-5 * (1.0 + b.abs()), "{a} vs {b}");
        }
    }
}

/// Without occlusion the visibility of every light is 1, so any clustering is exact: only the
/// visibility is approximated, shading is summed exactly.
#[test]
fn exact_without_occlusion_at_any_cluster_count() {
    let oracle = SyntheticVplOracle::new(12, 12, 2000, 2).with_occluder([10.0, 10.0, 10.0]);
    for (rows, columns) in [(1, 1), (4, 10), (20, 100)] {
        for method in [VisibilityClusterMethod::Split, KMEANS] {
            let config = VisibilityConfig::new(rows, columns).with_method(method);
            assert!(error(&oracle, config) < 1e-6, "{rows} / {columns}");
        }
    }
}

#[test]
fn error_falls_with_the_budget_for_both_methods() {
    let oracle = SyntheticVplOracle::new(24, 24, 3000, 3);
    for method in [VisibilityClusterMethod::Split, KMEANS] {
        let mean = |rows, columns| {
            (0..3)
                .map(|seed| {
                    let config = VisibilityConfig::new(rows, columns)
                        .with_method(method)
                        .with_seed(seed);
                    error(&oracle, config)
                })
                .sum::<f64>()
                / 3.0
        };
        let (small, large) = (mean(8, 8), mean(48, 200));
        assert!(small > 0.0, "the occluder must matter for this test");
        assert!(large < 0.5 * small, "{method:?}: {small} → {large}");
    }
}

/// k-means refines the divisive clustering: on the sampled rows its visibility error is no
/// larger on average.
#[test]
fn kmeans_lowers_the_sampled_visibility_error() {
    let oracle = SyntheticVplOracle::new(20, 20, 2000, 4);
    let (mut split, mut kmeans) = (0.0, 0.0);
    for seed in 0..3 {
        let config = VisibilityConfig::new(30, 40).with_seed(seed);
        split += visibility_clustering(&oracle, &config, &NoProgress)
            .unwrap()
            .visibility_error;
        kmeans += visibility_clustering(&oracle, &config.with_method(KMEANS), &NoProgress)
            .unwrap()
            .visibility_error;
    }
    assert!(kmeans <= split, "k-means {kmeans} vs split {split}");
}

#[test]
fn clusters_partition_the_lights_and_costs_are_counted() {
    let oracle = SyntheticVplOracle::new(10, 10, 500, 5);
    let config = VisibilityConfig::new(7, 30).with_seed(1);
    let estimate = visibility_clustering(&oracle, &config, &NoProgress).unwrap();
    let mut seen = vec![0; 500];
    for (c, &rep) in estimate.clusters.iter().zip(&estimate.representatives) {
        assert!(c.contains(&(rep as u32)));
        for &j in c {
            seen[j as usize] += 1;
        }
    }
    assert!(seen.iter().all(|&s| s == 1));
    assert_eq!(estimate.clusters.len(), 30);
    assert_eq!(estimate.elements, 7 * 500 + 30 * 100);
    assert_eq!(estimate.shading_evaluations, 7 * 500 + 100 * 500);
}

#[test]
fn same_seed_same_image_on_any_thread_count() {
    let oracle = SyntheticVplOracle::new(16, 16, 1000, 6);
    let config = VisibilityConfig::new(12, 40)
        .with_method(KMEANS)
        .with_seed(3);
    let run = |threads| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| visibility_clustering(&oracle, &config, &NoProgress).unwrap())
    };
    assert_eq!(run(1), run(3));
}

/// The synthetic oracle with NaN visibility for light 2 at pixel 5.
struct Poisoned(SyntheticVplOracle);

impl MatrixOracle for Poisoned {
    fn rows(&self) -> usize {
        self.0.rows()
    }
    fn cols(&self) -> usize {
        self.0.cols()
    }
    fn channels(&self) -> usize {
        3
    }
    fn eval_row(&self, i: usize, out: &mut [f32]) -> Result<(), CoreError> {
        self.0.eval_row(i, out)
    }
    fn eval_col(&self, j: usize, out: &mut [f32]) -> Result<(), CoreError> {
        self.0.eval_col(j, out)
    }
    fn elements_evaluated(&self) -> u64 {
        self.0.elements_evaluated()
    }
}

impl VisibilityOracle for Poisoned {
    fn shading(&self, i: usize, j: usize, out: &mut [f32]) -> Result<(), CoreError> {
        self.0.shading(i, j, out)?;
        if (i, j) == (5, 2) {
            out.fill(1.0);
        }
        Ok(())
    }
    fn visibility(&self, i: usize, j: usize) -> Result<f32, CoreError> {
        if (i, j) == (5, 2) {
            return Ok(f32::NAN);
        }
        self.0.visibility(i, j)
    }
}

#[test]
fn bad_input_is_a_typed_error() {
    let oracle = SyntheticVplOracle::new(4, 4, 10, 7);
    let run = |config| visibility_clustering(&oracle, &config, &NoProgress).unwrap_err();
    assert!(matches!(
        run(VisibilityConfig::new(0, 2)),
        ManyLightError::ZeroSamples { .. }
    ));
    assert!(matches!(
        run(VisibilityConfig::new(2, 0)),
        ManyLightError::ZeroSamples { .. }
    ));
    assert!(matches!(
        run(VisibilityConfig::new(17, 2)),
        ManyLightError::TooMany {
            requested: 17,
            available: 16,
            ..
        }
    ));
    assert!(matches!(
        run(VisibilityConfig::new(2, 11)),
        ManyLightError::TooMany {
            requested: 11,
            available: 10,
            ..
        }
    ));
    let empty = SyntheticVplOracle::new(4, 4, 0, 7);
    assert!(matches!(
        visibility_clustering(&empty, &VisibilityConfig::new(1, 1), &NoProgress),
        Err(ManyLightError::EmptyMatrix { .. })
    ));
    let poisoned = Poisoned(SyntheticVplOracle::new(4, 4, 10, 7));
    assert_eq!(
        visibility_clustering(&poisoned, &VisibilityConfig::new(16, 3), &NoProgress),
        Err(ManyLightError::NonFinite {
            row: 5,
            col: 2,
            channel: 0
        })
    );
}
