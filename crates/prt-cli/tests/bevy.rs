//! Bevy itself, on a software Vulkan driver (Mesa's lavapipe): a small bake of the Cornell box
//! glTF, exported for Bevy (`--target bevy --format rgba16f`), rendered by the example of
//! examples/bevy/ without a window into a linear `Rgba16Float` image, must show per surface the
//! radiance that `prt render --lookup bevy` computes from the same export, and no surface may
//! be black (issue 36: walls on the light probe's faces, where Bevy weighs the probe 0).
//!
//! The example binary is built by .ci/extra and named by `PRT_BEVY_EXAMPLE`; without it (at
//! build time) the test is ignored unless `PRT_REQUIRE_BEVY=1`. With
//! `PRT_BEVY_DOCS_DIR=DIR` it bakes finer (32³ voxels, 512 rays, for a less noisy picture) and
//! also writes both images into DIR as `bevy-cornell.png` and
//! `prt-render-bevy-lookup-cornell.png`, tone-mapped alike with prt render's tone map (the
//! exposure that maps prt's log-average luminance to 0.18, Narkowicz's ACES fit, sRGB).
//!
//! Measured (Mesa 22.3.6 lavapipe, 16³ bake, 256² pixels): per-surface median relative error
//! 0.03–0.04 %, 90th percentile ≤ 0.07 %, no pixel below 0.999 × prt's (the `Rgba16Float`
//! texture and image round to 2⁻¹¹); with the placement box shrunk to the bake bounds (the
//! bug) the ceiling, floor and back wall have black pixels and medians of 5–14 %. Pixels are
//! classified by the surface prt's ray hits (material and facing axis), and only those whose
//! 8 neighbours see the same surface are judged (the rasteriser and the rays may differ on
//! edges).
//!
//! The lightmap test: `prt lightmap` bakes an irradiance lightmap of the same Cornell box (64
//! samples per texel, 16 texels/m) with `--engine bevy`; the example renders the export's GLB
//! with Bevy's own `Lightmap` on every mesh (UV_1, texels `E/π`) and no other light, and each
//! surface must show what `prt lightmap`'s `view.exr` shows (prt-lightmap's `render_view`, same
//! camera, `albedo/π · E` bilinear in f32), under the same bounds as above, and the red and
//! green walls must keep their colours. Measured (Mesa 22.3.6 lavapipe, 256² pixels):
//! per-surface median relative error 0.03–0.04 %, 90th percentile ≤ 0.07 %, darkest ratio 0.999
//! (the f16 texture and image). With `PRT_BEVY_DOCS_DIR` it bakes 1024 samples and also writes
//! `bevy-lightmap-cornell.png` and `prt-lightmap-cornell.png`.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

use glam::Vec3;
use prt_render::{Rendered, ToneMap, luminance, views};
use prt_texture::Limits;
use prt_trace::RayTracer;
use prt_trace::camera::PinholeView;
use prt_trace::mesh::read_mesh;

/// Image side in pixels.
const SIZE: usize = 256;
/// Largest per-surface median relative error (luminance) between Bevy and `prt render`
/// (measured: 0.04 %).
const MAX_MEDIAN_ERROR: f64 = 0.002;
/// Largest per-surface 90th percentile of it (measured: 0.07 %).
const MAX_P90_ERROR: f64 = 0.005;
/// Smallest ratio of Bevy's to prt's luminance at any surface pixel (measured: 0.999; the old
/// bug gave 0).
const MIN_RATIO: f64 = 0.9;
/// Surfaces with fewer interior pixels than this are reported but not judged.
const MIN_PIXELS: usize = 40;

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("prt-bevy-test-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("temp dir");
    dir
}

fn run(command: &mut Command) -> String {
    let out = command.output().expect("the command runs");
    let text =
        String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{command:?} failed:\n{text}");
    text
}

fn prt() -> Command {
    Command::new(env!("CARGO_BIN_EXE_prt"))
}

/// The Cornell box of ../shared/scenes (beside the workspace).
fn cornell_gltf() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/scenes/cornell_box/CornellBox-Original.gltf")
}

fn bevy_example() -> PathBuf {
    let path = PathBuf::from(std::env::var_os("PRT_BEVY_EXAMPLE").expect(
        "PRT_BEVY_EXAMPLE names the built examples/bevy binary (the test runs because \
         PRT_REQUIRE_BEVY=1 or because it was set when the test was built)",
    ));
    assert!(
        path.is_file(),
        "PRT_BEVY_EXAMPLE={} is not a file",
        path.display()
    );
    path
}

