//! Laws of the MBD solver: monotone loss, exact recovery, bounded coefficients, determinism,
//! extremes and bad input.

use ndarray::{Array2, Array3};
use proptest::prelude::*;
use prt_core::{
    Aabb, AtomicProgress, Compressor, CoreError, FieldModel, GridField, KernelWeights, NoProgress,
    SpatialKernels,
};
use prt_kernels::HatGrid;
use prt_mbd::*;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

mod common;
use common::global_rank_field;

fn quick(rank: usize) -> MbdOptions {
    MbdOptions {
        rank,
        max_iterations: 12,
        ..MbdOptions::default()
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(6))]

    /// Every accepted step lowers (or keeps) the loss on its own samples.
    #[test]
    fn loss_never_increases_across_an_accepted_step(seed in 0u64..1000, rank in 1usize..4, pre in 0usize..2) {
        let field = SyntheticField { dims: [6, 5, 4], dim: 7, harmonics: 3, seed }.build(Aabb::UNIT).unwrap();
        let preconditioner = if pre == 0 { Preconditioner::Diagonal } else { Preconditioner::Lumped };
        let options = MbdOptions { rank, seed, preconditioner, ..quick(rank) };
        let (_, report) = Mbd { basis_nodes: [3, 2, 2], options }.fit(&field, &NoProgress).unwrap();
        prop_assert!(!report.history.is_empty());
        for r in &report.history {
            prop_assert!(r.loss_after <= r.loss_before, "{} > {}", r.loss_after, r.loss_before);
            prop_assert!(r.step >= 0.0 && r.step <= 1.0);
        }
    }

    /// A field that is exactly rank-L MBD is recovered to 1e-5 relative MSE.
    #[test]
    fn exact_rank_l_field_is_recovered(seed in 0u64..1000, rank in 1usize..4) {
        let field = global_rank_field([6, 5, 4], 9, rank, seed);
        let mbd = Mbd { basis_nodes: [2, 3, 2], options: quick(rank) };
        let (model, _) = mbd.fit(&field, &NoProgress).unwrap();
        let e = evaluate(&model, &field, &EvalOptions::default()).unwrap();
        prop_assert!(e.relative_mse <= 1e-5, "relative MSE {}", e.relative_mse);
    }

    /// The ridge resolves the scale ambiguity `c b = (s c)(b / s)`: since the loss never rises,
    /// `λ/2 ‖c‖² ≤ E(initial)`, even when the field is scaled by 1e3.
    #[test]
    fn regularisation_keeps_coefficients_bounded(seed in 0u64..1000, scale_exp in -3i32..4) {
        let scale = 10f32.powi(scale_exp);
        let mut field = SyntheticField { dims: [5, 5, 5], dim: 6, harmonics: 2, seed }.build(Aabb::UNIT).unwrap();
        field.data_mut().mapv_inplace(|v| v * scale);
        let options = MbdOptions { lambda: 1e-2, ..quick(2) };
        let (model, report) = Mbd { basis_nodes: [2, 2, 2], options: options.clone() }.fit(&field, &NoProgress).unwrap();
        let c2: f64 = model.coefficients().iter().map(|&c| (c as f64) * (c as f64)).sum();
        let e0 = report.history[0].loss_before;
        prop_assert!(0.5 * options.lambda as f64 * c2 <= e0 * (1.0 + 1e-6), "{} > {}", 0.5 * options.lambda as f64 * c2, e0);
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(3))]

    /// The rank-2L model space contains the rank-L one, so twice the rank must end at least as
    /// well, and no fit may end worse than its own global-PCA start. On this locally rank-3
    /// field the rank-2L curvature blocks are singular; before the solver floored them, rank 16
    /// diverged slowly from its start and ended ~4× worse than rank 8 (regression test).
    #[test]
    fn a_larger_rank_ends_at_least_as_well(seed in 0u64..1000, rank in 6usize..=8) {
        let field = SyntheticField { dims: [8, 8, 8], dim: 48, harmonics: 4, seed }.build(Aabb::UNIT).unwrap();
        let fit = |rank: usize, max_iterations: usize| {
            let options = MbdOptions { rank, max_iterations, tolerance: 0.0, seed, ..MbdOptions::default() };
            let (model, _) = Mbd { basis_nodes: [3, 3, 3], options }.fit(&field, &NoProgress).unwrap();
            evaluate(&model, &field, &EvalOptions::default()).unwrap().relative_mse
        };
        let small = fit(rank, 64);
        let (start, big) = (fit(2 * rank, 0), fit(2 * rank, 64));
        prop_assert!(big <= small, "rank {}: {big:e} > rank {rank}: {small:e}", 2 * rank);
        prop_assert!(big <= start, "rank {} ends at {big:e} above its start {start:e}", 2 * rank);
    }
}

