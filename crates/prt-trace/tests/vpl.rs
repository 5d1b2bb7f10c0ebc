//! The many-light scene side: VPL tracing, G-buffer, the pixel × VPL oracle.

mod common;

use std::f32::consts::PI;
use std::sync::OnceLock;

use glam::Vec3;
use proptest::prelude::*;
use prt_core::{CoreError, MatrixOracle, NoProgress};
use prt_trace::camera::GatherPoint;
use prt_trace::camera::{GBuffer, PinholeView};
use prt_trace::manylight::{
    DirectionalLight, SunAndUniformSky, Vpl, VplOptions, VplOracle, directional_lights,
    emitted_power, trace_vpls,
};
use prt_trace::scene::Material;
use prt_trace::{RayTracer, Scene, TraceError};

struct Cornell {
    scene: Scene,
    tracer: RayTracer,
    gbuffer: GBuffer,
    vpls: Vec<Vpl>,
}

fn cornell() -> &'static Cornell {
    static C: OnceLock<Cornell> = OnceLock::new();
    C.get_or_init(|| {
        let scene = Scene::cornell_box();
        let tracer = RayTracer::new(scene.triangles());
        let view = PinholeView::for_scene(&scene).unwrap();
        let gbuffer = GBuffer::render(&scene, &tracer, &view, 32, 32).unwrap();
        let options = VplOptions {
            particles: 800,
            max_bounces: 2,
            seed: 3,
            ..Default::default()
        };
        let vpls = trace_vpls(&scene, &tracer, &options, &NoProgress).unwrap();
        Cornell {
            scene,
            tracer,
            gbuffer,
            vpls,
        }
    })
}

#[test]
fn emitter_vpls_carry_exactly_the_light_power() {
    let c = cornell();
    let power = emitted_power(&c.scene, &SunAndUniformSky::default()).unwrap();
    // The Cornell light: a 0.47 × 0.38 quad of radiance 1, power π A.
    let expected = PI * 0.47 * 0.38;
    assert!((power - Vec3::splat(expected)).abs().max_element() < 1e-4 * expected);
    let emitted: Vec3 = c
        .vpls
        .iter()
        .filter(|v| v.bounce == 0)
        .map(|v| v.flux)
        .sum();
    // Both triangles of the white quad have the same power, so every particle carries P / N.
    assert_eq!(c.vpls.iter().filter(|v| v.bounce == 0).count(), 800);
    assert!((emitted - power).abs().max_element() < 1e-4 * expected);
    for v in c.vpls.iter().filter(|v| v.bounce == 0) {
        assert!((v.position.y - 1.98).abs() < 1e-5 && v.normal.y < -0.999);
    }
    // Bounces only lose energy: the brightest albedo is 0.725 and nothing escapes upwards.
    let first: Vec3 = c
        .vpls
        .iter()
        .filter(|v| v.bounce == 1)
        .map(|v| v.flux)
        .sum();
    assert!(first.max_element() < 0.73 * expected && first.min_element() > 0.0);
}

#[test]
fn sun_on_a_ground_plane_deposits_albedo_times_irradiance_times_area() {
    let half = 2.0;
    let albedo = 0.5;
    let scene = Scene::ground_plane(half, Vec3::splat(albedo));
    let tracer = RayTracer::new(scene.triangles());
    let sun = SunAndUniformSky {
        sun_direction: Vec3::NEG_Y,
        sun_irradiance: Vec3::ONE,
        sky_radiance: Vec3::ZERO,
    };
    let n = 4000;
    let options = VplOptions {
        particles: n,
        max_bounces: 1,
        seed: 11,
        sun_sky: sun,
    };
    let vpls = trace_vpls(&scene, &tracer, &options, &NoProgress).unwrap();
    let total: f64 = vpls.iter().map(|v| f64::from(v.flux.x)).sum();
    // Particles leave a disk of the bounding sphere's radius R = √2 h; a fraction 4h²/(πR²) = 2/π
    // lands, each with flux ρ E π R² / N: the sum is binomial around ρ E 4 h².
    let radius2 = 2.0 * f64::from(half * half);
    let per = f64::from(albedo) * std::f64::consts::PI * radius2 / n as f64;
    let p = 2.0 / std::f64::consts::PI;
    let mean = f64::from(albedo) * 4.0 * f64::from(half * half);
    let sigma = per * (n as f64 * p * (1.0 - p)).sqrt();
    assert!(
        (total - mean).abs() < 4.0 * sigma,
        "{total} vs {mean} ± {sigma}"
    );
    assert!(
        vpls.iter()
            .all(|v| v.position.y.abs() < 1e-4 && v.normal.y > 0.999)
    );
}

