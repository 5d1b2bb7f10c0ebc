//! Laws of the exact polish: its loss is the continuous loss, it never increases, it recovers
//! exactly representable fields, it is deterministic, and it refuses what it cannot do.

use glam::Vec3;
use ndarray::{Array2, Array3};
use proptest::prelude::*;
use prt_core::{Aabb, GridField, NoProgress};
use prt_kernels::HatGrid;
use prt_mbd::expert::{
    POLISH_MAX_BASIS_UNKNOWNS, PolishStep, exact_loss, polish, trilinear_energy,
};
use prt_mbd::*;

mod common;
use common::{
    check_exact_loss, check_polish_descends, check_polish_fits_exactly,
    check_polish_is_deterministic, global_rank_field, hat_kernels, hat_mbd,
};

/// A model with random tensors on the hat grids of [`Basis::HatGrid`] for `field`.
fn random_model(
    field: &GridField,
    nodes: [usize; 3],
    rank: usize,
    seed: u64,
) -> MbdModel<HatGrid, HatGrid> {
    common::random_model(field, hat_kernels(field, nodes).1, rank, seed)
}

/// The exact loss is the integral. The composite midpoint rule's error falls as h², so its
/// Richardson extrapolation from 8³ and 16³ points per voxel agrees with the exact value to
/// ~1e-6 (measured 1e-7), while either midpoint estimate alone is off by 1e-4 .. 3e-4 — on a
/// grid whose basis nodes fall between voxel centres (5 voxels / 3 cells), on a voxel centre
/// (7 voxels / 2 cells) and on a voxel boundary (6 / 2).
#[test]
fn exact_loss_is_the_continuous_integral() {
    let bounds = Aabb::new(Vec3::new(-1.0, 0.0, 2.0), Vec3::new(2.0, 1.5, 5.0));
    let field = SyntheticField {
        dims: [6, 5, 7],
        dim: 5,
        harmonics: 3,
        seed: 4,
    }
    .build(bounds)
    .unwrap();
    // `Mbd`'s basis spans the voxel centres' box; a basis over the field's whole box (the
    // old layout) is integrated exactly too.
    let centred = random_model(&field, [3, 4, 3], 2, 7);
    let whole_box = MbdModel::new(
        centred.coefficient_kernels().clone(),
        HatGrid::new([3, 4, 3], bounds).unwrap(),
        centred.coefficients().clone(),
        centred.basis().clone(),
    )
    .unwrap();
    for model in [centred, whole_box] {
        check_exact_loss(&field, &model);
    }
}

/// The trilinear energy is the polish's `∫‖f‖²`, and a constant field's is its volume in voxels
/// times `|f|²` (also with a single voxel along an axis, where the field is constant along it).
#[test]
fn trilinear_energy_is_exact() {
    let field = SyntheticField {
        dims: [6, 5, 7],
        dim: 5,
        harmonics: 3,
        seed: 4,
    }
    .build(Aabb::UNIT)
    .unwrap();
    let model = random_model(&field, [3, 4, 3], 2, 7);
    let from_polish = exact_loss(&field, &model, 1e-4).unwrap().energy;
    assert!((trilinear_energy(&field) - from_polish).abs() <= 1e-12 * from_polish);
    for dims in [[4, 3, 5], [4, 1, 5], [1, 1, 1]] {
        let constant = GridField::from_fn(dims, Aabb::UNIT, 3, |_, out| {
            out.copy_from_slice(&[1.0, -2.0, 0.5])
        })
        .unwrap();
        let expected = constant.num_voxels() as f64 * 5.25;
        let got = trilinear_energy(&constant);
        assert!(
            (got - expected).abs() <= 1e-12 * expected,
            "{dims:?}: {got} vs {expected}"
        );
    }
}

