//! Per-pixel wavelet transport: sparsification, determinism, the file round trip, the engine's
//! exact product and the bounce against a brute-force estimate.

use glam::Vec3;
use proptest::prelude::*;
use prt_core::NoProgress;
use prt_texture::Limits;
use prt_trace::camera::PinholeView;
use prt_trace::relight::{
    Bounce, PixelRelighter, PixelTransport, PixelTransportBaker, PixelTransportOptions, Sparsify,
};
use prt_trace::{RayTracer, Scene};
use prt_wavelet::{BandMode, CubemapHaar, FrameUpdate, Term};
use rand::{Rng, SeedableRng};

fn tiny(bounce: Option<Bounce>) -> PixelTransportOptions {
    PixelTransportOptions {
        width: 8,
        height: 6,
        cube_size: 4,
        samples: 2,
        sparsify: Sparsify {
            energy: 1.0,
            max_terms: 96,
        },
        bounce,
        ..Default::default()
    }
}

fn bake(scene: &Scene, options: PixelTransportOptions) -> PixelTransport {
    let tracer = RayTracer::new(scene.triangles());
    let view = PinholeView::for_scene(scene).unwrap();
    PixelTransportBaker::new(scene, &tracer, view, options)
        .unwrap()
        .bake(&NoProgress)
        .unwrap()
}

proptest! {
    #[test]
    fn sparsify_keeps_the_energy_asked_for(
        row in prop::collection::vec(-10.0f32..10.0, 1..200),
        energy in 0.05f32..1.0,
        max_terms in 1usize..300,
    ) {
        let kept = Sparsify { energy, max_terms }.keep(&row, &mut Vec::new());
        prop_assert!(kept.len() <= max_terms);
        prop_assert!(kept.windows(2).all(|w| w[0].0 < w[1].0));
        let total: f64 = row.iter().map(|&v| (v as f64).powi(2)).sum();
        let got: f64 = kept.iter().map(|&(_, v)| (v as f64).powi(2)).sum();
        let nonzero = row.iter().filter(|&&v| v != 0.0).count();
        if kept.len() < max_terms.min(nonzero) {
            prop_assert!(got >= energy as f64 * total * (1.0 - 1e-9));
            // The fewest: without the smallest kept entry the energy is not reached.
            let smallest = kept.iter().map(|e| (e.1 as f64).powi(2)).fold(f64::MAX, f64::min);
            prop_assert!(got - smallest < energy as f64 * total);
        }
        // Every kept magnitude is at least every dropped one.
        let least_kept = kept.iter().map(|e| e.1.abs()).fold(f32::MAX, f32::min);
        for (j, v) in row.iter().enumerate() {
            if !kept.iter().any(|e| e.0 as usize == j) {
                prop_assert!(v.abs() <= least_kept);
            }
        }
    }
}

