//! Ray throughput of prt-trace's CWBVH (closest hit and shadow, on the detected and the baseline
//! instruction set) and a small Cornell bake.
use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use glam::Vec3;
use prt_core::NoProgress;
use prt_trace::{BakeOptions, RayTracer, Scene, TransferBaker};
use rand::{Rng, SeedableRng};

fn rays(c: &mut Criterion) {
    let scene = Scene::cornell_box();
    let tracer = RayTracer::new(scene.triangles());
    let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(1);
    let batch: Vec<(Vec3, Vec3)> = (0..4096)
        .map(|_| {
            let o = Vec3::new(
                rng.random_range(-1.0..1.0),
                rng.random_range(0.0..2.0),
                rng.random_range(-1.0..1.0),
            );
            let d = Vec3::new(
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
            );
            (o, d.normalize_or(Vec3::Y))
        })
        .collect();
    let mut group = c.benchmark_group("cornell_rays");
    group.throughput(Throughput::Elements(batch.len() as u64));
    group.bench_function("closest", |b| {
        b.iter(|| tracer.closest_hits(&batch, 0.0, f32::INFINITY))
    });
    group.bench_function("shadow", |b| {
        b.iter(|| tracer.occluded_batch(&batch, 0.0, f32::INFINITY))
    });
    // The same queries without the run-time-selected instruction set (when it is wider).
    let baseline = tracer.clone().with_baseline_instruction_set();
    group.bench_function("closest_baseline_isa", |b| {
        b.iter(|| baseline.closest_hits(&batch, 0.0, f32::INFINITY))
    });
    group.bench_function("shadow_baseline_isa", |b| {
        b.iter(|| baseline.occluded_batch(&batch, 0.0, f32::INFINITY))
    });
    group.finish();
}

fn bake(c: &mut Criterion) {
    let scene = Scene::cornell_box();
    let options = BakeOptions {
        resolution: [8; 3],
        rays_per_voxel: 96,
        cache_rays: 32,
        seed: 1,
        ..Default::default()
    };
    let baker = TransferBaker::new(&scene, options).expect("Cornell is not empty");
    let mut group = c.benchmark_group("cornell_bake");
    group.sample_size(10);
    group.throughput(Throughput::Elements(512));
    group.bench_function("8^3_96_rays", |b| {
        b.iter(|| baker.bake(&NoProgress).expect("not cancelled"))
    });
    group.finish();
}

criterion_group!(benches, rays, bake);
criterion_main!(benches);
