//! Trilinear sampling of a 324-D field (the MBD target), points per second.
use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use glam::Vec3;
use prt_core::{Aabb, GridField};
use rand::{Rng, SeedableRng};

fn sampling(c: &mut Criterion) {
    let field = GridField::from_fn([32, 32, 32], Aabb::UNIT, 324, |p, out| {
        for (k, o) in out.iter_mut().enumerate() {
            *o = (p.x * k as f32).sin() + p.y * p.z;
        }
    })
    .expect("finite synthetic field");
    let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(1);
    let points: Vec<Vec3> = (0..1024)
        .map(|_| Vec3::new(rng.random(), rng.random(), rng.random()))
        .collect();
    let mut out = vec![0.0f32; 324];
    let mut group = c.benchmark_group("grid_field");
    group.throughput(Throughput::Elements(points.len() as u64));
    group.bench_function("trilinear_sample_324d", |b| {
        b.iter(|| {
            for &p in &points {
                field.sample(p, &mut out).expect("finite point");
            }
            std::hint::black_box(&out);
        })
    });
    group.finish();
}

criterion_group!(benches, sampling);
criterion_main!(benches);
