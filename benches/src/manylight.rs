//! Helpers shared by the many-light sweeps: the budget list, VPL tracing to a target count and image strips.

use std::path::Path;

use prt_core::NoProgress;
use prt_trace::{LoadOptions, RayTracer, Scene, Vpl, VplOptions, trace_vpls};

/// The (rows, columns) budgets of the sweep, from 100/200 to 900/1800 (300/900 is the
/// paper's; 432/864 and 400/1300 sit near 50x fewer elements at 256²).
pub const BUDGETS: [(usize, usize); 6] = [
    (100, 200),
    (300, 900),
    (432, 864),
    (400, 1300),
    (600, 1200),
    (900, 1800),
];

/// The scene of a sweep by name: `cornell` (built in) or `sponza` (`../shared/scenes/sponza`,
/// relative to the benches' `manifest` directory). `None`, with the reason on stderr, when it is
/// unknown or cannot be loaded.
pub fn load_scene(name: &str, manifest: &Path) -> Option<Scene> {
    match name {
        "cornell" => Some(Scene::cornell_box()),
        "sponza" => {
            let path = manifest.join("../../shared/scenes/sponza/Sponza.gltf");
            Scene::load_gltf(&path, &LoadOptions::default())
                .map_err(|e| eprintln!("skipping Sponza: {e}"))
                .ok()
        }
        other => {
            eprintln!("unknown scene {other} (cornell or sponza)");
            None
        }
    }
}

/// About `target` VPLs (two bounces, seed 1): a pilot run of 2000 particles measures VPLs per
/// particle. Panics on a scene without lights (a sweep's setup error).
pub fn trace_about(scene: &Scene, tracer: &RayTracer, target: usize) -> Vec<Vpl> {
    let options = |particles| VplOptions {
        particles,
        max_bounces: 2,
        seed: 1,
        ..Default::default()
    };
    let pilot = trace_vpls(scene, tracer, &options(2000), &NoProgress).expect("lit scene");
    let per_particle = (pilot.len() as f64 / 2000.0).max(0.1);
    let particles = (target as f64 / per_particle).round().max(1.0) as usize;
    trace_vpls(scene, tracer, &options(particles), &NoProgress).expect("lit scene")
}

/// Writes `reference | panels…` side by side (square RGB images of `width`), tone-mapped with
/// one exposure (99th percentile of the reference at 0.8) and sRGB gamma; reports failure on
/// stderr instead of stopping the sweep.
pub fn write_strip(path: &Path, width: usize, reference: &[f32], panels: &[Vec<f32>]) {
    let mut sorted: Vec<f32> = reference.to_vec();
    sorted.sort_by(f32::total_cmp);
    let exposure = 0.8 / sorted[(sorted.len() * 99) / 100].max(1e-12);
    let tone = |v: f32| ((v * exposure).clamp(0.0, 1.0).powf(1.0 / 2.2) * 255.0).round() as u8;
    let panels: Vec<&[f32]> = std::iter::once(reference)
        .chain(panels.iter().map(Vec::as_slice))
        .collect();
    let mut out = image::RgbImage::new((panels.len() * width) as u32, width as u32);
    for (k, panel) in panels.iter().enumerate() {
        for y in 0..width {
            for x in 0..width {
                let p = 3 * (y * width + x);
                let rgb = [tone(panel[p]), tone(panel[p + 1]), tone(panel[p + 2])];
                out.put_pixel((k * width + x) as u32, y as u32, image::Rgb(rgb));
            }
        }
    }
    match out.save(path) {
        Ok(()) => println!("wrote {}", path.display()),
        Err(e) => eprintln!("could not write {}: {e}", path.display()),
    }
}