#[test]
fn vpls_are_identical_for_a_seed_on_any_thread_count() {
    let scene = Scene::cornell_box();
    let tracer = RayTracer::new(scene.triangles());
    let options = VplOptions {
        particles: 3000,
        max_bounces: 3,
        seed: 5,
        ..Default::default()
    };
    let run = |threads| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| trace_vpls(&scene, &tracer, &options, &NoProgress).unwrap())
    };
    let one = run(1);
    assert_eq!(one, run(3));
    let other = trace_vpls(
        &scene,
        &tracer,
        &VplOptions { seed: 6, ..options },
        &NoProgress,
    )
    .unwrap();
    assert_ne!(one, other);
}

#[test]
fn the_default_cornell_view_sees_only_the_box_from_its_open_side() {
    let c = cornell();
    let view = PinholeView::for_scene(&c.scene).unwrap();
    assert!(view.position.z > 0.99 && view.forward == Vec3::NEG_Z);
    for (p, g) in c.gbuffer.points.iter().enumerate() {
        let g = g.expect("every pixel of the framed box hits a wall");
        let dir = view.ray(p % 32, p / 32, 32, 32);
        assert!(g.normal.dot(dir) < 0.0, "pixel {p} sees a back face");
    }
    // The leftmost column sees the red wall, the rightmost the green one.
    let left = c.gbuffer.points[16 * 32].unwrap().albedo;
    let right = c.gbuffer.points[16 * 32 + 31].unwrap().albedo;
    assert!(left.x > 0.6 && right.y > 0.4);
}

#[test]
fn rows_columns_and_the_reference_image_agree() {
    let c = cornell();
    let oracle = VplOracle::new(&c.tracer, &c.gbuffer, &c.vpls, 0.1, 1e-4).unwrap();
    let (rows, cols) = (oracle.rows(), oracle.cols());
    let mut row = vec![0.0; 3 * cols];
    let mut col = vec![0.0; 3 * rows];
    let mut image_from_cols = vec![0f64; 3 * rows];
    let mut columns = Vec::with_capacity(cols);
    for j in 0..cols {
        oracle.eval_col(j, &mut col).unwrap();
        for (acc, v) in image_from_cols.iter_mut().zip(&col) {
            *acc += f64::from(*v);
        }
        columns.push(col.clone());
    }
    for i in (0..rows).step_by(37) {
        oracle.eval_row(i, &mut row).unwrap();
        for (j, col) in columns.iter().enumerate() {
            assert_eq!(row[3 * j..3 * j + 3], col[3 * i..3 * i + 3]);
        }
    }
    oracle.reset_count();
    let image = oracle.reference_image(&NoProgress).unwrap();
    assert_eq!(oracle.elements_evaluated(), (rows * cols) as u64);
    assert_eq!(image.len(), 3 * rows);
    for (a, b) in image.iter().zip(&image_from_cols) {
        assert!((f64::from(*a) - b).abs() <= 1e-5 * b.abs() + 1e-9);
    }
    assert!(image.iter().all(|v| v.is_finite() && *v >= 0.0));
    // The floor below the light is lit; the red wall reflects more red than green.
    let left = 16 * 32 + 1;
    assert!(image[3 * left] > image[3 * left + 1]);
    let lit = image.iter().filter(|v| **v > 0.0).count();
    assert!(lit > image.len() / 2, "{lit} lit channels");
}

