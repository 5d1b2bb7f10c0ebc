//! The renderer against cases with a known answer, and its determinism.

use glam::{Mat4, Vec3};
use prt_core::{Aabb, AtomicProgress, GridField, NoProgress};
use prt_render::{RenderConfig, Rendered, SurfaceLight, ToneMap, image_metrics, render, views};
use prt_sphere::Sky;
use prt_trace::camera::PinholeView;
use prt_trace::scene::Camera;
use prt_trace::{BakeOptions, LitVolume, RayTracer, Scene, TRANSFER_DIM, TransferBaker};

/// A transfer volume that passes the sky through unchanged (direct transfer = identity,
/// no bounce) everywhere, times `scale`.
fn open_sky(dims: [usize; 3], bounds: Aabb, scale: f32) -> GridField {
    GridField::from_fn(dims, bounds, TRANSFER_DIM, |_, t| {
        for i in 0..9 {
            t[i * 9 + i] = scale;
        }
    })
    .expect("field")
}

/// [`open_sky`] lit by `sky`, every voxel valid.
fn lit_open_sky(dims: [usize; 3], bounds: Aabb, scale: f32, sky: &Sky) -> LitVolume {
    let valid = vec![true; dims.iter().product()];
    LitVolume::from_transfer(&open_sky(dims, bounds, scale), &valid, sky, &NoProgress)
        .expect("volume")
}

fn looking_down() -> PinholeView {
    PinholeView {
        position: Vec3::new(0.0, 2.0, 0.0),
        forward: Vec3::NEG_Y,
        up: Vec3::NEG_Z,
        yfov: 0.6,
    }
}

fn small(width: usize, height: usize) -> RenderConfig {
    RenderConfig { width, height }
}

fn draw(scene: &Scene, view: &PinholeView, volume: &LitVolume, sky: &Sky, size: usize) -> Rendered {
    let tracer = RayTracer::new(scene.triangles());
    render(
        scene,
        &tracer,
        view,
        volume,
        sky,
        &small(size, size),
        &NoProgress,
    )
    .expect("render")
}

fn close(a: [f32; 3], b: [f32; 3], tol: f32) -> bool {
    (0..3).all(|c| (a[c] - b[c]).abs() <= tol * b[c].abs().max(1.0))
}

#[test]
fn a_plane_under_a_constant_sky_shows_albedo_times_radiance() {
    let albedo = Vec3::new(0.8, 0.5, 0.2);
    let scene = Scene::ground_plane(2.0, albedo);
    let bounds = Aabb::new(Vec3::new(-2.0, -1.0, -2.0), Vec3::new(2.0, 1.0, 2.0));
    let radiance = [1.5f32, 1.0, 0.5];
    let sky = Sky::constant(radiance);
    let volume = lit_open_sky([4, 3, 4], bounds, 1.0, &sky);
    let image = draw(&scene, &looking_down(), &volume, &sky, 16);
    assert!(image.hit.iter().all(|&h| h), "the plane fills the view");
    assert_eq!(image.unlit, 0);
    let want = (albedo * Vec3::from_array(radiance)).to_array();
    for p in &image.pixels {
        assert!(close(*p, want, 1e-4), "{p:?} vs {want:?}");
    }
}

#[test]
fn the_default_sky_lights_an_upward_surface_with_its_cosine_weighted_mean() {
    // L = c (1 + 0.6 ω_y) gives E = c (π + 0.6 · 2π/3) = 1.4 π c on an upward surface, so the
    // surface shows 1.4 ρ c (order-3 SH holds this sky exactly).
    let albedo = Vec3::splat(0.5);
    let scene = Scene::ground_plane(2.0, albedo);
    let bounds = Aabb::new(Vec3::splat(-2.0), Vec3::splat(2.0));
    let sky = Sky::default();
    let volume = lit_open_sky([2, 2, 2], bounds, 1.0, &sky);
    let image = draw(&scene, &looking_down(), &volume, &sky, 8);
    let want = [0.9f32, 1.0, 1.2].map(|c| 1.4 * 0.5 * c);
    for p in &image.pixels {
        assert!(close(*p, want, 1e-4), "{p:?} vs {want:?}");
    }
}