fn quick_fit(
    field: &GridField,
    nodes: [usize; 3],
    rank: usize,
    iterations: usize,
    seed: u64,
) -> MbdModel<HatGrid, BasisKernels> {
    let options = SolverOptions {
        max_iterations: iterations,
        seed,
        ..SolverOptions::default()
    };
    hat_mbd(rank, nodes, options)
        .fit(field, &NoProgress)
        .unwrap()
        .model
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(6))]

    /// No half-step raises the exact loss, the report's last loss is the returned model's, and
    /// the polish lowers the loss of a short stochastic solve.
    #[test]
    fn polish_never_increases_the_exact_loss(seed in 0u64..1000, rank in 1usize..4, random in proptest::bool::ANY) {
        let field = SyntheticField { dims: [6, 5, 4], dim: 7, harmonics: 3, seed }.build(Aabb::UNIT).unwrap();
        let options = PolishOptions { iterations: 4, tolerance: 0.0, ..PolishOptions::default() };
        if random {
            check_polish_descends(&field, random_model(&field, [3, 2, 2], rank, seed), &options)?;
        } else {
            check_polish_descends(&field, quick_fit(&field, [3, 2, 2], rank, 8, seed), &options)?;
        }
    }

    /// A field that is exactly a rank-L MBD (one global basis) is fitted to rounding.
    #[test]
    fn polish_is_exact_on_a_rank_l_field(seed in 0u64..1000, rank in 1usize..4) {
        let field = global_rank_field([5, 6, 4], 9, rank, seed);
        let model = quick_fit(&field, [2, 3, 2], rank, 4, seed);
        let options = PolishOptions { iterations: 6, lambda: 1e-7, ..PolishOptions::default() };
        check_polish_fits_exactly(&field, model, &options)?;
    }
}

/// The same model on 1 and 2 threads, bit for bit.
#[test]
fn polish_is_deterministic_across_thread_counts() {
    let field = SyntheticField {
        dims: [9, 8, 7],
        dim: 12,
        harmonics: 3,
        seed: 3,
    }
    .build(Aabb::UNIT)
    .unwrap();
    let model = quick_fit(&field, [3, 3, 2], 3, 6, 1);
    let options = PolishOptions {
        iterations: 3,
        tolerance: 0.0,
        ..PolishOptions::default()
    };
    check_polish_is_deterministic(&field, &model, &options);
}

/// Kernels other than those of `Mbd`, bad options and too large a basis are typed errors.
#[test]
fn polish_refuses_what_it_cannot_do() {
    let field = SyntheticField {
        dims: [6, 5, 4],
        dim: 5,
        harmonics: 2,
        seed: 1,
    }
    .build(Aabb::UNIT)
    .unwrap();
    let model = random_model(&field, [3, 2, 2], 2, 1);
    let bad = |options: PolishOptions, what: &str| match polish(
        &field,
        model.clone(),
        &options,
        &NoProgress,
    ) {
        Err(MbdError::InvalidOption { what: w, .. }) => assert_eq!(w, what),
        other => panic!("{what}: {other:?}"),
    };
    bad(
        PolishOptions {
            lambda: -1.0,
            ..Default::default()
        },
        "lambda",
    );
    bad(
        PolishOptions {
            lambda: f32::NAN,
            ..Default::default()
        },
        "lambda",
    );
    bad(
        PolishOptions {
            tolerance: f64::INFINITY,
            ..Default::default()
        },
        "tolerance",
    );
    bad(
        PolishOptions {
            cg_tolerance: 0.0,
            ..Default::default()
        },
        "cg_tolerance",
    );
    bad(
        PolishOptions {
            max_cg_iterations: 0,
            ..Default::default()
        },
        "max_cg_iterations",
    );
    // Coefficient kernels that are not one hat per voxel centre.
    let (coefficients, basis) = hat_kernels(&field, [3, 2, 2]);
    let coarse = HatGrid::new([3, 5, 4], Aabb::UNIT).unwrap();
    let wrong = MbdModel::new(
        coarse,
        basis.clone(),
        Array2::zeros((60, 2)),
        model.basis().clone(),
    )
    .unwrap();
    assert!(matches!(
        polish(&field, wrong, &PolishOptions::default(), &NoProgress),
        Err(MbdError::InvalidKernels {
            which: "coefficient",
            ..
        })
    ));
    // A basis grid over another box.
    let shifted = HatGrid::new([3, 2, 2], Aabb::new(Vec3::ZERO, Vec3::splat(2.0))).unwrap();
    let wrong = MbdModel::new(
        coefficients.clone(),
        shifted,
        model.coefficients().clone(),
        model.basis().clone(),
    )
    .unwrap();
    assert!(matches!(
        exact_loss(&field, &wrong, 1e-4),
        Err(MbdError::InvalidKernels { which: "basis", .. })
    ));
    // A model of another dimension.
    let other = MbdModel::new(
        coefficients,
        basis,
        model.coefficients().clone(),
        Array3::zeros((12, 2, 4)),
    )
    .unwrap();
    assert!(matches!(
        exact_loss(&field, &other, 1e-4),
        Err(MbdError::ShapeMismatch { .. })
    ));
    // Too many basis unknowns for the dense basis step.
    let big = hat_kernels(&field, [6, 5, 4]);
    let rank = POLISH_MAX_BASIS_UNKNOWNS / 120 + 1;
    let huge = MbdModel::new(
        big.0,
        big.1,
        Array2::zeros((120, rank)),
        Array3::zeros((120, rank, 5 * rank)),
    )
    .unwrap();
    let wide = SyntheticField {
        dims: [6, 5, 4],
        dim: 5 * rank,
        harmonics: 2,
        seed: 1,
    }
    .build(Aabb::UNIT)
    .unwrap();
    assert!(matches!(
        exact_loss(&wide, &huge, 1e-4),
        Err(MbdError::InvalidOption {
            what: "polish basis size",
            ..
        })
    ));
    // A single voxel along an axis.
    let flat = SyntheticField {
        dims: [6, 1, 4],
        dim: 5,
        harmonics: 2,
        seed: 1,
    }
    .build(Aabb::UNIT)
    .unwrap();
    let kernels = hat_kernels(&flat, [3, 2, 2]);
    let thin = MbdModel::new(
        kernels.0,
        kernels.1,
        Array2::zeros((24, 2)),
        Array3::zeros((12, 2, 5)),
    )
    .unwrap();
    assert!(matches!(
        exact_loss(&flat, &thin, 1e-4),
        Err(MbdError::InvalidKernels { .. })
    ));
    // Cancellation.
    let progress = prt_core::AtomicProgress::new();
    progress.cancel();
    let cancelled = polish(&field, model, &PolishOptions::default(), &progress).unwrap_err();
    assert!(cancelled.is_cancelled(), "{cancelled:?}");
}

