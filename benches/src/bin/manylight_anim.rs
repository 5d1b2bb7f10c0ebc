//! Tensor clustering (MRCS 2008) against per-frame row-column sampling at equal cost on a
//! Cornell box animation: the camera pans across the open side over `FRAMES` frames, the VPLs
//! stay. Relative RMS error over the whole sequence, elements and time.
//!
//! `cargo run --release -p prt-benches --bin manylight_anim -- --width 64 --vpls 20000 --frames 30 --clamp 0.1 --seeds 2 [--image PATH]`
//! (the defaults). The brute-force frames are cached in `target/manylight_cache/`. `--image`
//! gets the middle frame: reference | per-frame row-column | tensor clustering, at the second
//! budget (100/200).
use std::path::PathBuf;
use std::time::Instant;

use clap::Parser;
use glam::Vec3;
use prt_benches::manylight::{mean_and_max, write_strip};
use prt_benches::{Table, cache_dir, fmt_duration};
use prt_core::metrics::relative_frobenius_error;
use prt_core::{MatrixOracle, NoProgress};
use prt_manylight::{RowColumnConfig, TensorConfig, row_column_sampling, tensor_clustering};
use prt_trace::camera::{GBuffer, PinholeView};
use prt_trace::manylight::{VplOptions, VplOracle, trace_vpls};
use prt_trace::{RayTracer, Scene};

const CONFIGS: [(usize, usize); 3] = [(50, 100), (100, 200), (200, 400)];

#[derive(Debug, Parser)]
#[command(about = "Tensor clustering against per-frame row-column sampling on a Cornell box pan")]
struct Cli {
    /// Frame side in pixels (frames are WIDTH × WIDTH).
    #[arg(long, default_value_t = 64)]
    width: usize,
    /// About this many VPLs (particles with 2 bounces, seed 1), fixed over the animation.
    #[arg(long, default_value_t = 20_000)]
    vpls: usize,
    /// Frames of the pan.
    #[arg(long, default_value_t = 30, value_parser = clap::value_parser!(u64).range(1..))]
    frames: u64,
    /// VPL clamp distance in scene units.
    #[arg(long, default_value_t = 0.1)]
    clamp: f32,
    /// Seeds per configuration (7 .. 7 + SEEDS; mean and max of the error).
    #[arg(long, default_value_t = 2)]
    seeds: u64,
    /// PNG path for the middle frame: reference | per-frame row-column | tensor clustering.
    #[arg(long)]
    image: Option<PathBuf>,
}

fn main() {
    let cli = Cli::parse();
    let (width, target_vpls, frames) = (cli.width, cli.vpls, cli.frames as usize);
    let (clamp, seeds, image_path) = (cli.clamp, cli.seeds, cli.image);

    let scene = Scene::cornell_box();
    let tracer = RayTracer::new(scene.triangles());
    let options = VplOptions {
        particles: target_vpls * 10 / 23,
        max_bounces: 2,
        seed: 1,
        ..Default::default()
    };
    let vpls = trace_vpls(&scene, &tracer, &options, &NoProgress).expect("lit scene");
    let base = PinholeView::for_scene(&scene).expect("non-empty scene");
    let target = Vec3::new(0.0, 1.0, -0.2);
    let gbuffers: Vec<GBuffer> = (0..frames)
        .map(|t| {
            let s = if frames > 1 {
                t as f32 / (frames - 1) as f32 - 0.5
            } else {
                0.0
            };
            let position = base.position + Vec3::new(1.2 * s, 0.2 * s, 0.0);
            let forward = (target - position).normalize();
            let up = (Vec3::Y - forward * Vec3::Y.dot(forward)).normalize();
            let view = PinholeView {
                position,
                forward,
                up,
                yfov: base.yfov,
            };
            GBuffer::render(&scene, &tracer, &view, width, width).expect("valid size")
        })
        .collect();
    let oracles: Vec<VplOracle<'_>> = gbuffers
        .iter()
        .map(|g| VplOracle::new(&tracer, g, &vpls, clamp, 1e-4).expect("finite input"))
        .collect();
    let frame_refs: Vec<&dyn MatrixOracle> =
        oracles.iter().map(|o| o as &dyn MatrixOracle).collect();
    let m = vpls.len();
    let cache = cache_dir("manylight_cache");
    std::fs::create_dir_all(&cache).expect("cache folder");
    let start = Instant::now();
    let reference: Vec<Vec<f32>> = oracles
        .iter()
        .enumerate()
        .map(|(t, o)| {
            let file = cache.join(format!("cornell_anim_{width}_{m}_{clamp}_{frames}_{t}.bin"));
            o.reference_image_cached(&file, &NoProgress)
                .expect("reference image")
        })
        .collect();
    let brute = (width * width * m * frames) as f64;
    println!(
        "Cornell box pan: {frames} frames of {width} × {width} pixels, {m} VPLs, clamp {clamp}, \
         {} threads; brute force {} ({brute:.3e} elements; 0 s when cached)\n",
        rayon::current_num_threads(),
        fmt_duration(start.elapsed()),
    );
    let all_reference = reference.concat();
    let mut table = Table::new(&[
        "method",
        "rows / columns per frame",
        "elements (sequence)",
        "fewer than brute force",
        "time (mean)",
        "relative RMS error (mean of seeds)",
        "max over seeds",
        "light / time splits",
    ]);
    for (k, (rows, columns)) in CONFIGS.into_iter().enumerate() {
        let mut middle = Vec::new();
        for method in ["per-frame row-column", "tensor clustering"] {
            let (mut errors, mut elements, mut splits) = (Vec::new(), 0u64, String::new());
            let start = Instant::now();
            for seed in 0..seeds {
                let images: Vec<Vec<f32>> = if method == "tensor clustering" {
                    let config = TensorConfig::new(rows, columns).with_seed(seed + 7);
                    let e = tensor_clustering(&frame_refs, &config, &NoProgress).expect("valid");
                    elements = e.elements;
                    splits = format!("{} / {}", e.light_splits, e.time_splits);
                    e.images
                } else {
                    elements = 0;
                    frame_refs
                        .iter()
                        .enumerate()
                        .map(|(t, o)| {
                            let config = RowColumnConfig::new(rows, columns)
                                .with_seed((seed + 7) * 1000 + t as u64);
                            let e = row_column_sampling(*o, &config, &NoProgress).expect("valid");
                            elements += e.elements;
                            e.image
                        })
                        .collect()
                };
                errors.push(
                    relative_frobenius_error(&images.concat(), &all_reference).expect("same size"),
                );
                if seed == 0 {
                    middle.push(images[frames / 2].clone());
                }
            }
            let time = start.elapsed() / seeds.max(1) as u32;
            let (mean, max) = mean_and_max(&errors);
            println!("{method} {rows}/{columns}: {:.2}%", 100.0 * mean);
            table.row(vec![
                method.to_string(),
                format!("{rows} / {columns}"),
                format!("{:.3e}", elements as f64),
                format!("{:.1}×", brute / elements as f64),
                fmt_duration(time),
                format!("{:.2}%", 100.0 * mean),
                format!("{:.2}%", 100.0 * max),
                splits,
            ]);
        }
        if let (Some(path), 1) = (&image_path, k) {
            write_strip(path, width, &reference[frames / 2], &middle);
        }
    }
    println!("\n{}", table.markdown());
}
