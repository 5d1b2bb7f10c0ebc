//! prt-linalg kernels: PCA fit, one k-means Lloyd iteration, NNLS solves.
//!
//! `cargo bench -p prt-benches --bench linalg` (add `--features lapack` for the OpenBLAS backend).
//! The side-by-side comparison with numpy / scikit-learn / scipy is `linalg_sweep`.
use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use ndarray::{Array1, Array2};
use prt_core::NoProgress;
use prt_linalg::synthetic::low_rank_matrix;
use prt_linalg::{KMeansOptions, Pca, PcaMethod, PcaOptions, kmeans, nnls, nnls_gram};
use rand::{Rng, SeedableRng};

const ROWS: usize = 8192;
const D: usize = 324;

fn pca(c: &mut Criterion) {
    let data = low_rank_matrix(ROWS, D, 40, 0.8, 1e-3, 0.0, 1).expect("valid shape");
    let mut group = c.benchmark_group("pca_8192x324_rank16");
    group.sample_size(10);
    group.throughput(Throughput::Elements(ROWS as u64));
    for (name, method) in [
        ("covariance", PcaMethod::Covariance),
        ("covariance_f64", PcaMethod::CovarianceF64),
        (
            "randomized_q1",
            PcaMethod::Randomized {
                oversample: 10,
                power_iters: 1,
                seed: 0,
            },
        ),
    ] {
        let opts = PcaOptions { method };
        group.bench_function(name, |b| {
            b.iter(|| Pca::fit(data.view(), 16, &opts, &NoProgress).expect("valid input"))
        });
    }
    group.finish();
}

fn kmeans_iteration(c: &mut Criterion) {
    let data = low_rank_matrix(ROWS, D, 40, 0.8, 1e-3, 0.0, 2).expect("valid shape");
    let mut group = c.benchmark_group("kmeans_8192x324_k125");
    group.sample_size(10);
    // Seeding plus one assignment step, and plus three more: the difference is 3 iterations.
    for iters in [1usize, 4] {
        let opts = KMeansOptions {
            max_iters: iters,
            tol: 0.0,
            seed: 0,
        };
        group.bench_function(format!("seed_plus_{iters}_iterations"), |b| {
            b.iter(|| kmeans(data.view(), 125, &opts, &NoProgress).expect("valid input"))
        });
    }
    group.finish();
}

fn nnls_solves(c: &mut Criterion) {
    let mut rng = rand_pcg::Pcg64::seed_from_u64(5);
    let a = Array2::from_shape_simple_fn((1000, 12), || rng.random_range(-1.0..1.0));
    let b = Array1::from_shape_simple_fn(1000, || rng.random_range(-1.0..1.0));
    let gram = a.t().dot(&a);
    let atb = a.t().dot(&b);
    let mut group = c.benchmark_group("nnls");
    group.bench_function("design_1000x12", |bench| {
        bench.iter(|| nnls(a.view(), b.view()).expect("valid input"))
    });
    group.bench_function("gram_12x12", |bench| {
        bench.iter(|| nnls_gram(gram.view(), atb.view()).expect("valid input"))
    });
    group.finish();
}

criterion_group!(benches, pca, kmeans_iteration, nnls_solves);
criterion_main!(benches);