#[test]
fn a_miss_shows_the_sky_along_the_ray() {
    let scene = Scene::ground_plane(1.0, Vec3::ONE);
    let sky = Sky::default();
    let bounds = Aabb::new(Vec3::splat(-1.0), Vec3::splat(1.0));
    let volume = lit_open_sky([2, 2, 2], bounds, 1.0, &sky);
    let up = PinholeView {
        position: Vec3::new(0.0, 1.0, 0.0),
        forward: Vec3::Y,
        up: Vec3::Z,
        yfov: 1.0,
    };
    let image = draw(&scene, &up, &volume, &sky, 9);
    assert!(image.hit.iter().all(|&h| !h));
    for (i, p) in image.pixels.iter().enumerate() {
        let want = sky.radiance(up.ray(i % 9, i / 9, 9, 9)).to_array();
        assert_eq!(*p, want);
    }
}

#[test]
fn invalid_voxels_are_left_out_of_the_interpolation() {
    // The lower layer of voxels is invalid and holds five times the sky: it must not show.
    let albedo = Vec3::splat(0.6);
    let scene = Scene::ground_plane(2.0, albedo);
    let bounds = Aabb::new(Vec3::new(-2.0, -1.0, -2.0), Vec3::new(2.0, 1.0, 2.0));
    let dims = [2, 2, 2];
    let mut transfer = open_sky(dims, bounds, 1.0);
    let mut valid = vec![true; 8];
    for v in 0..8 {
        if transfer.coords(v)[1] == 0 {
            valid[v] = false;
            for i in 0..9 {
                transfer.voxel_mut(v)[i * 9 + i] = 5.0;
            }
        }
    }
    let sky = Sky::constant([1.0; 3]);
    let volume = LitVolume::from_transfer(&transfer, &valid, &sky, &NoProgress).expect("volume");
    // No normal offset: the plane lies halfway between the two layers.
    let config = small(8, 8);
    let tracer = RayTracer::new(scene.triangles());
    let image = render(
        &scene,
        &tracer,
        &looking_down(),
        &AtSurface(&volume),
        &sky,
        &config,
        &NoProgress,
    )
    .expect("render");
    for p in &image.pixels {
        assert!(close(*p, [0.6; 3], 1e-4), "{p:?}");
    }
    // With every voxel invalid nothing is lit: the plane shows its (zero) emission.
    let none = LitVolume::from_transfer(&transfer, &[false; 8], &sky, &NoProgress).expect("volume");
    let dark = draw(&scene, &looking_down(), &none, &sky, 8);
    assert_eq!(dark.unlit, 64);
    assert!(dark.pixels.iter().all(|p| *p == [0.0; 3]));
}

/// A lit volume read at the surface point itself, with no normal offset.
struct AtSurface<'a>(&'a LitVolume);

impl SurfaceLight for AtSurface<'_> {
    fn surface_irradiance(&self, position: Vec3, normal: Vec3) -> Option<Vec3> {
        self.0.valid_irradiance_at(position, normal)
    }
}

#[test]
fn prts_lookup_moves_half_a_voxel_off_the_surface() {
    // Transfer that grows with height: the plane at y = 0 reads the volume at y = offset.
    let scene = Scene::ground_plane(2.0, Vec3::ONE);
    let bounds = Aabb::new(Vec3::new(-2.0, -2.0, -2.0), Vec3::new(2.0, 2.0, 2.0));
    let transfer = GridField::from_fn([2, 4, 2], bounds, TRANSFER_DIM, |c, t| {
        for i in 0..9 {
            t[i * 9 + i] = 1.0 + c.y;
        }
    })
    .expect("field");
    let sky = Sky::constant([1.0; 3]);
    let volume =
        LitVolume::from_transfer(&transfer, &[true; 16], &sky, &NoProgress).expect("volume");
    let tracer = RayTracer::new(scene.triangles());
    let at_surface = AtSurface(&volume);
    for (offset, light) in [(0.0f32, &at_surface as &dyn SurfaceLight), (0.5, &volume)] {
        let image = render(
            &scene,
            &tracer,
            &looking_down(),
            light,
            &sky,
            &small(4, 4),
            &NoProgress,
        )
        .expect("render");
        // One voxel is 1 unit tall; the transfer is linear in y between voxel centres.
        let want = 1.0 + offset;
        assert!(
            close(image.pixels[5], [want; 3], 1e-4),
            "{offset}: {:?}",
            image.pixels[5]
        );
    }
}

