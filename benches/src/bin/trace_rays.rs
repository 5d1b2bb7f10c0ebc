//! Raw ray throughput of prt-trace's CWBVH: 10M random rays (origins uniform in the scene box,
//! directions uniform on the sphere), closest hit and shadow (first hit), on 2 threads, for the
//! scenes of ../shared/design/anchors.md, next to the anchor figures (obvhs and Embree) and to
//! obvhs used directly on the same rays in the same run (the anchors come from another machine;
//! the same-run row separates our overhead from the machine's speed). prt-trace runs on the
//! instruction set it detects at run time (x86-64-v3 where the CPU has it) and, for the same-run
//! ratio, on the build's baseline; single-ray and batched queries. Rays are generated before the
//! timed loops.
//!
//! `cargo run --release -p prt-benches --bin trace_rays -- --rays 10000000 --quality medium [--csv DIR]`
//! (the defaults).
use std::hint::black_box;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use clap::Parser;
use glam::Vec3;
use obvhs::BvhBuildParams;
use obvhs::cwbvh::CwBvh;
use obvhs::cwbvh::builder::build_cwbvh_from_tris;
use obvhs::ray::{Ray, RayHit};
use obvhs::rt_triangle::RtTriangle;
use obvhs::triangle::Triangle;
use prt_benches::{BvhQuality, Table, cpu_seconds, fmt_duration, load_scene};
use prt_trace::expert::BuildQuality;
use prt_trace::{RayTracer, Scene};
use rand::{Rng, SeedableRng};
use rayon::prelude::*;

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

/// obvhs's CWBVH used the way its examples use it: triangles gathered into BVH order,
/// `ray_traverse` / `ray_traverse_miss` with an `RtTriangle::intersect` closure.
struct DirectObvhs {
    bvh: CwBvh,
    tris: Vec<RtTriangle>,
}

impl DirectObvhs {
    fn new(triangles: &[[Vec3; 3]], quality: BuildQuality) -> Self {
        let input: Vec<Triangle> = triangles
            .iter()
            .map(|t| Triangle {
                v0: t[0].into(),
                v1: t[1].into(),
                v2: t[2].into(),
            })
            .collect();
        let params = match quality {
            BuildQuality::Fast => BvhBuildParams::fast_build(),
            BuildQuality::Slow => BvhBuildParams::slow_build(),
            BuildQuality::VerySlow => BvhBuildParams::very_slow_build(),
            _ => BvhBuildParams::medium_build(),
        };
        let bvh = build_cwbvh_from_tris(&input, params, &mut Duration::default());
        let tris = bvh
            .primitive_indices
            .iter()
            .map(|&i| RtTriangle::from(&input[i as usize]))
            .collect();
        Self { bvh, tris }
    }

    fn closest(&self, o: Vec3, d: Vec3) -> bool {
        let ray = Ray::new(o.into(), d.into(), 0.0, f32::INFINITY);
        let mut hit = RayHit::none();
        self.bvh
            .ray_traverse(ray, &mut hit, |r, id| self.tris[id].intersect(r))
    }

    fn occluded(&self, o: Vec3, d: Vec3) -> bool {
        let ray = Ray::new(o.into(), d.into(), 0.0, f32::INFINITY);
        !self
            .bvh
            .ray_traverse_miss(ray, |r, id| self.tris[id].intersect(r))
    }
}

/// Throughputs `[wall, CPU-normalised]` in Mrays/s of one implementation, and hit counts.
struct Throughput {
    closest: [f64; 2],
    shadow: [f64; 2],
    hits: usize,
    occluded: usize,
}

/// Rays per call of the batched queries (bounds the result vectors to ~32 MB).
const BATCH: usize = 1 << 20;

/// A batch query under test: traces the rays it is given and returns how many hit.
type RayCounter<'a> = dyn Fn(&[(Vec3, Vec3)]) -> usize + Sync + 'a;

