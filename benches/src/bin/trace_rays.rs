//! Raw ray throughput of prt-trace's CWBVH: 10M random rays (origins uniform in the scene box,
//! directions uniform on the sphere), closest hit and shadow (first hit), on 2 threads, for the
//! scenes of ../shared/design/anchors.md, next to the anchor figures (obvhs and Embree).
//!
//! `cargo run --release -p prt-benches --bin trace_rays [rays] [fast|medium|slow]`
use std::path::Path;
use std::time::Instant;

use glam::Vec3;
use prt_benches::{Table, fmt_duration};
use prt_trace::{BuildQuality, LoadOptions, RayTracer, Scene};
use rand::{Rng, SeedableRng};
use rayon::prelude::*;

/// CPU time (user + system) of this process so far, in seconds (Linux `/proc/self/stat`, 100
/// ticks per second). On a shared machine, rays / (CPU time / 2) estimates what 2 free cores do.
fn cpu_seconds() -> f64 {
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    let rest = stat.rsplit(')').next().unwrap_or("");
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks = |i: usize| {
        f.get(i)
            .and_then(|v| v.parse::<f64>().ok())
            .unwrap_or(f64::NAN)
    };
    (ticks(11) + ticks(12)) / 100.0
}

fn random_rays(scene: &Scene, count: usize, seed: u64) -> Vec<(Vec3, Vec3)> {
    let Some(b) = scene.bounds() else {
        return Vec::new();
    };
    let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(seed);
    (0..count)
        .map(|_| {
            let o = b.min + b.size() * Vec3::new(rng.random(), rng.random(), rng.random());
            let z: f32 = rng.random_range(-1.0..1.0);
            let phi: f32 = rng.random_range(0.0..std::f32::consts::TAU);
            let r = (1.0 - z * z).max(0.0).sqrt();
            (o, Vec3::new(r * phi.cos(), z, r * phi.sin()))
        })
        .collect()
}

fn main() {
    let count: usize = std::env::args()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(10_000_000);
    let quality = match std::env::args().nth(2).as_deref() {
        Some("fast") => BuildQuality::Fast,
        Some("slow") => BuildQuality::Slow,
        _ => BuildQuality::Medium,
    };
    let scenes = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/scenes");
    // (name, loader, anchor obvhs closest/shadow, anchor Embree closest/shadow) in Mrays/s.
    let anchors: [(&str, Option<&str>, [f64; 4]); 3] = [
        ("Cornell", None, [17.3, 21.0, 16.3, 22.0]),
        (
            "Sponza",
            Some("sponza/Sponza.gltf"),
            [4.65, 7.45, 7.02, 12.5],
        ),
        (
            "Gas station",
            Some("gas_station/GasStation.gltf"),
            [8.65, 8.23, 14.8, 13.6],
        ),
    ];
    let mut table = Table::new(&[
        "scene",
        "triangles",
        "BVH build",
        "closest Mrays/s wall (CPU-normalised)",
        "shadow Mrays/s wall (CPU-normalised)",
        "hit rate",
        "CPU-normalised vs obvhs anchor (closest / shadow)",
        "CPU-normalised vs Embree anchor (closest / shadow)",
    ]);
    for (name, file, a) in anchors {
        let scene = match file {
            None => Scene::cornell_box(),
            Some(f) => match Scene::load_gltf(scenes.join(f), &LoadOptions::default()) {
                Ok(s) => s,
                Err(e) => {
                    eprintln!("skipping {name}: {e}");
                    continue;
                }
            },
        };
        let t = Instant::now();
        let tracer = RayTracer::with_quality(scene.triangles(), quality);
        let build = t.elapsed();
        let rays = random_rays(&scene, count, 7);
        let threads = rayon::current_num_threads() as f64;
        let (t, c) = (Instant::now(), cpu_seconds());
        let hits = rays
            .par_iter()
            .with_min_len(4096)
            .filter(|&&(o, d)| tracer.closest_hit(o, d, 0.0, f32::INFINITY).is_some())
            .count();
        let closest = count as f64 / t.elapsed().as_secs_f64() / 1e6;
        let closest_cpu = count as f64 / ((cpu_seconds() - c) / threads) / 1e6;
        let (t, c) = (Instant::now(), cpu_seconds());
        let blocked = rays
            .par_iter()
            .with_min_len(4096)
            .filter(|&&(o, d)| tracer.occluded(o, d, 0.0, f32::INFINITY))
            .count();
        let shadow = count as f64 / t.elapsed().as_secs_f64() / 1e6;
        let shadow_cpu = count as f64 / ((cpu_seconds() - c) / threads) / 1e6;
        if blocked != hits {
            eprintln!("{name}: {hits} closest hits but {blocked} occluded shadow rays");
        }
        table.row(vec![
            name.into(),
            scene.triangles().len().to_string(),
            fmt_duration(build),
            format!("{closest:.2} ({closest_cpu:.2})"),
            format!("{shadow:.2} ({shadow_cpu:.2})"),
            format!("{:.3}", hits as f64 / count as f64),
            format!("{:.2} / {:.2}", closest_cpu / a[0], shadow_cpu / a[1]),
            format!("{:.2} / {:.2}", closest_cpu / a[2], shadow_cpu / a[3]),
        ]);
    }
    println!(
        "threads: {}, rays: {count}, BVH quality: {quality:?}\n",
        rayon::current_num_threads()
    );
    println!("{}", table.markdown());
    if let Err(e) = table.write_csv_if_requested("trace_rays") {
        eprintln!("csv: {e}");
    }
}