#[test]
fn zero_and_constant_fields_are_handled_exactly() {
    let zero = GridField::new([4, 3, 5], Aabb::UNIT, 6).unwrap();
    let (model, report) = Mbd {
        basis_nodes: [2, 2, 2],
        options: quick(2),
    }
    .fit(&zero, &NoProgress)
    .unwrap();
    assert!(model.coefficients().iter().all(|&c| c == 0.0));
    assert!(report.converged);
    assert_eq!(
        evaluate(&model, &zero, &EvalOptions::default())
            .unwrap()
            .relative_mse,
        0.0
    );

    let constant = GridField::from_fn([4, 3, 5], Aabb::UNIT, 6, |_, out| {
        out.iter_mut()
            .enumerate()
            .for_each(|(i, o)| *o = i as f32 - 2.5)
    })
    .unwrap();
    let (model, _) = Mbd {
        basis_nodes: [3, 2, 2],
        options: quick(1),
    }
    .fit(&constant, &NoProgress)
    .unwrap();
    let e = evaluate(&model, &constant, &EvalOptions::default()).unwrap();
    assert!(e.relative_mse < 1e-8, "{}", e.relative_mse);
}

#[test]
fn mbd_beats_global_pca_on_a_curved_field() {
    let field = SyntheticField::new([10, 10, 10], 24)
        .build(Aabb::UNIT)
        .unwrap();
    let (model, report) = Mbd {
        basis_nodes: [3, 3, 3],
        options: MbdOptions {
            max_iterations: 24,
            ..quick(3)
        },
    }
    .fit(&field, &NoProgress)
    .unwrap();
    let mbd = evaluate(&model, &field, &EvalOptions::default())
        .unwrap()
        .relative_mse;
    let pca = {
        use prt_core::Compressor;
        let m = GlobalPca { rank: 3 }.compress(&field, &NoProgress).unwrap();
        evaluate(&m, &field, &EvalOptions::default())
            .unwrap()
            .relative_mse
    };
    // The solver starts from global PCA; a moving basis must do much better on a curved manifold.
    assert!(mbd < 0.5 * pca, "MBD {mbd} vs global PCA {pca}");
    assert!(report.history.last().unwrap().loss_after < report.history[0].loss_before * 0.5);
}

/// The default stopping rule (held-out loss of the averaged iterates) fires within the issue's
/// 16-128 iterations, at an error within 10 % of a run four times as long.
///
/// On fields this small the rule does not always fire by 128: the held-out error can still be
/// creeping at just over its 0.1 % per iteration there (seeds 4 and 5 of this field do, at
/// ~0.12 %); this seed stops at 112. The traced volumes stop at 100-108 (docs/results.md).
#[test]
fn default_solver_stops_near_its_long_run_error() {
    let field = SyntheticField {
        dims: [10, 10, 10],
        dim: 24,
        harmonics: 3,
        seed: 3,
    }
    .build(Aabb::UNIT)
    .unwrap();
    let fit = |options: MbdOptions| {
        let (model, report) = Mbd {
            basis_nodes: [3, 3, 3],
            options,
        }
        .fit(&field, &NoProgress)
        .unwrap();
        let e = evaluate(&model, &field, &EvalOptions::default()).unwrap();
        (e.relative_mse, report)
    };
    let (stopped, report) = fit(MbdOptions {
        rank: 2,
        ..MbdOptions::default()
    });
    let iterations = report.history.len();
    assert!(report.converged, "no stop within {iterations} iterations");
    assert!((16..128).contains(&iterations), "{iterations} iterations");
    let (long, _) = fit(MbdOptions {
        rank: 2,
        max_iterations: 4 * iterations,
        tolerance: 0.0,
        ..MbdOptions::default()
    });
    assert!(
        stopped <= 1.1 * long,
        "stopped after {iterations} at {stopped:e}, long run {long:e}"
    );
}

