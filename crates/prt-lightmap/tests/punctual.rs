//! Point, spot and directional lights seen directly from texels, against their closed forms.

use glam::Vec3;
use prt_core::NoProgress;
use prt_lightmap::{
    Atlas, Encoder, LightmapBasis, LightmapConfig, TexelMap, UnwrapConfig, bake_lightmap,
    unwrap_charts,
};
use prt_trace::{LoadOptions, Scene};

fn base64(bytes: &[u8]) -> String {
    const ALPHABET: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::new();
    for chunk in bytes.chunks(3) {
        let n = chunk
            .iter()
            .enumerate()
            .fold(0u32, |acc, (i, &b)| acc | u32::from(b) << (16 - 8 * i));
        for i in 0..4 {
            if i <= chunk.len() {
                out.push(ALPHABET[(n >> (18 - 6 * i) & 63) as usize] as char);
            } else {
                out.push('=');
            }
        }
    }
    out
}

/// A 2 m × 2 m floor at y = 0 facing +Y (and, with `occluder`, a 0.4 m square at y = 0.5 over
/// x, z ∈ [0.3, 0.7] facing down), lit by `light` (a `KHR_lights_punctual` light JSON) on a node
/// at `translation` with `rotation`.
fn floor_with_light(
    light: &str,
    translation: [f32; 3],
    rotation: [f32; 4],
    occluder: bool,
) -> Scene {
    let mut positions: Vec<[f32; 3]> = vec![
        [-1.0, 0.0, -1.0],
        [-1.0, 0.0, 1.0],
        [1.0, 0.0, 1.0],
        [-1.0, 0.0, -1.0],
        [1.0, 0.0, 1.0],
        [1.0, 0.0, -1.0],
    ];
    if occluder {
        positions.extend([
            [0.3, 0.5, 0.3],
            [0.3, 0.5, 0.7],
            [0.7, 0.5, 0.7],
            [0.3, 0.5, 0.3],
            [0.7, 0.5, 0.7],
            [0.7, 0.5, 0.3],
        ]);
    }
    let bin: Vec<u8> = positions
        .iter()
        .flatten()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    let json = format!(
        r#"{{
  "asset": {{"version": "2.0"}},
  "extensionsUsed": ["KHR_lights_punctual"],
  "extensions": {{"KHR_lights_punctual": {{"lights": [{light}]}}}},
  "buffers": [{{"uri": "data:application/octet-stream;base64,{data}", "byteLength": {len}}}],
  "bufferViews": [{{"buffer": 0, "byteOffset": 0, "byteLength": {len}}}],
  "accessors": [{{"bufferView": 0, "componentType": 5126, "count": {count}, "type": "VEC3",
                  "min": [-1, 0, -1], "max": [1, 0.5, 1]}}],
  "materials": [{{"doubleSided": true, "pbrMetallicRoughness": {{"baseColorFactor": [0.5, 0.5, 0.5, 1]}}}}],
  "meshes": [{{"primitives": [{{"attributes": {{"POSITION": 0}}, "material": 0}}]}}],
  "nodes": [{{"mesh": 0}},
            {{"translation": {translation:?}, "rotation": {rotation:?},
              "extensions": {{"KHR_lights_punctual": {{"light": 0}}}}}}],
  "scenes": [{{"nodes": [0, 1]}}],
  "scene": 0
}}"#,
        data = base64(&bin),
        len = bin.len(),
        count = positions.len(),
    );
    Scene::load_gltf_slice(json.as_bytes(), None, &LoadOptions::default()).expect("loads")
}

fn atlas(scene: &Scene) -> Atlas {
    unwrap_charts(
        scene.triangles(),
        &UnwrapConfig {
            texels_per_metre: 12.0,
            ..Default::default()
        },
    )
    .unwrap()
}

/// Direct light only: no bounce, so the floor's samples see nothing and the lightmap is the
/// punctual term alone, deterministic.
fn direct_only(basis: LightmapBasis, encoder: Encoder) -> LightmapConfig {
    LightmapConfig {
        basis,
        encoder,
        samples: 1,
        pass_samples: 1,
        bounces: 0,
        ..Default::default()
    }
}

/// The bake moves a texel's point towards its triangle's centre by at most ten ray offsets
/// (`1e-4` of the scene's diagonal each); `E` changes by at most `|∇E|` times that.
fn pull(scene: &Scene) -> f32 {
    let b = scene.bounds().unwrap();
    10.0 * 1e-4 * (b.max - b.min).length()
}