/// Times `closest` then `shadow` over all `rays`; each returns how many of its rays hit.
fn measure_counts(
    rays: &[(Vec3, Vec3)],
    closest: &RayCounter<'_>,
    shadow: &RayCounter<'_>,
) -> Throughput {
    let threads = rayon::current_num_threads() as f64;
    let count = rays.len() as f64;
    let run = |f: &RayCounter<'_>| {
        let (t, c) = (Instant::now(), cpu_seconds());
        let n = f(rays);
        let wall = count / t.elapsed().as_secs_f64() / 1e6;
        let cpu = count / ((cpu_seconds() - c) / threads) / 1e6;
        (n, [wall, cpu])
    };
    let (hits, closest) = run(closest);
    let (occluded, shadow) = run(shadow);
    Throughput {
        closest,
        shadow,
        hits,
        occluded,
    }
}

/// [`measure_counts`] of single-ray queries run over the rayon pool.
fn measure(
    rays: &[(Vec3, Vec3)],
    closest: impl Fn(Vec3, Vec3) -> bool + Sync,
    shadow: impl Fn(Vec3, Vec3) -> bool + Sync,
) -> Throughput {
    let per_ray = |f: &(dyn Fn(Vec3, Vec3) -> bool + Sync), rays: &[(Vec3, Vec3)]| {
        rays.par_iter()
            .with_min_len(4096)
            .filter(|&&(o, d)| f(o, d))
            .count()
    };
    measure_counts(
        rays,
        &|r: &[(Vec3, Vec3)]| per_ray(&closest, r),
        &|r: &[(Vec3, Vec3)]| per_ray(&shadow, r),
    )
}

/// [`measure_counts`] of prt-trace's batched queries (`closest_hits`, `occluded_batch`).
fn measure_batched(rays: &[(Vec3, Vec3)], tracer: &RayTracer) -> Throughput {
    measure_counts(
        rays,
        &|r: &[(Vec3, Vec3)]| {
            r.chunks(BATCH)
                .map(|c| {
                    let hits = tracer.closest_hits(c, 0.0, f32::INFINITY);
                    hits.iter().filter(|h| h.is_some()).count()
                })
                .sum()
        },
        &|r: &[(Vec3, Vec3)]| {
            r.chunks(BATCH)
                .map(|c| {
                    let blocked = tracer.occluded_batch(c, 0.0, f32::INFINITY);
                    blocked.iter().filter(|&&b| b).count()
                })
                .sum()
        },
    )
}

#[derive(Debug, Parser)]
#[command(about = "Raw ray throughput of prt-trace's CWBVH beside obvhs and the anchors")]
struct Cli {
    /// Random rays per scene (origins uniform in the scene box, directions on the sphere).
    #[arg(long, default_value_t = 10_000_000)]
    rays: usize,
    /// BVH build quality (prt-trace and obvhs alike).
    #[arg(long, value_enum, default_value = "medium")]
    quality: BvhQuality,
    /// Folder for the table as CSV (trace_rays.csv).
    #[arg(long)]
    csv: Option<PathBuf>,
}

