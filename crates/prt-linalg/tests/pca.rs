//! Laws of the PCA: equality with the thin-SVD optimum, orthonormality, determinism, extremes.

use ndarray::{Array2, Axis, ShapeBuilder, s};
use proptest::prelude::*;
use prt_core::{AtomicProgress, NoProgress};
use prt_linalg::synthetic::low_rank_matrix;
use prt_linalg::{LinalgError, Pca, PcaMethod, PcaOptions, thin_svd};

const COV: PcaOptions = PcaOptions {
    method: PcaMethod::Covariance,
};
const COV_F64: PcaOptions = PcaOptions {
    method: PcaMethod::CovarianceF64,
};
const RANDOMIZED: PcaOptions = PcaOptions {
    method: PcaMethod::Randomized {
        oversample: 10,
        power_iters: 2,
        seed: 7,
    },
};

/// Optimal rank-`k` residual of the mean-centred data: the sum of its squared singular values
/// beyond the `k`-th (Eckart-Young), computed in f64.
fn optimal_residual(data: &Array2<f32>, k: usize) -> f64 {
    let x = data.mapv(f64::from);
    let centred = &x - &x.mean_axis(Axis(0)).unwrap().insert_axis(Axis(0));
    thin_svd(centred.view())
        .unwrap()
        .s
        .iter()
        .skip(k)
        .map(|s| s * s)
        .sum()
}

fn orthonormality_error(c: &Array2<f32>) -> f64 {
    let c = c.mapv(f64::from);
    (c.dot(&c.t()) - Array2::<f64>::eye(c.nrows()))
        .iter()
        .fold(0.0, |m, v| m.max(v.abs()))
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(24))]

    #[test]
    fn residual_equals_the_thin_svd_optimum(
        n in 2usize..60, d in 1usize..10, k_frac in 0.0f64..1.0, true_rank_frac in 0.0f64..1.0,
        offset in -100.0f64..100.0, seed in 0u64..1000,
    ) {
        let k = 1 + ((d - 1) as f64 * k_frac) as usize;
        let true_rank = 1 + ((d - 1) as f64 * true_rank_frac) as usize;
        let data = low_rank_matrix(n, d, true_rank, 0.7, 0.05, offset, seed).unwrap();
        let pca = Pca::fit(data.view(), k, &COV, &NoProgress).unwrap();
        prop_assert!(orthonormality_error(&pca.components) < 1e-5);
        let ours = pca.residual_energy(data.view()).unwrap();
        let best = optimal_residual(&data, k);
        let total = pca.total_variance * (n - 1) as f64;
        // f32 storage of the data round trip limits agreement to ~1e-6 of the total energy.
        prop_assert!((ours - best).abs() <= 1e-4 * best + 1e-5 * total, "ours {ours} best {best} total {total}");
        // The in-sample residual is also what the spectrum says.
        prop_assert!((pca.residual_variance() * (n - 1) as f64 - best).abs() <= 1e-4 * best + 1e-6 * total);
        prop_assert!(pca.explained_variance.windows(2).into_iter().all(|w| w[0] >= w[1]));
    }
}

#[test]
fn explained_variance_is_the_squared_singular_values() {
    let data = low_rank_matrix(200, 12, 6, 0.8, 0.01, 3.0, 1).unwrap();
    let x = data.mapv(f64::from);
    let centred = &x - &x.mean_axis(Axis(0)).unwrap().insert_axis(Axis(0));
    let svd = thin_svd(centred.view()).unwrap();
    let total: f64 = svd.s.iter().map(|s| s * s).sum::<f64>() / 199.0;
    // f32 block products agree to f32 rounding, f64 ones to f64 rounding.
    for (opts, tol) in [(COV, 1e-5), (COV_F64, 1e-9)] {
        let pca = Pca::fit(data.view(), 4, &opts, &NoProgress).unwrap();
        for i in 0..4 {
            let expected = svd.s[i] * svd.s[i] / 199.0;
            let err = (pca.explained_variance[i] - expected).abs() / expected;
            assert!(err < tol, "{opts:?} {i}: {err}");
            // Same direction as the SVD's (both use the positive-largest-entry sign convention).
            let dot: f64 = (0..12)
                .map(|j| f64::from(pca.components[[i, j]]) * svd.vt[[i, j]])
                .sum();
            assert!(dot > 1.0 - 1e-5, "component {i}: dot {dot}");
        }
        assert!((pca.total_variance - total).abs() < tol * total, "{opts:?}");
    }
}

#[test]
fn rank_16_of_the_spectrum_target_is_within_0_1_percent_of_optimal() {
    // The accuracy target, scaled down (the full 262144-row run is in the bench sweep).
    let data = low_rank_matrix(4096, 324, 40, 0.8, 1e-3, 0.5, 3).unwrap();
    let best = optimal_residual(&data, 16);
    for opts in [COV, COV_F64, RANDOMIZED] {
        let pca = Pca::fit(data.view(), 16, &opts, &NoProgress).unwrap();
        let ours = pca.residual_energy(data.view()).unwrap();
        assert!(ours >= best * (1.0 - 1e-6), "{opts:?}: below the optimum?");
        assert!(
            ours <= best * 1.001,
            "{opts:?}: residual {ours} vs optimal {best}"
        );
        assert!(orthonormality_error(&pca.components) < 1e-5);
    }
}