/// A Portable Float Map (`PF`, RGB, bottom row first) as rows from the top.
fn read_pfm(path: &Path) -> Rendered {
    let bytes = std::fs::read(path).expect("read the screenshot");
    let mut fields = Vec::new();
    let mut start = 0;
    let mut at = 0;
    while fields.len() < 4 {
        if bytes[at].is_ascii_whitespace() {
            if at > start {
                fields.push(String::from_utf8_lossy(&bytes[start..at]).into_owned());
            }
            start = at + 1;
        }
        at += 1;
    }
    assert_eq!(fields[0], "PF", "not an RGB PFM");
    let width: usize = fields[1].parse().expect("width");
    let height: usize = fields[2].parse().expect("height");
    let scale: f32 = fields[3].parse().expect("scale");
    let data = &bytes[at..];
    assert_eq!(data.len(), 12 * width * height, "PFM data size");
    let value = |i: usize| {
        let b: [u8; 4] = data[4 * i..4 * i + 4].try_into().expect("4 bytes");
        if scale < 0.0 {
            f32::from_le_bytes(b)
        } else {
            f32::from_be_bytes(b)
        }
    };
    let mut pixels = Vec::with_capacity(width * height);
    for y in 0..height {
        let row = height - 1 - y;
        for x in 0..width {
            let i = 3 * (row * width + x);
            pixels.push([value(i), value(i + 1), value(i + 2)]);
        }
    }
    Rendered {
        width,
        height,
        hit: vec![true; pixels.len()],
        pixels,
        unlit: 0,
    }
}

fn read_exr(path: &Path) -> Rendered {
    let image = image::open(path).expect("read the EXR").to_rgb32f();
    let (width, height) = (image.width() as usize, image.height() as usize);
    let pixels: Vec<[f32; 3]> = image.pixels().map(|p| p.0).collect();
    Rendered {
        width,
        height,
        hit: vec![true; pixels.len()],
        pixels,
        unlit: 0,
    }
}

fn save_png(path: &Path, image: &Rendered, tone: &ToneMap) {
    image::RgbImage::from_raw(image.width as u32, image.height as u32, tone.apply(image))
        .expect("size")
        .save(path)
        .expect("write PNG");
}

/// The surface each pixel of `view` sees: `material name` and the sign and axis of the
/// geometric normal facing the camera (`floor +y`), or `None` for a miss or an emitter.
fn surfaces_of(scene: &prt_trace::Scene, view: &PinholeView) -> Vec<Option<String>> {
    let tracer = RayTracer::new(scene.triangles());
    let mut out = Vec::with_capacity(SIZE * SIZE);
    for y in 0..SIZE {
        for x in 0..SIZE {
            let dir = view.ray(x, y, SIZE, SIZE);
            out.push(
                tracer
                    .closest_hit(view.position, dir, 0.0, f32::INFINITY)
                    .and_then(|hit| {
                        let material = scene.material_of(hit.triangle as usize);
                        if material.emissive != Vec3::ZERO {
                            return None;
                        }
                        let n = if hit.normal.dot(dir) > 0.0 {
                            -hit.normal
                        } else {
                            hit.normal
                        };
                        let axis = n.abs().max_position();
                        let sign = if n[axis] > 0.0 { '+' } else { '-' };
                        Some(format!("{} {sign}{}", material.name, ["x", "y", "z"][axis]))
                    }),
            );
        }
    }
    out
}

/// `--view EX,EY,EZ,TX,TY,TZ,FOV` of the example for `view` (+Y up).
fn view_arg(view: &PinholeView) -> String {
    let target = view.position + view.forward;
    let e = view.position;
    [
        e.x,
        e.y,
        e.z,
        target.x,
        target.y,
        target.z,
        view.yfov.to_degrees(),
    ]
    .map(|v| format!("{v}"))
    .join(",")
}

/// The surfaces [`surfaces_of`] sees from the bake's camera `camera`, and its `--view`.
fn surfaces(bake: &Path, camera: usize) -> (Vec<Option<String>>, String) {
    let scene = read_mesh(&bake.join("scene.mesh"), &Limits::default()).expect("scene mesh");
    let view = views(&scene)[camera].view;
    (surfaces_of(&scene, &view), view_arg(&view))
}

