//! One relit frame of prt-trace's per-pixel relighting engine (approximation step, transport
//! update, image): NWA, BI and PBI at 30 terms on a small traced Cornell-box transport (32²
//! pixels, 32² cube faces, direct light) under a synthetic sky with a sun turning 1° per frame.
use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use glam::Vec3;
use prt_core::NoProgress;
use prt_sphere::LatLongMap;
use prt_trace::camera::PinholeView;
use prt_trace::relight::{
    MethodRelighter, PixelTransportBaker, PixelTransportOptions, RelightMethod,
};
use prt_trace::{RayTracer, Scene};
use prt_wavelet::CubemapHaar;
use prt_wavelet::sequence::Rotation;

const CUBE: usize = 32;

/// A blue-to-white gradient with a small bright sun: all-frequency lighting without files.
fn sky() -> LatLongMap {
    let sun = Vec3::new(0.5, 0.6, 0.3).normalize();
    LatLongMap::from_fn(128, 64, |d| {
        let sky = Vec3::new(0.3, 0.5, 1.0) * (0.5 + 0.5 * d.y.max(0.0)) + Vec3::splat(0.2);
        if d.dot(sun) > 0.995 {
            sky + Vec3::splat(200.0)
        } else {
            sky
        }
    })
    .expect("finite sky")
}

fn frame(c: &mut Criterion) {
    let scene = Scene::cornell_box();
    let tracer = RayTracer::new(scene.triangles());
    let view = PinholeView::for_scene(&scene).expect("Cornell has bounds");
    let options = PixelTransportOptions {
        width: 32,
        height: 32,
        cube_size: CUBE,
        ..Default::default()
    };
    let transport = PixelTransportBaker::new(&scene, &tracer, view, options)
        .expect("options")
        .bake(&NoProgress)
        .expect("not cancelled");
    // Frames alternate between consecutive rotation steps, so every step has a real change.
    let rotation = Rotation::new(sky(), CUBE, 1f32.to_radians(), 1000).expect("rotation");
    let mut haar = CubemapHaar::new(CUBE).expect("size");
    let frames: Vec<(Vec<f32>, Vec<f32>)> = (0..16)
        .map(|f| {
            let texels = rotation.frame(f).expect("frame").into_data();
            let mut coefficients = texels.clone();
            haar.forward(&mut coefficients).expect("forward");
            (coefficients, texels)
        })
        .collect();
    let mut group = c.benchmark_group("pixel_relight_frame_cornell_32px_32cube");
    group.throughput(Throughput::Elements(transport.pixels() as u64));
    for method in [
        RelightMethod::Nwa(30),
        RelightMethod::Bi(30),
        RelightMethod::Pbi(30),
    ] {
        let mut relighter = MethodRelighter::new(&transport, method).expect("relighter");
        let mut next = 0;
        group.bench_function(method.name(), |b| {
            b.iter(|| {
                let (coefficients, texels) = &frames[next % frames.len()];
                next += 1;
                relighter.frame(coefficients, texels).expect("frame").bytes
            })
        });
    }
    group.finish();
}

criterion_group!(benches, frame);
criterion_main!(benches);