/// Compares every floor texel's irradiance with `expected(point)`, within the change the texel
/// point's pull can make (`expected`'s change over the floor within the pull) and f32
/// rounding.
fn check_floor(scene: &Scene, config: &LightmapConfig, expected: impl Fn(Vec3) -> Vec3) -> usize {
    let atlas = atlas(scene);
    let bake = bake_lightmap(scene, &atlas, config, &NoProgress, &mut |_| {}).unwrap();
    let map = TexelMap::new(scene.triangles(), &atlas);
    let lm = &bake.lightmap;
    let h = pull(scene);
    let mut checked = 0;
    for (i, texel) in map.texels.iter().enumerate() {
        let Some(t) = texel else { continue };
        if t.normal.y < 0.5 {
            continue;
        }
        let p = t.position;
        let want = expected(p);
        // The largest change over the disk of the pull's radius (16 directions, a fifth more).
        let change = (0..16)
            .map(|k| {
                let a = std::f32::consts::TAU * k as f32 / 16.0;
                (expected(p + Vec3::new(a.cos(), 0.0, a.sin()) * h) - want).abs()
            })
            .fold(Vec3::ZERO, Vec3::max);
        let tolerance = change * 1.2 + want * 1e-4 + Vec3::splat(1e-6);
        let got = Vec3::from_slice(&lm.irradiance[3 * i..3 * i + 3]);
        assert!(
            (got - want).abs().cmple(tolerance).all(),
            "texel {i} at {}: {got} against {want} (± {tolerance})",
            t.position
        );
        checked += 1;
    }
    checked
}

#[test]
fn a_point_light_gives_the_floor_i_cos_over_d_squared() {
    let light_at = Vec3::new(0.3, 1.0, -0.2);
    let scene = floor_with_light(
        r#"{"type": "point", "color": [1, 0.5, 0.25], "intensity": 5}"#,
        light_at.to_array(),
        [0.0, 0.0, 0.0, 1.0],
        false,
    );
    let intensity = Vec3::new(5.0, 2.5, 1.25);
    let checked = check_floor(
        &scene,
        &direct_only(LightmapBasis::Irradiance, Encoder::PlsqNonNegative),
        |p| {
            let d = light_at - p;
            intensity * (d.y / d.length().powi(3))
        },
    );
    assert!(checked > 400, "{checked} texels");
}

#[test]
fn a_spot_light_follows_the_extensions_cone_and_range() {
    let light_at = Vec3::new(0.0, 1.0, 0.0);
    let (inner, outer, range) = (0.3f32, 0.6f32, 1.5f32);
    // Pointing down: -Z turned -90° about X.
    let h = std::f32::consts::FRAC_1_SQRT_2;
    let scene = floor_with_light(
        &format!(
            r#"{{"type": "spot", "intensity": 8, "range": {range},
                 "spot": {{"innerConeAngle": {inner}, "outerConeAngle": {outer}}}}}"#
        ),
        light_at.to_array(),
        [-h, 0.0, 0.0, h],
        false,
    );
    assert!((scene.lights()[0].direction - Vec3::NEG_Y).length() < 1e-5);
    let expected = |p: Vec3| {
        let d = light_at - p;
        let dist = d.length();
        let c = d.y / dist;
        let ramp = ((c - outer.cos()) / (inner.cos() - outer.cos())).clamp(0.0, 1.0);
        let window = (1.0 - (dist / range).powi(4)).clamp(0.0, 1.0);
        Vec3::splat(8.0 * ramp * ramp * window * c / (dist * dist))
    };
    let checked = check_floor(
        &scene,
        &direct_only(LightmapBasis::Irradiance, Encoder::PlsqNonNegative),
        expected,
    );
    assert!(checked > 400, "{checked} texels");
}

#[test]
fn an_occluder_casts_the_point_lights_shadow() {
    let light_at = Vec3::new(0.5, 1.0, 0.5);
    let scene = floor_with_light(
        r#"{"type": "point", "intensity": 2}"#,
        light_at.to_array(),
        [0.0, 0.0, 0.0, 1.0],
        true,
    );
    let atlas = atlas(&scene);
    let bake = bake_lightmap(
        &scene,
        &atlas,
        &direct_only(LightmapBasis::Irradiance, Encoder::PlsqNonNegative),
        &NoProgress,
        &mut |_| {},
    )
    .unwrap();
    let map = TexelMap::new(scene.triangles(), &atlas);
    let (mut shadowed, mut lit) = (0, 0);
    for (i, t) in map.texels.iter().enumerate() {
        let Some(t) = t else { continue };
        if t.normal.y < 0.5 || t.position.y > 0.1 {
            continue;
        }
        // The shadow of the square [0.3, 0.7]² at y = 0.5 from (0.5, 1, 0.5) is [0.1, 0.9]².
        let inside = |v: f32| (0.15..0.85).contains(&v);
        let outside = |v: f32| !(0.05..0.95).contains(&v);
        let e = lm_texel(&bake.lightmap.irradiance, i);
        if inside(t.position.x) && inside(t.position.z) {
            assert_eq!(e, 0.0, "texel at {} is in the shadow", t.position);
            shadowed += 1;
        } else if outside(t.position.x) || outside(t.position.z) {
            assert!(e > 0.0, "texel at {} is lit", t.position);
            lit += 1;
        }
    }
    assert!(shadowed > 30 && lit > 300, "{shadowed} shadowed, {lit} lit");
}