#[test]
fn bake_is_identical_on_any_thread_count_and_survives_a_file() {
    let scene = Scene::cornell_box();
    let options = tiny(Some(Bounce { gathers: 3 }));
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap()
        .install(|| bake(&scene, options));
    let two = rayon::ThreadPoolBuilder::new()
        .num_threads(3)
        .build()
        .unwrap()
        .install(|| bake(&scene, options));
    assert_eq!(one, two);
    assert_eq!(one.transport.len(), 3);
    assert!(one.nnz() > 0);

    let dir = std::env::temp_dir().join(format!("prt-pixel-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("t.prtpx");
    one.write(&path).unwrap();
    let back = PixelTransport::read(&path, &Limits::default()).unwrap();
    assert_eq!(back, one);

    // Every truncation is a typed error, never a panic.
    let bytes = std::fs::read(&path).unwrap();
    for cut in [0, 7, 20, 60, 100, bytes.len() / 2, bytes.len() - 1] {
        std::fs::write(&path, &bytes[..cut]).unwrap();
        assert!(
            PixelTransport::read(&path, &Limits::default()).is_err(),
            "{cut}"
        );
    }
    let mut wrong = bytes.clone();
    wrong[8] = 9; // version
    std::fs::write(&path, &wrong).unwrap();
    assert!(PixelTransport::read(&path, &Limits::default()).is_err());
    std::fs::remove_dir_all(&dir).unwrap();
}

/// The engine fed every coefficient is the dense product `albedo ⊙ (T L) + emission`.
#[test]
fn a_full_update_gives_the_exact_product() {
    let scene = Scene::cornell_box();
    for bounce in [None, Some(Bounce { gathers: 2 })] {
        let t = bake(&scene, tiny(bounce));
        let cols = t.cols();
        let mut rng = rand_pcg::Pcg64::seed_from_u64(3);
        let lighting: Vec<f32> = (0..3 * cols).map(|_| rng.random_range(-1.0..2.0)).collect();
        let update = FrameUpdate {
            modes: vec![BandMode::Replace; 1],
            terms: (0..cols as u32)
                .map(|index| Term { index, band: 0 })
                .collect(),
            values: (0..cols)
                .flat_map(|j| [lighting[j], lighting[cols + j], lighting[2 * cols + j]])
                .collect(),
            residual: 0.0,
        };
        let mut engine = PixelRelighter::new(&t, 1).unwrap();
        engine.apply(&update).unwrap();
        let image = engine.image();
        let dense: Vec<Vec<f32>> = t.transport.iter().map(|s| s.to_dense()).collect();
        for p in 0..t.pixels() {
            for c in 0..3 {
                let d = &dense[if dense.len() == 1 { 0 } else { c }];
                let product: f64 = (0..cols)
                    .map(|j| d[p * cols + j] as f64 * lighting[c * cols + j] as f64)
                    .sum();
                let want = product as f32 * t.albedo[p][c] + t.emission[p][c];
                let got = image[p][c];
                assert!(
                    (got - want).abs() <= 1e-4 * (1.0 + want.abs()),
                    "{p} {c}: {got} {want}"
                );
            }
        }
    }
}

/// Under constant white light the direct row integrates to the sky visibility (cosine
/// weighted), and the bounce adds `ρ_h` times the secondary point's visibility, averaged over
/// cosine-distributed gathers. A brute-force estimate with independent random rays (a
/// cosine-weighted ray to the first hit, then one cosine-weighted ray from there that must
/// escape) agrees within its Monte Carlo noise, per channel.
#[test]
fn the_bounce_matches_a_brute_force_estimate() {
    let scene = Scene::cornell_box();
    let gathers = 256;
    let mut options = tiny(Some(Bounce { gathers }));
    options.width = 4;
    options.height = 4;
    options.sparsify.max_terms = 96;
    let t = bake(&scene, options);
    let tracer = RayTracer::new(scene.triangles());
    let view = PinholeView::for_scene(&scene).unwrap();
    let gbuffer = prt_trace::camera::GBuffer::render(&scene, &tracer, &view, 4, 4).unwrap();
    let offset = 1e-4 * scene.bounds().unwrap().size().length();
    // Constant light 1 in the wavelet domain: the scaling coefficient of every face.
    let mut ones = vec![1.0f32; t.cols()];
    CubemapHaar::new(4).unwrap().forward(&mut ones).unwrap();
    let dense: Vec<Vec<f32>> = t.transport.iter().map(|s| s.to_dense()).collect();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(11);
    let cosine = |n: Vec3, rng: &mut rand_pcg::Pcg64| {
        let (u1, u2): (f32, f32) = (rng.random(), rng.random());
        let (r, phi) = (u1.sqrt(), std::f32::consts::TAU * u2);
        let (b1, b2) = n.any_orthonormal_pair();
        (b1 * r * phi.cos() + b2 * r * phi.sin() + n * (1.0 - u1).max(0.0).sqrt()).normalize()
    };
    let (mut checked, samples) = (0, 20_000);
    for (p, point) in gbuffer.points.iter().enumerate() {
        let Some(point) = point else { continue };
        let origin = point.position + point.normal * offset;
        let mut sum = [0.0f64; 3];
        let mut direct = 0.0f64;
        for _ in 0..samples {
            let dir = cosine(point.normal, &mut rng);
            match tracer.closest_hit(origin, dir, 0.0, f32::INFINITY) {
                None => direct += 1.0,
                Some(hit) => {
                    let material = scene.material_of(hit.triangle as usize);
                    if !(hit.front_face || material.double_sided) {
                        continue;
                    }
                    let n = if hit.front_face {
                        hit.normal
                    } else {
                        -hit.normal
                    };
                    let h = origin + dir * hit.t + n * offset;
                    let out = cosine(n, &mut rng);
                    if !tracer.occluded(h, out, 0.0, f32::INFINITY) {
                        for (s, a) in sum.iter_mut().zip(material.albedo.to_array()) {
                            *s += a as f64;
                        }
                    }
                }
            }
        }
        for c in 0..3 {
            let baked: f64 = (0..t.cols())
                .map(|j| dense[c][p * t.cols() + j] as f64 * ones[j] as f64)
                .sum();
            let brute = (direct + sum[c]) / samples as f64;
            // Brute-force noise ~ 0.5/sqrt(samples) ≈ 0.004; the baked gathers (256 Sobol'
            // rays) and the cube's horizon texels add a little more.
            assert!(
                (baked - brute).abs() < 0.03,
                "pixel {p} channel {c}: baked {baked}, brute force {brute}"
            );
        }
        checked += 1;
    }
    assert!(checked >= 8, "{checked} pixels hit");
}

#[test]
fn bad_options_are_typed_errors() {
    let scene = Scene::cornell_box();
    let tracer = RayTracer::new(scene.triangles());
    let view = PinholeView::for_scene(&scene).unwrap();
    for options in [
        PixelTransportOptions {
            cube_size: 12,
            ..tiny(None)
        },
        PixelTransportOptions {
            sparsify: Sparsify {
                energy: 0.0,
                max_terms: 4,
            },
            ..tiny(None)
        },
        tiny(Some(Bounce { gathers: 0 })),
        PixelTransportOptions {
            width: 0,
            ..tiny(None)
        },
    ] {
        assert!(PixelTransportBaker::new(&scene, &tracer, view, options).is_err());
    }
    assert!(PixelTransportBaker::new(&Scene::empty(), &tracer, view, tiny(None)).is_err());
}
