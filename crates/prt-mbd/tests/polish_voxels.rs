//! The exact polish with basis kernels stored at the voxel centres ([`LabelKernels`]): its loss is the continuous integral, it never increases, it fits an exactly
//! representable field, it is deterministic, and it refuses kernels of another grid.

use glam::Vec3;
use proptest::prelude::*;
use prt_core::{Aabb, Compressor, GridField, NoProgress};
use prt_mbd::expert::{LabelKernels, exact_loss, polish};
use prt_mbd::*;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

mod common;
use common::{
    check_exact_loss, check_polish_descends, check_polish_fits_exactly,
    check_polish_is_deterministic, global_rank_field, polish_trace, random_model, solve_trace,
};

fn random_labels(n: usize, len: usize, seed: u64) -> Vec<u32> {
    let mut rng = Pcg64Mcg::seed_from_u64(seed);
    (0..n).map(|_| rng.random_range(0..len as u32)).collect()
}

fn label_kernels(field: &GridField, len: usize, radius: usize, seed: u64) -> LabelKernels {
    let labels = random_labels(field.num_voxels(), len, seed);
    let smoothing = LabelSmoothing {
        radius,
        falloff: 0.5,
    };
    LabelKernels::new(field.dims(), field.bounds(), &labels, len, None, &smoothing).unwrap()
}

/// The exact loss is the continuous integral for label kernels (sharp and smoothed), on a box
/// that is not the unit cube.
#[test]
fn exact_loss_with_voxel_kernels_is_the_continuous_integral() {
    let bounds = Aabb::new(Vec3::new(-1.0, 0.0, 2.0), Vec3::new(2.0, 1.5, 5.0));
    let field = SyntheticField {
        dims: [6, 5, 7],
        dim: 5,
        harmonics: 3,
        seed: 4,
    }
    .build(bounds)
    .unwrap();
    for radius in [0, 2] {
        let model = random_model(&field, label_kernels(&field, 4, radius, 9), 2, 7);
        check_exact_loss(&field, &model);
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(6))]

    /// No half-step raises the exact loss, the report's last loss is the returned model's, and
    /// the polish lowers the loss of a short clustered solve.
    #[test]
    fn polish_with_label_kernels_never_increases_the_exact_loss(seed in 0u64..1000, rank in 1usize..4, radius in 0usize..3) {
        let field = SyntheticField { dims: [6, 5, 4], dim: 7, harmonics: 3, seed }.build(Aabb::UNIT).unwrap();
        let clustered = Mbd {
            rank,
            basis: Basis::Clusters { count: 4, smoothing: LabelSmoothing { radius, falloff: 0.5 } },
            solver: SolverOptions { max_iterations: 8, seed, ..SolverOptions::default() },
            polish: None,
            coarse_start: None,
            loss_weighting: None,
            centre_projection: false,
        };
        let model = clustered.fit(&field, &NoProgress).unwrap().model;
        let options = PolishOptions { iterations: 4, tolerance: 0.0, ..PolishOptions::default() };
        check_polish_descends(&field, model, &options)?;
    }

    /// A field that is exactly a rank-L MBD with one global basis (the same basis on every
    /// kernel, blended by a partition of unity, is that basis) is fitted to rounding after a
    /// short clustered solve.
    #[test]
    fn polish_with_label_kernels_is_exact_on_a_rank_l_field(seed in 0u64..1000, rank in 1usize..4) {
        let field = global_rank_field([5, 6, 4], 9, rank, seed);
        let mut clustered = Mbd::new(rank, Basis::Clusters { count: 3, smoothing: LabelSmoothing::default() });
        clustered.solver.max_iterations = 4;
        clustered.solver.seed = seed;
        let model = clustered.fit(&field, &NoProgress).unwrap().model;
        let options = PolishOptions { iterations: 16, lambda: 1e-7, ..PolishOptions::default() };
        check_polish_fits_exactly(&field, model, &options)?;
    }
}

