//! Many-light matrix sampling against brute force at equal element (shadow-ray) budgets:
//! row-column sampling, LightSlice (and its options) and visibility clustering (divisive and
//! k-means) on the Cornell box or Sponza VPL oracle of prt-trace, or on the synthetic VPL
//! matrix. Relative RMS error vs elements and time, per VPL clamp.
//!
//! ```text
//! cargo run --release -p prt-benches --bin manylight_methods -- \
//!     --scene cornell --width 128 --vpls 50000 --clamp 0.1 --seeds 2 --first-seed 7 \
//!     --methods rowcol,slice,vis,kmeans --light direct \
//!     --budgets 100/200,300/900,432/864,400/1300,600/1200,900/1800 [--image PATH] [--csv DIR]
//! ```
//!
//! (the defaults; `--help` lists the LightSlice knobs). The brute-force image of the VPL
//! columns is cached in `target/manylight_cache/` per (scene, width, VPLs, clamp); the
//! directional columns (Sponza's sun and sky) are evaluated on every run. Every seed's error is
//! printed as it finishes; the table at the end has one row per clamp, budget and method, time
//! as wall [process CPU] per run. `--image` gets reference | the first two methods | their 10×
//! absolute errors, for the first clamp, the first seed and `--image-budget`.
use std::path::{Path, PathBuf};

use clap::Parser;
use prt_benches::manylight::{Budget, Light, Reference, SweepScene, mean_and_max, write_strip};
use prt_benches::{Stopwatch, Table, fmt_duration};
use prt_core::NoProgress;
use prt_core::metrics::relative_frobenius_error;
use prt_manylight::{
    LightSliceConfig, RowColumnConfig, ShadingGuide, SliceOracle, SliceSplit, SyntheticVplOracle,
    UnseenLights, VisibilityClusterMethod, VisibilityConfig, VisibilityOracle, brute_force,
    light_slice, light_slice_guided, row_column_sampling, visibility_clustering,
};

/// The matrix to sample.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum SceneName {
    /// prt-trace's Cornell box (lit by its ceiling quad: no directional lights).
    Cornell,
    /// Sponza from ../shared/scenes, lit by the sun and sky.
    Sponza,
    /// prt-manylight's `SyntheticVplOracle` (a lit floor; `--clamp` and `--light` unused).
    Synthetic,
}

/// A method and its options; listed in the order the table and the image use.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, clap::ValueEnum)]
enum Method {
    /// Row-column sampling (unseen lights sampled: `UnseenLights::Sample`).
    Rowcol,
    /// Row-column sampling, unseen lights skipped (`UnseenLights::Skip`, the paper's estimator).
    RowcolSkip,
    /// Row-column sampling, unseen lights in `columns / --group-divisor` groups.
    RowcolGroups,
    /// LightSlice with the paper's settings.
    Slice,
    /// LightSlice, unseen lights skipped.
    SliceSkip,
    /// LightSlice, unseen lights in groups.
    SliceGroups,
    /// LightSlice, slices cut by spread (`SliceSplit::Spread`).
    SliceSpread,
    /// LightSlice, skip unseen, spread slices.
    SliceSkipSpread,
    /// LightSlice, skip unseen, `LightSliceConfig::local_importance`.
    SliceSkipLocal,
    /// LightSlice, skip unseen, spread slices, local importance.
    SliceSkipSpreadLocal,
    /// LightSlice, skip unseen, spread slices, shading guide (`light_slice_guided`).
    SliceSkipSpreadGuided,
    /// Visibility clustering, divisive.
    Vis,
    /// Visibility clustering, k-means (4 iterations from the divisive clustering).
    Kmeans,
}