/// Momentum and averaging off give the plain solver of the paper (with the block
/// preconditioner); each still never increases the loss across an accepted step.
#[test]
fn momentum_keeps_accepted_steps_monotone() {
    let field = SyntheticField {
        dims: [8, 7, 6],
        dim: 12,
        harmonics: 3,
        seed: 9,
    }
    .build(Aabb::UNIT)
    .unwrap();
    for (momentum_basis, momentum_coefficients) in [(0.0, 0.0), (0.9, 0.6), (0.99, 0.99)] {
        let options = MbdOptions {
            momentum_basis,
            momentum_coefficients,
            max_iterations: 24,
            tolerance: 0.0,
            ..quick(3)
        };
        let (_, report) = Mbd {
            basis_nodes: [3, 3, 2],
            options,
        }
        .fit(&field, &NoProgress)
        .unwrap();
        assert_eq!(report.history.len(), 24);
        for r in &report.history {
            assert!(
                r.loss_after <= r.loss_before,
                "{} > {}",
                r.loss_after,
                r.loss_before
            );
        }
    }
}

#[test]
fn same_seed_gives_the_same_model_on_any_thread_count() {
    let field = SyntheticField {
        dims: [8, 6, 5],
        dim: 10,
        harmonics: 3,
        seed: 4,
    }
    .build(Aabb::UNIT)
    .unwrap();
    let fit = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            Mbd {
                basis_nodes: [3, 3, 2],
                options: quick(3),
            }
            .fit(&field, &NoProgress)
            .unwrap()
            .0
        })
    };
    let (a, b) = (fit(1), fit(3));
    assert_eq!(a.coefficients(), b.coefficients());
    assert_eq!(a.basis(), b.basis());
}

#[test]
fn cancellation_stops_the_solver() {
    let field = SyntheticField {
        dims: [6, 6, 6],
        dim: 5,
        harmonics: 2,
        seed: 1,
    }
    .build(Aabb::UNIT)
    .unwrap();
    let progress = AtomicProgress::cancel_after(2);
    let err = Mbd {
        basis_nodes: [2, 2, 2],
        options: quick(2),
    }
    .fit(&field, &progress)
    .unwrap_err();
    assert!(err.is_cancelled(), "{err}");
    assert_eq!(progress.position(), 2);
}

/// A hat grid that refuses points outside a smaller box, standing in for a scattered kernel
/// family that leaves part of the field uncovered.
#[derive(Debug)]
struct Cropped(HatGrid, Aabb);

impl SpatialKernels for Cropped {
    fn len(&self) -> usize {
        self.0.len()
    }
    fn max_support(&self) -> usize {
        self.0.max_support()
    }
    fn domain(&self) -> Aabb {
        self.1
    }
    fn eval(&self, x: glam::Vec3, out: &mut KernelWeights) -> Result<(), CoreError> {
        if !self.1.contains(x) {
            return Err(CoreError::Uncovered {
                point: x.to_array(),
            });
        }
        self.0.eval(x, out)
    }
}

