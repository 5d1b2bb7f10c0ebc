//! The bake's laws: determinism, non-negativity, the exact cases, budget and cancellation.

use std::sync::atomic::{AtomicU64, Ordering};

use glam::Vec3;
use prt_core::{NoProgress, Progress};
use prt_lightmap::{
    Encoder, Lighting, LightmapBasis, LightmapConfig, LightmapError, UnwrapConfig, bake_lightmap,
    unwrap_charts,
};
use prt_trace::Scene;
use prt_trace::manylight::SunAndUniformSky;

fn cornell_atlas(scene: &Scene) -> prt_lightmap::Atlas {
    unwrap_charts(
        scene.triangles(),
        &UnwrapConfig {
            texels_per_metre: 4.0,
            ..Default::default()
        },
    )
    .unwrap()
}

fn sky_only(radiance: f32) -> Lighting {
    Lighting {
        sun_sky: Some(SunAndUniformSky {
            sun_direction: Vec3::NEG_Y,
            sun_irradiance: Vec3::ZERO,
            sky_radiance: Vec3::splat(radiance),
        }),
    }
}

#[test]
fn a_seed_gives_the_same_lightmap_on_any_thread_count() {
    let scene = Scene::cornell_box();
    let atlas = cornell_atlas(&scene);
    for encoder in [Encoder::PlsqNonNegative, Encoder::LeastSquares] {
        let config = LightmapConfig {
            samples: 8,
            pass_samples: 3,
            encoder,
            ..Default::default()
        };
        let bake = |threads| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| {
                bake_lightmap(&scene, &atlas, &config, &NoProgress, &mut |_| {}).unwrap()
            })
        };
        let (one, two) = (bake(1), bake(2));
        assert_eq!(one, two, "{encoder:?}");
        let other_seed = bake_lightmap(
            &scene,
            &atlas,
            &LightmapConfig { seed: 2, ..config },
            &NoProgress,
            &mut |_| {},
        )
        .unwrap();
        assert_ne!(one.lightmap.irradiance, other_seed.lightmap.irradiance);
    }
}

/// Non-negative PLSQ into non-negative functions (SG, ambient dice) reconstructs no negative
/// radiance anywhere; plain PLSQ on the same samples does ring below zero.
#[test]
fn the_non_negative_encoder_gives_non_negative_reconstructions() {
    let scene = Scene::cornell_box();
    let atlas = cornell_atlas(&scene);
    for basis in [LightmapBasis::Sg { lobes: 9 }, LightmapBasis::AmbientDice] {
        let config = LightmapConfig {
            samples: 16,
            basis,
            ..Default::default()
        };
        let bake = bake_lightmap(&scene, &atlas, &config, &NoProgress, &mut |_| {}).unwrap();
        assert!(
            bake.lightmap
                .coefficients
                .iter()
                .flatten()
                .all(|&c| c >= 0.0),
            "{basis:?}"
        );
        assert!(bake.lightmap.irradiance.iter().all(|&e| e >= 0.0));
        let plain = LightmapConfig {
            encoder: Encoder::Plsq,
            ..config
        };
        let bake = bake_lightmap(&scene, &atlas, &plain, &NoProgress, &mut |_| {}).unwrap();
        assert!(
            bake.lightmap
                .coefficients
                .iter()
                .flatten()
                .any(|&c| c < 0.0),
            "{basis:?}"
        );
    }
}

/// An open ground plane under a constant sky L with no bounce: every texel's irradiance is πL.
/// The Monte Carlo estimate `2π L cos θ` has standard deviation `2πL/√12` per sample; the
/// irradiance basis must land within 5 standard errors, the fitted bases within 3%.
#[test]
fn a_plane_under_a_constant_sky_receives_pi_l() {
    let scene = Scene::ground_plane(1.0, Vec3::splat(0.5));
    let atlas = unwrap_charts(
        scene.triangles(),
        &UnwrapConfig {
            texels_per_metre: 4.0,
            ..Default::default()
        },
    )
    .unwrap();
    let samples = 256;
    let se = std::f32::consts::TAU / 12f32.sqrt() / (samples as f32).sqrt();
    for (basis, encoder, tolerance) in [
        (
            LightmapBasis::Irradiance,
            Encoder::Naive,
            5.0 * se / std::f32::consts::PI,
        ),
        (LightmapBasis::Sh { order: 3 }, Encoder::LeastSquares, 0.03),
        (
            LightmapBasis::Sg { lobes: 9 },
            Encoder::PlsqNonNegative,
            0.03,
        ),
    ] {
        let config = LightmapConfig {
            samples,
            basis,
            encoder,
            bounces: 0,
            lighting: Some(sky_only(1.0)),
            ..Default::default()
        };
        let bake = bake_lightmap(&scene, &atlas, &config, &NoProgress, &mut |_| {}).unwrap();
        for (i, e) in bake.lightmap.irradiance.chunks_exact(3).enumerate() {
            if bake.lightmap.covered[i] {
                let rel = (e[1] / std::f32::consts::PI - 1.0).abs();
                assert!(
                    rel < tolerance,
                    "{basis:?}: texel {i} irradiance {e:?} ({rel} > {tolerance})"
                );
            }
        }
    }
}

