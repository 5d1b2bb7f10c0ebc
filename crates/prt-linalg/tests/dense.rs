//! Laws of the dense decompositions and solvers.

use ndarray::{Array1, Array2, array};
use proptest::prelude::*;
use prt_linalg::{LinalgError, cholesky_solve, ldlt_solve, lstsq, sym_eig, thin_svd};

fn matrix(rows: usize, cols: usize) -> impl Strategy<Value = Array2<f64>> {
    proptest::collection::vec(-1.0f64..1.0, rows * cols)
        .prop_map(move |v| Array2::from_shape_vec((rows, cols), v).unwrap())
}

fn max_abs(a: &Array2<f64>) -> f64 {
    a.iter().fold(0.0, |m, v| m.max(v.abs()))
}

fn identity_error(q: &Array2<f64>) -> f64 {
    max_abs(&(q.t().dot(q) - Array2::<f64>::eye(q.ncols())))
}

fn spd(m: &Array2<f64>) -> Array2<f64> {
    m.t().dot(m) + Array2::<f64>::eye(m.ncols()) * 0.1
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]

    #[test]
    fn sym_eig_reconstructs_with_orthonormal_vectors(m in (1usize..12).prop_flat_map(|n| matrix(n, n))) {
        let a = &m + &m.t();
        let e = sym_eig(a.view()).unwrap();
        prop_assert!(identity_error(&e.vectors) < 1e-12);
        let recon = e.vectors.dot(&Array2::from_diag(&e.values)).dot(&e.vectors.t());
        prop_assert!(max_abs(&(recon - &a)) < 1e-12);
        prop_assert!(e.values.windows(2).into_iter().all(|w| w[0] >= w[1]));
    }

    #[test]
    fn thin_svd_reconstructs_with_orthonormal_factors(
        m in (1usize..14, 1usize..14).prop_flat_map(|(r, c)| matrix(r, c))
    ) {
        let svd = thin_svd(m.view()).unwrap();
        let k = m.nrows().min(m.ncols());
        prop_assert_eq!(svd.s.len(), k);
        prop_assert!(identity_error(&svd.u) < 1e-12);
        prop_assert!(identity_error(&svd.vt.t().to_owned()) < 1e-12);
        prop_assert!(svd.s.iter().all(|&s| s >= 0.0));
        prop_assert!(svd.s.windows(2).into_iter().all(|w| w[0] >= w[1]));
        let recon = svd.u.dot(&Array2::from_diag(&svd.s)).dot(&svd.vt);
        prop_assert!(max_abs(&(recon - &m)) < 1e-12);
    }

    #[test]
    fn cholesky_and_ldlt_solve_spd_systems(
        (m, b) in (1usize..12, 1usize..4).prop_flat_map(|(n, r)| (matrix(n, n), matrix(n, r))),
        ridge in prop_oneof![Just(0.0), 0.0f64..2.0],
    ) {
        let a = spd(&m);
        let shifted = &a + &(Array2::<f64>::eye(a.nrows()) * ridge);
        for x in [cholesky_solve(a.view(), b.view(), ridge).unwrap(), ldlt_solve(a.view(), b.view(), ridge).unwrap()] {
            prop_assert!(max_abs(&(shifted.dot(&x) - &b)) < 1e-9 * (1.0 + max_abs(&x)));
        }
    }

    #[test]
    fn ldlt_solves_indefinite_systems(
        (m, b) in (1usize..10).prop_flat_map(|n| (matrix(n, n), matrix(n, 1)))
    ) {
        // Symmetric with eigenvalues bounded away from zero but of both signs.
        let e = sym_eig((&m + &m.t()).view()).unwrap();
        let values: Array1<f64> = e.values.mapv(|v| if v >= 0.0 { v + 0.5 } else { v - 0.5 });
        let a = e.vectors.dot(&Array2::from_diag(&values)).dot(&e.vectors.t());
        let x = ldlt_solve(a.view(), b.view(), 0.0).unwrap();
        prop_assert!(max_abs(&(a.dot(&x) - &b)) < 1e-9 * (1.0 + max_abs(&x)));
    }

    #[test]
    fn lstsq_satisfies_the_normal_equations(
        (a, b) in (1usize..16, 1usize..8).prop_flat_map(|(r, c)| (matrix(r, c), matrix(r, 2))),
        ridge in prop_oneof![Just(0.0), 0.01f64..1.0],
    ) {
        let x = lstsq(a.view(), b.view(), ridge).unwrap();
        // Gradient of |a x - b|^2 + ridge |x|^2 vanishes at the minimiser: a^T (a x - b) + ridge x = 0.
        let grad = a.t().dot(&(a.dot(&x) - &b)) + &x * ridge;
        if ridge > 0.0 || a.nrows() >= a.ncols() {
            // Full column rank almost surely (or regularised): the gradient vanishes.
            prop_assert!(max_abs(&grad) < 1e-9, "gradient {}", max_abs(&grad));
        }
    }
}

