//! Bakes the Cornell box (32³) and Sponza (64³) transfer volumes, prints timings, Mrays/s and
//! peak RSS, and writes the horizontal-slice pictures of docs/images/trace_*.png.
//!
//! `cargo run --release -p prt-benches --bin trace_bake [cornell|sponza|sponza128|all] [rays] [cache rays] [fast|medium|slow|very-slow]`
//!
//! The last argument is the BVH build quality (default `medium`, the baker's default); the
//! pictures are written for the default quality only.
use std::path::Path;
use std::time::Instant;

use prt_benches::{Table, cpu_seconds, fmt_duration};
use prt_core::NoProgress;
use prt_trace::{
    BakeOptions, BuildQuality, LoadOptions, RayTracer, Scene, TransferBaker, TransferVolume,
    constant_sky,
};

fn peak_rss_mib() -> f64 {
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    status
        .lines()
        .find_map(|l| l.strip_prefix("VmHWM:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<f64>().ok())
        .map_or(f64::NAN, |kb| kb / 1024.0)
}

/// Two panels side by side: sky visibility (grey) and mean indirect radiance under a unit
/// constant sky (RGB, x4 exposure), on the horizontal voxel slice `iy`; invalid voxels magenta.
fn write_slice(volume: &TransferVolume, iy: usize, path: &Path) {
    let [nx, _, nz] = volume.field.dims();
    let scale = (512 / nx.max(nz)).max(1) as u32;
    let (w, h) = (nx as u32 * scale, nz as u32 * scale);
    let mut img = image::RgbImage::new(2 * w + scale, h);
    let sky = [constant_sky(1.0); 3];
    let y0 = prt_trace::sh9(glam::Vec3::Y)[0];
    let to8 = |x: f32| (255.0 * x.clamp(0.0, 1.0).powf(1.0 / 2.2)).round() as u8;
    for ix in 0..nx {
        for iz in 0..nz {
            let v = volume.field.index(ix, iy, iz);
            let (vis, ind) = if volume.valid[v] {
                let l = volume.incident(v, &sky);
                let vis = volume.sky_visibility(v);
                let ind = [1, 2, 3].map(|c| 4.0 * l[c][0] * y0);
                ([to8(vis); 3], ind.map(to8))
            } else {
                ([255, 0, 255], [255, 0, 255])
            };
            for dx in 0..scale {
                for dz in 0..scale {
                    let (px, py) = (ix as u32 * scale + dx, iz as u32 * scale + dz);
                    img.put_pixel(px, py, image::Rgb(vis));
                    img.put_pixel(w + scale + px, py, image::Rgb(ind));
                }
            }
        }
    }
    if let Err(e) = img.save(path) {
        eprintln!("cannot write {}: {e}", path.display());
    }
}

fn main() {
    let which = std::env::args().nth(1).unwrap_or_else(|| "all".into());
    let rays: usize = std::env::args()
        .nth(2)
        .and_then(|s| s.parse().ok())
        .unwrap_or(256);
    let cache_rays: usize = std::env::args()
        .nth(3)
        .and_then(|s| s.parse().ok())
        .unwrap_or(64);
    let quality = match std::env::args().nth(4).as_deref() {
        Some("fast") => BuildQuality::Fast,
        Some("slow") => BuildQuality::Slow,
        Some("very-slow") => BuildQuality::VerySlow,
        _ => BuildQuality::Medium,
    };
    let scenes = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/scenes");
    let images = Path::new(env!("CARGO_MANIFEST_DIR")).join("../docs/images");
    let mut table = Table::new(&[
        "scene",
        "triangles",
        "grid",
        "rays/voxel",
        "BVH",
        "cache points (evaluated sides)",
        "tracing",
        "total (wall)",
        "total (CPU)",
        "Mrays/s wall (CPU-normalised)",
        "invalid",
        "peak RSS",
    ]);
    let mut jobs: Vec<(&str, usize, f32)> = Vec::new();
    if which == "cornell" || which == "all" {
        jobs.push(("cornell", 32, 0.0));
    }
    if which == "sponza" || which == "all" {
        jobs.push(("sponza", 64, 0.0));
    }
    if which == "sponza128" {
        jobs.push(("sponza", 128, 0.0));
    }
    for (name, res, margin) in jobs {
        let t_load = Instant::now();
        let scene = match name {
            "cornell" => Scene::cornell_box(),
            _ => match Scene::load_gltf(scenes.join("sponza/Sponza.gltf"), &LoadOptions::default())
            {
                Ok(s) => s,
                Err(e) => {
                    eprintln!("skipping Sponza: {e}");
                    continue;
                }
            },
        };
        eprintln!(
            "{name}: {} triangles loaded in {}",
            scene.triangles().len(),
            fmt_duration(t_load.elapsed())
        );
        let options = BakeOptions {
            resolution: [res; 3],
            margin,
            rays_per_voxel: rays,
            cache_rays,
            seed: 1,
            build_quality: quality,
            ..Default::default()
        };
        let t = Instant::now();
        let cpu0 = cpu_seconds();
        let volume = match TransferBaker::new(&scene, options).and_then(|b| b.bake(&NoProgress)) {
            Ok(v) => v,
            Err(e) => {
                eprintln!("{name}: bake failed: {e}");
                continue;
            }
        };
        let total = t.elapsed();
        let cpu = cpu_seconds() - cpu0;
        let s = &volume.stats;
        table.row(vec![
            name.into(),
            scene.triangles().len().to_string(),
            format!("{res}³"),
            s.rays_per_voxel.to_string(),
            fmt_duration(s.bvh_time),
            format!("{} ({})", s.cache_points, s.cache_evaluated),
            fmt_duration(s.voxel_time),
            fmt_duration(total),
            format!("{cpu:.2} s"),
            format!(
                "{:.2} ({:.2})",
                s.mrays_per_second(),
                s.rays() as f64 / (cpu / rayon::current_num_threads() as f64) / 1e6
            ),
            s.invalid_voxels.to_string(),
            format!("{:.0} MiB", peak_rss_mib()),
        ]);
        if res <= 64 && quality == BuildQuality::Medium {
            let iy = match name {
                "cornell" => res * 3 / 10, // y ≈ 0.6: between the short box's top and the tall box's
                _ => res / 8,              // just above Sponza's ground floor
            };
            write_slice(&volume, iy, &images.join(format!("trace_{name}_slice.png")));
        }
    }
    println!(
        "threads: {}, BVH quality: {quality:?}, instruction set: {}\n",
        rayon::current_num_threads(),
        RayTracer::new(&[]).instruction_set()
    );
    println!("{}", table.markdown());
    if let Err(e) = table.write_csv_if_requested("trace_bake") {
        eprintln!("csv: {e}");
    }
}
