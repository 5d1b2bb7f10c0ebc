//! The transfer-volume baker against analytic answers, brute force and its own laws.
use glam::Vec3;
use proptest::prelude::*;
use prt_core::{Aabb, AtomicProgress, NoProgress};
use prt_sphere::Sky;
use prt_trace::expert::{IndirectMode, block};
use prt_trace::lit::{constant_sky, incident_radiance};
use prt_trace::sh::{SH9, sh9};
use prt_trace::{BakeOptions, Scene, TRANSFER_DIM, TraceError, TransferBaker, TransferVolume};

fn bake(scene: &Scene, options: BakeOptions) -> TransferVolume {
    TransferBaker::new(scene, options)
        .and_then(|b| b.bake(&NoProgress))
        .expect("bake succeeds")
}

#[test]
fn empty_scene_direct_is_identity_and_indirect_zero() {
    let scene = Scene::empty();
    let bounds = Aabb::new(Vec3::splat(-1.0), Vec3::splat(1.0));
    let options = BakeOptions {
        resolution: [3, 2, 2],
        bounds: Some(bounds),
        rays_per_voxel: 36,
        ..Default::default()
    };
    let volume = bake(&scene, options);
    assert!(volume.valid.iter().all(|&v| v));
    for v in 0..volume.field.num_voxels() {
        let t = volume.field.voxel(v);
        for i in 0..SH9 {
            for j in 0..SH9 {
                let e = if i == j { 1.0 } else { 0.0 };
                assert!(
                    (t[i * SH9 + j] - e).abs() < 2e-6,
                    "voxel {v} D[{i}][{j}] = {}",
                    t[i * SH9 + j]
                );
            }
        }
        assert!(t[block(1).start..].iter().all(|&x| x == 0.0));
        // With D = I and no bounce, the incident radiance is the sky itself.
        let sky = Sky::default();
        let l = incident_radiance(t, &sky);
        for c in 0..3 {
            for i in 0..SH9 {
                assert!(
                    (l[c][i] - sky.sh[c][i]).abs() < 1e-5,
                    "voxel {v} l[{c}][{i}]"
                );
            }
        }
    }
    // Without explicit bounds an empty scene cannot be baked.
    assert!(matches!(
        TransferBaker::new(&scene, BakeOptions::default()),
        Err(TraceError::EmptyScene)
    ));
}

#[test]
fn closed_box_transfers_nothing_inside() {
    let scene = Scene::closed_box(1.0, Vec3::splat(0.8));
    let options = BakeOptions {
        resolution: [3, 3, 3],
        rays_per_voxel: 48,
        cache_rays: 16,
        ..Default::default()
    };
    let volume = bake(&scene, options);
    assert!(
        volume.valid.iter().all(|&v| v),
        "inside the box every hit is a front face"
    );
    for v in 0..volume.field.num_voxels() {
        for (k, &x) in volume.field.voxel(v).iter().enumerate() {
            assert!(x.abs() < 1e-6, "voxel {v} element {k} = {x}");
        }
    }
}

/// SH projection of the incident radiance above an infinite plane of albedo `rho` under a
/// constant sky `l`: `l` from the upper hemisphere, `rho l` from the lower one.
fn plane_projection(l: f32, rho: f32) -> [f32; SH9] {
    let pi = std::f32::consts::PI;
    let mut f = [0.0; SH9];
    f[0] = pi.sqrt() * l * (1.0 + rho); // ∫_H Y_0 = 2π Y_0 = √π on each hemisphere
    f[2] = 0.488_602_5 * pi * l * (1.0 - rho); // ∫_upper Y_2 = C1 π, lower -C1 π
    f
}

