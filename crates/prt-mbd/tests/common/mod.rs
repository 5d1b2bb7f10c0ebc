//! Fields shared by the integration tests.

use glam::Vec3;
use prt_core::{Aabb, GridField, KernelWeights, SpatialKernels};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

/// A field that is exactly a rank-`rank` MBD with one global basis: random voxel coefficients
/// times fixed random vectors; its trilinear interpolation is representable exactly.
#[allow(dead_code)] // not every test file uses every field
pub fn global_rank_field(dims: [usize; 3], dim: usize, rank: usize, seed: u64) -> GridField {
    let mut rng = Pcg64Mcg::seed_from_u64(seed);
    let basis: Vec<f32> = (0..rank * dim).map(|_| rng.random::<f32>() - 0.5).collect();
    GridField::from_fn(dims, Aabb::UNIT, dim, |_, out| {
        out.fill(0.0);
        for l in 0..rank {
            let c = rng.random::<f32>() * 2.0 - 1.0;
            for d in 0..dim {
                out[d] += c * basis[l * dim + d];
            }
        }
    })
    .unwrap()
}

/// The weights of `kernels` at `x` as a dense vector over the family.
#[allow(dead_code)] // not every test file uses every helper
pub fn dense<K: SpatialKernels>(kernels: &K, x: Vec3) -> Vec<f64> {
    let mut w = KernelWeights::default();
    kernels.eval(x, &mut w).unwrap();
    let mut out = vec![0.0; kernels.len()];
    for (i, wi) in w.iter() {
        out[i as usize] += f64::from(wi);
    }
    out
}

/// `∫ ‖f − f̂‖²` and `∫ ‖f‖²` (voxel units) by the composite midpoint rule with `s³` points per
/// voxel.
#[allow(dead_code)] // not every test file uses every helper
pub fn midpoint(field: &GridField, model: &dyn prt_core::FieldModel, s: usize) -> (f64, f64) {
    let d = field.dim();
    let (mut f, mut g) = (vec![0.0f32; d], vec![0.0f32; d]);
    let (mut err, mut energy) = (0.0, 0.0);
    let size = field.voxel_size();
    for v in 0..field.num_voxels() {
        let corner = field.centre_of(v) - 0.5 * size;
        for i in 0..s * s * s {
            let t = Vec3::new((i % s) as f32, (i / s % s) as f32, (i / (s * s)) as f32) + 0.5;
            let x = corner + t / s as f32 * size;
            field.sample(x, &mut f).unwrap();
            model.eval(x, &mut g).unwrap();
            for (a, b) in f.iter().zip(&g) {
                err += ((a - b) as f64).powi(2);
                energy += (*a as f64).powi(2);
            }
        }
    }
    let n = (s * s * s) as f64;
    (err / n, energy / n)
}

/// Checks [`prt_mbd::expert::exact_loss`] against the Richardson extrapolation of the midpoint rule
/// (8³ and 16³ points per voxel; either alone is off by more than 5e-5), and the ridge.
#[allow(dead_code)] // not every test file uses every helper
pub fn check_exact_loss<B: prt_mbd::expert::PolishBasis + Clone>(
    field: &GridField,
    model: &prt_mbd::MbdModel<prt_kernels::HatGrid, B>,
) {
    let exact = prt_mbd::expert::exact_loss(field, model, 1e-4).unwrap();
    let (err8, energy8) = midpoint(field, model, 8);
    let (err16, energy16) = midpoint(field, model, 16);
    let richardson = |coarse: f64, fine: f64| (4.0 * fine - coarse) / 3.0;
    let close = |a: f64, b: f64, tol: f64| (a - b).abs() <= tol * b.abs();
    assert!(
        !close(err16, exact.data, 5e-5),
        "midpoint alone should differ: {err16} vs {}",
        exact.data
    );
    assert!(
        close(richardson(err8, err16), exact.data, 2e-6),
        "{} vs {}",
        richardson(err8, err16),
        exact.data
    );
    assert!(
        close(richardson(energy8, energy16), exact.energy, 2e-6),
        "{} vs {}",
        richardson(energy8, energy16),
        exact.energy
    );
    let c2: f64 = model
        .coefficients()
        .iter()
        .map(|&v| (v as f64).powi(2))
        .sum();
    assert!(close(exact.ridge, 0.5e-4 * c2, 1e-6));
}

