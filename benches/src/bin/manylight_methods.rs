//! Row-column sampling, LightSlice and visibility clustering (divisive and k-means) at equal
//! element (shadow-ray) budgets, on the Cornell box VPL oracle and on the synthetic VPL matrix:
//! relative RMS error vs elements and vs time.
//!
//! `cargo run --release -p prt-benches --bin manylight_methods -- SCENE WIDTH VPLS CLAMP [SEEDS] [IMAGE] [METHODS] [LIGHT] [BUDGETS] [FIRST_SEED] [GROUP_DIVISOR] [NEIGHBOURS] [GLOBAL_PERCENT] [ADAPTIVE_PERCENT] [DEFENSIVE_PERCENT] [GUIDE_PERCENT] [PROBES] [UNSEEN_DRAWS]`
//!
//! `SCENE` is `cornell` or `sponza` (prt-trace's VPL oracle, plus the sun and sky's direct light
//! as directional columns for Sponza, as in `manylight_scene`; the brute-force image of the VPL
//! columns is cached in `target/manylight_cache/` and shared with `manylight_scene`) or `synthetic`
//! (`SyntheticVplOracle`, `CLAMP` unused). Visibility clustering also evaluates the unshadowed
//! shading of every pixel against every light (no shadow rays), reported separately. `IMAGE`
//! (a PNG path, `-` for none) gets reference | the first two methods | their 10× absolute
//! errors at the first budget, for the first seed.
//! * `METHODS`: comma-separated subset of `rowcol`, `rowcol-skip`, `rowcol-groups`, `slice`,
//!   `slice-skip`, `slice-groups`, `slice-skip-local`, `slice-spread`, `slice-skip-spread`,
//!   `slice-skip-spread-local`, `slice-skip-spread-guided`
//!   (the `-skip` variants with `UnseenLights::Skip`, the `-groups` ones with
//!   `UnseenLights::Groups(columns / GROUP_DIVISOR)`, `-local` with
//!   `LightSliceConfig::local_importance`, `-spread` with `SliceSplit::Spread`, `-guided` with
//!   `light_slice_guided` and `ShadingGuide::new(GUIDE_PERCENT, PROBES)`
//!   `.with_unseen_draws(UNSEEN_DRAWS)`), `vis`, `kmeans`
//!   (default `rowcol,slice,vis,kmeans`);
//! * `LIGHT` (Cornell and Sponza): `direct` (default, every light sampled) or `exact-sun`: the sun
//!   (the first directional light) is evaluated as one exact column (`pixels` elements, counted)
//!   and the methods sample the other lights, as in `manylight_scene`;
//! * `BUDGETS`: comma-separated `rows/columns` (default: the six of the paper's range);
//! * `FIRST_SEED` (default 7): seeds `FIRST_SEED .. FIRST_SEED + SEEDS` (settings are chosen on
//!   seeds 1..6 and reported on 7..12). Every seed's error is printed as it finishes;
//! * `GROUP_DIVISOR` (default 16): the `-groups` methods cut the unseen lights into
//!   `columns / GROUP_DIVISOR` groups (at least 1), out of the column budget;
//! * `NEIGHBOURS` (default 8, `LightSliceConfig::neighbours`): the slices whose rows refine a
//!   slice's clustering;
//! * `GLOBAL_PERCENT` (default 50, `LightSliceConfig::new`'s): LightSlice's global clusters in
//!   percent of its local clusters;
//! * `ADAPTIVE_PERCENT` (default 0, `LightSliceConfig::adaptive_percent`): the percent of
//!   LightSlice's representatives spread over the slices by brightness;
//! * `DEFENSIVE_PERCENT` (default 0, `LightSliceConfig::defensive_percent`): the percent of
//!   LightSlice's representative draws made uniformly within the cluster;
//! * `GUIDE_PERCENT` (default 50), `PROBES` (default 8; `all` for every pixel of a slice) and
//!   `UNSEEN_DRAWS` (default 0): the `-guided` methods' shading guide. Its shading evaluations
//!   (no shadow rays) are reported beside the elements.
//!
//! Time is wall time per run, and process CPU time per run (all threads) in brackets.
use std::path::{Path, PathBuf};
use std::time::Instant;

use prt_benches::manylight::{
    Args, Reference, SceneOracle, SweepScene, parse_budgets, write_strip,
};
use prt_benches::{Table, cpu_seconds, fmt_duration};
use prt_core::NoProgress;
use prt_core::metrics::relative_frobenius_error;
use prt_manylight::{
    LightSliceConfig, RowColumnConfig, ShadingGuide, SliceOracle, SliceSplit, SyntheticVplOracle,
    UnseenLights, VisibilityClusterMethod, VisibilityConfig, VisibilityOracle, brute_force,
    light_slice, light_slice_guided, row_column_sampling, visibility_clustering,
};

