//! Row-column sampling (prt-manylight) on the real VPL scene oracle of prt-trace (Cornell box or
//! Sponza) against the brute-force image: relative RMS error vs elements evaluated, for several
//! VPL clamp distances (the clamp decides how spiky the matrix is).
//!
//! `cargo run --release -p prt-benches --bin manylight_scene -- SCENE WIDTH VPLS CLAMPS [SEEDS] [IMAGE]`
//!
//! * `SCENE`: `cornell` (built-in box, lit by its ceiling quad) or `sponza`
//!   (`../shared/scenes/sponza`, sun and sky);
//! * `WIDTH`: the image is `WIDTH × WIDTH`; `VPLS`: about this many VPLs (particles with 2
//!   bounces); `CLAMPS`: comma-separated clamp distances in scene units;
//! * `SEEDS` (default 2): seeds per configuration (mean and max of the error);
//! * `IMAGE`: a PNG path: reference | row-column 300/900 | 10× error, for the first clamp.
//!
//! Brute-force images are cached in `target/manylight_cache/` (keyed by shape and fingerprint),
//! so that only the first run of a (scene, size, VPLs, clamp) pays for them.
use std::path::{Path, PathBuf};
use std::time::Instant;

use prt_benches::manylight::{trace_about, write_strip};
use prt_benches::{Table, fmt_duration};
use prt_core::metrics::relative_frobenius_error;
use prt_core::{MatrixOracle, NoProgress};
use prt_manylight::{RowColumnConfig, row_column_sampling};
use prt_trace::{GBuffer, LoadOptions, PinholeView, RayTracer, Scene, VplOracle};

const CONFIGS: [(usize, usize); 6] = [
    (100, 200),
    (300, 900),
    (432, 864),
    (400, 1300),
    (600, 1200),
    (900, 1800),
];

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let scene_name = args.first().map(String::as_str).unwrap_or("cornell");
    let width: usize = args.get(1).and_then(|a| a.parse().ok()).unwrap_or(128);
    let target_vpls: usize = args.get(2).and_then(|a| a.parse().ok()).unwrap_or(50_000);
    let clamps: Vec<f32> = args
        .get(3)
        .map(|a| a.split(',').filter_map(|c| c.parse().ok()).collect())
        .unwrap_or_else(|| vec![0.05]);
    let seeds: u64 = args.get(4).and_then(|a| a.parse().ok()).unwrap_or(2);
    let image_path = args.get(5).map(PathBuf::from);

    let manifest = Path::new(env!("CARGO_MANIFEST_DIR"));
    let scene = match scene_name {
        "cornell" => Scene::cornell_box(),
        "sponza" => {
            let path = manifest.join("../../shared/scenes/sponza/Sponza.gltf");
            match Scene::load_gltf(&path, &LoadOptions::default()) {
                Ok(s) => s,
                Err(e) => {
                    eprintln!("skipping Sponza: {e}");
                    return;
                }
            }
        }
        other => {
            eprintln!("unknown scene {other} (cornell or sponza)");
            return;
        }
    };
    let tracer = RayTracer::new(scene.triangles());
    let vpls = trace_about(&scene, &tracer, target_vpls);
    let view = PinholeView::for_scene(&scene).expect("non-empty scene");
    let gbuffer = GBuffer::render(&scene, &tracer, &view, width, width).expect("valid size");
    let cache = manifest.join("../target/manylight_cache");
    std::fs::create_dir_all(&cache).expect("cache folder");
    println!(
        "{scene_name}: {width} × {width} pixels, {} VPLs, {} threads",
        vpls.len(),
        rayon::current_num_threads()
    );

    let mut table = Table::new(&[
        "clamp",
        "rows / columns",
        "elements",
        "fewer elements than brute force",
        "time (mean)",
        "relative RMS error (mean of seeds)",
        "max over seeds",
    ]);
    for (c, &clamp) in clamps.iter().enumerate() {
        let oracle = VplOracle::new(&tracer, &gbuffer, &vpls, clamp, 1e-4).expect("finite input");
        let (n, m) = (oracle.rows(), oracle.cols());
        let file = cache.join(format!("{scene_name}_{width}_{m}_{clamp}.bin"));
        let start = Instant::now();
        let reference = oracle
            .reference_image_cached(&file, &NoProgress)
            .expect("reference image");
        println!(
            "clamp {clamp}: brute force {} ({:.3e} elements; 0 s when cached)",
            fmt_duration(start.elapsed()),
            (n * m) as f64
        );
        let brute = (n * m) as f64;
        for (rows, columns) in CONFIGS {
            if rows > n || columns > m {
                continue;
            }
            let mut errors = Vec::new();
            let mut elements = 0;
            let start = Instant::now();
            let mut first_image = None;
            for seed in 0..seeds {
                let config = RowColumnConfig::new(rows, columns).with_seed(seed + 7);
                let estimate =
                    row_column_sampling(&oracle, &config, &NoProgress).expect("valid config");
                elements = estimate.elements;
                errors.push(
                    relative_frobenius_error(&estimate.image, &reference)
                        .expect("images of equal size"),
                );
                if first_image.is_none() {
                    first_image = Some(estimate.image);
                }
            }
            let time = start.elapsed() / seeds.max(1) as u32;
            let mean = errors.iter().sum::<f64>() / errors.len() as f64;
            let max = errors.iter().copied().fold(0.0, f64::max);
            table.row(vec![
                format!("{clamp}"),
                format!("{rows} / {columns}"),
                format!("{:.3e}", elements as f64),
                format!("{:.1}×", brute / elements as f64),
                fmt_duration(time),
                format!("{:.2}%", 100.0 * mean),
                format!("{:.2}%", 100.0 * max),
            ]);
            if let (0, (300, 900), Some(path), Some(image)) =
                (c, (rows, columns), &image_path, first_image)
            {
                let difference: Vec<f32> = reference
                    .iter()
                    .zip(&image)
                    .map(|(a, b)| 10.0 * (a - b).abs())
                    .collect();
                write_strip(path, width, &reference, &[image, difference]);
            }
        }
    }
    println!("\n{}", table.markdown());
}