#[test]
fn counts_row_and_column_elements() {
    let c = cornell();
    let oracle = VplOracle::new(&c.tracer, &c.gbuffer, &c.vpls, 0.1, 1e-4).unwrap();
    let mut row = vec![0.0; 3 * oracle.cols()];
    let mut col = vec![0.0; 3 * oracle.rows()];
    oracle.eval_row(0, &mut row).unwrap();
    oracle.eval_col(0, &mut col).unwrap();
    assert_eq!(
        oracle.elements_evaluated(),
        (oracle.rows() + oracle.cols()) as u64
    );
    assert!(matches!(
        oracle.eval_row(oracle.rows(), &mut row),
        Err(CoreError::OutOfRange { .. })
    ));
    assert!(matches!(
        oracle.element(0, oracle.cols()),
        Err(CoreError::OutOfRange { .. })
    ));
    assert!(matches!(
        oracle.eval_col(0, &mut row[..3]),
        Err(CoreError::LengthMismatch { .. })
    ));
}

/// A floor `y = 0` over `[-2, 2]²` and, optionally, a wall `x = 0` up to `y = 3`.
fn floor_and_wall(wall: bool) -> Scene {
    let q = |a: [f32; 3], b: [f32; 3], c: [f32; 3], d: [f32; 3]| {
        let [a, b, c, d] = [a, b, c, d].map(Vec3::from_array);
        [[a, b, c], [a, c, d]]
    };
    let mut tris: Vec<[Vec3; 3]> = q(
        [-2.0, 0.0, -2.0],
        [-2.0, 0.0, 2.0],
        [2.0, 0.0, 2.0],
        [2.0, 0.0, -2.0],
    )
    .to_vec();
    if wall {
        tris.extend(q(
            [0.0, 0.0, -2.0],
            [0.0, 3.0, -2.0],
            [0.0, 3.0, 2.0],
            [0.0, 0.0, 2.0],
        ));
    }
    let ids = vec![0; tris.len()];
    Scene::from_triangles(tris, ids, vec![Material::diffuse("grey", Vec3::splat(0.5))]).unwrap()
}

#[test]
fn a_vpl_behind_a_wall_contributes_nothing() {
    let gbuffer = GBuffer {
        width: 1,
        height: 1,
        points: vec![Some(GatherPoint {
            position: Vec3::new(-1.0, 0.0, 0.0),
            normal: Vec3::Y,
            albedo: Vec3::new(0.5, 0.25, 1.0),
            emission: Vec3::ZERO,
        })],
    };
    let normal = Vec3::new(-1.0, -1.0, 0.0).normalize();
    let vpls = [Vpl {
        position: Vec3::new(1.0, 1.0, 0.0),
        normal,
        flux: Vec3::new(2.0, 2.0, 2.0),
        albedo: Vec3::splat(0.5),
        bounce: 1,
    }];
    let open = floor_and_wall(false);
    let open_tracer = RayTracer::new(open.triangles());
    let oracle = VplOracle::new(&open_tracer, &gbuffer, &vpls, 0.0, 1e-4).unwrap();
    let e = oracle.element(0, 0).unwrap();
    // d² = 5, cos_i = 1/√5, cos_j = 3/√10.
    let w = Vec3::new(2.0, 1.0, 0.0) / 5f32.sqrt();
    let expected = Vec3::new(0.5, 0.25, 1.0) * 2.0 * (w.y * -normal.dot(w) / (PI * PI * 5.0));
    assert!(
        (e - expected).abs().max_element() < 1e-6,
        "{e} vs {expected}"
    );
    // A clamp beyond the distance caps 1/d² at 1/clamp².
    let clamped = VplOracle::new(&open_tracer, &gbuffer, &vpls, 3.0, 1e-4).unwrap();
    assert!(
        (clamped.element(0, 0).unwrap() - expected * 5.0 / 9.0)
            .abs()
            .max_element()
            < 1e-6
    );

    let walled = floor_and_wall(true);
    let walled_tracer = RayTracer::new(walled.triangles());
    let oracle = VplOracle::new(&walled_tracer, &gbuffer, &vpls, 0.0, 1e-4).unwrap();
    assert_eq!(oracle.element(0, 0).unwrap(), Vec3::ZERO);
}