/// Pixels whose 8 neighbours see the same surface (rasterisation and ray casting may disagree
/// along edges).
fn interior(surface: &[Option<String>]) -> Vec<bool> {
    let s = SIZE as isize;
    (0..SIZE * SIZE)
        .map(|i| {
            let (x, y) = ((i % SIZE) as isize, (i / SIZE) as isize);
            surface[i].is_some()
                && (-1..=1).all(|dy| {
                    (-1..=1).all(|dx| {
                        let (u, v) = (x + dx, y + dy);
                        (0..s).contains(&u)
                            && (0..s).contains(&v)
                            && surface[(v * s + u) as usize] == surface[i]
                    })
                })
        })
        .collect()
}

/// Bevy against prt on the interior pixels of one surface (luminance).
struct SurfaceStats {
    pixels: usize,
    /// Mean linear RGB of Bevy's and of prt's pixels.
    mean_bevy: [f64; 3],
    mean_cpu: [f64; 3],
    /// Median and 90th percentile of `|Bevy − prt| / prt`.
    median: f64,
    p90: f64,
    /// Smallest `Bevy / prt`.
    darkest: f64,
}

impl std::fmt::Display for SurfaceStats {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let luma = |c: [f64; 3]| luminance(c.map(|v| v as f32));
        write!(
            f,
            "{:5} px, mean luminance Bevy {:.4} / prt {:.4}, relative error median {:.2} % \
             p90 {:.2} %, darkest ratio {:.3}",
            self.pixels,
            luma(self.mean_bevy),
            luma(self.mean_cpu),
            100.0 * self.median,
            100.0 * self.p90,
            self.darkest
        )
    }
}

/// Prints each surface's statistics and returns what breaks the bounds: a pixel darker than
/// [`MIN_RATIO`] × prt's (a black wall), or, on surfaces of [`MIN_PIXELS`]+ pixels, a median or
/// 90th-percentile relative error above [`MAX_MEDIAN_ERROR`] / [`MAX_P90_ERROR`].
fn surface_failures(by_surface: &BTreeMap<String, SurfaceStats>) -> Vec<String> {
    let mut failures = Vec::new();
    for (name, stats) in by_surface {
        eprintln!("{name:>14}: {stats}");
        if stats.darkest < MIN_RATIO {
            failures.push(format!(
                "{name}: a pixel at {:.3} × prt's luminance (a black wall?)",
                stats.darkest
            ));
        }
        if stats.pixels >= MIN_PIXELS
            && (stats.median > MAX_MEDIAN_ERROR || stats.p90 > MAX_P90_ERROR)
        {
            failures.push(format!(
                "{name}: relative error median {:.2} % p90 {:.2} % (at most {:.2} % / {:.2} %)",
                100.0 * stats.median,
                100.0 * stats.p90,
                100.0 * MAX_MEDIAN_ERROR,
                100.0 * MAX_P90_ERROR
            ));
        }
    }
    failures
}

/// At least five surfaces are large enough in view to be judged.
fn assert_enough_surfaces(by_surface: &BTreeMap<String, SurfaceStats>) {
    let judged = by_surface
        .values()
        .filter(|stats| stats.pixels >= MIN_PIXELS)
        .count();
    assert!(
        judged >= 5,
        "only {judged} surfaces with {MIN_PIXELS}+ pixels in view"
    );
}

/// Per surface ([`surfaces_of`]), over its [`interior`] pixels.
fn compare_by_surface(
    bevy: &Rendered,
    cpu: &Rendered,
    surface: &[Option<String>],
) -> BTreeMap<String, SurfaceStats> {
    let inside = interior(surface);
    let mut by_surface: BTreeMap<String, Vec<usize>> = BTreeMap::new();
    for i in 0..SIZE * SIZE {
        if let (true, Some(name)) = (inside[i], &surface[i]) {
            by_surface.entry(name.clone()).or_default().push(i);
        }
    }
    let mean = |image: &Rendered, pixels: &[usize]| -> [f64; 3] {
        std::array::from_fn(|c| {
            pixels
                .iter()
                .map(|&i| f64::from(image.pixels[i][c]))
                .sum::<f64>()
                / pixels.len() as f64
        })
    };
    by_surface
        .into_iter()
        .map(|(name, pixels)| {
            let pairs: Vec<(f64, f64)> = pixels
                .iter()
                .map(|&i| {
                    (
                        f64::from(luminance(bevy.pixels[i])),
                        f64::from(luminance(cpu.pixels[i])),
                    )
                })
                .collect();
            let mut errors: Vec<f64> = pairs
                .iter()
                .map(|&(b, c)| (b - c).abs() / c.max(1e-12))
                .collect();
            errors.sort_by(f64::total_cmp);
            let stats = SurfaceStats {
                pixels: pixels.len(),
                mean_bevy: mean(bevy, &pixels),
                mean_cpu: mean(cpu, &pixels),
                median: errors[errors.len() / 2],
                p90: errors[errors.len() * 9 / 10],
                darkest: pairs
                    .iter()
                    .map(|&(b, c)| b / c.max(1e-12))
                    .fold(f64::INFINITY, f64::min),
            };
            (name, stats)
        })
        .collect()
}