/// Per-voxel errors `l - projection` (R channel) for the ground plane, one row per voxel.
fn ground_plane_errors(rays: usize, seed: u64, rho: f32) -> Vec<[f32; SH9]> {
    let scene = Scene::ground_plane(1000.0, Vec3::splat(rho));
    let bounds = Aabb::new(Vec3::new(-1.0, 0.5, -1.0), Vec3::new(1.0, 1.5, 1.0));
    let options = BakeOptions {
        resolution: [4, 4, 4],
        bounds: Some(bounds),
        margin: 2.0,
        rays_per_voxel: rays,
        cache_rays: 8,
        seed,
        ..Default::default()
    };
    let volume = bake(&scene, options);
    let l = 2.0;
    let sky = [constant_sky(l); 3];
    let exact = plane_projection(l, rho);
    (0..volume.field.num_voxels())
        .map(|v| {
            assert!(volume.valid[v]);
            let [d, r, _, _] = volume.incident(v, &sky);
            let lit = incident_radiance(volume.field.voxel(v), &Sky::constant([l; 3]));
            assert!((0..SH9).all(|i| (lit[0][i] - d[i] - r[i]).abs() < 1e-5));
            std::array::from_fn(|i| d[i] + r[i] - exact[i])
        })
        .collect()
}

#[test]
fn ground_plane_under_constant_sky_matches_the_projection() {
    // 64 voxels with independent scrambles: 64 i.i.d. estimates of the same vector.
    let errors = ground_plane_errors(96, 3, 0.6);
    let n = errors.len() as f64;
    for i in 0..SH9 {
        let mean = errors.iter().map(|e| e[i] as f64).sum::<f64>() / n;
        let var = errors
            .iter()
            .map(|e| (e[i] as f64 - mean).powi(2))
            .sum::<f64>()
            / (n - 1.0);
        let se = (var / n).sqrt();
        // Unbiased: the mean error is within 5 standard errors of zero (plus float slack).
        assert!(
            mean.abs() <= 5.0 * se + 1e-5,
            "coefficient {i}: mean error {mean}, standard error {se}"
        );
    }
    // And the estimate is useful: the error of coefficient 2 is small relative to its value.
    let rms2 = (errors.iter().map(|e| (e[2] as f64).powi(2)).sum::<f64>() / n).sqrt();
    assert!(
        rms2 < 0.1 * plane_projection(2.0, 0.6)[2] as f64,
        "rms {rms2}"
    );
}

#[test]
fn monte_carlo_error_falls_at_least_like_one_over_sqrt_n() {
    let rms = |rays: usize| {
        let e = ground_plane_errors(rays, 17, 0.3);
        (e.iter()
            .flat_map(|x| x.iter())
            .map(|&x| (x as f64).powi(2))
            .sum::<f64>()
            / e.len() as f64)
            .sqrt()
    };
    let (e1, e4, e16) = (rms(24), rms(96), rms(384));
    // 1/√N predicts a factor 2 per quadrupling; stratification may do better. The slack of 1.4
    // covers the sampling spread of an RMS over 64 voxels.
    assert!(e4 < e1 / 2.0 * 1.4, "24 → 96 rays: {e1} → {e4}");
    assert!(e16 < e4 / 2.0 * 1.4, "96 → 384 rays: {e4} → {e16}");
    assert!(e16 > 0.0, "the estimate is random, not exact");
}

/// Mean indirect radiance (R) under a unit constant sky per voxel, over `seeds`.
fn indirect_means(mode: IndirectMode, seeds: std::ops::Range<u64>) -> Vec<Vec<f64>> {
    let scene = Scene::cornell_box();
    let sky = [constant_sky(1.0); 3];
    let y0 = sh9(Vec3::Y)[0];
    seeds
        .map(|seed| {
            let options = BakeOptions {
                resolution: [3, 3, 3],
                margin: -0.0,
                bounds: Some(Aabb::new(
                    Vec3::new(-0.8, 0.2, -0.8),
                    Vec3::new(0.8, 1.8, 0.8),
                )),
                rays_per_voxel: 96,
                cache_rays: 16,
                cache_spacing: Some(0.1),
                indirect: mode,
                seed,
                ..Default::default()
            };
            let v = bake(&scene, options);
            (0..v.field.num_voxels())
                .map(|k| {
                    if v.valid[k] {
                        (v.incident(k, &sky)[1][0] * y0) as f64
                    } else {
                        f64::NAN
                    }
                })
                .collect()
        })
        .collect()
}

