//! The front door: `Mbd::fit` is the expert entry points it names (the solver on its kernels,
//! MBD on clustered PCA's clusters, the polish of the solver's model), bit for bit; its
//! `BasisKernels` are the kernels they wrap; bad options and degenerate bases fail before any
//! work.

use glam::Vec3;
use proptest::prelude::*;
use prt_core::{
    Aabb, AtomicProgress, Compressor, GridField, KernelWeights, NoProgress, SpatialKernels,
};
use prt_kernels::HatGrid;
use prt_mbd::expert::{
    LabelKernels, POLISH_MAX_BASIS_UNKNOWNS, basis_box, exact_loss, fit_on_clusters, polish, solve,
};
use prt_mbd::*;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

mod common;
use common::{hat_kernels, hat_mbd, polish_trace, solve_trace};

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

fn clusters(count: usize) -> Basis {
    Basis::Clusters {
        count,
        smoothing: LabelSmoothing::default(),
    }
}

/// Both models have the same tensors, bit for bit.
fn assert_same_tensors<C: SpatialKernels, B: SpatialKernels, D: SpatialKernels>(
    a: &MbdModel<C, B>,
    b: &MbdModel<C, D>,
) {
    assert_eq!(a.coefficients(), b.coefficients());
    assert_eq!(a.basis(), b.basis());
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(4))]

    /// `Basis::HatGrid` is `expert::solve` on one hat per voxel centre and the hat grid over
    /// `expert::basis_box`, with the same rank and options; `compress` returns the fit's model.
    #[test]
    fn hat_grid_fit_is_the_solver_on_its_kernels(
        seed in 0u64..1000,
        rank in 1usize..4,
        nodes in [2usize..4, 2usize..4, 2usize..4],
    ) {
        let field = field([6, 5, 4], 7, seed);
        let solver = SolverOptions { max_iterations: 8, seed, ..SolverOptions::default() };
        let mbd = hat_mbd(rank, nodes, solver.clone());
        let fit = mbd.fit(&field, &NoProgress).unwrap();
        prop_assert!(fit.polish.is_none());
        let (coefficients, basis) = hat_kernels(&field, nodes);
        let (model, report) = solve(&field, coefficients, basis, rank, &solver, &NoProgress).unwrap();
        assert_same_tensors(&fit.model, &model);
        prop_assert_eq!(solve_trace(&fit.solve), solve_trace(&report));
        prop_assert_eq!(fit.solve.converged, report.converged);
        prop_assert!(matches!(fit.model.basis_kernels(), BasisKernels::HatGrid(h) if h.nodes() == nodes && h.domain() == basis_box(&field)));
        let compressed = mbd.compress(&field, &NoProgress).unwrap();
        assert_same_tensors(&compressed, &fit.model);
    }

    /// `BasisKernels` answers every `SpatialKernels` question as the kernels it wraps, at random
    /// points inside and around their box.
    #[test]
    fn basis_kernels_delegate_to_the_wrapped_kernels(
        seed in 0u64..1000,
        nodes in [2usize..5, 2usize..5, 2usize..5],
        dims in [1usize..5, 1usize..5, 1usize..5],
        len in 1usize..5,
        radius in 0usize..3,
        u in prop::collection::vec([-0.2f32..1.2, -0.2f32..1.2, -0.2f32..1.2], 8),
    ) {
        let bounds = Aabb::new(Vec3::new(-1.0, 0.5, 2.0), Vec3::new(2.0, 1.5, 2.8));
        let hats = HatGrid::new(nodes, bounds).unwrap();
        let mut rng = Pcg64Mcg::seed_from_u64(seed);
        let labels: Vec<u32> = (0..dims.iter().product())
            .map(|_| rng.random_range(0..len as u32))
            .collect();
        let smoothing = LabelSmoothing { radius, falloff: 0.5 };
        let labelled = LabelKernels::new(dims, bounds, &labels, len, None, &smoothing).unwrap();
        let points: Vec<Vec3> = u.iter().map(|&u| bounds.min + bounds.size() * Vec3::from(u)).collect();
        check_delegation(&hats, &BasisKernels::HatGrid(hats.clone()), &points)?;
        check_delegation(&labelled, &BasisKernels::Clusters(labelled.clone()), &points)?;
    }
}