#[test]
#[cfg_attr(
    prt_skip_bevy,
    ignore = "needs the examples/bevy binary (PRT_BEVY_EXAMPLE) and ../shared/scenes, absent at \
              build time (PRT_REQUIRE_BEVY=1 and PRT_REQUIRE_SHARED=1 require them)"
)]
fn bevy_on_lavapipe_shows_what_prt_render_shows_and_no_black_walls() {
    let gltf = cornell_gltf();
    assert!(
        gltf.is_file(),
        "{} is missing (the test runs because PRT_REQUIRE_SHARED=1 or because it was there at \
         build time)",
        gltf.display()
    );
    let example = bevy_example();
    let dir = scratch("cornell");
    let bake = dir.join("bake");
    let docs = std::env::var_os("PRT_BEVY_DOCS_DIR").map(PathBuf::from);
    let quality: &[&str] = if docs.is_some() {
        &["--res", "32", "--rays", "512"]
    } else {
        &[
            "--res",
            "16",
            "--rays",
            "64",
            "--cache-rays",
            "16",
            "--rank",
            "4",
        ]
    };
    run(prt()
        .arg("bake")
        .arg(&gltf)
        .args(quality)
        .args(["--basis-nodes", "3", "--iterations", "8", "--no-baselines"])
        .arg("--out")
        .arg(&bake));
    let export = dir.join("bevy");
    run(prt()
        .arg("export")
        .arg(&bake)
        .args(["--target", "bevy", "--format", "rgba16f", "--out"])
        .arg(&export));

    let camera = 0;
    let (surface, view) = surfaces(&bake, camera);
    let shot = dir.join("bevy.pfm");
    let started = std::time::Instant::now();
    let mut bevy_command = Command::new(example);
    bevy_command
        .arg(&export)
        .arg(&gltf)
        .args(["--view", &view])
        .args(["--size", &SIZE.to_string(), "--frames", "3", "--screenshot"])
        .arg(&shot)
        .env("WGPU_BACKEND", "vulkan")
        .env("RUST_LOG", "warn");
    eprintln!("{bevy_command:?}");
    let log = run(&mut bevy_command);
    eprintln!(
        "Bevy rendered in {:.1} s: {}",
        started.elapsed().as_secs_f64(),
        log.lines()
            .filter(|l| l.starts_with("wrote"))
            .collect::<String>()
    );
    let bevy = read_pfm(&shot);
    assert_eq!((bevy.width, bevy.height), (SIZE, SIZE));

    let reference = dir.join("prt.exr");
    run(prt()
        .arg("render")
        .arg(&bake)
        .args(["--camera", &camera.to_string(), "--size", &SIZE.to_string()])
        .args(["--lookup", "bevy", "--out"])
        .arg(&reference));
    let cpu = read_exr(&reference);

    if let Some(docs) = &docs {
        // Both with the exposure prt render picks for its own image.
        let mut lit = cpu.clone();
        lit.hit = surface.iter().map(Option::is_some).collect();
        let tone = ToneMap::auto(&lit);
        save_png(&docs.join("bevy-cornell.png"), &bevy, &tone);
        save_png(
            &docs.join("prt-render-bevy-lookup-cornell.png"),
            &cpu,
            &tone,
        );
    }

    let by_surface = compare_by_surface(&bevy, &cpu, &surface);
    let failures = surface_failures(&by_surface);
    assert_enough_surfaces(&by_surface);
    assert!(
        failures.is_empty(),
        "{} (images in {})",
        failures.join("; "),
        dir.display()
    );
    let _ = std::fs::remove_dir_all(&dir);
}