impl Method {
    /// The name in the table.
    fn label(self) -> &'static str {
        match self {
            Self::Rowcol => "row-column",
            Self::RowcolSkip => "row-column (skip unseen)",
            Self::RowcolGroups => "row-column (grouped unseen)",
            Self::Slice => "LightSlice",
            Self::SliceSkip => "LightSlice (skip unseen)",
            Self::SliceGroups => "LightSlice (grouped unseen)",
            Self::SliceSpread => "LightSlice (spread slices)",
            Self::SliceSkipSpread => "LightSlice (skip unseen, spread slices)",
            Self::SliceSkipLocal => "LightSlice (skip unseen, local importance)",
            Self::SliceSkipSpreadLocal => {
                "LightSlice (skip unseen, spread slices, local importance)"
            }
            Self::SliceSkipSpreadGuided => "LightSlice (skip unseen, spread slices, shading guide)",
            Self::Vis => "visibility (split)",
            Self::Kmeans => "visibility (k-means)",
        }
    }
}

/// `--probes`: a count, or `all` for every pixel of a slice.
fn parse_probes(text: &str) -> Result<usize, String> {
    match text {
        "all" => Ok(usize::MAX),
        n => n
            .parse::<usize>()
            .map(|p| p.max(1))
            .map_err(|e| format!("{n}: {e} (a count or `all`)")),
    }
}

#[derive(Debug, Parser)]
#[command(about = "Many-light sampling methods against brute force at equal shadow rays")]
struct Cli {
    /// The matrix to sample.
    #[arg(long, value_enum, default_value = "cornell")]
    scene: SceneName,
    /// Image side in pixels (the image is WIDTH × WIDTH).
    #[arg(long, default_value_t = 128)]
    width: usize,
    /// About this many VPLs (particles with 2 bounces, seed 1); lights of the synthetic matrix.
    #[arg(long, default_value_t = 50_000)]
    vpls: usize,
    /// VPL clamp distances in scene units, comma-separated (the 1/d² falloff is capped at
    /// 1/clamp²; the LightSlice authors use 2.5% of the scene diagonal: 0.087 Cornell, 1.58
    /// Sponza).
    #[arg(long, value_delimiter = ',', default_value = "0.1")]
    clamp: Vec<f32>,
    /// Seeds per configuration (mean and max of the error).
    #[arg(long, default_value_t = 2)]
    seeds: u64,
    /// The first seed: seeds FIRST_SEED .. FIRST_SEED + SEEDS (settings were chosen on 1..6
    /// and reported on 7..).
    #[arg(long, default_value_t = 7)]
    first_seed: u64,
    /// Methods to run, comma-separated (run and shown in the order of this list's help).
    #[arg(
        long,
        value_enum,
        value_delimiter = ',',
        default_value = "rowcol,slice,vis,kmeans"
    )]
    methods: Vec<Method>,
    /// The lights beside the VPLs (Cornell and Sponza).
    #[arg(long, value_enum, default_value = "direct")]
    light: Light,
    /// Budgets to run, comma-separated `rows/columns` (rows = LightSlice's slices, columns =
    /// its local clusters; the same elements for every method).
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "100/200,300/900,432/864,400/1300,600/1200,900/1800"
    )]
    budgets: Vec<Budget>,
    /// PNG path: reference | the first two methods | their 10× absolute errors, at the first
    /// clamp, first seed and `--image-budget`.
    #[arg(long)]
    image: Option<PathBuf>,
    /// The budget of `--image` (default: the first of `--budgets`).
    #[arg(long)]
    image_budget: Option<Budget>,
    /// The `-groups` methods cut the unseen lights into columns / GROUP_DIVISOR groups (at
    /// least 1), out of the column budget.
    #[arg(long, default_value_t = 16, value_parser = clap::value_parser!(u64).range(1..))]
    group_divisor: u64,
    /// LightSlice: the slices whose rows refine a slice's clustering
    /// (`LightSliceConfig::neighbours`).
    #[arg(long, default_value_t = 8, value_parser = clap::value_parser!(u64).range(1..))]
    neighbours: u64,
    /// LightSlice: global clusters in percent of the local clusters.
    #[arg(long, default_value_t = 50, value_parser = clap::value_parser!(u64).range(1..=100))]
    global_percent: u64,
    /// LightSlice: percent of the representatives spread over the slices by brightness
    /// (`LightSliceConfig::adaptive_percent`).
    #[arg(long, default_value_t = 0, value_parser = clap::value_parser!(u32).range(0..=100))]
    adaptive_percent: u32,
    /// LightSlice: percent of each representative draw made uniformly within the cluster
    /// (`LightSliceConfig::defensive_percent`).
    #[arg(long, default_value_t = 0, value_parser = clap::value_parser!(u32).range(0..=99))]
    defensive_percent: u32,
    /// The shading guide of `slice-skip-spread-guided`: percent of each draw by the probes'
    /// unshadowed shading (`ShadingGuide::new`).
    #[arg(long, default_value_t = 50, value_parser = clap::value_parser!(u32).range(0..=99))]
    guide_percent: u32,
    /// The shading guide's probe pixels per slice, or `all` for every pixel of the slice.
    #[arg(long, default_value = "8", value_parser = parse_probes)]
    probes: usize,
    /// The shading guide's draws per slice among the unseen lights
    /// (`ShadingGuide::with_unseen_draws`).
    #[arg(long, default_value_t = 0)]
    unseen_draws: usize,
    /// Folder for the table as CSV (manylight_methods.csv).
    #[arg(long)]
    csv: Option<PathBuf>,
}