/// Every `SpatialKernels` answer of `wrapped` is `inner`'s.
fn check_delegation<K: SpatialKernels>(
    inner: &K,
    wrapped: &BasisKernels,
    points: &[Vec3],
) -> Result<(), TestCaseError> {
    prop_assert_eq!(wrapped.len(), inner.len());
    prop_assert_eq!(wrapped.max_support(), inner.max_support());
    prop_assert_eq!(wrapped.domain(), inner.domain());
    prop_assert_eq!(wrapped.num_support_cells(), inner.num_support_cells());
    for i in 0..=inner.len() {
        prop_assert_eq!(wrapped.centre(i), inner.centre(i));
    }
    let (mut got, mut want) = (KernelWeights::default(), KernelWeights::default());
    for &x in points {
        let (a, b) = (wrapped.eval(x, &mut got), inner.eval(x, &mut want));
        prop_assert_eq!(a, b);
        prop_assert_eq!(&got, &want);
        prop_assert_eq!(wrapped.support_cell(x), inner.support_cell(x));
    }
    Ok(())
}

/// `Basis::Clusters` is `expert::fit_on_clusters` on `ClusteredPca::new(rank, count)`'s model,
/// bit for bit.
#[test]
fn cluster_fit_is_fit_on_clustered_pca() {
    let field = field([7, 6, 5], 9, 5);
    let mut mbd = Mbd::new(2, clusters(4));
    mbd.solver.max_iterations = 6;
    let fit = mbd.fit(&field, &NoProgress).unwrap();
    let cpca = ClusteredPca::new(2, 4)
        .compress(&field, &NoProgress)
        .unwrap();
    let expected = fit_on_clusters(&mbd, &field, &cpca, &NoProgress).unwrap();
    assert_same_tensors(&fit.model, &expected.model);
    assert_eq!(solve_trace(&fit.solve), solve_trace(&expected.solve));
    let labels = |model: &MbdModel<HatGrid, BasisKernels>| match model.basis_kernels() {
        BasisKernels::Clusters(k) => k.labels().to_vec(),
        other => panic!("not cluster kernels: {other:?}"),
    };
    assert_eq!(labels(&fit.model), labels(&expected.model));
    let compressed = mbd.compress(&field, &NoProgress).unwrap();
    assert_same_tensors(&compressed, &fit.model);
}

/// `Mbd { polish: Some(options) }` on a hat grid is `expert::polish` with those options applied
/// to the model of the same `Mbd` without polish, bit for bit.
#[test]
fn polish_option_is_the_polish_of_the_solver_model() {
    let field = field([7, 6, 5], 9, 5);
    let options = PolishOptions {
        iterations: 3,
        tolerance: 0.0,
        ..PolishOptions::default()
    };
    let mut mbd = Mbd::new(2, Basis::HatGrid { nodes: [3, 2, 2] });
    mbd.solver.max_iterations = 6;
    let solved = mbd.fit(&field, &NoProgress).unwrap();
    let (expected, expected_report) = polish(&field, solved.model, &options, &NoProgress).unwrap();
    mbd.polish = Some(options);
    let chained = mbd.fit(&field, &NoProgress).unwrap();
    assert_eq!(solve_trace(&chained.solve), solve_trace(&solved.solve));
    let report = chained.polish.as_ref().expect("a polish report");
    assert_eq!(report.initial, expected_report.initial);
    assert_eq!(polish_trace(report), polish_trace(&expected_report));
    assert_same_tensors(&chained.model, &expected);
    let compressed = mbd.compress(&field, &NoProgress).unwrap();
    assert_same_tensors(&compressed, &chained.model);
}