fn main() {
    let args = Args::from_env();
    let scene_name = args.text(0).unwrap_or("cornell");
    let width: usize = args.parsed(1, 128);
    let target_vpls: usize = args.parsed(2, 50_000);
    let clamp: f32 = args.parsed(3, 0.1);
    let seeds: u64 = args.parsed(4, 2);
    let image_path = args.text(5).filter(|a| *a != "-").map(PathBuf::from);
    let selected: Vec<&'static str> = {
        let wanted = args.text(6).unwrap_or("rowcol,slice,vis,kmeans");
        [
            ("rowcol", "row-column"),
            ("rowcol-skip", "row-column (skip unseen)"),
            ("rowcol-groups", "row-column (grouped unseen)"),
            ("slice", "LightSlice"),
            ("slice-skip", "LightSlice (skip unseen)"),
            ("slice-groups", "LightSlice (grouped unseen)"),
            ("slice-spread", "LightSlice (spread slices)"),
            (
                "slice-skip-spread",
                "LightSlice (skip unseen, spread slices)",
            ),
            (
                "slice-skip-local",
                "LightSlice (skip unseen, local importance)",
            ),
            (
                "slice-skip-spread-local",
                "LightSlice (skip unseen, spread slices, local importance)",
            ),
            (
                "slice-skip-spread-guided",
                "LightSlice (skip unseen, spread slices, shading guide)",
            ),
            ("vis", "visibility (split)"),
            ("kmeans", "visibility (k-means)"),
        ]
        .into_iter()
        .filter(|(key, _)| wanted.split(',').any(|w| w == *key))
        .map(|(_, name)| name)
        .collect()
    };
    let exact_sun = match args.text(7).unwrap_or("direct") {
        "direct" => false,
        "exact-sun" => true,
        other => {
            eprintln!("unknown LIGHT {other} (direct or exact-sun)");
            return;
        }
    };
    let budgets = parse_budgets(args.text(8));
    let first_seed: u64 = args.parsed(9, 7);
    let group_divisor: usize = args.parsed(10, 16);
    let neighbours: usize = args.parsed(11, 8);
    let global_percent: usize = args.parsed(12, 50);
    let adaptive_percent: u32 = args.parsed(13, 0);
    let defensive_percent: u32 = args.parsed(14, 0);
    let guide_percent: u32 = args.parsed(15, 50);
    let probes = match args.text(16) {
        Some("all") => usize::MAX,
        _ => args.parsed(16, 8),
    };
    let unseen_draws: usize = args.parsed(17, 0);
    let run = Run {
        unseen_draws,
        guide_percent: guide_percent.min(99),
        probes: probes.max(1),
        defensive_percent: defensive_percent.min(99),
        adaptive_percent: adaptive_percent.min(100),
        global_percent: global_percent.clamp(1, 100),
        neighbours: neighbours.max(1),
        group_divisor: group_divisor.max(1),
        width,
        seeds: first_seed..first_seed + seeds,
        image_path: image_path.as_deref(),
        methods: &selected,
        budgets: &budgets,
    };
    match scene_name {
        "cornell" | "sponza" => {
            let Some(setup) = SweepScene::load(scene_name, width, target_vpls) else {
                return;
            };
            let directional = setup.sun_sky();
            let SweepScene { vpls, gbuffer, .. } = &setup;
            let start = Instant::now();
            let Reference {
                image: reference,
                sun,
                ..
            } = setup.reference(&directional, clamp);
            let (n, m) = (reference.len() / 3, vpls.len() + directional.len());
            // The sun is the first directional light; with `exact-sun` its column is kept apart
            // as the exact part of every estimate.
            let exact = usize::from(exact_sun && !directional.is_empty());
            let exact_image = if exact > 0 { sun } else { vec![0.0f32; 3 * n] };
            println!(
                "{scene_name}: {width} × {width} pixels, {} VPLs + {} directional lights ({exact} \
                 exact), clamp {clamp}, {} threads; brute force {} ({:.3e} elements; VPL columns \
                 cached)\n",
                vpls.len(),
                directional.len(),
                rayon::current_num_threads(),
                fmt_duration(start.elapsed()),
                (n * m) as f64
            );
            let inner = setup.oracle(clamp, &directional[exact..]);
            let oracle = SceneOracle { inner, gbuffer };
            let exact = Exact {
                image: exact_image,
                elements: (exact * n) as u64,
                columns: exact,
            };
            compare(&oracle, &reference, &exact, &run);
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
            let exact = Exact {
                image: vec![0.0; reference.len()],
                elements: 0,
                columns: 0,
            };
            compare(&oracle, &reference, &exact, &run);
        }
        other => eprintln!("unknown scene {other} (cornell, sponza or synthetic)"),
    }
}

/// The settings of a comparison run.
struct Run<'a> {
    width: usize,
    group_divisor: usize,
    neighbours: usize,
    global_percent: usize,
    adaptive_percent: u32,
    defensive_percent: u32,
    guide_percent: u32,
    probes: usize,
    unseen_draws: usize,
    seeds: std::ops::Range<u64>,
    image_path: Option<&'a Path>,
    methods: &'a [&'static str],
    budgets: &'a [(usize, usize)],
}