fn json_vec3(v: &serde_json::Value) -> Vec3 {
    Vec3::from_array(std::array::from_fn(|k| {
        v[k].as_f64().expect("a number") as f32
    }))
}

#[test]
#[cfg_attr(
    prt_skip_bevy,
    ignore = "needs the examples/bevy binary (PRT_BEVY_EXAMPLE) and ../shared/scenes, absent at \
              build time (PRT_REQUIRE_BEVY=1 and PRT_REQUIRE_SHARED=1 require them)"
)]
fn bevy_lightmap_on_lavapipe_shows_what_prt_lightmap_shows() {
    let gltf = cornell_gltf();
    assert!(gltf.is_file(), "{} is missing", gltf.display());
    let example = bevy_example();
    let dir = scratch("lightmap");
    let out = dir.join("lightmap");
    let docs = std::env::var_os("PRT_BEVY_DOCS_DIR").map(PathBuf::from);
    let samples = if docs.is_some() { "1024" } else { "64" };
    run(prt()
        .arg("lightmap")
        .arg(&gltf)
        .args([
            "--basis",
            "irradiance",
            "--samples",
            samples,
            "--pass",
            "64",
        ])
        .args(["--preview-every", "0", "--texels-per-metre", "16"])
        .args([
            "--view-size",
            &SIZE.to_string(),
            "--engine",
            "bevy",
            "--out",
        ])
        .arg(&out));
    let manifest: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(out.join("manifest.json")).expect("manifest"),
    )
    .expect("manifest JSON");
    let camera = &manifest["view"];
    let view = PinholeView {
        position: json_vec3(&camera["position"]),
        forward: json_vec3(&camera["forward"]),
        up: json_vec3(&camera["up"]),
        yfov: camera["yfov"].as_f64().expect("yfov") as f32,
    };
    assert_eq!(view.up, Vec3::Y, "the example's camera has +Y up");
    let scene = prt_trace::Scene::load_gltf(&gltf, &prt_trace::LoadOptions::default())
        .expect("load the Cornell box");
    let surface = surfaces_of(&scene, &view);

    let shot = dir.join("bevy.pfm");
    let started = std::time::Instant::now();
    let mut bevy_command = Command::new(example);
    bevy_command
        .arg(out.join("bevy"))
        .args(["--view", &view_arg(&view)])
        .args(["--size", &SIZE.to_string(), "--frames", "3", "--screenshot"])
        .arg(&shot)
        .env("WGPU_BACKEND", "vulkan")
        .env("RUST_LOG", "warn");
    eprintln!("{bevy_command:?}");
    run(&mut bevy_command);
    eprintln!(
        "Bevy rendered the lightmap in {:.1} s",
        started.elapsed().as_secs_f64()
    );
    let bevy = read_pfm(&shot);
    assert_eq!((bevy.width, bevy.height), (SIZE, SIZE));
    let cpu = read_exr(&out.join("view.exr"));
    assert_eq!((cpu.width, cpu.height), (SIZE, SIZE));

    if let Some(docs) = &docs {
        let mut lit = cpu.clone();
        lit.hit = surface.iter().map(Option::is_some).collect();
        let tone = ToneMap::auto(&lit);
        save_png(&docs.join("bevy-lightmap-cornell.png"), &bevy, &tone);
        save_png(&docs.join("prt-lightmap-cornell.png"), &cpu, &tone);
    }

    let by_surface = compare_by_surface(&bevy, &cpu, &surface);
    let mut failures = surface_failures(&by_surface);
    // The walls keep their colours: a lightmap read at the wrong UVs or channel mixes them.
    for (wall, channel, other) in [("leftWall +x", 0, 1), ("rightWall -x", 1, 0)] {
        let stats = by_surface
            .get(wall)
            .unwrap_or_else(|| panic!("no {wall} in view"));
        let mean = stats.mean_bevy;
        if mean[channel] <= 2.0 * mean[other] || mean[channel].is_nan() {
            failures.push(format!("{wall}: Bevy's mean {mean:?} lost its colour"));
        }
    }
    assert_enough_surfaces(&by_surface);
    assert!(
        failures.is_empty(),
        "{} (images in {})",
        failures.join("; "),
        dir.display()
    );
    let _ = std::fs::remove_dir_all(&dir);
}