/// The same model on 1 and 2 threads, bit for bit.
#[test]
fn polish_with_label_kernels_is_deterministic_across_thread_counts() {
    let field = SyntheticField {
        dims: [9, 8, 7],
        dim: 12,
        harmonics: 3,
        seed: 3,
    }
    .build(Aabb::UNIT)
    .unwrap();
    let model = random_model(&field, label_kernels(&field, 6, 2, 1), 3, 1);
    let options = PolishOptions {
        iterations: 2,
        tolerance: 0.0,
        ..PolishOptions::default()
    };
    check_polish_is_deterministic(&field, &model, &options);
}

/// Kernels stored on another grid (other dims, or the same dims over another box) are typed
/// errors.
#[test]
fn polish_refuses_voxel_kernels_of_another_grid() {
    let field = SyntheticField {
        dims: [6, 5, 4],
        dim: 5,
        harmonics: 2,
        seed: 1,
    }
    .build(Aabb::UNIT)
    .unwrap();
    let smoothing = LabelSmoothing::default();
    let other_dims =
        LabelKernels::new([6, 5, 5], Aabb::UNIT, &[0; 150], 1, None, &smoothing).unwrap();
    let shifted = Aabb::new(Vec3::splat(0.5), Vec3::splat(1.5));
    let other_box = LabelKernels::new([6, 5, 4], shifted, &[0; 120], 1, None, &smoothing).unwrap();
    for kernels in [other_dims, other_box] {
        let model = random_model(&field, kernels, 1, 2);
        assert!(matches!(
            exact_loss(&field, &model, 1e-4),
            Err(MbdError::InvalidKernels { which: "basis", .. })
        ));
        assert!(matches!(
            polish(&field, model, &PolishOptions::default(), &NoProgress),
            Err(MbdError::InvalidKernels { which: "basis", .. })
        ));
    }
}

/// [`Basis::Clusters`] with `polish` set is its solve followed by that polish, bit for bit, and
/// bad polish options fail before the solve.
#[test]
fn cluster_basis_chains_the_polish() {
    let field = SyntheticField {
        dims: [7, 6, 5],
        dim: 9,
        harmonics: 3,
        seed: 5,
    }
    .build(Aabb::UNIT)
    .unwrap();
    let options = PolishOptions {
        iterations: 3,
        tolerance: 0.0,
        ..PolishOptions::default()
    };
    let mut clustered = Mbd::new(
        2,
        Basis::Clusters {
            count: 4,
            smoothing: LabelSmoothing::default(),
        },
    );
    clustered.solver.max_iterations = 6;
    let solved = clustered.fit(&field, &NoProgress).unwrap();
    assert!(solved.polish.is_none());
    let (expected, expected_report) =
        polish(&field, solved.model.clone(), &options, &NoProgress).unwrap();
    clustered.polish = Some(options);
    let chained = clustered.fit(&field, &NoProgress).unwrap();
    assert_eq!(solve_trace(&chained.solve), solve_trace(&solved.solve));
    let polished = chained.polish.expect("a polish report");
    assert_eq!(polished.initial, expected_report.initial);
    assert_eq!(polish_trace(&polished), polish_trace(&expected_report));
    assert_eq!(chained.model.coefficients(), expected.coefficients());
    assert_eq!(chained.model.basis(), expected.basis());
    let before = exact_loss(&field, &solved.model, 1e-8).unwrap().loss();
    let after = exact_loss(&field, &chained.model, 1e-8).unwrap().loss();
    assert!(after < before, "polish {before:.4e} -> {after:.4e}");
    let compressed = clustered.compress(&field, &NoProgress).unwrap();
    assert_eq!(compressed.basis(), chained.model.basis());

    clustered.polish = Some(PolishOptions {
        tolerance: -1.0,
        ..PolishOptions::default()
    });
    let cancelled = prt_core::AtomicProgress::new();
    cancelled.cancel();
    // Rejected before the solve: a cancelled progress would otherwise end the fit first.
    assert!(matches!(
        clustered.fit(&field, &cancelled),
        Err(MbdError::InvalidOption { .. })
    ));
}
