//! prt-wavelet hot paths: cube-map Haar and db2 round trips, one approximation step per policy.
use criterion::{Criterion, criterion_group, criterion_main};
use prt_wavelet::{
    Approximator, BandStrategy, CubemapHaar, CubemapLayout, Daubechies4, Policy, Weighting,
};
use rand::{Rng, SeedableRng};

fn transforms(c: &mut Criterion) {
    let mut rng = rand_pcg::Pcg64::seed_from_u64(1);
    let mut cube: Vec<f32> = (0..6 * 64 * 64).map(|_| rng.random()).collect();
    let mut haar = CubemapHaar::new(64).expect("size");
    let mut sig: Vec<f32> = (0..256).map(|_| rng.random()).collect();
    let mut db2 = Daubechies4::new(256).expect("size");
    let mut group = c.benchmark_group("wavelet_transform");
    group.bench_function("haar_cubemap_6x64x64_roundtrip", |b| {
        b.iter(|| {
            haar.forward(&mut cube).expect("forward");
            haar.inverse(&mut cube).expect("inverse");
        })
    });
    group.bench_function("db2_256_roundtrip", |b| {
        b.iter(|| {
            db2.forward(&mut sig).expect("forward");
            db2.inverse(&mut sig).expect("inverse");
        })
    });
    group.finish();
}

fn approximation(c: &mut Criterion) {
    let layout = CubemapLayout::new(64).expect("size");
    let n = layout.len();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(2);
    // Two nearby RGB lightings with a coarse-heavy spectrum; stepping alternates between them.
    let a: Vec<f32> = (0..3 * n)
        .map(|i| rng.random_range(-1.0f32..1.0) / (1.0 + (i % 4096) as f32).sqrt())
        .collect();
    let b: Vec<f32> = a
        .iter()
        .map(|v| v + rng.random_range(-0.05f32..0.05) * v.abs())
        .collect();
    let mut group = c.benchmark_group("wavelet_step_30_terms_rgb_64");
    for (name, policy) in [
        ("nwa", Policy::NonIncremental),
        ("bi", Policy::Incremental),
        ("pbi_l1_test", Policy::PerBand(BandStrategy::L1Test)),
        ("pbi_exhaustive", Policy::PerBand(BandStrategy::Exhaustive)),
        ("pbi_dealer", Policy::PerBand(BandStrategy::Dealer)),
    ] {
        let mut approx =
            Approximator::for_cubemap(&layout, 3, Weighting::Area, 30, policy).expect("config");
        let mut flip = false;
        group.bench_function(name, |bench| {
            bench.iter(|| {
                flip = !flip;
                approx
                    .step(if flip { &a } else { &b })
                    .expect("step")
                    .terms
                    .len()
            })
        });
    }
    group.finish();
}

criterion_group!(benches, transforms, approximation);
criterion_main!(benches);