#[test]
fn surface_cache_agrees_with_brute_force_within_noise() {
    let seeds = 6u64;
    let cache = indirect_means(IndirectMode::SurfaceCache, 0..seeds);
    let brute = indirect_means(IndirectMode::BruteForce, 100..100 + seeds);
    let voxels = cache[0].len();
    let stats = |runs: &[Vec<f64>], v: usize| {
        let xs: Vec<f64> = runs.iter().map(|r| r[v]).collect();
        let m = xs.iter().sum::<f64>() / xs.len() as f64;
        let var = xs.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (xs.len() - 1) as f64;
        (m, var)
    };
    let mut z2 = 0.0;
    let mut counted = 0;
    let (mut sum_c, mut sum_b) = (0.0, 0.0);
    for v in 0..voxels {
        let ((mc, vc), (mb, vb)) = (stats(&cache, v), stats(&brute, v));
        if mc.is_nan() || mb.is_nan() {
            continue;
        }
        let se2 = (vc + vb) / seeds as f64;
        z2 += (mc - mb).powi(2) / se2.max(1e-12);
        counted += 1;
        sum_c += mc;
        sum_b += mb;
    }
    assert!(counted >= 20, "{counted} valid voxels");
    // Mean squared z-score ~ 1 when both estimate the same quantity; the t-distribution of 6
    // seeds and the cache's interpolation bias widen it a little.
    let mz2 = z2 / counted as f64;
    assert!(mz2 < 4.0, "mean squared z-score {mz2}");
    assert!(
        (sum_c - sum_b).abs() < 0.03 * sum_b,
        "cache {sum_c} vs brute force {sum_b}"
    );
    assert!(sum_b > 0.0);
}

#[test]
fn bakes_are_identical_on_any_thread_count() {
    let scene = Scene::cornell_box();
    let options = BakeOptions {
        resolution: [5, 4, 3],
        rays_per_voxel: 48,
        cache_rays: 8,
        seed: 42,
        ..Default::default()
    };
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("pool");
        pool.install(|| bake(&scene, options.clone()))
    };
    let (a, b) = (run(1), run(3));
    assert_eq!(a.field, b.field);
    assert_eq!(a.valid, b.valid);
    let c = bake(
        &scene,
        BakeOptions {
            seed: 43,
            ..options
        },
    );
    assert_ne!(a.field, c.field, "the seed matters");
}

#[test]
fn cancellation_stops_the_bake() {
    let scene = Scene::cornell_box();
    let options = BakeOptions {
        resolution: [8, 8, 8],
        rays_per_voxel: 24,
        cache_rays: 8,
        ..Default::default()
    };
    let progress = AtomicProgress::cancel_after(1);
    let r = TransferBaker::new(&scene, options.clone()).and_then(|b| b.bake(&progress));
    assert!(matches!(r, Err(ref e) if e.is_cancelled()), "{r:?}");
    // Progress reaches its length on a full run.
    let progress = AtomicProgress::new();
    let v = TransferBaker::new(&scene, options)
        .and_then(|b| b.bake(&progress))
        .expect("bakes");
    assert_eq!(progress.position(), progress.len());
    assert_eq!(progress.len(), 512 * v.stats.rays_per_voxel as u64);
}