#[test]
fn projection_and_reconstruction_round_trip_at_full_rank() {
    let data = low_rank_matrix(50, 6, 6, 0.9, 0.1, -2.0, 5).unwrap();
    let pca = Pca::fit(data.view(), 6, &COV, &NoProgress).unwrap();
    let back = pca
        .reconstruct(pca.project(data.view()).unwrap().view())
        .unwrap();
    let err = (&back - &data).iter().fold(0.0f32, |m, v| m.max(v.abs()));
    assert!(err < 1e-5, "{err}");
    assert!(pca.residual_variance() < 1e-9 * pca.total_variance);
}

#[test]
fn constant_data_gives_zero_variance_without_nan() {
    let data = Array2::from_elem((30, 5), 4.25f32);
    for opts in [COV, RANDOMIZED] {
        let pca = Pca::fit(data.view(), 3, &opts, &NoProgress).unwrap();
        assert_eq!(pca.total_variance, 0.0);
        assert!(pca.explained_variance.iter().all(|&v| v == 0.0));
        assert!(pca.mean.iter().all(|&m| m == 4.25));
        assert!(orthonormality_error(&pca.components) < 1e-6, "{opts:?}");
        assert_eq!(pca.residual_energy(data.view()).unwrap(), 0.0);
    }
    // A single row is constant data too.
    let one = Array2::from_shape_vec((1, 3), vec![1.0f32, -2.0, 3.0]).unwrap();
    let pca = Pca::fit(one.view(), 2, &COV, &NoProgress).unwrap();
    assert_eq!(pca.total_variance, 0.0);
}

#[test]
fn randomized_with_rank_above_the_row_count_completes_the_basis() {
    let data = low_rank_matrix(3, 8, 2, 0.5, 0.1, 0.0, 2).unwrap();
    let pca = Pca::fit(data.view(), 6, &RANDOMIZED, &NoProgress).unwrap();
    assert_eq!(pca.components.dim(), (6, 8));
    assert!(orthonormality_error(&pca.components) < 1e-5);
    assert!(pca.residual_energy(data.view()).unwrap() < 1e-8);
}

#[test]
fn results_do_not_depend_on_the_thread_count() {
    // More rows than one chunk, so the reduction really is split.
    let data = low_rank_matrix(20_000, 10, 5, 0.8, 0.01, 1.0, 9).unwrap();
    let fit = |threads: usize, opts: PcaOptions| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| Pca::fit(data.view(), 3, &opts, &NoProgress).unwrap())
    };
    for opts in [COV, RANDOMIZED] {
        assert_eq!(fit(1, opts), fit(3, opts), "{opts:?}");
    }
}

#[test]
fn results_do_not_depend_on_the_memory_layout() {
    // Rows are read as slices when contiguous and copied otherwise: same numbers either way.
    let data = low_rank_matrix(3000, 9, 4, 0.8, 0.01, 2.0, 4).unwrap();
    let mut column_major = Array2::<f32>::zeros(data.raw_dim().f());
    column_major.assign(&data);
    assert!(column_major.row(0).as_slice().is_none());
    for opts in [COV, COV_F64, RANDOMIZED] {
        let a = Pca::fit(data.view(), 3, &opts, &NoProgress).unwrap();
        let b = Pca::fit(column_major.view(), 3, &opts, &NoProgress).unwrap();
        assert_eq!(a, b, "{opts:?}");
    }
}

#[test]
fn bad_input_gives_typed_errors() {
    let mut data = low_rank_matrix(10, 4, 2, 0.5, 0.1, 0.0, 1).unwrap();
    assert_eq!(
        Pca::fit(data.view(), 0, &COV, &NoProgress),
        Err(LinalgError::InvalidRank { rank: 0, max: 4 })
    );
    assert_eq!(
        Pca::fit(data.view(), 5, &COV, &NoProgress),
        Err(LinalgError::InvalidRank { rank: 5, max: 4 })
    );
    let empty = Array2::<f32>::zeros((0, 4));
    assert!(matches!(
        Pca::fit(empty.view(), 1, &COV, &NoProgress),
        Err(LinalgError::Empty { .. })
    ));
    let pca = Pca::fit(data.view(), 2, &COV, &NoProgress).unwrap();
    assert!(matches!(
        pca.project(data.slice(s![.., ..3])),
        Err(LinalgError::ShapeMismatch { .. })
    ));
    assert!(matches!(
        pca.reconstruct(data.view()),
        Err(LinalgError::ShapeMismatch { .. })
    ));
    data[[7, 2]] = f32::NAN;
    assert_eq!(
        pca.project(data.view()),
        Err(LinalgError::NonFinite {
            what: "x",
            index: 30
        })
    );
    for opts in [COV, RANDOMIZED] {
        assert_eq!(
            Pca::fit(data.view(), 2, &opts, &NoProgress),
            Err(LinalgError::NonFinite {
                what: "data",
                index: 30
            })
        );
    }
}

#[test]
fn cancellation_is_honoured() {
    let data = low_rank_matrix(40_000, 4, 2, 0.5, 0.1, 0.0, 1).unwrap();
    let progress = AtomicProgress::cancel_after(1);
    assert_eq!(
        Pca::fit(data.view(), 2, &COV, &progress),
        Err(LinalgError::Cancelled)
    );
}