fn norm(v: &[f32]) -> f64 {
    v.iter().map(|&x| x as f64 * x as f64).sum::<f64>().sqrt()
}

fn main() {
    let mut cli = Cli::parse();
    cli.methods.sort();
    cli.methods.dedup();
    let mut table = Table::new(&[
        "clamp",
        "method",
        "rows / columns",
        "elements (shadow rays)",
        "fewer than brute force",
        "time (mean) [CPU]",
        "relative RMS error (mean of seeds)",
        "max over seeds",
        "unseen lights (mean)",
        "error / ‖sampled lights' image‖ (mean)",
    ]);
    let (width, scene) = (cli.width, cli.scene);
    match scene {
        SceneName::Cornell | SceneName::Sponza => {
            let name = if scene == SceneName::Cornell {
                "cornell"
            } else {
                "sponza"
            };
            let Some(setup) = SweepScene::load(name, width, cli.vpls) else {
                return;
            };
            let directional = match cli.light {
                Light::Indirect => Vec::new(),
                Light::Direct | Light::ExactSun => setup.sun_sky(),
            };
            // With `exact-sun` the sun (the first directional light) is kept apart as the
            // exact part of every estimate.
            let exact = usize::from(cli.light == Light::ExactSun && !directional.is_empty());
            for (c, &clamp) in cli.clamp.iter().enumerate() {
                let watch = Stopwatch::start();
                let Reference {
                    image: reference,
                    vpl_image,
                    sun,
                } = setup.reference(&directional, clamp);
                let n = reference.len() / 3;
                let m = setup.vpls.len() + directional.len();
                println!(
                    "{name}: {width} × {width} pixels, {} VPLs + {} directional lights ({exact} \
                     exact), clamp {clamp}, {} threads; brute force {} ({:.3e} elements; VPL \
                     columns cached); ‖indirect (VPL columns)‖ / ‖reference‖ = {:.4}",
                    setup.vpls.len(),
                    directional.len(),
                    rayon::current_num_threads(),
                    fmt_duration(watch.wall()),
                    (n * m) as f64,
                    norm(&vpl_image) / norm(&reference),
                );
                let exact_image = if exact > 0 {
                    let lit = sun.chunks(3).filter(|p| p.iter().any(|&v| v > 0.0)).count();
                    println!(
                        "exact column (the sun): {lit} of {n} pixels lit ({:.2}%), ‖column‖ / \
                         ‖reference‖ = {:.3}",
                        100.0 * lit as f64 / n as f64,
                        norm(&sun) / norm(&reference)
                    );
                    sun
                } else {
                    vec![0.0f32; 3 * n]
                };
                let oracle = setup.oracle(clamp, &directional[exact..]);
                let exact = Exact {
                    image: exact_image,
                    elements: (exact * n) as u64,
                    columns: exact,
                };
                let image = cli.image.as_deref().filter(|_| c == 0);
                compare(&oracle, &reference, &exact, &cli, clamp, image, &mut table);
            }
        }
        SceneName::Synthetic => {
            let oracle = SyntheticVplOracle::new(width, width, cli.vpls, 1);
            let watch = Stopwatch::start();
            let reference = brute_force(&oracle, &NoProgress).expect("finite oracle");
            println!(
                "synthetic VPL matrix: {width} × {width} pixels, {} lights, {} threads; brute \
                 force {} [{:.1} s CPU]\n",
                cli.vpls,
                rayon::current_num_threads(),
                fmt_duration(watch.wall()),
                watch.cpu(),
            );
            let exact = Exact {
                image: vec![0.0; reference.len()],
                elements: 0,
                columns: 0,
            };
            let image = cli.image.as_deref();
            compare(
                &oracle,
                &reference,
                &exact,
                &cli,
                f32::NAN,
                image,
                &mut table,
            );
        }
    }
    println!("\n{}", table.markdown());
    if let Err(e) = table.write_csv(cli.csv.as_deref(), "manylight_methods") {
        eprintln!("could not write the CSV: {e}");
    }
}