#[test]
fn bad_input_gives_typed_errors() {
    let field = SyntheticField {
        dims: [4, 4, 4],
        dim: 5,
        harmonics: 2,
        seed: 1,
    }
    .build(Aabb::UNIT)
    .unwrap();
    let fit = |rank: usize, nodes: [usize; 3]| {
        Mbd {
            basis_nodes: nodes,
            options: quick(rank),
        }
        .fit(&field, &NoProgress)
    };
    assert!(matches!(
        fit(0, [2, 2, 2]),
        Err(MbdError::InvalidRank { rank: 0, dim: 5 })
    ));
    assert!(matches!(
        fit(6, [2, 2, 2]),
        Err(MbdError::InvalidRank { rank: 6, dim: 5 })
    ));
    assert!(matches!(
        fit(2, [2, 1, 2]),
        Err(MbdError::InvalidKernels { which: "basis", .. })
    ));

    let coef = HatGrid::new([4, 4, 4], voxel_centre_box(&field)).unwrap();
    let half = Aabb::new(glam::Vec3::ZERO, glam::Vec3::splat(0.5));
    let basis = Cropped(HatGrid::new([2, 2, 2], Aabb::UNIT).unwrap(), half);
    let err = solve(&field, coef.clone(), basis, &quick(2), &NoProgress).unwrap_err();
    assert!(
        matches!(err, MbdError::KernelsDoNotCover { which: "basis", .. }),
        "{err}"
    );

    let mut nan = field.clone();
    nan.data_mut()[[17, 3]] = f32::NAN;
    let err = solve(
        &nan,
        coef.clone(),
        HatGrid::new([2, 2, 2], Aabb::UNIT).unwrap(),
        &quick(2),
        &NoProgress,
    )
    .unwrap_err();
    assert_eq!(
        err,
        MbdError::Core(CoreError::NonFinite {
            what: "field data",
            index: 17 * 5 + 3
        })
    );

    let bad_lambda = MbdOptions {
        lambda: -1.0,
        ..quick(2)
    };
    let err = solve(
        &field,
        coef,
        HatGrid::new([2, 2, 2], Aabb::UNIT).unwrap(),
        &bad_lambda,
        &NoProgress,
    )
    .unwrap_err();
    assert!(matches!(
        err,
        MbdError::InvalidOption { what: "lambda", .. }
    ));

    // An empty field cannot even be built: the shared type refuses it.
    assert!(matches!(
        GridField::new([0, 4, 4], Aabb::UNIT, 5),
        Err(CoreError::Empty { .. })
    ));
}

#[test]
fn model_checks_tensor_shapes_and_values() {
    let coef = HatGrid::new([3, 3, 3], Aabb::UNIT).unwrap();
    let basis = HatGrid::new([2, 2, 2], Aabb::UNIT).unwrap();
    let ok = MbdModel::new(
        coef.clone(),
        basis.clone(),
        Array2::zeros((27, 2)),
        Array3::zeros((8, 2, 4)),
    )
    .unwrap();
    assert_eq!(ok.stored_scalars(), 27 * 2 + 8 * 2 * 4);
    assert_eq!(FieldModel::dim(&ok), 4);
    let wrong = MbdModel::new(
        coef.clone(),
        basis.clone(),
        Array2::zeros((26, 2)),
        Array3::zeros((8, 2, 4)),
    );
    assert!(matches!(
        wrong,
        Err(MbdError::ShapeMismatch {
            what: "coefficient tensor",
            ..
        })
    ));
    let wrong = MbdModel::new(
        coef.clone(),
        basis.clone(),
        Array2::zeros((27, 2)),
        Array3::zeros((8, 3, 4)),
    );
    assert!(matches!(
        wrong,
        Err(MbdError::ShapeMismatch {
            what: "basis tensor",
            ..
        })
    ));
    let mut b = Array3::zeros((8, 2, 4));
    b[[1, 0, 2]] = f32::INFINITY;
    let err = MbdModel::new(coef, basis, Array2::zeros((27, 2)), b).unwrap_err();
    assert_eq!(
        err,
        MbdError::Core(CoreError::NonFinite {
            what: "MBD basis",
            index: 8 + 2
        })
    );
}

/// The model evaluates `Σ_l c_l(x) b_l(x)` with interpolated coefficients and bases.
#[test]
fn model_eval_is_the_product_of_interpolants() {
    let coef = HatGrid::new([2, 2, 2], Aabb::UNIT).unwrap();
    let basis = HatGrid::new([2, 2, 2], Aabb::UNIT).unwrap();
    // c(x) = x (node value = its x coordinate), b(x) = (1, y) for rank 1.
    let c = Array2::from_shape_fn((8, 1), |(n, _)| (n & 1) as f32);
    let b = Array3::from_shape_fn(
        (8, 1, 2),
        |(n, _, d)| if d == 0 { 1.0 } else { ((n >> 1) & 1) as f32 },
    );
    let model = MbdModel::new(coef, basis, c, b).unwrap();
    let mut out = [0.0; 2];
    model
        .eval(glam::Vec3::new(0.25, 0.5, 0.9), &mut out)
        .unwrap();
    assert!(
        (out[0] - 0.25).abs() < 1e-6 && (out[1] - 0.125).abs() < 1e-6,
        "{out:?}"
    );
}