#[test]
fn empty_inputs_are_typed_errors() {
    let c = cornell();
    assert!(matches!(
        VplOracle::new(&c.tracer, &c.gbuffer, &[], 0.1, 1e-4),
        Err(CoreError::Empty { .. })
    ));
    let no_pixels = GBuffer {
        width: 0,
        height: 0,
        points: Vec::new(),
    };
    assert!(matches!(
        VplOracle::new(&c.tracer, &no_pixels, &c.vpls, 0.1, 1e-4),
        Err(CoreError::Empty { .. })
    ));
    let view = PinholeView::for_scene(&c.scene).unwrap();
    assert!(matches!(
        GBuffer::render(&c.scene, &c.tracer, &view, 0, 8),
        Err(TraceError::InvalidOption { .. })
    ));
    let zero = VplOptions {
        particles: 0,
        ..Default::default()
    };
    assert!(matches!(
        trace_vpls(&c.scene, &c.tracer, &zero, &NoProgress),
        Err(TraceError::InvalidOption { .. })
    ));
    let empty = Scene::empty();
    let empty_tracer = RayTracer::new(empty.triangles());
    assert!(matches!(
        trace_vpls(&empty, &empty_tracer, &VplOptions::default(), &NoProgress),
        Err(TraceError::EmptyScene)
    ));
    let dark = Scene::ground_plane(1.0, Vec3::ONE);
    let dark_tracer = RayTracer::new(dark.triangles());
    let no_light = VplOptions {
        sun_sky: SunAndUniformSky {
            sun_irradiance: Vec3::ZERO,
            sky_radiance: Vec3::ZERO,
            ..SunAndUniformSky::default()
        },
        ..Default::default()
    };
    assert!(matches!(
        trace_vpls(&dark, &dark_tracer, &no_light, &NoProgress),
        Err(TraceError::InvalidOption { .. })
    ));
}

#[test]
fn non_finite_vpls_and_options_are_typed_errors() {
    let c = cornell();
    let mut vpls = c.vpls[..10].to_vec();
    vpls[7].flux.y = f32::NAN;
    assert!(matches!(
        VplOracle::new(&c.tracer, &c.gbuffer, &vpls, 0.1, 1e-4),
        Err(CoreError::NonFinite { index: 7, .. })
    ));
    assert!(matches!(
        VplOracle::new(&c.tracer, &c.gbuffer, &c.vpls, f32::INFINITY, 1e-4),
        Err(CoreError::Invalid { .. })
    ));
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(24))]
    #[test]
    fn row_and_column_elements_are_the_same_number(i in 0usize..1024, j in 0usize..2000) {
        let c = cornell();
        let oracle = VplOracle::new(&c.tracer, &c.gbuffer, &c.vpls, 0.05, 1e-4).unwrap();
        let j = j % oracle.cols();
        let mut row = vec![0.0; 3 * oracle.cols()];
        let mut col = vec![0.0; 3 * oracle.rows()];
        oracle.eval_row(i, &mut row).unwrap();
        oracle.eval_col(j, &mut col).unwrap();
        prop_assert_eq!(&row[3 * j..3 * j + 3], &col[3 * i..3 * i + 3]);
        prop_assert!(row.iter().all(|v| v.is_finite() && *v >= 0.0));
    }
}