/// The columns evaluated exactly (outside the methods' oracle): their image, elements and count.
struct Exact {
    image: Vec<f32>,
    elements: u64,
    columns: usize,
}

/// One run's image, elements, shading evaluations (no shadow rays) and unseen lights (row-column
/// sampling only).
struct Run {
    image: Vec<f32>,
    elements: u64,
    shading: u64,
    unseen: Option<usize>,
}

fn run_method<O: SliceOracle + VisibilityOracle>(
    oracle: &O,
    method: Method,
    budget: Budget,
    seed: u64,
    cli: &Cli,
) -> Run {
    let Budget { rows, columns } = budget;
    let unseen = match method {
        Method::RowcolSkip
        | Method::SliceSkip
        | Method::SliceSkipSpread
        | Method::SliceSkipLocal
        | Method::SliceSkipSpreadLocal
        | Method::SliceSkipSpreadGuided => UnseenLights::Skip,
        Method::RowcolGroups | Method::SliceGroups => {
            UnseenLights::Groups((columns / cli.group_divisor as usize).max(1))
        }
        _ => UnseenLights::Sample,
    };
    match method {
        Method::Rowcol | Method::RowcolSkip | Method::RowcolGroups => {
            let c = RowColumnConfig::new(rows, columns)
                .with_seed(seed)
                .with_unseen(unseen);
            let r = row_column_sampling(oracle, &c, &NoProgress).expect("valid");
            Run {
                image: r.image,
                elements: r.elements,
                shading: 0,
                unseen: Some(r.unseen_lights),
            }
        }
        Method::Vis | Method::Kmeans => {
            let mut c = VisibilityConfig::new(rows, columns).with_seed(seed);
            if method == Method::Kmeans {
                c = c.with_method(VisibilityClusterMethod::KMeans { iterations: 4 });
            }
            let r = visibility_clustering(oracle, &c, &NoProgress).expect("valid");
            Run {
                image: r.image,
                elements: r.elements,
                shading: r.shading_evaluations,
                unseen: None,
            }
        }
        _ => {
            let spread = matches!(
                method,
                Method::SliceSpread
                    | Method::SliceSkipSpread
                    | Method::SliceSkipSpreadLocal
                    | Method::SliceSkipSpreadGuided
            );
            let local = matches!(
                method,
                Method::SliceSkipLocal | Method::SliceSkipSpreadLocal
            );
            let c = LightSliceConfig {
                neighbours: cli.neighbours as usize,
                global_clusters: (columns * cli.global_percent as usize / 100).max(1),
                ..LightSliceConfig::new(rows, columns)
            }
            .with_seed(seed)
            .with_unseen(unseen)
            .with_local_importance(local)
            .with_adaptive_percent(cli.adaptive_percent)
            .with_defensive_percent(cli.defensive_percent)
            .with_split(if spread {
                SliceSplit::Spread
            } else {
                SliceSplit::Largest
            });
            let r = if method == Method::SliceSkipSpreadGuided {
                let guide = ShadingGuide::new(cli.guide_percent, cli.probes)
                    .with_unseen_draws(cli.unseen_draws);
                light_slice_guided(oracle, &c.with_guide(guide), &NoProgress).expect("valid")
            } else {
                light_slice(oracle, &c, &NoProgress).expect("valid")
            };
            Run {
                image: r.image,
                elements: r.elements,
                shading: r.shading_evaluations,
                unseen: None,
            }
        }
    }
}

