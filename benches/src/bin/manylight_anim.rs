//! Tensor clustering (MRCS 2008) against per-frame row-column sampling at equal cost on a
//! Cornell box animation: the camera pans across the open side over `FRAMES` frames, the VPLs
//! stay. Relative RMS error over the whole sequence, elements and time.
//!
//! `cargo run --release -p prt-benches --bin manylight_anim -- [WIDTH VPLS FRAMES CLAMP SEEDS IMAGE]`
//! (defaults 64 pixels, 20000 VPLs, 30 frames, clamp 0.1, 2 seeds). The brute-force frames are
//! cached in `target/manylight_cache/`. `IMAGE` (a PNG path) gets the middle frame: reference |
//! per-frame row-column | tensor clustering, at the second budget.
use std::path::{Path, PathBuf};
use std::time::Instant;

use glam::Vec3;
use prt_benches::manylight::write_strip;
use prt_benches::{Table, fmt_duration};
use prt_core::metrics::relative_frobenius_error;
use prt_core::{MatrixOracle, NoProgress};
use prt_manylight::{RowColumnConfig, TensorConfig, row_column_sampling, tensor_clustering};
use prt_trace::{GBuffer, PinholeView, RayTracer, Scene, VplOptions, VplOracle, trace_vpls};

const CONFIGS: [(usize, usize); 3] = [(50, 100), (100, 200), (200, 400)];

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let arg = |k: usize, default: f64| -> f64 {
        args.get(k).and_then(|a| a.parse().ok()).unwrap_or(default)
    };
    let width = arg(0, 64.0) as usize;
    let target_vpls = arg(1, 20_000.0) as usize;
    let frames = (arg(2, 30.0) as usize).max(1);
    let clamp = arg(3, 0.1) as f32;
    let seeds = arg(4, 2.0) as u64;
    let image_path = args.get(5).map(PathBuf::from);

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
    let cache = Path::new(env!("CARGO_MANIFEST_DIR")).join("../target/manylight_cache");
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
            let mean = errors.iter().sum::<f64>() / errors.len() as f64;
            let max = errors.iter().copied().fold(0.0, f64::max);
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