/// With the default polish after the default solver: the solver stops by its rule, the polish
/// never raises the exact loss, ends below where the solver stopped, and its report's last loss
/// is the returned model's.
#[test]
fn polish_after_the_solver_ends_below_it() {
    // A field on which the solver's rule fires before its cap (see the solver tests).
    let field = field([10, 10, 10], 24, 3);
    let mut mbd = Mbd::new(2, Basis::HatGrid { nodes: [3, 3, 3] });
    mbd.polish = Some(PolishOptions::default());
    let fit = mbd.fit(&field, &NoProgress).unwrap();
    let iterations = fit.solve.history.len();
    assert!(
        fit.solve.converged,
        "no stop within {iterations} iterations"
    );
    assert!(iterations < 128, "{iterations}");
    let polished = fit.polish.expect("a polish report");
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
    let exact = exact_loss(&field, &fit.model, PolishOptions::default().lambda).unwrap();
    assert!((exact.relative_mse() - end).abs() <= 1e-9 * end.max(1e-30) + 1e-15);
}

#[test]
fn polished_fit_is_the_same_on_one_and_two_threads() {
    let field = field([8, 6, 5], 10, 4);
    let mut mbd = Mbd::new(3, Basis::HatGrid { nodes: [3, 3, 2] });
    mbd.solver.max_iterations = 24;
    mbd.polish = Some(PolishOptions::default());
    let run = |threads| on_threads(threads, || mbd.fit(&field, &NoProgress).unwrap().model);
    assert_same_tensors(&run(1), &run(2));
}

/// Polish options the polish would refuse, and a basis too large for its dense basis step, fail
/// before any work: the progress never got a length, and a cancelled progress (which would end
/// the solve or the clustering first) still gets the option's error.
#[test]
fn bad_polish_options_fail_before_any_work() {
    let field = field([6, 6, 6], 8, 3);
    let with = |basis: Basis, change: fn(&mut PolishOptions)| {
        let mut options = PolishOptions::default();
        change(&mut options);
        Mbd {
            polish: Some(options),
            ..Mbd::new(2, basis)
        }
    };
    let hats = Basis::HatGrid { nodes: [2, 2, 2] };
    let mut cases = Vec::new();
    for basis in [hats, clusters(3)] {
        cases.push((with(basis, |o| o.cg_tolerance = 0.0), "cg_tolerance"));
        cases.push((with(basis, |o| o.tolerance = f64::NAN), "tolerance"));
        cases.push((
            with(basis, |o| o.max_cg_iterations = 0),
            "max_cg_iterations",
        ));
        cases.push((with(basis, |o| o.lambda = -1.0), "lambda"));
    }
    // One more cluster than the polish's basis step takes at rank 2.
    let too_many = POLISH_MAX_BASIS_UNKNOWNS / 2 + 1;
    cases.push((
        with(
            Basis::HatGrid {
                nodes: [20, 20, 20],
            },
            |_| {},
        ),
        "polish basis size",
    ));
    cases.push((with(clusters(too_many), |_| {}), "polish basis size"));
    for (mbd, name) in cases {
        let progress = AtomicProgress::new();
        let err = mbd.fit(&field, &progress).unwrap_err();
        assert!(
            matches!(err, MbdError::InvalidOption { what, .. } if what == name),
            "{name} on {:?}: {err:?}",
            mbd.basis
        );
        assert!(progress.is_empty(), "{name}: work started");
        let cancelled = AtomicProgress::new();
        cancelled.cancel();
        let err = mbd.fit(&field, &cancelled).unwrap_err();
        assert!(
            matches!(err, MbdError::InvalidOption { what, .. } if what == name),
            "{name} on {:?}, cancelled: {err:?}",
            mbd.basis
        );
    }
}

/// A hat grid with fewer than 2 nodes on an axis and zero clusters are typed errors, before any
/// work.
#[test]
fn degenerate_bases_are_typed_errors() {
    let field = field([4, 4, 4], 5, 1);
    for basis in [
        Basis::HatGrid { nodes: [1, 2, 2] },
        Basis::HatGrid { nodes: [2, 2, 1] },
        Basis::HatGrid { nodes: [1, 1, 1] },
        Basis::HatGrid { nodes: [0, 2, 2] },
        clusters(0),
    ] {
        let progress = AtomicProgress::new();
        let err = Mbd::new(2, basis).fit(&field, &progress).unwrap_err();
        assert!(
            matches!(err, MbdError::InvalidKernels { which: "basis", .. }),
            "{basis:?}: {err:?}"
        );
        assert!(progress.is_empty(), "{basis:?}: work started");
    }
}
