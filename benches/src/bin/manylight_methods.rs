//! Row-column sampling, LightSlice and visibility clustering (divisive and k-means) at equal
//! element (shadow-ray) budgets, on the Cornell box VPL oracle and on the synthetic VPL matrix:
//! relative RMS error vs elements and vs time.
//!
//! `cargo run --release -p prt-benches --bin manylight_methods -- SCENE WIDTH VPLS CLAMP [SEEDS] [IMAGE]`
//!
//! `SCENE` is `cornell` or `sponza` (prt-trace's VPL oracle, plus the sun and sky's direct light
//! as directional columns for Sponza, as in `manylight_scene`; the brute-force image of the VPL
//! columns is cached in `target/manylight_cache/` and shared with `manylight_scene`) or `synthetic`
//! (`SyntheticVplOracle`, `CLAMP` unused). Visibility clustering also evaluates the unshadowed
//! shading of every pixel against every light (no shadow rays), reported separately. `IMAGE`
//! (a PNG path) gets reference | row-column | LightSlice at 300 / 900 for the first seed.
//! `METHODS` (optional, after `IMAGE`, `-` for no image): comma-separated subset of `rowcol`,
//! `rowcol-skip`, `slice`, `slice-skip` (the `-skip` variants with `UnseenLights::Skip`), `vis`,
//! `kmeans` (default `rowcol,slice,vis,kmeans`).
use std::path::{Path, PathBuf};
use std::time::Instant;

use prt_benches::manylight::{BUDGETS, load_scene, trace_about, write_strip};
use prt_benches::{Table, fmt_duration};
use prt_core::metrics::relative_frobenius_error;
use prt_core::{CoreError, MatrixOracle, NoProgress};
use prt_manylight::{
    GatherGeometry, LightSliceConfig, RowColumnConfig, SliceOracle, SyntheticVplOracle,
    UnseenLights, VisibilityClusterMethod, VisibilityConfig, VisibilityOracle, brute_force,
    light_slice, row_column_sampling, visibility_clustering,
};
use prt_trace::{GBuffer, PinholeView, RayTracer, SunSky, VplOracle, directional_lights};
use rayon::prelude::*;

/// prt-trace's VPL oracle with the G-buffer's geometry, for LightSlice and visibility
/// clustering.
struct SceneOracle<'a> {
    inner: VplOracle<'a>,
    gbuffer: &'a GBuffer,
}

impl MatrixOracle for SceneOracle<'_> {
    fn rows(&self) -> usize {
        self.inner.rows()
    }
    fn cols(&self) -> usize {
        self.inner.cols()
    }
    fn channels(&self) -> usize {
        3
    }
    fn eval_row(&self, i: usize, out: &mut [f32]) -> Result<(), CoreError> {
        self.inner.eval_row(i, out)
    }
    fn eval_col(&self, j: usize, out: &mut [f32]) -> Result<(), CoreError> {
        self.inner.eval_col(j, out)
    }
    fn elements_evaluated(&self) -> u64 {
        self.inner.elements_evaluated()
    }
}

impl SliceOracle for SceneOracle<'_> {
    fn eval_col_rows(&self, j: usize, rows: &[usize], out: &mut [f32]) -> Result<(), CoreError> {
        out.par_chunks_mut(3)
            .zip(rows.par_iter())
            .with_min_len(64)
            .try_for_each(|(o, &i)| {
                o.copy_from_slice(&self.inner.element(i, j)?.to_array());
                Ok(())
            })
    }

    fn gather_point(&self, i: usize) -> Option<GatherGeometry> {
        let g = self.gbuffer.points.get(i).copied().flatten()?;
        Some(GatherGeometry {
            position: g.position.to_array(),
            normal: g.normal.to_array(),
        })
    }
}

