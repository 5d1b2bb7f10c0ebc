//! Laws of the Lawson-Hanson NNLS solver.

use ndarray::{Array1, Array2, array};
use proptest::prelude::*;
use prt_linalg::{LinalgError, lstsq, nnls, nnls_gram};

fn problem(rows: usize, cols: usize) -> impl Strategy<Value = (Array2<f64>, Array1<f64>)> {
    (
        proptest::collection::vec(-1.0f64..1.0, rows * cols),
        proptest::collection::vec(-1.0f64..1.0, rows),
    )
        .prop_map(move |(a, b)| {
            (
                Array2::from_shape_vec((rows, cols), a).unwrap(),
                Array1::from(b),
            )
        })
}

/// Largest violation of the KKT conditions of `min |a x - b|^2, x >= 0`, relative to the scale
/// of `a^T b`.
fn kkt_violation(gram: &Array2<f64>, atb: &Array1<f64>, x: &Array1<f64>) -> f64 {
    let g = gram.dot(x) - atb;
    let scale = 1.0 + atb.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let mut worst = 0.0f64;
    for i in 0..x.len() {
        worst = worst.max(-x[i]); // primal feasibility
        worst = worst.max(-g[i] / scale); // dual feasibility
        if x[i] > 0.0 {
            worst = worst.max(g[i].abs() / scale); // complementary slackness
        }
    }
    worst
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn kkt_conditions_hold_on_random_problems(
        (a, b) in (1usize..20, 1usize..12).prop_flat_map(|(extra, n)| problem(n + extra, n))
    ) {
        let sol = nnls(a.view(), b.view()).unwrap();
        let gram = a.t().dot(&a);
        let atb = a.t().dot(&b);
        prop_assert!(kkt_violation(&gram, &atb, &sol.x) <= 1e-6, "violation {}", kkt_violation(&gram, &atb, &sol.x));
        prop_assert!(sol.x.iter().all(|&v| v >= 0.0));
        // The reported gradient is the one of the returned x.
        prop_assert!((&sol.gradient - &(gram.dot(&sol.x) - &atb)).iter().all(|v| v.abs() < 1e-12));
    }

    #[test]
    fn kkt_conditions_hold_for_underdetermined_problems(
        (a, b) in (1usize..6, 1usize..6).prop_flat_map(|(m, extra)| problem(m, m + extra))
    ) {
        // a^T a is singular here: the passive-set solves must cope.
        let sol = nnls(a.view(), b.view()).unwrap();
        let gram = a.t().dot(&a);
        let atb = a.t().dot(&b);
        prop_assert!(kkt_violation(&gram, &atb, &sol.x) <= 1e-6);
    }

    #[test]
    fn equals_least_squares_when_that_is_non_negative(
        (a, x_true) in (1usize..20, 1usize..10).prop_flat_map(|(extra, n)| (
            proptest::collection::vec(-1.0f64..1.0, (n + extra) * n)
                .prop_map(move |v| Array2::from_shape_vec((n + extra, n), v).unwrap()),
            proptest::collection::vec(0.1f64..2.0, n).prop_map(Array1::from),
        )),
        noise in proptest::collection::vec(-0.01f64..0.01, 30),
    ) {
        let b = a.dot(&x_true) + Array1::from_iter(noise.iter().copied().cycle().take(a.nrows()));
        let ls = lstsq(a.view(), b.view().insert_axis(ndarray::Axis(1)), 0.0).unwrap();
        prop_assume!(ls.iter().all(|&v| v > 1e-6));
        // Well-conditioned designs only: NNLS works on the Gram matrix.
        let s = prt_linalg::thin_svd(a.view()).unwrap().s;
        prop_assume!(s[s.len() - 1] > 1e-3 * s[0]);
        let sol = nnls(a.view(), b.view()).unwrap();
        for i in 0..sol.x.len() {
            prop_assert!((sol.x[i] - ls[[i, 0]]).abs() < 1e-8 * (1.0 + ls[[i, 0]].abs()), "{} vs {}", sol.x, ls);
        }
    }
}

#[test]
fn gram_form_matches_design_form() {
    let a = array![
        [1.0, 0.5, -0.2],
        [0.3, 1.0, 0.1],
        [0.2, -0.4, 1.0],
        [1.0, 1.0, 1.0]
    ];
    let b = array![1.0, -2.0, 0.5, 0.3];
    let direct = nnls(a.view(), b.view()).unwrap();
    let gram = nnls_gram(a.t().dot(&a).view(), a.t().dot(&b).view()).unwrap();
    assert!((&direct.x - &gram.x).iter().all(|v| v.abs() < 1e-14));
    // The unconstrained solution has a negative entry, which NNLS must clamp to an active bound.
    let ls = lstsq(a.view(), b.view().insert_axis(ndarray::Axis(1)), 0.0).unwrap();
    assert!(ls.iter().any(|&v| v < 0.0));
    assert!(direct.x.iter().any(|&v| v == 0.0));
}

#[test]
fn non_positive_correlations_give_zero() {
    let gram = array![[2.0, 0.1], [0.1, 1.0]];
    let sol = nnls_gram(gram.view(), array![-1.0, 0.0].view()).unwrap();
    assert_eq!(sol.x.to_vec(), vec![0.0, 0.0]);
    assert_eq!(sol.iterations, 0);
}

#[test]
fn huge_dynamic_range() {
    let a = array![[1e6, 0.0], [0.0, 1e-6]];
    let b = array![1e6, 1e-6];
    let sol = nnls(a.view(), b.view()).unwrap();
    assert!((sol.x[0] - 1.0).abs() < 1e-9);
    // The second column is below the tolerance relative to the first: its x is either exact or 0.
    assert!(sol.x[1] == 0.0 || (sol.x[1] - 1.0).abs() < 1e-6);
}

#[test]
fn bad_input_gives_typed_errors() {
    let a = array![[1.0, 2.0], [3.0, f64::INFINITY]];
    assert_eq!(
        nnls(a.view(), array![1.0, 2.0].view()).unwrap_err(),
        LinalgError::NonFinite {
            what: "a",
            index: 3
        }
    );
    let a = array![[1.0, 2.0], [3.0, 4.0]];
    assert!(matches!(
        nnls(a.view(), array![1.0].view()),
        Err(LinalgError::ShapeMismatch { .. })
    ));
    assert!(matches!(
        nnls(Array2::<f64>::zeros((0, 2)).view(), Array1::zeros(0).view()),
        Err(LinalgError::Empty { .. })
    ));
    assert!(matches!(
        nnls_gram(Array2::<f64>::zeros((2, 3)).view(), Array1::zeros(2).view()),
        Err(LinalgError::ShapeMismatch { .. })
    ));
    assert_eq!(
        nnls_gram(Array2::<f64>::eye(2).view(), array![f64::NAN, 1.0].view()).unwrap_err(),
        LinalgError::NonFinite {
            what: "atb",
            index: 0
        }
    );
}