fn lm_texel(irradiance: &[f32], i: usize) -> f32 {
    irradiance[3 * i]
}

#[test]
fn a_least_squares_sh_fit_of_the_delta_has_the_sh_irradiance_of_a_delta() {
    // For orthonormal SH of bands 0..=2, the fit of E⊥ δ(ω − ω_l) has the irradiance
    // E⊥ Σ_l A_l (2l + 1)/(4π) P_l(cos θ) = E⊥ (1/4 + cos θ / 2 + 5/16 P₂(cos θ))
    // (Ramamoorthi and Hanrahan's clamped-cosine coefficients A = π, 2π/3, π/4).
    let light_at = Vec3::new(0.3, 1.0, -0.2);
    let scene = floor_with_light(
        r#"{"type": "point", "intensity": 3}"#,
        light_at.to_array(),
        [0.0, 0.0, 0.0, 1.0],
        false,
    );
    for encoder in [Encoder::LeastSquares, Encoder::Plsq, Encoder::Naive] {
        let config = direct_only(LightmapBasis::Sh { order: 3 }, encoder);
        let checked = check_floor(&scene, &config, |p| {
            let d = light_at - p;
            let dist = d.length();
            let c = d.y / dist;
            let p2 = 0.5 * (3.0 * c * c - 1.0);
            Vec3::splat(3.0 / (dist * dist) * (0.25 + 0.5 * c + 5.0 / 16.0 * p2))
        });
        assert!(checked > 400, "{encoder:?}: {checked} texels");
    }
}

#[test]
fn non_negative_encoders_keep_the_delta_non_negative() {
    let scene = floor_with_light(
        r#"{"type": "directional", "intensity": 2}"#,
        [0.0, 3.0, 0.0],
        // Turned -1 rad about X: shining down at 33° from the vertical.
        [-(0.5f32.sin()), 0.0, 0.0, 0.5f32.cos()],
        false,
    );
    let atlas = atlas(&scene);
    for encoder in [Encoder::PlsqNonNegative, Encoder::Nnls] {
        let bake = bake_lightmap(
            &scene,
            &atlas,
            &direct_only(LightmapBasis::Sg { lobes: 9 }, encoder),
            &NoProgress,
            &mut |_| {},
        )
        .unwrap();
        let lm = &bake.lightmap;
        assert!(lm.coefficients.iter().flatten().all(|&c| c >= 0.0));
        let covered: Vec<f32> = (0..lm.covered.len())
            .filter(|&i| lm.covered[i])
            .map(|i| lm.irradiance[3 * i])
            .collect();
        // A directional light: every texel of the floor gets the same fit.
        let (lo, hi) = covered
            .iter()
            .fold((f32::MAX, f32::MIN), |(lo, hi), &e| (lo.min(e), hi.max(e)));
        assert!(
            lo > 0.0 && (hi - lo) <= 1e-4 * hi,
            "{encoder:?}: {lo}..{hi}"
        );
    }
}

#[test]
fn the_sun_gives_the_ground_its_irradiance_times_the_cosine_from_the_first_sample() {
    // The sun is a delta too: every encoder shows it from the first pass, with no sample noise
    // (a sun found by hemisphere samples would leave a few texels at 10⁵ times the sky).
    let scene = Scene::ground_plane(1.0, Vec3::splat(0.5));
    let sun = prt_trace::manylight::SunAndUniformSky {
        sun_direction: Vec3::new(0.3, -1.0, 0.2).normalize(),
        sun_irradiance: Vec3::new(3.0, 2.5, 2.0),
        sky_radiance: Vec3::ZERO,
    };
    let cos = sun.sun_direction.y.abs();
    let atlas = atlas(&scene);
    for (basis, encoder, tolerance) in [
        (LightmapBasis::Irradiance, Encoder::Naive, 1e-5),
        // The SH fit of a delta has the irradiance of the law in the SH test.
        (LightmapBasis::Sh { order: 3 }, Encoder::Plsq, 2e-3),
    ] {
        let config = LightmapConfig {
            lighting: Some(prt_lightmap::Lighting { sun_sky: Some(sun) }),
            ..direct_only(basis, encoder)
        };
        let bake = bake_lightmap(&scene, &atlas, &config, &NoProgress, &mut |_| {}).unwrap();
        let lm = &bake.lightmap;
        let p2 = 0.5 * (3.0 * cos * cos - 1.0);
        let factor = match basis {
            LightmapBasis::Irradiance => cos,
            _ => 0.25 + 0.5 * cos + 5.0 / 16.0 * p2,
        };
        let want = sun.sun_irradiance * factor;
        for i in (0..lm.covered.len()).filter(|&i| lm.covered[i]) {
            let got = Vec3::from_slice(&lm.irradiance[3 * i..3 * i + 3]);
            assert!(
                ((got - want).abs() / want).max_element() <= tolerance,
                "{basis:?}: texel {i}: {got} against {want}"
            );
        }
    }
}
