//! Kernel evaluation throughput (points per second) for every family of prt-kernels: the trait's
//! sparse `eval` and the hat grids' allocation-free `eval_local`, plus Shepard against a
//! brute-force scan of all kernels (what the bucket grid saves).
use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use glam::Vec3;
use prt_core::{Aabb, KernelWeights, SpatialKernels};
use prt_kernels::{HatGrid, HybridKernels, Shepard, wendland_c2};
use rand::{Rng, SeedableRng};

const POINTS: usize = 4096;

fn random_points(rng: &mut rand_pcg::Pcg64Mcg, domain: Aabb, n: usize) -> Vec<Vec3> {
    (0..n)
        .map(|_| domain.min + Vec3::new(rng.random(), rng.random(), rng.random()) * domain.size())
        .collect()
}

fn bench_trait(c: &mut Criterion, name: &str, kernels: &dyn SpatialKernels, points: &[Vec3]) {
    let mut group = c.benchmark_group("kernels");
    group.throughput(Throughput::Elements(points.len() as u64));
    let mut w = KernelWeights::with_capacity(kernels.max_support());
    group.bench_function(name, |b| {
        b.iter(|| {
            let mut total = 0usize;
            for &p in points {
                kernels.eval(p, &mut w).expect("covered finite point");
                total += w.len();
            }
            std::hint::black_box(total)
        })
    });
    group.finish();
}

fn hat_grids(c: &mut Criterion) {
    let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(7);
    let domain = Aabb::new(Vec3::ZERO, Vec3::new(64.0, 16.0, 64.0));
    let points = random_points(&mut rng, domain, POINTS);
    let grid3 = HatGrid::new([33, 9, 33], domain).expect("valid grid");
    let grid2 = HatGrid::plane_xz(33, 33, domain).expect("valid grid");
    let grid1 = HatGrid::line_x(33, domain).expect("valid grid");
    let hybrid = HybridKernels::new(17, 17, domain).expect("valid grid");
    bench_trait(c, "hat3d_eval", &grid3, &points);
    bench_trait(c, "hat2d_eval", &grid2, &points);
    bench_trait(c, "hat1d_eval", &grid1, &points);
    bench_trait(c, "hybrid_eval", &hybrid, &points);

    let mut group = c.benchmark_group("kernels");
    group.throughput(Throughput::Elements(POINTS as u64));
    group.bench_function("hat3d_eval_local", |b| {
        b.iter(|| {
            let mut total = 0.0f32;
            for &p in &points {
                let local = grid3.eval_local(p).expect("finite point");
                total += local.weights()[7] + local.indices()[0] as f32;
            }
            std::hint::black_box(total)
        })
    });
    group.finish();
}

fn shepard(c: &mut Criterion) {
    let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(11);
    // 4096 centres in the unit cube (mean spacing 1/16), radius 1.5 / 16: ~14 kernels overlap
    // at a typical point. Queries near centres, so that they are covered.
    let centres = random_points(&mut rng, Aabb::UNIT, 4096);
    let radius = 1.5 / 16.0;
    let kernels = Shepard::with_radius(centres.clone(), radius).expect("valid kernels");
    let points: Vec<Vec3> = (0..POINTS)
        .map(|i| {
            let jitter = Vec3::new(rng.random(), rng.random(), rng.random()) - 0.5;
            centres[i % centres.len()] + jitter * radius
        })
        .collect();
    bench_trait(c, "shepard_4096_eval", &kernels, &points);

    let mut group = c.benchmark_group("kernels");
    group.throughput(Throughput::Elements(POINTS as u64));
    group.bench_function("shepard_4096_brute_force", |b| {
        b.iter(|| {
            let mut total = 0.0f64;
            for &p in &points {
                for &c in &centres {
                    total += wendland_c2(p.distance(c) as f64 / radius as f64);
                }
            }
            std::hint::black_box(total)
        })
    });
    group.finish();
}

criterion_group!(benches, hat_grids, shepard);
criterion_main!(benches);