#[test]
fn a_uniform_sky_on_a_ground_plane_deposits_albedo_times_pi_radiance_times_area() {
    let half = 2.0;
    let albedo = 0.8;
    let scene = Scene::ground_plane(half, Vec3::splat(albedo));
    let tracer = RayTracer::new(scene.triangles());
    let sky = SunAndUniformSky {
        sun_irradiance: Vec3::ZERO,
        sky_radiance: Vec3::ONE,
        ..SunAndUniformSky::default()
    };
    let n = 6000;
    let options = VplOptions {
        particles: n,
        max_bounces: 1,
        seed: 2,
        sun_sky: sky,
    };
    let vpls = trace_vpls(&scene, &tracer, &options, &NoProgress).unwrap();
    let total: f64 = vpls.iter().map(|v| f64::from(v.flux.y)).sum();
    // Irradiance under a uniform sky of radiance 1 is π: the mean is ρ π A. Each particle carries
    // ρ 2π πR² / N and lands with probability A cos θ / (πR²); the count's variance is at most
    // N p̄ (1 - p̄) with p̄ = A / (2πR²) = 1/π.
    let radius2 = 2.0 * f64::from(half * half);
    let area = 4.0 * f64::from(half * half);
    let pi = std::f64::consts::PI;
    let per = f64::from(albedo) * 2.0 * pi * pi * radius2 / n as f64;
    let p = 1.0 / pi;
    let mean = f64::from(albedo) * pi * area;
    let sigma = per * (n as f64 * p * (1.0 - p)).sqrt();
    assert!(
        (total - mean).abs() < 4.0 * sigma,
        "{total} vs {mean} ± {sigma}"
    );
    let power = emitted_power(&scene, &sky).unwrap();
    assert!((f64::from(power.x) - 2.0 * pi * pi * radius2).abs() < 1e-4 * f64::from(power.x));
}