/// Alternating least squares: every iteration lowers the discrete loss, an exact rank-L field is
/// recovered, and kernels that do not interpolate at the voxel centres are refused.
#[test]
fn als_decreases_the_loss_and_recovers_exact_fields() {
    let field = SyntheticField {
        dims: [8, 7, 6],
        dim: 12,
        harmonics: 3,
        seed: 2,
    }
    .build(Aabb::UNIT)
    .unwrap();
    let mbd = Mbd {
        basis_nodes: [3, 3, 2],
        options: quick(3),
    };
    let (coef, basis) = mbd.kernels(&field).unwrap();
    let (model, report) = solve_als(&field, coef, basis, &mbd.options, &NoProgress).unwrap();
    assert!(
        report
            .history
            .iter()
            .all(|r| r.loss_after <= r.loss_before * (1.0 + 1e-6))
    );
    let first = report.history[0].loss_before;
    assert!(report.history.last().unwrap().loss_after < 0.5 * first);
    let als = evaluate(&model, &field, &EvalOptions::default())
        .unwrap()
        .relative_mse;
    assert!(als < 0.05, "{als}");

    let exact = global_rank_field([6, 5, 4], 9, 2, 3);
    let mbd = Mbd {
        basis_nodes: [2, 2, 2],
        options: quick(2),
    };
    let (coef, basis) = mbd.kernels(&exact).unwrap();
    let (model, _) = solve_als(&exact, coef, basis, &mbd.options, &NoProgress).unwrap();
    assert!(
        evaluate(&model, &exact, &EvalOptions::default())
            .unwrap()
            .relative_mse
            < 1e-5
    );

    // Right after the global-PCA start every node holds the same basis, so the basis normal
    // equations are rank deficient: the step must still succeed and lower the loss.
    let wide = SyntheticField {
        dims: [10, 10, 10],
        dim: 40,
        harmonics: 4,
        seed: 1,
    }
    .build(Aabb::UNIT)
    .unwrap();
    let mbd = Mbd {
        basis_nodes: [3, 3, 3],
        options: MbdOptions {
            max_iterations: 2,
            ..quick(6)
        },
    };
    let (coef, basis) = mbd.kernels(&wide).unwrap();
    let (_, report) = solve_als(&wide, coef, basis, &mbd.options, &NoProgress).unwrap();
    assert!(report.history[0].loss_after < report.history[0].loss_before);

    let coarse = HatGrid::new([3, 3, 3], Aabb::UNIT).unwrap();
    let err = solve_als(
        &exact,
        coarse,
        HatGrid::new([2, 2, 2], Aabb::UNIT).unwrap(),
        &quick(2),
        &NoProgress,
    )
    .unwrap_err();
    assert!(
        matches!(
            err,
            MbdError::InvalidKernels {
                which: "coefficient",
                ..
            }
        ),
        "{err}"
    );
}

#[test]
fn als_accepts_hat_weights_rounded_off_the_origin() {
    // The traced Cornell box's grid: 32 × 31 × 32 voxels over bounds away from the origin, where
    // the f32 hat weights at voxel centres miss 1 by a few 1e-6 (ALS refused this grid).
    let bounds = Aabb::new(
        glam::Vec3::new(-1.02, 0.0, -1.04),
        glam::Vec3::new(1.0, 1.99, 0.99),
    );
    let field = SyntheticField {
        dims: [32, 31, 32],
        dim: 3,
        harmonics: 1,
        seed: 4,
    }
    .build(bounds)
    .unwrap();
    let mbd = Mbd {
        basis_nodes: [2, 2, 2],
        options: MbdOptions {
            max_iterations: 1,
            ..quick(1)
        },
    };
    let (coef, basis) = mbd.kernels(&field).unwrap();
    let (_, report) = solve_als(&field, coef, basis, &mbd.options, &NoProgress).unwrap();
    assert!(report.history[0].loss_after <= report.history[0].loss_before);
}