/// The columns evaluated exactly (outside the methods' oracle): their image, elements and count.
struct Exact {
    image: Vec<f32>,
    elements: u64,
    columns: usize,
}

fn compare<O: SliceOracle + VisibilityOracle>(
    oracle: &O,
    reference: &[f32],
    exact: &Exact,
    run: &Run<'_>,
) {
    let brute = (oracle.rows() * (oracle.cols() + exact.columns)) as f64;
    let mut table = Table::new(&[
        "method",
        "rows / columns",
        "elements (shadow rays)",
        "fewer than brute force",
        "time (mean) [CPU]",
        "relative RMS error (mean of seeds)",
        "max over seeds",
    ]);
    let kmeans = VisibilityClusterMethod::KMeans { iterations: 4 };
    let seeds = run.seeds.end.saturating_sub(run.seeds.start).max(1);
    let unseen_for = |method: &str, columns: usize| {
        if method.contains("skip") {
            UnseenLights::Skip
        } else if method.contains("grouped") {
            UnseenLights::Groups((columns / run.group_divisor).max(1))
        } else {
            UnseenLights::Sample
        }
    };
    for (b, &(rows, columns)) in run.budgets.iter().enumerate() {
        if rows > oracle.rows() || columns > oracle.cols() {
            continue;
        }
        let mut images: Vec<Vec<f32>> = Vec::new();
        for &method in run.methods {
            let (mut errors, mut elements, mut extra) = (Vec::new(), 0u64, 0u64);
            let (start, cpu_start) = (Instant::now(), cpu_seconds());
            for seed in run.seeds.clone() {
                let (mut image, e) = match method {
                    m if m.starts_with("row-column") => {
                        let c = RowColumnConfig::new(rows, columns)
                            .with_seed(seed)
                            .with_unseen(unseen_for(method, columns));
                        let r = row_column_sampling(oracle, &c, &NoProgress).expect("valid");
                        (r.image, r.elements)
                    }
                    m if m.starts_with("LightSlice") => {
                        let c = LightSliceConfig {
                            neighbours: run.neighbours,
                            global_clusters: (columns * run.global_percent / 100).max(1),
                            ..LightSliceConfig::new(rows, columns)
                        }
                        .with_seed(seed)
                        .with_unseen(unseen_for(method, columns))
                        .with_local_importance(method.contains("local"))
                        .with_adaptive_percent(run.adaptive_percent)
                        .with_defensive_percent(run.defensive_percent)
                        .with_split(if method.contains("spread") {
                            SliceSplit::Spread
                        } else {
                            SliceSplit::Largest
                        });
                        let r = if method.contains("shading guide") {
                            let guide = ShadingGuide::new(run.guide_percent, run.probes)
                                .with_unseen_draws(run.unseen_draws);
                            let c = c.with_guide(guide);
                            light_slice_guided(oracle, &c, &NoProgress).expect("valid")
                        } else {
                            light_slice(oracle, &c, &NoProgress).expect("valid")
                        };
                        extra = r.shading_evaluations;
                        (r.image, r.elements)
                    }
                    _ => {
                        let mut c = VisibilityConfig::new(rows, columns).with_seed(seed);
                        if method.contains("k-means") {
                            c = c.with_method(kmeans);
                        }
                        let r = visibility_clustering(oracle, &c, &NoProgress).expect("valid");
                        extra = r.shading_evaluations;
                        (r.image, r.elements)
                    }
                };
                for (v, &e) in image.iter_mut().zip(&exact.image) {
                    *v += e;
                }
                let e = e + exact.elements;
                elements += e;
                let error = relative_frobenius_error(&image, reference).expect("same size");
                println!(
                    "  seed {seed}: {method} {rows}/{columns}: {e} elements, {:.2}%",
                    100.0 * error
                );
                errors.push(error);
                if seed == run.seeds.start {
                    images.push(image);
                }
            }
            let time = start.elapsed() / seeds as u32;
            let cpu = (cpu_seconds() - cpu_start) / seeds as f64;
            let elements = elements / seeds;
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
                format!("{} [{cpu:.1} s]", fmt_duration(time)),
                format!("{:.2}%", 100.0 * mean),
                format!("{:.2}%", 100.0 * max),
            ]);
            println!("{method} {rows}/{columns}: {:.2}%", 100.0 * mean);
        }
        if let (Some(path), 0, 2..) = (run.image_path, b, images.len()) {
            let errors: Vec<Vec<f32>> = images[..2]
                .iter()
                .map(|image| {
                    reference
                        .iter()
                        .zip(image)
                        .map(|(a, b)| 10.0 * (a - b).abs())
                        .collect()
                })
                .collect();
            let panels = [images[0].clone(), images[1].clone()]
                .into_iter()
                .chain(errors)
                .collect::<Vec<_>>();
            write_strip(path, run.width, reference, &panels);
        }
    }
    println!("\n{}", table.markdown());
}