#[test]
fn an_emitter_seen_directly_shows_its_emission() {
    let scene = Scene::cornell_box();
    let bounds = scene.bounds().expect("bounds");
    let sky = Sky::constant([1.0; 3]);
    let volume = lit_open_sky([2, 2, 2], bounds, 0.0, &sky);
    // Looking up at the light from below it.
    let view = PinholeView {
        position: Vec3::new(0.0, 1.0, -0.03),
        forward: Vec3::Y,
        up: Vec3::Z,
        yfov: 0.1,
    };
    let image = draw(&scene, &view, &volume, &sky, 4);
    for p in &image.pixels {
        assert!(close(*p, [1.0; 3], 1e-6), "{p:?}");
    }
}

fn cornell_volume() -> (Scene, LitVolume, Sky) {
    let scene = Scene::cornell_box();
    let options = BakeOptions {
        resolution: [6, 6, 6],
        rays_per_voxel: 48,
        cache_rays: 16,
        seed: 3,
        ..Default::default()
    };
    let baked = TransferBaker::new(&scene, options)
        .expect("baker")
        .bake(&NoProgress)
        .expect("bake");
    let sky = Sky::default().rotated_about_y(30.0);
    let volume =
        LitVolume::from_transfer(&baked.field, &baked.valid, &sky, &NoProgress).expect("volume");
    (scene, volume, sky)
}

#[test]
fn the_image_is_the_same_on_any_thread_count() {
    let (scene, volume, sky) = cornell_volume();
    let view = views(&scene)[0].view;
    let run = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("pool")
            .install(|| draw(&scene, &view, &volume, &sky, 24))
    };
    let one = run(1);
    assert_eq!(one, run(3));
    // Something is lit, and the sky shows nowhere through the closed back of the box.
    assert!(one.pixels.iter().any(|p| p[0] > 0.01));
    assert!(one.hit[12 * 24 + 12]);
}

#[test]
fn cancelling_stops_the_render() {
    let (scene, volume, sky) = cornell_volume();
    let progress = AtomicProgress::new();
    progress.cancel();
    let tracer = RayTracer::new(scene.triangles());
    let view = views(&scene)[0].view;
    let result = render(
        &scene,
        &tracer,
        &view,
        &volume,
        &sky,
        &small(8, 8),
        &progress,
    );
    assert!(result.is_err());
}

#[test]
fn bad_inputs_are_errors() {
    let bounds = Aabb::new(Vec3::splat(-1.0), Vec3::splat(1.0));
    let sky = Sky::default();
    assert!(
        LitVolume::from_transfer(
            &open_sky([2, 2, 2], bounds, 1.0),
            &[true; 7],
            &sky,
            &NoProgress
        )
        .is_err()
    );
    let narrow = GridField::new([2, 2, 2], bounds, 27).expect("field");
    assert!(LitVolume::from_transfer(&narrow, &[true; 8], &sky, &NoProgress).is_err());
    let (scene, volume, sky) = cornell_volume();
    let tracer = RayTracer::new(scene.triangles());
    let view = views(&scene)[0].view;
    assert!(
        render(
            &scene,
            &tracer,
            &view,
            &volume,
            &sky,
            &small(0, 4),
            &NoProgress
        )
        .is_err()
    );
}

#[test]
fn views_list_the_cameras_then_front_and_inside() {
    let scene = Scene::cornell_box();
    let names: Vec<String> = views(&scene).into_iter().map(|v| v.name).collect();
    assert_eq!(names, ["front", "inside"]);
    let camera = Camera {
        name: Some("overhead".into()),
        to_world: Mat4::from_translation(Vec3::new(0.0, 1.0, 3.0)),
        yfov: 0.7,
        aspect_ratio: None,
        znear: 0.1,
    };
    let with = Scene::cornell_box().with_cameras([camera.clone()]);
    let all = views(&with);
    assert_eq!(all.len(), 3);
    assert_eq!(all[0].name, "overhead");
    assert_eq!(all[0].view, PinholeView::from_camera(&camera));
    // The inside view starts inside the box and looks into it.
    let inside = all[2].view;
    let bounds = with.bounds().expect("bounds");
    assert!(bounds.contains(inside.position));
    assert!(inside.forward.z < -0.9 && inside.up.y > 0.9);
    assert!(views(&Scene::empty()).is_empty());
}