#[test]
fn voxels_inside_geometry_are_invalid_and_outside_voxels_are_skipped() {
    let scene = Scene::cornell_box();
    // A tiny grid inside the tall box (x ∈ [-0.71, 0.04], z ∈ [-0.67, 0.09], y < 1.2).
    let inside = Aabb::new(Vec3::new(-0.4, 0.5, -0.35), Vec3::new(-0.3, 0.7, -0.25));
    let inside_options = |resolution: [usize; 3]| BakeOptions {
        resolution,
        bounds: Some(inside),
        rays_per_voxel: 96,
        ..Default::default()
    };
    // A grid with no valid voxel at all is an error, not an all-zero volume.
    match TransferBaker::new(&scene, inside_options([2, 2, 2])).and_then(|b| b.bake(&NoProgress)) {
        Err(
            e @ TraceError::NoValidVoxels {
                voxels: 8,
                invalid: 8,
                skipped: 0,
            },
        ) => {
            // A library error names the option, not a command-line flag of some front end.
            let message = e.to_string();
            assert!(message.contains("BakeOptions::margin"), "{message}");
            assert!(!message.contains("--"), "{message}");
        }
        other => panic!("expected NoValidVoxels, got {:?}", other.map(|v| v.stats)),
    }
    // Stretched into the open room above the box, some voxels are valid.
    let tall = Aabb::new(inside.min, Vec3::new(-0.3, 1.9, -0.25));
    let v = bake(
        &scene,
        BakeOptions {
            bounds: Some(tall),
            ..inside_options([1, 8, 1])
        },
    );
    let invalid = v.stats.invalid_voxels;
    assert!((2..8).contains(&invalid), "{invalid} invalid");
    assert_eq!(v.stats.valid_voxels(), 8 - invalid);
    assert_eq!(v.stats.valid_fraction(), (8 - invalid) as f64 / 8.0);
    // Invalid voxels stop after their probe rays and are zero.
    assert_eq!(
        v.stats.voxel_rays,
        (invalid * 48 + (8 - invalid) * 96) as u64
    );
    for k in (0..8).filter(|&k| !v.valid[k]) {
        assert!(v.field.voxel(k).iter().all(|&x| x == 0.0));
    }
    // A grid twice the scene's size: voxels beyond bounds + margin are neither traced nor valid.
    let b = scene.bounds().expect("bounds");
    let big = Aabb::new(b.centre() - b.size(), b.centre() + b.size());
    let options = BakeOptions {
        resolution: [4, 4, 4],
        bounds: Some(big),
        margin: 0.1,
        rays_per_voxel: 24,
        cache_rays: 8,
        ..Default::default()
    };
    let v = bake(&scene, options);
    assert!(
        v.stats.skipped_voxels >= 56,
        "{} skipped",
        v.stats.skipped_voxels
    );
    for k in 0..64 {
        let c = v.field.centre_of(k);
        if !b.expand(0.1).contains(c) {
            assert!(!v.valid[k] && v.field.voxel(k).iter().all(|&x| x == 0.0));
        }
    }
}

#[test]
fn invalid_options_are_typed_errors() {
    let scene = Scene::cornell_box();
    for options in [
        BakeOptions {
            resolution: [0, 4, 4],
            ..Default::default()
        },
        BakeOptions {
            rays_per_voxel: 0,
            ..Default::default()
        },
        BakeOptions {
            margin: f32::NAN,
            ..Default::default()
        },
        BakeOptions {
            cache_spacing: Some(-1.0),
            ..Default::default()
        },
        BakeOptions {
            max_backface_fraction: 2.0,
            ..Default::default()
        },
        BakeOptions {
            bounds: Some(Aabb {
                min: Vec3::ONE,
                max: Vec3::ZERO,
            }),
            ..Default::default()
        },
    ] {
        assert!(matches!(
            TransferBaker::new(&scene, options),
            Err(TraceError::InvalidOption { .. })
        ));
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(16))]
    /// At any point: D is symmetric with 0 ⪯ D ⪯ I (exact for rotated icosahedra), and under a
    /// constant sky the mean indirect radiance is at most max albedo x the occluded fraction.
    #[test]
    fn transfer_laws_hold_anywhere_in_the_cornell_box(
        x in -0.95f32..0.95, y in 0.05f32..1.95, z in -0.95f32..1.5, seed in 0u64..1000, probe in prop::array::uniform9(-1f32..1.0),
    ) {
        let scene = Scene::cornell_box();
        let p = Vec3::new(x, y, z);
        let options = BakeOptions {
            resolution: [1, 1, 1],
            bounds: Some(Aabb::new(p, p + Vec3::splat(1e-3))),
            margin: 1.0,
            rays_per_voxel: 48,
            probe_rays: 48,
            max_backface_fraction: 1.0,
            cache_rays: 8,
            cache_spacing: Some(0.25),
            seed,
            ..Default::default()
        };
        let v = bake(&scene, options);
        let t = v.field.voxel(0);
        prop_assert_eq!(t.len(), TRANSFER_DIM);
        let d = &t[block(0)];
        let mut quad = 0.0f64;
        for i in 0..SH9 {
            for j in 0..SH9 {
                prop_assert!((d[i * SH9 + j] - d[j * SH9 + i]).abs() < 1e-6);
                quad += (probe[i] * d[i * SH9 + j] * probe[j]) as f64;
            }
        }
        let norm2: f64 = probe.iter().map(|&a| (a as f64).powi(2)).sum();
        prop_assert!(quad >= -1e-5 && quad <= norm2 * (1.0 + 1e-5), "x^T D x = {} for |x|² = {}", quad, norm2);
        let y0 = sh9(Vec3::Y)[0];
        let occluded = 1.0 - d[0] as f64;
        let max_albedo = scene.materials().iter().map(|m| m.albedo.max_element()).fold(0.0, f32::max) as f64;
        let sky = [constant_sky(1.0); 3];
        let l = v.incident(0, &sky);
        for c in 1..4 {
            let mean = (l[c][0] * y0) as f64;
            prop_assert!(mean >= -1e-6 && mean <= max_albedo * occluded + 1e-5, "channel {}: {} > {} x {}", c, mean, max_albedo, occluded);
        }
    }
}