/// Polishes `model` and checks the polish's laws: the report starts at the model's exact loss,
/// no half-step raises it, the report ends at the returned model's exact loss, and that is
/// below the start.
#[allow(dead_code)] // not every test file uses every helper
pub fn check_polish_descends<B: prt_mbd::expert::PolishBasis + Clone>(
    field: &GridField,
    model: prt_mbd::MbdModel<prt_kernels::HatGrid, B>,
    options: &prt_mbd::PolishOptions,
) -> Result<(), proptest::test_runner::TestCaseError> {
    use proptest::prop_assert;
    let start = prt_mbd::expert::exact_loss(field, &model, options.lambda).unwrap();
    let (polished, report) =
        prt_mbd::expert::polish(field, model, options, &prt_core::NoProgress).unwrap();
    prop_assert!((report.initial.loss() - start.loss()).abs() <= 1e-9 * start.loss());
    let mut previous = report.initial.loss();
    for r in &report.history {
        prop_assert!(
            r.loss.loss() <= previous * (1.0 + 1e-12),
            "{:?}: {} > {previous}",
            r.step,
            r.loss.loss()
        );
        previous = r.loss.loss();
    }
    let end = prt_mbd::expert::exact_loss(field, &polished, options.lambda).unwrap();
    prop_assert!(
        (end.loss() - report.last().loss()).abs() <= 1e-9 * end.loss(),
        "{end:?} vs {:?}",
        report.last()
    );
    prop_assert!(
        end.loss() < start.loss(),
        "{} !< {}",
        end.loss(),
        start.loss()
    );
    Ok(())
}

/// Polishes `model` of a field that is exactly representable and checks that the exact and the
/// sampled relative MSE end below 1e-10.
#[allow(dead_code)] // not every test file uses every helper
pub fn check_polish_fits_exactly<B: prt_mbd::expert::PolishBasis + Clone>(
    field: &GridField,
    model: prt_mbd::MbdModel<prt_kernels::HatGrid, B>,
    options: &prt_mbd::PolishOptions,
) -> Result<(), proptest::test_runner::TestCaseError> {
    use proptest::prop_assert;
    let (polished, report) =
        prt_mbd::expert::polish(field, model, options, &prt_core::NoProgress).unwrap();
    let relative = report.last().relative_mse();
    prop_assert!(
        relative < 1e-10,
        "relative MSE {relative:e} (start {:e})",
        report.initial.relative_mse()
    );
    let evaluated = prt_mbd::evaluate(&polished, field, &prt_mbd::EvalOptions::default())
        .unwrap()
        .relative_mse;
    prop_assert!(evaluated < 1e-10, "evaluate {evaluated:e}");
    Ok(())
}

/// A model with random tensors: `Mbd`'s coefficient hats and the given basis kernels.
#[allow(dead_code)] // not every test file uses every helper
pub fn random_model<B: SpatialKernels>(
    field: &GridField,
    basis_kernels: B,
    rank: usize,
    seed: u64,
) -> prt_mbd::MbdModel<prt_kernels::HatGrid, B> {
    let coefficient_kernels =
        prt_kernels::HatGrid::new(field.dims(), prt_mbd::expert::voxel_centre_box(field)).unwrap();
    let mut rng = Pcg64Mcg::seed_from_u64(seed);
    let coefficients =
        ndarray::Array2::from_shape_fn((field.num_voxels(), rank), |_| rng.random::<f32>() - 0.5);
    let basis = ndarray::Array3::from_shape_fn((basis_kernels.len(), rank, field.dim()), |_| {
        rng.random::<f32>() - 0.5
    });
    prt_mbd::MbdModel::new(coefficient_kernels, basis_kernels, coefficients, basis).unwrap()
}