#[test]
fn lstsq_of_a_rank_deficient_matrix_is_minimum_norm() {
    // Two identical columns: the minimum-norm solution splits the weight equally.
    let a = array![[1.0, 1.0], [2.0, 2.0], [3.0, 3.0]];
    let b = array![[2.0], [4.0], [6.0]];
    let x = lstsq(a.view(), b.view(), 0.0).unwrap();
    assert!(
        (x[[0, 0]] - 1.0).abs() < 1e-12 && (x[[1, 0]] - 1.0).abs() < 1e-12,
        "{x}"
    );
}

#[test]
fn lstsq_is_stable_where_normal_equations_fail() {
    // Laeuchli matrix: a^T a is singular in f64 for eps = 1e-9, the SVD still solves it.
    let eps = 1e-9;
    let a = array![[1.0, 1.0], [eps, 0.0], [0.0, eps]];
    let b = array![[2.0], [eps], [eps]];
    let x = lstsq(a.view(), b.view(), 0.0).unwrap();
    assert!(
        (x[[0, 0]] - 1.0).abs() < 1e-6 && (x[[1, 0]] - 1.0).abs() < 1e-6,
        "{x}"
    );
}

#[test]
fn cholesky_rejects_indefinite_and_semidefinite_without_ridge() {
    let a = array![[1.0, 0.0], [0.0, -1.0]];
    let b = array![[1.0], [1.0]];
    assert!(matches!(
        cholesky_solve(a.view(), b.view(), 0.0),
        Err(LinalgError::NotPositiveDefinite { pivot: 1 })
    ));
    let semi = array![[1.0, 1.0], [1.0, 1.0]];
    assert!(matches!(
        cholesky_solve(semi.view(), b.view(), 0.0),
        Err(LinalgError::NotPositiveDefinite { .. })
    ));
    let x = cholesky_solve(semi.view(), b.view(), 1.0).unwrap();
    // (J + I) x = 1 with J the all-ones matrix: x = 1/3.
    assert!((x[[0, 0]] - 1.0 / 3.0).abs() < 1e-14);
}

#[test]
fn ldlt_reports_exactly_singular_matrices() {
    let a = array![[0.0, 0.0], [0.0, 0.0]];
    let b = array![[1.0], [1.0]];
    assert_eq!(
        ldlt_solve(a.view(), b.view(), 0.0),
        Err(LinalgError::Singular)
    );
}

#[test]
fn bad_input_gives_typed_errors() {
    let mut a = Array2::<f64>::eye(3);
    a[[2, 1]] = f64::NAN;
    assert_eq!(
        sym_eig(a.view()).unwrap_err(),
        LinalgError::NonFinite {
            what: "a",
            index: 7
        }
    );
    assert!(matches!(
        thin_svd(a.view()),
        Err(LinalgError::NonFinite { index: 7, .. })
    ));
    let empty = Array2::<f64>::zeros((0, 3));
    assert!(matches!(
        thin_svd(empty.view()),
        Err(LinalgError::Empty { .. })
    ));
    assert!(matches!(
        sym_eig(Array2::<f64>::zeros((2, 3)).view()),
        Err(LinalgError::ShapeMismatch { .. })
    ));
    let eye = Array2::<f64>::eye(3);
    let b = Array2::<f64>::zeros((2, 1));
    assert!(matches!(
        cholesky_solve(eye.view(), b.view(), 0.0),
        Err(LinalgError::ShapeMismatch {
            what: "rows of b",
            ..
        })
    ));
    let b = Array2::<f64>::zeros((3, 1));
    assert!(matches!(
        cholesky_solve(eye.view(), b.view(), -1.0),
        Err(LinalgError::InvalidParameter { what: "ridge", .. })
    ));
    assert!(matches!(
        lstsq(eye.view(), b.view(), f64::NAN),
        Err(LinalgError::InvalidParameter { .. })
    ));
}

#[test]
fn zero_matrix_has_zero_spectrum() {
    let z = Array2::<f64>::zeros((4, 3));
    let svd = thin_svd(z.view()).unwrap();
    assert!(svd.s.iter().all(|&s| s == 0.0));
    assert!(identity_error(&svd.vt.t().to_owned()) < 1e-14);
    let e = sym_eig(Array2::<f64>::zeros((3, 3)).view()).unwrap();
    assert!(e.values.iter().all(|&v| v == 0.0));
}

#[test]
fn huge_dynamic_range_is_handled() {
    let a = array![[1e6, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1e-6]];
    let e = sym_eig(a.view()).unwrap();
    assert_eq!(e.values.to_vec(), vec![1e6, 1.0, 1e-6]);
    let b = array![[1e6], [1.0], [1e-6]];
    let x = cholesky_solve(a.view(), b.view(), 0.0).unwrap();
    assert!(x.iter().all(|&v| (v - 1.0).abs() < 1e-9), "{x}");
}
