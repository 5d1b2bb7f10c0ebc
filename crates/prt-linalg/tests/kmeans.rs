//! Laws of k-means: monotone objective, nearest-centroid assignments, determinism, extremes.

use ndarray::{Array2, array};
use proptest::prelude::*;
use prt_core::{AtomicProgress, NoProgress};
use prt_linalg::{KMeansOptions, LinalgError, kmeans};

fn dist(a: &[f32], b: &[f32]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(&p, &q)| (f64::from(p) - f64::from(q)).powi(2))
        .sum()
}

fn data(n: usize, d: usize) -> impl Strategy<Value = Array2<f32>> {
    proptest::collection::vec(-10.0f32..10.0, n * d)
        .prop_map(move |v| Array2::from_shape_vec((n, d), v).unwrap())
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(32))]

    #[test]
    fn objective_never_increases_and_assignments_are_nearest(
        x in (5usize..200, 1usize..8).prop_flat_map(|(n, d)| data(n, d)),
        k_frac in 0.0f64..1.0, seed in 0u64..100,
    ) {
        let n = x.nrows();
        let k = 1 + ((n.min(20) - 1) as f64 * k_frac) as usize;
        let opts = KMeansOptions { max_iters: 50, tol: 0.0, seed };
        let km = kmeans(x.view(), k, &opts, &NoProgress).unwrap();
        for w in km.history.windows(2) {
            prop_assert!(w[1] <= w[0] * (1.0 + 1e-12), "history {:?}", km.history);
        }
        let mut cost = 0.0;
        for (i, row) in x.rows().into_iter().enumerate() {
            let row = row.to_vec();
            let a = km.assignments[i] as usize;
            let own = dist(&row, km.centroids.row(a).as_slice().unwrap());
            cost += own;
            for c in km.centroids.rows() {
                prop_assert!(own <= dist(&row, c.as_slice().unwrap()), "row {i} not at its nearest centroid");
            }
        }
        prop_assert!((cost - km.objective).abs() <= 1e-9 * cost.max(1.0));
        prop_assert_eq!(km.objective, *km.history.last().unwrap());
    }
}

#[test]
fn separated_blobs_are_recovered() {
    let centres = [[0.0f32, 0.0], [100.0, 0.0], [0.0, 100.0]];
    let x = Array2::from_shape_fn((300, 2), |(i, j)| {
        centres[i % 3][j] + ((i * 7 + j * 3) % 11) as f32 * 0.1
    });
    let km = kmeans(x.view(), 3, &KMeansOptions::default(), &NoProgress).unwrap();
    for i in 3..300 {
        assert_eq!(km.assignments[i], km.assignments[i % 3]);
    }
    let labels: std::collections::BTreeSet<u32> = km.assignments.iter().copied().collect();
    assert_eq!(labels.len(), 3);
}

#[test]
fn fewer_distinct_points_than_clusters() {
    // Two distinct points, four clusters: two centroids duplicate rows and stay empty.
    let x = array![
        [1.0f32, 1.0],
        [1.0, 1.0],
        [5.0, 5.0],
        [5.0, 5.0],
        [1.0, 1.0],
        [5.0, 5.0]
    ];
    let km = kmeans(x.view(), 4, &KMeansOptions::default(), &NoProgress).unwrap();
    assert_eq!(km.objective, 0.0);
    assert!(km.centroids.iter().all(|v| v.is_finite()));
    assert_ne!(km.assignments[0], km.assignments[2]);
}

#[test]
fn one_cluster_per_point_has_zero_objective() {
    let x = array![[0.0f32, 1.0], [2.0, 3.0], [4.0, -5.0]];
    let km = kmeans(x.view(), 3, &KMeansOptions::default(), &NoProgress).unwrap();
    assert_eq!(km.objective, 0.0);
    let mut labels = km.assignments.clone();
    labels.sort();
    assert_eq!(labels, vec![0, 1, 2]);
}

#[test]
fn single_cluster_is_the_mean() {
    let x = array![[0.0f32, 1.0], [2.0, 3.0], [4.0, -1.0]];
    let km = kmeans(x.view(), 1, &KMeansOptions::default(), &NoProgress).unwrap();
    assert_eq!(km.centroids.row(0).to_vec(), vec![2.0, 1.0]);
    assert!((km.objective - 16.0).abs() < 1e-12);
}

#[test]
fn huge_offsets_do_not_break_the_distance_trick() {
    // |x|^2 ~ 1e12 while the clusters are 1 apart: the GEMM distances cancel catastrophically in
    // f32, the exact re-ranking must still separate them.
    let x = Array2::from_shape_fn((200, 3), |(i, j)| {
        1e6 + if j == 0 { (i % 2) as f32 * 4.0 } else { 0.0 }
    });
    let km = kmeans(x.view(), 2, &KMeansOptions::default(), &NoProgress).unwrap();
    assert_eq!(km.objective, 0.0);
    for i in 2..200 {
        assert_eq!(km.assignments[i], km.assignments[i % 2]);
    }
}

#[test]
fn results_do_not_depend_on_the_thread_count() {
    let x = Array2::from_shape_fn((9000, 6), |(i, j)| {
        ((i * 31 + j * 17) % 101) as f32 * 0.37 + (i % 7) as f32
    });
    let run = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| {
                kmeans(
                    x.view(),
                    12,
                    &KMeansOptions {
                        max_iters: 10,
                        tol: 0.0,
                        seed: 3,
                    },
                    &NoProgress,
                )
                .unwrap()
            })
    };
    assert_eq!(run(1), run(3));
}

#[test]
fn bad_input_gives_typed_errors() {
    let mut x = array![[0.0f32, 1.0], [2.0, 3.0]];
    let opts = KMeansOptions::default();
    assert!(matches!(
        kmeans(x.view(), 0, &opts, &NoProgress),
        Err(LinalgError::InvalidParameter { what: "k", .. })
    ));
    assert!(matches!(
        kmeans(x.view(), 3, &opts, &NoProgress),
        Err(LinalgError::InvalidParameter { what: "k", .. })
    ));
    let bad_tol = KMeansOptions {
        tol: f64::NAN,
        ..opts
    };
    assert!(matches!(
        kmeans(x.view(), 1, &bad_tol, &NoProgress),
        Err(LinalgError::InvalidParameter { what: "tol", .. })
    ));
    assert!(matches!(
        kmeans(Array2::<f32>::zeros((0, 2)).view(), 1, &opts, &NoProgress),
        Err(LinalgError::Empty { .. })
    ));
    x[[1, 1]] = f32::INFINITY;
    assert_eq!(
        kmeans(x.view(), 1, &opts, &NoProgress),
        Err(LinalgError::NonFinite {
            what: "data",
            index: 3
        })
    );
}

#[test]
fn cancellation_is_honoured() {
    let x = Array2::from_shape_fn((100, 2), |(i, j)| (i * (j + 1)) as f32);
    let progress = AtomicProgress::cancel_after(1);
    assert_eq!(
        kmeans(
            x.view(),
            5,
            &KMeansOptions {
                max_iters: 50,
                tol: 0.0,
                seed: 0
            },
            &progress
        ),
        Err(LinalgError::Cancelled)
    );
}