#[test]
fn als_stays_bounded_where_most_voxels_are_zero() {
    // Like a traced volume with invalid (zero) voxels through it (60 % here), so some basis
    // nodes see little. On the traced Sponza volume the undamped basis step grew the basis there
    // (exact at the voxel centres, wrong between them) and ended 5.5x above its global-PCA
    // start; this smaller field does not reproduce that blow-up (it passes undamped too), so it
    // guards the property, not the Sponza case (measured in docs/results.md).
    let mut field = SyntheticField {
        dims: [20, 20, 20],
        dim: 96,
        harmonics: 3,
        seed: 8,
    }
    .build(Aabb::UNIT)
    .unwrap();
    for v in 0..field.num_voxels() {
        let [x, y, z] = field.coords(v);
        if (x * 7 + y * 3 + z * 5) % 5 < 3 {
            field.voxel_mut(v).fill(0.0);
        }
    }
    let options = MbdOptions {
        max_iterations: 2,
        tolerance: 0.0,
        ..quick(8)
    };
    let mbd = Mbd {
        basis_nodes: [5, 5, 5],
        options: options.clone(),
    };
    let start = {
        let (coef, basis) = mbd.kernels(&field).unwrap();
        let none = MbdOptions {
            max_iterations: 0,
            ..options.clone()
        };
        solve_als(&field, coef, basis, &none, &NoProgress)
            .unwrap()
            .0
    };
    let (coef, basis) = mbd.kernels(&field).unwrap();
    let (model, _) = solve_als(&field, coef, basis, &options, &NoProgress).unwrap();
    let error = |m: &dyn FieldModel| {
        evaluate(m, &field, &EvalOptions::default())
            .unwrap()
            .relative_mse
    };
    let (before, after) = (error(&start), error(&model));
    assert!(after < before, "ALS {after:.3e} vs its start {before:.3e}");
}

/// The solve starts from the given basis, not from `options.init`: from the field's exact
/// subspace at every node one iteration ends at rounding error, from a random basis far from it;
/// a basis of the wrong shape or with a NaN is a typed error.
#[test]
fn solve_from_basis_checks_and_uses_the_given_basis() {
    let field = global_rank_field([6, 5, 4], 10, 3, 5);
    let mbd = Mbd {
        basis_nodes: [2, 2, 2],
        options: MbdOptions {
            rank: 3,
            max_iterations: 1,
            ..MbdOptions::default()
        },
    };
    let (c, b) = mbd.kernels(&field).unwrap();
    let global = GlobalPca { rank: 3 }.compress(&field, &NoProgress).unwrap();
    let exact = global.bases().broadcast((8, 3, 10)).unwrap().to_owned();
    let eval = EvalOptions::default();
    let error_from = |basis: &Array3<f32>| {
        let (model, _) = solve_from_basis(
            &field,
            c.clone(),
            b.clone(),
            basis,
            &mbd.options,
            &NoProgress,
        )
        .unwrap();
        evaluate(&model, &field, &eval).unwrap().relative_mse
    };
    assert!(error_from(&exact) < 1e-8, "{:.3e}", error_from(&exact));
    let mut rng = Pcg64Mcg::seed_from_u64(3);
    let random = Array3::from_shape_fn((8, 3, 10), |_| rng.random::<f32>() - 0.5);
    assert!(error_from(&random) > 1e-3, "{:.3e}", error_from(&random));
    let wrong = Array3::<f32>::zeros((8, 2, 10));
    assert!(matches!(
        solve_from_basis(
            &field,
            c.clone(),
            b.clone(),
            &wrong,
            &mbd.options,
            &NoProgress
        ),
        Err(MbdError::InvalidOption {
            what: "initial_basis",
            ..
        })
    ));
    let mut nan = exact;
    nan[[3, 1, 4]] = f32::NAN;
    assert!(matches!(
        solve_from_basis(&field, c, b, &nan, &mbd.options, &NoProgress),
        Err(MbdError::InvalidOption {
            what: "initial_basis",
            ..
        })
    ));
}