/// Inside a closed box with no emitter no light arrives: zero, exactly.
#[test]
fn a_closed_box_is_black() {
    let scene = Scene::closed_box(1.0, Vec3::splat(0.8));
    let atlas = cornell_atlas(&scene);
    let config = LightmapConfig {
        samples: 8,
        lighting: Some(sky_only(1.0)),
        ..Default::default()
    };
    let bake = bake_lightmap(&scene, &atlas, &config, &NoProgress, &mut |_| {}).unwrap();
    assert!(bake.lightmap.irradiance.iter().all(|&e| e == 0.0));
}

/// The Cornell light faces down: with no bounce the ceiling sees only its back (black), the
/// floor its front; bounces then light the ceiling.
#[test]
fn the_cornell_ceiling_is_lit_by_bounces_only() {
    let scene = Scene::cornell_box();
    let atlas = cornell_atlas(&scene);
    let map = prt_lightmap::TexelMap::new(scene.triangles(), &atlas);
    let mean = |bounces: u32, name: &str| {
        let config = LightmapConfig {
            samples: 64,
            bounces,
            basis: LightmapBasis::Irradiance,
            ..Default::default()
        };
        let bake = bake_lightmap(&scene, &atlas, &config, &NoProgress, &mut |_| {}).unwrap();
        let (mut sum, mut n) = (0.0, 0);
        for (i, t) in map.texels.iter().enumerate() {
            if let Some(t) = t
                && scene.material_of(t.triangle as usize).name == name
            {
                sum += bake.lightmap.irradiance[3 * i + 1];
                n += 1;
            }
        }
        sum / n as f32
    };
    assert_eq!(mean(0, "ceiling"), 0.0);
    // About the light's radiance × area / height² = 0.18 / 4 under it, less towards the walls.
    let floor = mean(0, "floor");
    assert!(floor > 0.01 && floor < 0.05, "floor {floor}");
    let (ceiling, floor) = (mean(2, "ceiling"), mean(2, "floor"));
    assert!(
        ceiling > 0.1 * floor && ceiling < floor,
        "ceiling {ceiling}, floor {floor}"
    );
}

#[test]
fn a_bake_over_its_memory_budget_is_refused() {
    let scene = Scene::cornell_box();
    let atlas = cornell_atlas(&scene);
    let config = LightmapConfig {
        max_memory_bytes: Some(1000),
        ..Default::default()
    };
    let err = bake_lightmap(&scene, &atlas, &config, &NoProgress, &mut |_| {}).unwrap_err();
    assert!(
        matches!(err, LightmapError::MemoryBudget { budget: 1000, .. }),
        "{err}"
    );
}

/// Cancels once `after` samples were traced.
struct CancelAfter {
    done: AtomicU64,
    after: u64,
}

impl Progress for CancelAfter {
    fn set_len(&self, _len: u64) {}
    fn inc(&self, delta: u64) {
        self.done.fetch_add(delta, Ordering::SeqCst);
    }
    fn message(&self, _msg: &str) {}
    fn is_cancelled(&self) -> bool {
        self.done.load(Ordering::SeqCst) >= self.after
    }
}

/// Cancelling inside a pass keeps the last completed pass, bit for bit the same as a bake of
/// that many samples; snapshots come every `snapshot_every` samples.
#[test]
fn cancelling_keeps_the_last_completed_pass() {
    let scene = Scene::cornell_box();
    let atlas = cornell_atlas(&scene);
    let config = LightmapConfig {
        samples: 16,
        pass_samples: 4,
        snapshot_every: 8,
        ..Default::default()
    };
    let mut snapshots = Vec::new();
    let full = bake_lightmap(&scene, &atlas, &config, &NoProgress, &mut |l| {
        snapshots.push(l.samples_per_texel)
    })
    .unwrap();
    assert_eq!(snapshots, [8, 16]);
    let texels = full.texels as u64;
    let progress = CancelAfter {
        done: AtomicU64::new(0),
        after: 4 * texels + 10,
    };
    let cancelled = bake_lightmap(&scene, &atlas, &config, &progress, &mut |_| {}).unwrap();
    assert!(cancelled.cancelled);
    assert_eq!(cancelled.lightmap.samples_per_texel, 4);
    let four = bake_lightmap(
        &scene,
        &atlas,
        &LightmapConfig {
            samples: 4,
            ..config
        },
        &NoProgress,
        &mut |_| {},
    )
    .unwrap();
    assert_eq!(cancelled.lightmap, four.lightmap);
    let at_once = CancelAfter {
        done: AtomicU64::new(0),
        after: 0,
    };
    assert_eq!(
        bake_lightmap(&scene, &atlas, &config, &at_once, &mut |_| {}).unwrap_err(),
        LightmapError::Cancelled
    );
}
