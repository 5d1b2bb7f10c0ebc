//! Bakes the Cornell box (32³) and Sponza (64³) transfer volumes, prints timings, Mrays/s and
//! peak RSS, and writes the horizontal-slice pictures of docs/images/trace_*.png.
//!
//! `cargo run --release -p prt-benches --bin trace_bake -- --scene cornell,sponza --rays-per-voxel 256 --cache-rays 64 --quality medium [--grid N] [--csv DIR]`
//!
//! (the defaults). Grids are 32³ for the Cornell box and 64³ for Sponza unless `--grid` gives
//! one for every scene (`--scene sponza --grid 128` is the memory test). The pictures are
//! written for grids up to 64³ at the default quality only.
use std::path::{Path, PathBuf};
use std::time::Instant;

use clap::Parser;
use prt_benches::{
    BvhQuality, Stopwatch, Table, fmt_duration, load_scene, peak_resident_bytes, save_png,
};
use prt_core::NoProgress;
use prt_trace::expert::BuildQuality;
use prt_trace::lit::constant_sky;
use prt_trace::{BakeOptions, RayTracer, TransferBaker, TransferVolume};

/// A scene to bake.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum BakeScene {
    /// The built-in Cornell box (32³ by default).
    Cornell,
    /// Sponza from ../shared/scenes (64³ by default).
    Sponza,
}

#[derive(Debug, Parser)]
#[command(about = "Bakes transfer volumes and reports time, Mrays/s and peak memory")]
struct Cli {
    /// Scenes to bake, comma-separated.
    #[arg(
        long,
        value_enum,
        value_delimiter = ',',
        default_value = "cornell,sponza"
    )]
    scene: Vec<BakeScene>,
    /// Voxels along each axis for every scene (default: 32 Cornell, 64 Sponza).
    #[arg(long)]
    grid: Option<usize>,
    /// Directions traced per voxel (`BakeOptions::rays_per_voxel`).
    #[arg(long, default_value_t = 256)]
    rays_per_voxel: usize,
    /// Rays per surface-cache point (`BakeOptions::cache_rays`).
    #[arg(long, default_value_t = 64)]
    cache_rays: usize,
    /// BVH build quality.
    #[arg(long, value_enum, default_value = "medium")]
    quality: BvhQuality,
    /// Folder for the table as CSV (trace_bake.csv).
    #[arg(long)]
    csv: Option<PathBuf>,
}

/// Two panels side by side: sky visibility (grey) and mean indirect radiance under a unit
/// constant sky (RGB, x4 exposure), on the horizontal voxel slice `iy`; invalid voxels magenta.
fn write_slice(volume: &TransferVolume, iy: usize, path: &Path) {
    let [nx, _, nz] = volume.field.dims();
    let scale = (512 / nx.max(nz)).max(1) as u32;
    let (w, h) = (nx as u32 * scale, nz as u32 * scale);
    let mut img = image::RgbImage::new(2 * w + scale, h);
    let sky = [constant_sky(1.0); 3];
    let y0 = prt_trace::sh::sh9(glam::Vec3::Y)[0];
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
    if let Err(e) = save_png(&img, path) {
        eprintln!("cannot write {e}");
    }
}

fn main() {
    let cli = Cli::parse();
    let (rays, cache_rays) = (cli.rays_per_voxel, cli.cache_rays);
    let quality = BuildQuality::from(cli.quality);
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
    for which in cli.scene {
        let (name, default_grid) = match which {
            BakeScene::Cornell => ("cornell", 32),
            BakeScene::Sponza => ("sponza", 64),
        };
        let res = cli.grid.unwrap_or(default_grid);
        let t_load = Instant::now();
        let scene = match load_scene(name) {
            Ok(s) => s,
            Err(e) => {
                eprintln!("skipping {name}: {e}");
                continue;
            }
        };
        eprintln!(
            "{name}: {} triangles loaded in {}",
            scene.triangles().len(),
            fmt_duration(t_load.elapsed())
        );
        let options = BakeOptions {
            resolution: [res; 3],
            margin: 0.0,
            rays_per_voxel: rays,
            cache_rays,
            seed: 1,
            build_quality: quality,
            ..Default::default()
        };
        let watch = Stopwatch::start();
        let volume = match TransferBaker::new(&scene, options).and_then(|b| b.bake(&NoProgress)) {
            Ok(v) => v,
            Err(e) => {
                eprintln!("{name}: bake failed: {e}");
                continue;
            }
        };
        let (total, cpu) = (watch.wall(), watch.cpu());
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
            format!("{:.0} MiB", peak_resident_bytes() / (1024.0 * 1024.0)),
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
    if let Err(e) = table.write_csv(cli.csv.as_deref(), "trace_bake") {
        eprintln!("csv: {e}");
    }
}