#[test]
fn auto_exposure_maps_the_log_average_to_middle_grey() {
    let image = Rendered {
        width: 2,
        height: 1,
        pixels: vec![[0.5; 3], [2.0; 3]],
        hit: vec![true, true],
        unlit: 0,
    };
    let tone = ToneMap::auto(&image);
    assert!((tone.exposure - 0.18).abs() < 1e-5, "{}", tone.exposure);
    let bytes = tone.apply(&image);
    assert_eq!(bytes.len(), 6);
    assert!(bytes[0] < bytes[3]);
    assert_eq!(ToneMap { exposure: 1.0 }.display(0.0), 0.0);
    assert!(ToneMap { exposure: 1.0 }.display(1e9) <= 1.0);
}

#[test]
fn the_voxels_read_are_those_around_the_lookup_points() {
    // The plane y = 0 reads the volume half a voxel up, at y = 0.25: exactly the centres of the
    // third layer of four, so only that layer has weight.
    let scene = Scene::ground_plane(2.0, Vec3::ONE);
    let bounds = Aabb::new(Vec3::new(-2.0, -1.0, -2.0), Vec3::new(2.0, 1.0, 2.0));
    let grid = GridField::new([4, 4, 4], bounds, 1).expect("grid");
    let tracer = RayTracer::new(scene.triangles());
    let read = prt_render::voxels_read(&scene, &tracer, &looking_down(), &grid, &small(16, 16))
        .expect("voxels");
    assert!(read.iter().any(|&r| r));
    for (v, &r) in read.iter().enumerate() {
        let layer = grid.coords(v)[1];
        assert!(!r || layer == 2, "voxel {v} in layer {layer} read");
    }
    // A voxel of that layer under the view (which sees x, z within about ±0.62) is read.
    let centre = grid.index(1, 2, 1);
    assert!(read[centre]);
}

/// A flat test image: `value` on every surface pixel, the top row a miss showing `sky`.
fn flat(width: usize, height: usize, value: f32, sky: f32) -> Rendered {
    let hit: Vec<bool> = (0..width * height).map(|i| i >= width).collect();
    Rendered {
        width,
        height,
        pixels: hit
            .iter()
            .map(|&h| if h { [value; 3] } else { [sky; 3] })
            .collect(),
        hit,
        unlit: 0,
    }
}

#[test]
fn image_metrics_are_zero_for_the_same_image_and_grow_with_the_difference() {
    let reference = flat(32, 32, 0.2, 5.0);
    let tone = ToneMap { exposure: 1.0 };
    let same = image_metrics(&reference, &reference, &tone).expect("metrics");
    assert_eq!(same.pixels, 32 * 31, "only the surface pixels count");
    assert_eq!(
        (
            same.flip,
            same.mean_levels,
            same.share_off,
            same.dark_levels,
            same.median_relative
        ),
        (0.0, 0.0, 0.0, 0.0, 0.0)
    );
    // The sky differs but is not a surface: nothing changes.
    let other_sky = flat(32, 32, 0.2, 0.0);
    assert_eq!(
        image_metrics(&reference, &other_sky, &tone)
            .expect("metrics")
            .mean_levels,
        0.0
    );
    let mut last = same;
    for value in [0.21f32, 0.25, 0.4] {
        let m = image_metrics(&reference, &flat(32, 32, value, 5.0), &tone).expect("metrics");
        assert!(
            m.flip > last.flip && m.mean_levels > last.mean_levels,
            "{value}: {m:?}"
        );
        assert!((m.median_relative - f64::from(value / 0.2 - 1.0)).abs() < 1e-5);
        last = m;
    }
    assert_eq!(last.share_off, 1.0, "0.2 → 0.4 is far more than 10 levels");
    assert!(image_metrics(&reference, &flat(16, 32, 0.2, 5.0), &tone).is_err());
}