impl VisibilityOracle for SceneOracle<'_> {
    fn shading(&self, i: usize, j: usize, out: &mut [f32]) -> Result<(), CoreError> {
        out.copy_from_slice(&self.inner.shading(i, j)?.to_array());
        Ok(())
    }
    fn visibility(&self, i: usize, j: usize) -> Result<f32, CoreError> {
        Ok(if self.inner.visible(i, j)? { 1.0 } else { 0.0 })
    }
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let scene_name = args.first().map(String::as_str).unwrap_or("cornell");
    let width: usize = args.get(1).and_then(|a| a.parse().ok()).unwrap_or(128);
    let target_vpls: usize = args.get(2).and_then(|a| a.parse().ok()).unwrap_or(50_000);
    let clamp: f32 = args.get(3).and_then(|a| a.parse().ok()).unwrap_or(0.1);
    let seeds: u64 = args.get(4).and_then(|a| a.parse().ok()).unwrap_or(2);
    let image_path = args.get(5).filter(|a| *a != "-").map(PathBuf::from);
    let selected: Vec<&'static str> = {
        let wanted = args
            .get(6)
            .map(String::as_str)
            .unwrap_or("rowcol,slice,vis,kmeans");
        [
            ("rowcol", "row-column"),
            ("rowcol-skip", "row-column (skip unseen)"),
            ("slice", "LightSlice"),
            ("slice-skip", "LightSlice (skip unseen)"),
            ("vis", "visibility (split)"),
            ("kmeans", "visibility (k-means)"),
        ]
        .into_iter()
        .filter(|(key, _)| wanted.split(',').any(|w| w == *key))
        .map(|(_, name)| name)
        .collect()
    };
    let manifest = Path::new(env!("CARGO_MANIFEST_DIR"));
    match scene_name {
        "cornell" | "sponza" => {
            let Some(scene) = load_scene(scene_name, manifest) else {
                return;
            };
            let tracer = RayTracer::new(scene.triangles());
            let vpls = trace_about(&scene, &tracer, target_vpls);
            let directional =
                directional_lights(&scene, &SunSky::default(), 1024).expect("non-empty scene");
            let view = PinholeView::for_scene(&scene).expect("non-empty scene");
            let gbuffer =
                GBuffer::render(&scene, &tracer, &view, width, width).expect("valid size");
            let cache = manifest.join("../target/manylight_cache");
            std::fs::create_dir_all(&cache).expect("cache folder");
            let file = cache.join(format!("{scene_name}_{width}_{}_{clamp}.bin", vpls.len()));
            let start = Instant::now();
            let mut reference = VplOracle::new(&tracer, &gbuffer, &vpls, clamp, 1e-4)
                .expect("finite")
                .reference_image_cached(&file, &NoProgress)
                .expect("reference image");
            let inner = VplOracle::new(&tracer, &gbuffer, &vpls, clamp, 1e-4)
                .and_then(|o| o.with_directional(&directional))
                .expect("finite");
            let (n, m) = (inner.rows(), inner.cols());
            let mut column = vec![0.0f32; 3 * n];
            for j in vpls.len()..m {
                inner.eval_col(j, &mut column).expect("directional column");
                for (r, &c) in reference.iter_mut().zip(&column) {
                    *r += c;
                }
            }
            println!(
                "{scene_name}: {width} × {width} pixels, {} VPLs + {} directional lights, clamp \
                 {clamp}, {} threads; brute force {} ({:.3e} elements; VPL columns cached)\n",
                vpls.len(),
                directional.len(),
                rayon::current_num_threads(),
                fmt_duration(start.elapsed()),
                (n * m) as f64
            );
            let oracle = SceneOracle {
                inner,
                gbuffer: &gbuffer,
            };
            compare(
                &oracle,
                &reference,
                width,
                seeds,
                image_path.as_deref(),
                &selected,
            );
        }
        "synthetic" => {
            let oracle = SyntheticVplOracle::new(width, width, target_vpls, 1);
            let start = Instant::now();
            let reference = brute_force(&oracle, &NoProgress).expect("finite oracle");
            println!(
                "Synthetic VPL matrix: {width} × {width} pixels, {target_vpls} lights, {} threads; \
                 brute force {}\n",
                rayon::current_num_threads(),
                fmt_duration(start.elapsed()),
            );
            compare(
                &oracle,
                &reference,
                width,
                seeds,
                image_path.as_deref(),
                &selected,
            );
        }
        other => eprintln!("unknown scene {other} (cornell, sponza or synthetic)"),
    }
}

