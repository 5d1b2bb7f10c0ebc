//! Moving Basis Decomposition: the cost of one stochastic solver iteration and of evaluating a
//! fitted model, at a few sizes (through prt-mbd's public API).
//!
//! `cargo bench -p prt-benches --bench mbd`
//!
//! One iteration is timed from the solver's own report (time after the last iteration minus the
//! initialisation), so the global-PCA initialisation and the final model assembly are excluded.

use std::hint::black_box;
use std::time::Duration;

use criterion::{
    BenchmarkId, Criterion, SamplingMode, Throughput, criterion_group, criterion_main,
};
use glam::Vec3;
use prt_core::{Aabb, GridField, NoProgress};
use prt_kernels::HatGrid;
use prt_mbd::expert::EvalScratch;
use prt_mbd::{Basis, Mbd, MbdModel, SolverOptions, SyntheticField};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

fn field(n: usize, dim: usize) -> GridField {
    SyntheticField {
        dims: [n; 3],
        dim,
        harmonics: 4,
        seed: 1,
    }
    .build(Aabb::UNIT)
    .expect("synthetic field")
}

/// (voxels per axis, basis nodes per axis, D, L): the paper's 324-D sizes of Figure 8 and the
/// 12-D rank-3 setting of the scale test.
const ITERATION_SIZES: [(usize, usize, usize, usize); 3] =
    [(16, 3, 324, 8), (32, 5, 324, 8), (64, 9, 12, 3)];

fn solver_iteration(c: &mut Criterion) {
    let mut group = c.benchmark_group("mbd_iteration");
    group
        .sampling_mode(SamplingMode::Flat)
        .sample_size(10)
        .warm_up_time(Duration::from_millis(500))
        .measurement_time(Duration::from_secs(8));
    for (n, b, dim, rank) in ITERATION_SIZES {
        let f = field(n, dim);
        group.throughput(Throughput::Elements(f.num_voxels() as u64));
        let id = BenchmarkId::from_parameter(format!("{n}^3_{b}^3_D{dim}_L{rank}"));
        group.bench_function(id, |bench| {
            bench.iter_custom(|iterations| {
                let mbd = Mbd {
                    solver: SolverOptions {
                        max_iterations: iterations as usize,
                        // Never stop early: every requested iteration runs.
                        tolerance: 0.0,
                        ..SolverOptions::default()
                    },
                    ..Mbd::new(rank, Basis::HatGrid { nodes: [b; 3] })
                };
                let report = mbd.fit(&f, &NoProgress).expect("mbd").solve;
                let end = report.history.last().map_or(0.0, |r| r.elapsed);
                Duration::from_secs_f64((end - report.init_seconds).max(0.0))
            });
        });
    }
    group.finish();
}

/// A model with random tensors: evaluation cost does not depend on the values.
fn random_model(n: usize, b: usize, dim: usize, rank: usize) -> MbdModel<HatGrid, HatGrid> {
    let mut rng = Pcg64Mcg::seed_from_u64(7);
    let coefficient_kernels = HatGrid::new([n; 3], Aabb::UNIT).expect("hat grid");
    let basis_kernels = HatGrid::new([b; 3], Aabb::UNIT).expect("hat grid");
    let coefficients =
        ndarray::Array2::from_shape_fn((n * n * n, rank), |_| rng.random::<f32>() - 0.5);
    let basis =
        ndarray::Array3::from_shape_fn((b * b * b, rank, dim), |_| rng.random::<f32>() - 0.5);
    MbdModel::new(coefficient_kernels, basis_kernels, coefficients, basis).expect("model")
}

fn model_eval(c: &mut Criterion) {
    const POINTS: usize = 4096;
    let mut group = c.benchmark_group("mbd_eval");
    group.throughput(Throughput::Elements(POINTS as u64));
    // The last size has the scale test's D, L and a coefficient tensor (200 MB) far beyond
    // the caches, like its 512 × 512 × 128 grid.
    for (n, b, dim, rank) in [
        (32, 5, 324, 8),
        (64, 9, 324, 8),
        (64, 9, 12, 3),
        (256, 17, 12, 3),
    ] {
        let model = random_model(n, b, dim, rank);
        let mut rng = Pcg64Mcg::seed_from_u64(11);
        let points: Vec<Vec3> = (0..POINTS)
            .map(|_| Vec3::new(rng.random(), rng.random(), rng.random()))
            .collect();
        let id = BenchmarkId::from_parameter(format!("{n}^3_{b}^3_D{dim}_L{rank}"));
        group.bench_function(id, |bench| {
            let mut scratch = EvalScratch::default();
            let mut out = vec![0.0f32; dim];
            bench.iter(|| {
                let mut sum = 0.0f32;
                for &p in &points {
                    model.eval_with(p, &mut scratch, &mut out).expect("eval");
                    sum += out[0];
                }
                black_box(sum)
            });
        });
    }
    group.finish();
}

criterion_group!(benches, solver_iteration, model_eval);
criterion_main!(benches);