/// The tolerance stops the polish once the mean gain of its last three iterations falls below
/// that fraction of the data term; tolerance 0 runs every iteration.
#[test]
fn polish_stops_on_its_tolerance() {
    let field = SyntheticField {
        dims: [6, 5, 4],
        dim: 7,
        harmonics: 3,
        seed: 2,
    }
    .build(Aabb::UNIT)
    .unwrap();
    let model = quick_fit(&field, [3, 2, 2], 2, 8, 2);
    let run = |tolerance: f64| {
        let options = PolishOptions {
            iterations: 4,
            tolerance,
            ..PolishOptions::default()
        };
        polish(&field, model.clone(), &options, &NoProgress)
            .unwrap()
            .1
    };
    let iterations = |report: &PolishReport| {
        report
            .history
            .iter()
            .filter(|r| r.step == PolishStep::Coefficients)
            .count()
    };
    let stopped = run(10.0);
    assert!(stopped.converged);
    assert_eq!(stopped.history[0].step, PolishStep::Basis);
    // The first chance to stop is the third iteration.
    assert_eq!(iterations(&stopped), 3);
    assert_eq!(
        stopped.history.last().unwrap().step,
        PolishStep::Coefficients
    );
    let full = run(0.0);
    assert!(!full.converged);
    assert_eq!(iterations(&full), 4);
}

/// Extremes: a zero field stays exactly zero (no error, zero energy), a constant field is
/// fitted to rounding at rank 1.
#[test]
fn polish_handles_zero_and_constant_fields() {
    let zero = GridField::new([4, 3, 5], Aabb::UNIT, 4).unwrap();
    let model = quick_fit(&zero, [2, 2, 3], 2, 4, 0);
    let (polished, report) = polish(&zero, model, &PolishOptions::default(), &NoProgress).unwrap();
    assert_eq!(report.last().energy, 0.0);
    assert_eq!(report.last().data, 0.0);
    assert!(polished.coefficients().iter().all(|&c| c == 0.0));
    let constant = GridField::from_fn([4, 3, 5], Aabb::UNIT, 4, |_, out| {
        out.copy_from_slice(&[0.5, -1.0, 2.0, 0.25])
    })
    .unwrap();
    let model = quick_fit(&constant, [2, 2, 3], 1, 4, 0);
    let options = PolishOptions {
        iterations: 4,
        ..PolishOptions::default()
    };
    let (_, report) = polish(&constant, model, &options, &NoProgress).unwrap();
    assert!(
        report.last().relative_mse() < 1e-12,
        "{:e}",
        report.last().relative_mse()
    );
}
