//! Tensor clustering (MRCS 2008): exactness, unbiasedness, error against budget, the advantage
//! over per-frame row-column sampling on an animation, determinism and bad input.

use ndarray::Array2;
use prt_core::metrics::relative_frobenius_error;
use prt_core::{CoreError, DenseOracle, MatrixOracle, NoProgress};
use prt_manylight::{
    ManyLightError, RowColumnConfig, SyntheticVplOracle, TensorConfig, brute_force,
    row_column_sampling, tensor_clustering,
};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

/// `frames` frames of a non-negative `rows × cols` RGB matrix whose columns drift slowly over
/// time (frame `t` = base + t · drift), with every 5th column zero in every frame.
fn dense_frames(rows: usize, cols: usize, frames: usize, seed: u64) -> Vec<DenseOracle> {
    let mut rng = Pcg64Mcg::seed_from_u64(seed);
    let base = Array2::from_shape_fn((rows, cols * 3), |_| rng.random::<f32>());
    let drift = Array2::from_shape_fn((rows, cols * 3), |_| 0.2 * rng.random::<f32>());
    (0..frames)
        .map(|t| {
            let mut data = &base + &(&drift * t as f32);
            for j in (0..cols).step_by(5) {
                for c in 0..3 {
                    data.column_mut(j * 3 + c).fill(0.0);
                }
            }
            DenseOracle::new(data, 3).unwrap()
        })
        .collect()
}

/// An animation of the synthetic VPL matrix: the occluding sphere moves across the floor.
fn animation(size: usize, lights: usize, frames: usize) -> Vec<SyntheticVplOracle> {
    (0..frames)
        .map(|t| {
            let x = 0.3 + 0.4 * t as f32 / (frames.max(2) - 1) as f32;
            SyntheticVplOracle::new(size, size, lights, 3).with_occluder([x, 0.3, 0.5])
        })
        .collect()
}

fn refs<T: MatrixOracle>(frames: &[T]) -> Vec<&dyn MatrixOracle> {
    frames.iter().map(|f| f as &dyn MatrixOracle).collect()
}

fn exact(frames: &[&dyn MatrixOracle]) -> Vec<Vec<f32>> {
    frames
        .iter()
        .map(|f| brute_force(*f, &NoProgress).unwrap())
        .collect()
}

fn sequence_error(estimate: &[Vec<f32>], exact: &[Vec<f32>]) -> f64 {
    relative_frobenius_error(&estimate.concat(), &exact.concat()).unwrap()
}

#[test]
fn exact_when_every_light_is_its_own_cluster() {
    let frames = dense_frames(20, 12, 4, 1);
    let frames = refs(&frames);
    let want = exact(&frames);
    for seed in 0..3 {
        let config = TensorConfig::new(3, 12).with_seed(seed);
        let estimate = tensor_clustering(&frames, &config, &NoProgress).unwrap();
        assert_eq!(estimate.clusters.len(), 12);
        assert!(estimate.clusters.iter().all(|c| c.weight == 1.0));
        for (image, reference) in estimate.images.iter().zip(&want) {
            for (a, b) in image.iter().zip(reference) {
                assert!((a - b).abs() <= 1e-5 * (1.0 + b.abs()), "{a} vs {b}");
            }
        }
    }
}

/// The mean over seeds converges to the exact frames: tolerance 5 standard errors of the mean
/// per pixel (estimated from the samples), plus f32 rounding.
#[test]
fn unbiased_over_seeds() {
    let dense = dense_frames(24, 40, 3, 2);
    let vpl = animation(6, 300, 3);
    for (frames, config, runs) in [
        (refs(&dense), TensorConfig::new(4, 6), 600u64),
        (refs(&vpl), TensorConfig::new(6, 20), 400),
    ] {
        let want = exact(&frames).concat();
        let mut sum = vec![0.0f64; want.len()];
        let mut sum_sq = vec![0.0f64; want.len()];
        for seed in 0..runs {
            let estimate =
                tensor_clustering(&frames, &config.with_seed(seed), &NoProgress).unwrap();
            for ((s, q), &v) in sum
                .iter_mut()
                .zip(&mut sum_sq)
                .zip(&estimate.images.concat())
            {
                *s += v as f64;
                *q += v as f64 * v as f64;
            }
        }
        let n = runs as f64;
        let mut checked = 0;
        for ((s, q), &w) in sum.iter().zip(&sum_sq).zip(&want) {
            let mean = s / n;
            let var = (q / n - mean * mean).max(0.0);
            let tolerance = 5.0 * (var / n).sqrt() + 1e-4 * (1.0 + w.abs() as f64);
            assert!(
                (mean - w as f64).abs() <= tolerance,
                "mean {mean} vs exact {w} (tolerance {tolerance})"
            );
            checked += (var > 0.0) as usize;
        }
        assert!(
            checked > 0,
            "the estimator never varied: the test cannot fail"
        );
    }
}

#[test]
fn error_falls_with_the_budget() {
    let frames = animation(16, 2000, 6);
    let frames = refs(&frames);
    let want = exact(&frames);
    let mean_error = |rows, columns| {
        (0..4)
            .map(|seed| {
                let config = TensorConfig::new(rows, columns).with_seed(seed);
                let estimate = tensor_clustering(&frames, &config, &NoProgress).unwrap();
                sequence_error(&estimate.images, &want)
            })
            .sum::<f64>()
            / 4.0
    };
    let (small, large) = (mean_error(8, 20), mean_error(32, 200));
    assert!(large < 0.7 * small, "error {small} → {large}");
}