#[test]
fn a_flat_scene_gets_a_grid_one_voxel_thick() {
    // All triangles in the plane y = 0 and no margin: the box has no height.
    let scene = Scene::ground_plane(1.0, Vec3::splat(0.5));
    let options = BakeOptions {
        resolution: [4, 2, 4],
        rays_per_voxel: 24,
        cache_rays: 8,
        ..Default::default()
    };
    let baker = TransferBaker::new(&scene, options.clone()).expect("a flat scene is accepted");
    let g = baker.grid_bounds();
    // Longest axis 2 over 4 voxels: 0.5 thick, centred on the plane; x and z untouched.
    assert_eq!(g.min, Vec3::new(-1.0, -0.25, -1.0));
    assert_eq!(g.max, Vec3::new(1.0, 0.25, 1.0));
    let v = baker.bake(&NoProgress).expect("bakes");
    assert!(v.stats.valid_voxels() > 0);
    // A margin already gives thickness: nothing is added.
    let with_margin = TransferBaker::new(
        &scene,
        BakeOptions {
            margin: 0.1,
            ..options
        },
    )
    .expect("accepted");
    assert!((with_margin.grid_bounds().size().y - 0.2).abs() < 1e-6);
}

/// Adaptive sampling and the denoiser give the same bits on 1 and 3 threads, and adaptive
/// sampling spends fewer rays than its cap.
#[test]
fn adaptive_sampling_and_the_denoiser_are_deterministic_on_any_thread_count() {
    let scene = Scene::cornell_box();
    let options = BakeOptions {
        resolution: [8, 8, 8],
        rays_per_voxel: 480,
        cache_rays: 16,
        seed: 11,
        adaptive: Some(prt_trace::AdaptiveSampling {
            target_error: 0.2,
            min_rays: 48,
        }),
        denoise: Some(prt_trace::DenoiseOptions::default()),
        ..Default::default()
    };
    let on = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("thread pool")
            .install(|| bake(&scene, options.clone()))
    };
    let (one, three) = (on(1), on(3));
    assert_eq!(one.valid, three.valid);
    assert_eq!(one.field.data(), three.field.data());
    assert_eq!(one.stats.voxel_rays, three.stats.voxel_rays);
    let valid = one.stats.valid_voxels() as u64;
    assert!(
        one.stats.voxel_rays < valid * 480 * 3 / 4,
        "{} rays for {valid} valid voxels",
        one.stats.voxel_rays
    );
}