/// Runs every budget × method on `oracle` and appends their rows to `table`; writes the image
/// strip when `image` is given.
fn compare<O: SliceOracle + VisibilityOracle>(
    oracle: &O,
    reference: &[f32],
    exact: &Exact,
    cli: &Cli,
    clamp: f32,
    image: Option<&Path>,
    table: &mut Table,
) {
    let brute = (oracle.rows() * (oracle.cols() + exact.columns)) as f64;
    // ‖reference‖ / ‖reference − exact columns‖: scales the error to the sampled lights' image.
    let rest: Vec<f32> = reference
        .iter()
        .zip(&exact.image)
        .map(|(r, e)| r - e)
        .collect();
    let sampled_scale = norm(reference) / norm(&rest);
    let seeds = cli.first_seed..cli.first_seed + cli.seeds;
    let runs = cli.seeds.max(1);
    let image_budget = cli.image_budget.or(cli.budgets.first().copied());
    let clamp_cell = if clamp.is_nan() {
        "-".to_string()
    } else {
        clamp.to_string()
    };
    for &budget in &cli.budgets {
        if budget.rows > oracle.rows() || budget.columns > oracle.cols() {
            continue;
        }
        let mut images: Vec<Vec<f32>> = Vec::new();
        for &method in &cli.methods {
            let (mut errors, mut elements, mut shading, mut unseen) =
                (Vec::new(), 0u64, 0u64, None);
            let watch = Stopwatch::start();
            for seed in seeds.clone() {
                let mut run = run_method(oracle, method, budget, seed, cli);
                for (v, &e) in run.image.iter_mut().zip(&exact.image) {
                    *v += e;
                }
                let e = run.elements + exact.elements;
                elements += e;
                shading = run.shading;
                unseen = run.unseen.map(|u| u + unseen.unwrap_or(0));
                let error = relative_frobenius_error(&run.image, reference).expect("same size");
                println!(
                    "  seed {seed}: {} {budget}: {e} elements, {:.2}%",
                    method.label(),
                    100.0 * error
                );
                errors.push(error);
                if seed == cli.first_seed {
                    images.push(run.image);
                }
            }
            let time = watch.wall() / runs as u32;
            let cpu = watch.cpu() / runs as f64;
            let elements = elements / runs;
            let (mean, max) = mean_and_max(&errors);
            let elements_cell = if shading > 0 {
                format!("{:.3e} (+{:.2e} shading)", elements as f64, shading as f64)
            } else {
                format!("{:.3e}", elements as f64)
            };
            table.row(vec![
                clamp_cell.clone(),
                method.label().to_string(),
                format!("{} / {}", budget.rows, budget.columns),
                elements_cell,
                format!("{:.1}×", brute / elements as f64),
                format!("{} [{cpu:.1} s]", fmt_duration(time)),
                format!("{:.2}%", 100.0 * mean),
                format!("{:.2}%", 100.0 * max),
                unseen.map_or("-".into(), |u| format!("{:.0}", u as f64 / runs as f64)),
                format!("{:.2}%", 100.0 * mean * sampled_scale),
            ]);
            println!("{} {budget}: {:.2}%", method.label(), 100.0 * mean);
        }
        if let (Some(path), true, false) = (image, Some(budget) == image_budget, images.is_empty())
        {
            images.truncate(2);
            let errors: Vec<Vec<f32>> = images
                .iter()
                .map(|image| {
                    reference
                        .iter()
                        .zip(image)
                        .map(|(a, b)| 10.0 * (a - b).abs())
                        .collect()
                })
                .collect();
            images.extend(errors);
            write_strip(path, cli.width, reference, &images);
        }
    }
}