/// On a moving-occluder animation, tensor clustering with the same rows per frame and a
/// budget of the same columns per frame is more accurate than per-frame row-column sampling
/// (its clusters see the rows of every frame they span).
#[test]
fn beats_per_frame_row_column_sampling_at_equal_cost() {
    let frames = animation(16, 3000, 8);
    let frames = refs(&frames);
    let want = exact(&frames);
    let (rows, columns) = (12, 40);
    let (mut tensor_error, mut per_frame_error) = (0.0, 0.0);
    let (mut tensor_elements, mut per_frame_elements) = (0, 0);
    for seed in 0..4 {
        let config = TensorConfig::new(rows, columns).with_seed(seed);
        let estimate = tensor_clustering(&frames, &config, &NoProgress).unwrap();
        tensor_error += sequence_error(&estimate.images, &want);
        tensor_elements += estimate.elements;
        let mut images = Vec::new();
        for (t, frame) in frames.iter().enumerate() {
            let config = RowColumnConfig::new(rows, columns).with_seed(seed * 100 + t as u64);
            let e = row_column_sampling(*frame, &config, &NoProgress).unwrap();
            per_frame_elements += e.elements;
            images.push(e.image);
        }
        per_frame_error += sequence_error(&images, &want);
    }
    assert!(
        tensor_elements <= per_frame_elements,
        "{tensor_elements} > {per_frame_elements}"
    );
    assert!(
        tensor_error < per_frame_error,
        "tensor {tensor_error} vs per-frame {per_frame_error}"
    );
}

#[test]
fn clusters_partition_every_frame_and_respect_the_budget() {
    let frames = animation(12, 800, 5);
    let frames = refs(&frames);
    let config = TensorConfig::new(10, 30).with_seed(4);
    let estimate = tensor_clustering(&frames, &config, &NoProgress).unwrap();
    for t in 0..5 {
        let mut seen = vec![0u32; 800];
        for c in estimate.clusters.iter().filter(|c| c.frames.contains(&t)) {
            for &j in &c.lights {
                seen[j as usize] += 1;
            }
            assert!(c.lights.contains(&(c.representative as u32)));
        }
        assert!(seen.iter().all(|&s| s == 1), "frame {t} is not a partition");
    }
    let renders: usize = estimate.clusters.iter().map(|c| c.frames.len()).sum();
    assert!(renders <= 30 * 5, "{renders} column evaluations");
    assert_eq!(
        estimate.elements,
        (5 * 10 * 800 + renders * 144) as u64,
        "elements"
    );
    assert!(estimate.light_splits > 0);
}

#[test]
fn same_seed_same_images_on_any_thread_count() {
    let frames = animation(10, 500, 4);
    let frames = refs(&frames);
    let config = TensorConfig::new(8, 25).with_seed(9);
    let run = |threads| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| tensor_clustering(&frames, &config, &NoProgress).unwrap())
    };
    assert_eq!(run(1), run(3));
}

/// A dense oracle that returns NaN at element (3, 1), channel 1.
struct Poisoned(DenseOracle);

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
        self.0.eval_row(i, out)?;
        if i == 3 {
            out[4] = f32::NAN;
        }
        Ok(())
    }
    fn eval_col(&self, j: usize, out: &mut [f32]) -> Result<(), CoreError> {
        self.0.eval_col(j, out)?;
        if j == 1 {
            out[10] = f32::NAN;
        }
        Ok(())
    }
    fn elements_evaluated(&self) -> u64 {
        self.0.elements_evaluated()
    }
}

#[test]
fn bad_input_is_a_typed_error() {
    let frames = dense_frames(10, 8, 2, 5);
    let good = refs(&frames);
    let run = |frames: &[&dyn MatrixOracle], config: TensorConfig| {
        tensor_clustering(frames, &config, &NoProgress).unwrap_err()
    };
    assert_eq!(
        run(&[], TensorConfig::new(2, 2)),
        ManyLightError::EmptyMatrix { what: "frames" }
    );
    assert!(matches!(
        run(&good, TensorConfig::new(0, 2)),
        ManyLightError::ZeroSamples { .. }
    ));
    assert!(matches!(
        run(&good, TensorConfig::new(2, 0)),
        ManyLightError::ZeroSamples { .. }
    ));
    assert!(matches!(
        run(&good, TensorConfig::new(11, 2)),
        ManyLightError::TooMany {
            requested: 11,
            available: 10,
            ..
        }
    ));
    assert!(matches!(
        run(&good, TensorConfig::new(2, 9)),
        ManyLightError::TooMany {
            requested: 9,
            available: 8,
            ..
        }
    ));
    let other = dense_frames(10, 7, 1, 6);
    let mixed: Vec<&dyn MatrixOracle> = vec![good[0], &other[0]];
    assert!(matches!(
        run(&mixed, TensorConfig::new(2, 2)),
        ManyLightError::ShapeMismatch {
            frame: 1,
            cols: 7,
            expected_cols: 8,
            ..
        }
    ));
    let nan = Poisoned(dense_frames(10, 8, 1, 7).remove(0));
    let with_nan: Vec<&dyn MatrixOracle> = vec![good[0], &nan];
    assert!(matches!(
        run(&with_nan, TensorConfig::new(10, 2)),
        ManyLightError::NonFinite {
            row: 3,
            col: 1,
            channel: 1
        }
    ));
}
