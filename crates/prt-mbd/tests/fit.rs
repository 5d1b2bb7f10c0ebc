//! Session-7 convergence options: several jittered samples per voxel
//! (`MbdOptions::samples_per_voxel`) and the two-phase fit (`PolishedMbd`: the stochastic solver
//! until it stalls, then exact polish sweeps until they stall).

use prt_core::{Aabb, AtomicProgress, GridField, NoProgress};
use prt_mbd::*;

fn field(dims: [usize; 3], dim: usize, seed: u64) -> GridField {
    SyntheticField {
        dims,
        dim,
        harmonics: 3,
        seed,
    }
    .build(Aabb::UNIT)
    .unwrap()
}

fn on_threads<T: Send>(threads: usize, run: impl FnOnce() -> T + Send) -> T {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap()
        .install(run)
}

#[test]
fn samples_per_voxel_must_be_a_power_of_two_up_to_eight() {
    let field = field([4, 4, 4], 5, 1);
    for bad in [0usize, 3, 16] {
        let err = Mbd {
            basis_nodes: [2, 2, 2],
            options: MbdOptions {
                rank: 2,
                samples_per_voxel: bad,
                ..MbdOptions::default()
            },
        }
        .fit(&field, &NoProgress)
        .unwrap_err();
        assert!(
            matches!(
                err,
                MbdError::InvalidOption {
                    what: "samples_per_voxel",
                    ..
                }
            ),
            "{bad}: {err:?}"
        );
    }
}

/// With 8 samples per voxel every accepted step still lowers the loss on its samples, the result
/// is the same on 1 and 2 threads, and it differs from the one-sample solve (the samples are
/// really used).
#[test]
fn more_samples_per_voxel_keep_the_solver_monotone_and_deterministic() {
    let field = field([8, 7, 6], 12, 9);
    let fit = |samples_per_voxel: usize| {
        Mbd {
            basis_nodes: [3, 3, 2],
            options: MbdOptions {
                rank: 3,
                max_iterations: 16,
                tolerance: 0.0,
                samples_per_voxel,
                ..MbdOptions::default()
            },
        }
        .fit(&field, &NoProgress)
        .unwrap()
    };
    let (one, _) = fit(1);
    let (a, report) = on_threads(1, || fit(8));
    let (b, _) = on_threads(2, || fit(8));
    assert_eq!(a.coefficients(), b.coefficients());
    assert_eq!(a.basis(), b.basis());
    assert_ne!(a.coefficients(), one.coefficients());
    assert_eq!(report.history.len(), 16);
    for r in &report.history {
        assert!(r.loss_after <= r.loss_before, "{r:?}");
    }
    // The held-out error is the same estimate whatever the training samples: it fell.
    let held: Vec<f64> = report.history.iter().filter_map(|r| r.held_out).collect();
    assert!(held.last().unwrap() < held.first().unwrap(), "{held:?}");
}

/// The two-phase fit: the solver stops by its rule (the hand-off), the polish never raises the exact
/// loss and ends below where the solver handed off, and the model is the one returned by
/// `Compressor::compress` too.
#[test]
fn polished_fit_hands_off_and_ends_below_the_solver() {
    // A field on which the solver's rule fires before its cap (see the solver tests).
    let field = field([10, 10, 10], 24, 3);
    let fit = PolishedMbd::new(
        [3, 3, 3],
        MbdOptions {
            rank: 2,
            ..MbdOptions::default()
        },
    );
    assert_eq!(fit.mbd.options.tolerance, MbdOptions::default().tolerance);
    assert_eq!(fit.polish.tolerance, POLISH_STALL_TOLERANCE);
    let (model, solved, polished) = fit.fit(&field, &NoProgress).unwrap();
    let iterations = solved.history.len();
    assert!(
        solved.converged,
        "no hand-off within {iterations} iterations"
    );
    assert!(iterations < 128, "{iterations}");
    let mut previous = polished.initial.loss();
    for r in &polished.history {
        assert!(r.loss.loss() <= previous, "{r:?}");
        previous = r.loss.loss();
    }
    let end = polished.last().relative_mse();
    assert!(
        end < polished.initial.relative_mse(),
        "{end:e} vs {:e}",
        polished.initial.relative_mse()
    );
    let exact = exact_loss(&field, &model, fit.polish.lambda).unwrap();
    assert!((exact.relative_mse() - end).abs() <= 1e-9 * end.max(1e-30) + 1e-15);
    let compressed = prt_core::Compressor::compress(&fit, &field, &NoProgress).unwrap();
    assert_eq!(compressed.coefficients(), model.coefficients());
    assert_eq!(compressed.basis(), model.basis());
}

#[test]
fn polished_fit_is_the_same_on_one_and_two_threads() {
    let field = field([8, 6, 5], 10, 4);
    let fit = PolishedMbd::new(
        [3, 3, 2],
        MbdOptions {
            rank: 3,
            max_iterations: 24,
            ..MbdOptions::default()
        },
    );
    let run = |threads| on_threads(threads, || fit.fit(&field, &NoProgress).unwrap().0);
    let (a, b) = (run(1), run(2));
    assert_eq!(a.coefficients(), b.coefficients());
    assert_eq!(a.basis(), b.basis());
}

/// Options the polish would refuse fail before the stochastic phase has run an iteration.
#[test]
fn polished_fit_refuses_bad_polish_options_before_solving() {
    let field = field([6, 6, 6], 8, 3);
    let base = PolishedMbd::new(
        [2, 2, 2],
        MbdOptions {
            rank: 2,
            ..MbdOptions::default()
        },
    );
    let mut cases = Vec::new();
    let mut bad = base.clone();
    bad.polish.cg_tolerance = 0.0;
    cases.push((bad, "cg_tolerance"));
    let mut bad = base.clone();
    bad.polish.tolerance = f64::NAN;
    cases.push((bad, "tolerance"));
    let mut bad = base.clone();
    bad.polish.max_cg_iterations = 0;
    cases.push((bad, "max_cg_iterations"));
    let mut bad = base.clone();
    bad.mbd.basis_nodes = [20, 20, 20];
    cases.push((bad, "polish basis size"));
    for (fit, name) in cases {
        let progress = AtomicProgress::new();
        let err = fit.fit(&field, &progress).unwrap_err();
        assert!(
            matches!(err, MbdError::InvalidOption { what, .. } if what == name),
            "{name}: {err:?}"
        );
        assert!(progress.is_empty(), "{name}: the solver started");
    }
}