#[test]
fn the_reference_image_is_cached_on_disk_and_recomputed_when_the_input_changes() {
    let c = cornell();
    let dir = common::temp_dir("vpl-cache");
    let path = dir.join("cornell.ref");
    let vpls = &c.vpls[..200];
    let oracle = VplOracle::new(&c.tracer, &c.gbuffer, vpls, 0.1, 1e-4).unwrap();
    let first = oracle.reference_image_cached(&path, &NoProgress).unwrap();
    assert_eq!(oracle.elements_evaluated(), (oracle.rows() * 200) as u64);
    oracle.reset_count();
    let again = oracle.reference_image_cached(&path, &NoProgress).unwrap();
    assert_eq!(first, again);
    assert_eq!(oracle.elements_evaluated(), 0, "read back, not recomputed");
    // Other VPLs: a different fingerprint, so the image is recomputed and the file replaced.
    let other = VplOracle::new(&c.tracer, &c.gbuffer, &c.vpls[1..201], 0.1, 1e-4).unwrap();
    assert_ne!(other.fingerprint(), oracle.fingerprint());
    let image = other.reference_image_cached(&path, &NoProgress).unwrap();
    assert_eq!(other.elements_evaluated(), (other.rows() * 200) as u64);
    assert_eq!(image, other.reference_image(&NoProgress).unwrap());
    let unwritable = dir.join("missing-dir").join("x.ref");
    assert!(matches!(
        oracle.reference_image_cached(&unwritable, &NoProgress),
        Err(TraceError::Write { .. })
    ));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn sun_and_sky_become_directional_lights_whose_sky_irradiance_is_pi_radiance() {
    let sun_sky = SunAndUniformSky {
        sun_direction: Vec3::new(1.0, -1.0, 0.0),
        sun_irradiance: Vec3::new(3.0, 2.0, 1.0),
        sky_radiance: Vec3::new(0.1, 0.2, 0.4),
    };
    let lights = directional_lights(&floor_and_wall(false), &sun_sky, 200).unwrap();
    // The sun, then a 10 × 20 grid of sky directions.
    assert_eq!(lights.len(), 201);
    assert_eq!(lights[0].irradiance, sun_sky.sun_irradiance);
    assert!((lights[0].direction - Vec3::new(1.0, -1.0, 0.0).normalize()).length() < 1e-6);
    // Every sky direction comes from the upper hemisphere, and their irradiance on an upward
    // surface is π L (the midpoint rule in cos θ integrates cos θ exactly).
    assert!(lights[1..].iter().all(|l| l.direction.y < 0.0));
    let on_floor: Vec3 = lights[1..]
        .iter()
        .map(|l| l.irradiance * -l.direction.y)
        .sum();
    let expected = sun_sky.sky_radiance * PI;
    assert!(
        ((on_floor - expected) / expected).abs().max_element() < 1e-4,
        "{on_floor} vs {expected}"
    );
    // A scene lit by its own emitter needs none; zero sun and sky give none.
    assert!(
        directional_lights(&cornell().scene, &sun_sky, 200)
            .unwrap()
            .is_empty()
    );
    let dark = SunAndUniformSky {
        sun_irradiance: Vec3::ZERO,
        sky_radiance: Vec3::ZERO,
        ..sun_sky
    };
    assert!(
        directional_lights(&floor_and_wall(false), &dark, 200)
            .unwrap()
            .is_empty()
    );
    let bad = SunAndUniformSky {
        sun_direction: Vec3::NAN,
        ..sun_sky
    };
    assert!(matches!(
        directional_lights(&floor_and_wall(false), &bad, 8),
        Err(TraceError::InvalidOption { .. })
    ));
}

#[test]
fn a_directional_column_is_cosine_weighted_direct_light_with_a_shadow_ray() {
    // Two floor points on either side of the wall x = 0; the sun comes from +x, low.
    let point = |x: f32| {
        Some(GatherPoint {
            position: Vec3::new(x, 0.0, 0.0),
            normal: Vec3::Y,
            albedo: Vec3::new(0.5, 0.25, 1.0),
            emission: Vec3::ZERO,
        })
    };
    let gbuffer = GBuffer {
        width: 2,
        height: 1,
        points: vec![point(1.0), point(-1.0)],
    };
    let vpls = [Vpl {
        position: Vec3::new(1.0, 1.0, 1.0),
        normal: Vec3::NEG_Y,
        flux: Vec3::ONE,
        albedo: Vec3::splat(0.5),
        bounce: 1,
    }];
    let sun = [DirectionalLight {
        direction: Vec3::new(-1.0, -1.0, 0.0).normalize(),
        irradiance: Vec3::new(2.0, 2.0, 2.0),
    }];
    let walled = floor_and_wall(true);
    let tracer = RayTracer::new(walled.triangles());
    let oracle = VplOracle::new(&tracer, &gbuffer, &vpls, 0.1, 1e-4)
        .unwrap()
        .with_directional(&sun)
        .unwrap();
    assert_eq!((oracle.cols(), oracle.vpl_count()), (2, 1));
    let expected = Vec3::new(0.5, 0.25, 1.0) / PI * 2.0 * (1.0 / 2f32.sqrt());
    let lit = oracle.element(0, 1).unwrap();
    assert!(
        (lit - expected).abs().max_element() < 1e-6,
        "{lit} vs {expected}"
    );
    // The wall shadows the point at x = -1.
    assert_eq!(oracle.element(1, 1).unwrap(), Vec3::ZERO);
    let mut column = vec![0.0; 6];
    oracle.eval_col(1, &mut column).unwrap();
    assert_eq!(&column[..3], &lit.to_array());
    let mut row = vec![0.0; 6];
    oracle.eval_row(0, &mut row).unwrap();
    assert_eq!(&row[3..], &lit.to_array());
    assert!(matches!(
        oracle.element(0, 2),
        Err(CoreError::OutOfRange {
            index: 2,
            len: 2,
            ..
        })
    ));
    // The fingerprint (hence the reference cache) sees the directional lights.
    let plain = VplOracle::new(&tracer, &gbuffer, &vpls, 0.1, 1e-4).unwrap();
    assert_ne!(plain.fingerprint(), oracle.fingerprint());
    let bad = [DirectionalLight {
        direction: Vec3::ZERO,
        irradiance: Vec3::ONE,
    }];
    assert!(matches!(
        plain.with_directional(&bad),
        Err(CoreError::NonFinite { index: 0, .. })
    ));
}