fn main() {
    let cli = Cli::parse();
    let count = cli.rays;
    let quality = BuildQuality::from(cli.quality);
    // (name, scene, anchor obvhs closest/shadow, anchor Embree closest/shadow) in Mrays/s.
    let anchors: [(&str, &str, [f64; 4]); 3] = [
        ("Cornell", "cornell", [17.3, 21.0, 16.3, 22.0]),
        ("Sponza", "sponza", [4.65, 7.45, 7.02, 12.5]),
        ("Gas station", "gas_station", [8.65, 8.23, 14.8, 13.6]),
    ];
    let mut table = Table::new(&[
        "scene",
        "triangles",
        "implementation",
        "BVH build",
        "closest Mrays/s wall (CPU-normalised)",
        "shadow Mrays/s wall (CPU-normalised)",
        "hit rate",
        "CPU-normalised vs obvhs in this run (closest / shadow)",
        "CPU-normalised vs obvhs anchor (closest / shadow)",
        "CPU-normalised vs Embree anchor (closest / shadow)",
    ]);
    for (name, scene_name, a) in anchors {
        let scene = match load_scene(scene_name) {
            Ok(s) => s,
            Err(e) => {
                eprintln!("skipping {name}: {e}");
                continue;
            }
        };
        let rays = random_rays(&scene, count, 7);
        let t = Instant::now();
        let direct = DirectObvhs::new(scene.triangles(), quality);
        let direct_build = t.elapsed();
        let t = Instant::now();
        let tracer = RayTracer::with_quality(scene.triangles(), quality);
        let build = t.elapsed();
        // obvhs used directly, as its own examples and benchmarks do: the same-run baseline.
        let base = measure(
            &rays,
            |o, d| direct.closest(o, d),
            |o, d| direct.occluded(o, d),
        );
        let baseline = tracer.clone().with_baseline_instruction_set();
        let isa = tracer.instruction_set();
        let lean_base = measure(
            &rays,
            |o, d| {
                baseline
                    .closest_triangle(o, d, 0.0, f32::INFINITY)
                    .is_some()
            },
            |o, d| baseline.occluded(o, d, 0.0, f32::INFINITY),
        );
        let lean = measure(
            &rays,
            |o, d| tracer.closest_triangle(o, d, 0.0, f32::INFINITY).is_some(),
            |o, d| tracer.occluded(o, d, 0.0, f32::INFINITY),
        );
        let full = measure(
            &rays,
            // black_box: the record must be computed, not only tested for presence.
            |o, d| black_box(tracer.closest_hit(o, d, 0.0, f32::INFINITY)).is_some(),
            |o, d| tracer.occluded(o, d, 0.0, f32::INFINITY),
        );
        let batched = measure_batched(&rays, &tracer);
        for (implementation, build, m) in [
            (
                "obvhs directly (ray_traverse)".to_string(),
                direct_build,
                &base,
            ),
            (
                "prt-trace closest_triangle, baseline ISA".to_string(),
                build,
                &lean_base,
            ),
            (format!("prt-trace closest_triangle, {isa}"), build, &lean),
            (
                format!("prt-trace closest_hit (+ barycentrics, normal), {isa}"),
                build,
                &full,
            ),
            (
                format!("prt-trace closest_hits / occluded_batch, {isa}"),
                build,
                &batched,
            ),
        ] {
            if m.occluded != m.hits {
                eprintln!(
                    "{name}, {implementation}: {} closest hits but {} occluded shadow rays",
                    m.hits, m.occluded
                );
            }
            if m.hits != base.hits {
                eprintln!(
                    "{name}, {implementation}: {} closest hits, obvhs directly {}",
                    m.hits, base.hits
                );
            }
            table.row(vec![
                name.into(),
                scene.triangles().len().to_string(),
                implementation,
                fmt_duration(build),
                format!("{:.2} ({:.2})", m.closest[0], m.closest[1]),
                format!("{:.2} ({:.2})", m.shadow[0], m.shadow[1]),
                format!("{:.3}", m.hits as f64 / count as f64),
                format!(
                    "{:.2} / {:.2}",
                    m.closest[1] / base.closest[1],
                    m.shadow[1] / base.shadow[1]
                ),
                format!("{:.2} / {:.2}", m.closest[1] / a[0], m.shadow[1] / a[1]),
                format!("{:.2} / {:.2}", m.closest[1] / a[2], m.shadow[1] / a[3]),
            ]);
        }
    }
    println!(
        "threads: {}, rays: {count}, BVH quality: {quality:?}, instruction set detected: {}\n",
        rayon::current_num_threads(),
        RayTracer::new(&[]).instruction_set()
    );
    println!("{}", table.markdown());
    if let Err(e) = table.write_csv(cli.csv.as_deref(), "trace_rays") {
        eprintln!("csv: {e}");
    }
}