fn compare<O: SliceOracle + VisibilityOracle>(
    oracle: &O,
    reference: &[f32],
    width: usize,
    seeds: u64,
    image_path: Option<&Path>,
    methods: &[&str],
) {
    let brute = (oracle.rows() * oracle.cols()) as f64;
    let mut table = Table::new(&[
        "method",
        "rows / columns",
        "elements (shadow rays)",
        "fewer than brute force",
        "time (mean)",
        "relative RMS error (mean of seeds)",
        "max over seeds",
    ]);
    let kmeans = VisibilityClusterMethod::KMeans { iterations: 4 };
    for (rows, columns) in BUDGETS {
        if rows > oracle.rows() || columns > oracle.cols() {
            continue;
        }
        let mut images: Vec<Vec<f32>> = Vec::new();
        for &method in methods {
            let (mut errors, mut elements, mut extra) = (Vec::new(), 0u64, 0u64);
            let start = Instant::now();
            for seed in 0..seeds {
                let (image, e) = match method {
                    "row-column" | "row-column (skip unseen)" => {
                        let mut c = RowColumnConfig::new(rows, columns).with_seed(seed + 7);
                        if method.contains("skip") {
                            c = c.with_unseen(UnseenLights::Skip);
                        }
                        let r = row_column_sampling(oracle, &c, &NoProgress).expect("valid");
                        (r.image, r.elements)
                    }
                    "LightSlice" | "LightSlice (skip unseen)" => {
                        let mut c = LightSliceConfig::new(rows, columns).with_seed(seed + 7);
                        if method.contains("skip") {
                            c = c.with_unseen(UnseenLights::Skip);
                        }
                        let r = light_slice(oracle, &c, &NoProgress).expect("valid");
                        (r.image, r.elements)
                    }
                    _ => {
                        let mut c = VisibilityConfig::new(rows, columns).with_seed(seed + 7);
                        if method.contains("k-means") {
                            c = c.with_method(kmeans);
                        }
                        let r = visibility_clustering(oracle, &c, &NoProgress).expect("valid");
                        extra = r.shading_evaluations;
                        (r.image, r.elements)
                    }
                };
                elements += e;
                errors.push(relative_frobenius_error(&image, reference).expect("same size"));
                if seed == 0 {
                    images.push(image);
                }
            }
            let time = start.elapsed() / seeds.max(1) as u32;
            let elements = elements / seeds.max(1);
            let mean = errors.iter().sum::<f64>() / errors.len() as f64;
            let max = errors.iter().copied().fold(0.0, f64::max);
            let elements_cell = if extra > 0 {
                format!("{:.3e} (+{:.2e} shading)", elements as f64, extra as f64)
            } else {
                format!("{:.3e}", elements as f64)
            };
            table.row(vec![
                method.to_string(),
                format!("{rows} / {columns}"),
                elements_cell,
                format!("{:.1}×", brute / elements as f64),
                fmt_duration(time),
                format!("{:.2}%", 100.0 * mean),
                format!("{:.2}%", 100.0 * max),
            ]);
            println!("{method} {rows}/{columns}: {:.2}%", 100.0 * mean);
        }
        if let (Some(path), (300, 900), 2..) = (image_path, (rows, columns), images.len()) {
            write_strip(path, width, reference, &images[..2]);
        }
    }
    println!("\n{}", table.markdown());
}