/// Polishes `model` on 1 and on 2 threads and checks that the models and the reports (every
/// half-step's kind, exact loss, acceptance and CG iterations, and the initial loss) are the
/// same bit for bit.
#[allow(dead_code)] // not every test file uses every helper
pub fn check_polish_is_deterministic<B: prt_mbd::expert::PolishBasis + Clone + Send + Sync>(
    field: &GridField,
    model: &prt_mbd::MbdModel<prt_kernels::HatGrid, B>,
    options: &prt_mbd::PolishOptions,
) {
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            prt_mbd::expert::polish(field, model.clone(), options, &prt_core::NoProgress).unwrap()
        })
    };
    let (one, report_one) = run(1);
    let (two, report_two) = run(2);
    assert_eq!(one.coefficients(), two.coefficients());
    assert_eq!(one.basis(), two.basis());
    assert_eq!(polish_trace(&report_one), polish_trace(&report_two));
    assert_eq!(report_one.initial, report_two.initial);
}

/// A polish report without its timings: every half-step's kind, exact loss, acceptance and CG
/// iterations.
#[allow(dead_code)] // not every test file uses every helper
pub fn polish_trace(
    report: &prt_mbd::PolishReport,
) -> Vec<(
    prt_mbd::expert::PolishStep,
    prt_mbd::expert::ExactLoss,
    bool,
    usize,
)> {
    report
        .history
        .iter()
        .map(|h| (h.step, h.loss, h.accepted, h.cg_iterations))
        .collect()
}

/// A solve report without its timings: every iteration's losses, held-out error and step.
#[allow(dead_code)] // not every test file uses every helper
pub fn solve_trace(report: &prt_mbd::SolveReport) -> Vec<(f64, f64, f64, Option<f64>, f32)> {
    report
        .history
        .iter()
        .map(|r| {
            (
                r.loss_before,
                r.data_before,
                r.loss_after,
                r.held_out,
                r.step,
            )
        })
        .collect()
}

/// The kernels [`prt_mbd::Basis::HatGrid`] puts on `field`: one coefficient hat per voxel
/// centre, and `nodes` basis hats over [`prt_mbd::expert::basis_box`].
#[allow(dead_code)] // not every test file uses every helper
pub fn hat_kernels(
    field: &GridField,
    nodes: [usize; 3],
) -> (prt_kernels::HatGrid, prt_kernels::HatGrid) {
    let coefficients =
        prt_kernels::HatGrid::new(field.dims(), prt_mbd::expert::voxel_centre_box(field)).unwrap();
    let basis = prt_kernels::HatGrid::new(nodes, prt_mbd::expert::basis_box(field)).unwrap();
    (coefficients, basis)
}

/// [`prt_mbd::Mbd`] of rank `rank` on a hat grid of `nodes`, with `solver`, no polish.
#[allow(dead_code)] // not every test file uses every helper
pub fn hat_mbd(rank: usize, nodes: [usize; 3], solver: prt_mbd::SolverOptions) -> prt_mbd::Mbd {
    prt_mbd::Mbd {
        solver,
        ..prt_mbd::Mbd::new(rank, prt_mbd::Basis::HatGrid { nodes })
    }
}

/// A `dims` field of 7-D vectors on the unit box, each entry `scale(p) · (1 + u)` with `u` uniform
/// in [−½, ½) from a seeded LCG: magnitudes that follow `scale` across the box.
#[allow(dead_code)] // not every test file uses every field
pub fn scaled_noise_field(dims: [usize; 3], seed: u64, scale: impl Fn(Vec3) -> f32) -> GridField {
    let mut state = seed
        .wrapping_mul(6364136223846793005)
        .wrapping_add(1442695040888963407);
    let mut next = move || {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((state >> 33) as f32 / (1u64 << 31) as f32) - 0.5
    };
    GridField::from_fn(dims, Aabb::UNIT, 7, |p, out| {
        let s = scale(p);
        out.iter_mut().for_each(|x| *x = s * (1.0 + next()));
    })
    .expect("field")
}
