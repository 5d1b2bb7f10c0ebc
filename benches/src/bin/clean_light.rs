//! The default bake's light against a 16×-ray reference: each bake setting's wall time and the
//! image error of its MBD container, rendered from the scene's first view, against the traced
//! volume of a bake with 16× the rays and cache rays of another seed.
//!
//! ```text
//! cargo run --release -p prt-benches --bin clean_light -- --scene cornell --run base --run rays=1024
//! cargo run --release -p prt-benches --bin clean_light -- --scene sponza --res 64 --run base
//! ```
//!
//! A run is a comma-separated list of `knob=value` applied in order to `prt bake`'s defaults
//! (`base`: none; the default before the denoiser: `rays=256,denoise=off`). Knobs: `quality`
//! (`draft`, `default`, `high`: every knob of that `--quality` preset, the resolution staying
//! `--res`), `rays`, `cache_rays`, `rank`, `iterations`, `full_iterations`, `seed`, `adaptive`
//! (target relative standard error, `off`), `min_rays` (adaptive sampling's minimum), `denoise`
//! (strength, `off`), `radius` (the denoiser's half-width), `baselines` (`on`/`off`),
//! `weighting` (the loss weighting of `prt bake --loss-weighting`: `none`, `relative[:EXPONENT]`),
//! `projection` (MBD's centre projection, `on`/`off`). `--plot`
//! draws one line per run with its `rays` knob removed (more rays to the right). Each bake writes its container into a temporary folder, reads it
//! back and renders it (256², the reference's exposure); the traced volume itself is rendered
//! too (the trace's error before compression). The reference (16 × 256 rays, 16 × 64 cache rays,
//! seed 1001, neither adaptive nor denoised) is cached in `target/clean_light/`. Times: the
//! bake (`prt_bake::bake`, baselines as `prt bake`) in wall and process CPU seconds.
//!
//! `--methods mbd,bpca,cpca,traced` and `--views all` add a second table against the same
//! reference: each listed method's image (BPCA and CPCA lit from the bake's models as the
//! report lights them) in each view (`first`, or every view of the bake's report, each at its
//! own reference render's exposure), and their mean over the views, which the report ranks by:
//!
//! ```text
//! cargo run --release -p prt-benches --bin clean_light -- --scene gas_station --methods mbd,bpca,cpca --views all --run rays=256,denoise=off,weighting=none,projection=off --run base
//! ```

use std::path::{Path, PathBuf};

use clap::Parser;
use prt_bake::container::read_container;
use prt_bake::{BakeConfig, Quality, SceneInput, Stage, bake};
use prt_benches::mbd::{read_cached, write_cached};
use prt_benches::{
    PlotLabels, PlotPoint, Scratch, Stopwatch, Table, cache_dir, load_average, load_scene_input,
    plot_lines,
};
use prt_core::{GridField, NoProgress};
use prt_mbd::LossWeighting;
use prt_render::{ImageMetrics, RenderConfig, Rendered, ToneMap, image_metrics};
use prt_sphere::Sky;
use prt_texture::Limits;
use prt_trace::{BakeOptions, LitVolume, RayTracer, TransferBaker};

/// Seed of the reference trace: never a bake's (0 by default), whose directions it would share.
const REFERENCE_SEED: u64 = 1001;
/// The reference's directions per voxel and surface-cache rays: 16× those of the default bake
/// the issue measured (256 and 64), fixed so that changing the defaults keeps the reference.
const REFERENCE_RAYS: usize = 16 * 256;
const REFERENCE_CACHE_RAYS: usize = 16 * 64;
/// Width and height of the renders (the report's).
const RENDER_SIZE: usize = 256;

#[derive(Debug, Parser)]
#[command(about = "bake settings against wall time and the image error of the MBD container")]
struct Cli {
    /// Scene: `cornell` (built in), `sponza` or `gas_station` (../shared/scenes).
    #[arg(long, default_value = "cornell")]
    scene: String,
    /// Voxels along the longest axis (bake and reference) [default: 32].
    #[arg(long, default_value_t = 32)]
    res: usize,
    /// Settings to bake, each `knob=value,...` or `base` (repeatable).
    #[arg(long = "run", default_value = "base")]
    runs: Vec<String>,
    /// Write each table as CSV into this folder.
    #[arg(long)]
    csv: Option<PathBuf>,
    /// Plot image error against the bake's CPU time (steadier than wall time on a shared
    /// machine) into this PNG.
    #[arg(long)]
    plot: Option<PathBuf>,
    /// Methods of the per-view table, comma-separated: `mbd` (the container as written),
    /// `bpca`, `cpca` (the bake's baselines), `traced` (the bake's traced volume).
    #[arg(long, value_delimiter = ',', default_value = "mbd")]
    methods: Vec<String>,
    /// Views scored: the scene's `first` or `all` the views of the bake's report.
    #[arg(long, value_enum, default_value_t = Views::First)]
    views: Views,
}

/// Which of the scene's views are scored.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum Views {
    /// The first (the table's and the plot's).
    First,
    /// Every view `prt bake`'s report renders (glTF cameras, then `front` and `inside`).
    All,
}

/// The methods `--methods` may name: the report's keys, then the traced volume.
const METHODS: [(&str, &str); 4] = [
    ("mbd", "MBD"),
    ("bpca", "BPCA"),
    ("cpca", "CPCA"),
    ("traced", "traced"),
];

/// `weighting=`: `none` (the papers' loss) or `relative[:EXPONENT]` (the floor at its default),
/// as `prt bake --loss-weighting` reads them.
fn loss_weighting(value: &str) -> Result<Option<LossWeighting>, String> {
    LossWeighting::parse(value).map_err(|e| format!("weighting={value}: {e}"))
}

/// `base` with the settings of `run` applied.
fn apply(base: &BakeConfig, run: &str) -> Result<BakeConfig, String> {
    let mut config = base.clone();
    if run == "base" {
        return Ok(config);
    }
    for pair in run.split(',') {
        let (key, value) = pair
            .split_once('=')
            .ok_or_else(|| format!("{pair}: expected knob=value"))?;
        let count = || {
            value
                .parse::<usize>()
                .map_err(|e| format!("{key}={value}: {e}"))
        };
        let real = || {
            value
                .parse::<f32>()
                .map_err(|e| format!("{key}={value}: {e}"))
        };
        let optional = || {
            if value == "off" {
                Ok(None)
            } else {
                real().map(Some)
            }
        };
        let switch = || match value {
            "on" => Ok(true),
            "off" => Ok(false),
            _ => Err(format!("{key}={value}: on or off")),
        };
        match key {
            "quality" => {
                let quality = match value {
                    "draft" => Quality::Draft,
                    "default" => Quality::Default,
                    "high" => Quality::High,
                    _ => return Err(format!("{key}={value}: draft, default or high")),
                };
                config = BakeConfig {
                    resolution: config.resolution,
                    ..BakeConfig::preset(quality)
                };
            }
            "iterations" => config.max_iterations = count()?,
            "full_iterations" => config.full_iterations = count()?,
            "rays" => config.rays_per_voxel = count()?,
            "cache_rays" => config.cache_rays = count()?,
            "rank" => config.rank = count()?,
            "seed" => config.seed = count()? as u64,
            "baselines" => config.baselines = switch()?,
            "adaptive" => config.adaptive_error = optional()?,
            "min_rays" => config.adaptive_min_rays = count()?,
            "denoise" => config.denoise = optional()?,
            "radius" => config.denoise_radius = count()?,
            "weighting" => config.loss_weighting = loss_weighting(value)?,
            "projection" => config.centre_projection = switch()?,
            other => return Err(format!("unknown knob {other}")),
        }
    }
    Ok(config)
}

/// The line of the plot a run belongs to: the run without its `rays` knob.
fn series(run: &str) -> String {
    let rest: Vec<&str> = run
        .split(',')
        .filter(|pair| !pair.starts_with("rays="))
        .collect();
    if rest.is_empty() {
        "base".into()
    } else {
        rest.join(",")
    }
}

/// The reference's traced field and validity, read from `target/clean_light/` when an earlier
/// run wrote them.
fn reference(scene_name: &str, scene: &SceneInput, res: usize) -> (GridField, Vec<bool>) {
    let defaults = BakeConfig::default();
    let (rays, cache_rays) = (REFERENCE_RAYS, REFERENCE_CACHE_RAYS);
    let stem = format!("{scene_name}_{res}_r{rays}_c{cache_rays}_s{REFERENCE_SEED}");
    let path = cache_dir("clean_light").join(format!("{stem}.f32"));
    let mask_path = cache_dir("clean_light").join(format!("{stem}.valid"));
    if let (Some(field), Ok(mask)) = (read_cached(&path), std::fs::read(&mask_path))
        && mask.len() == field.num_voxels()
    {
        eprintln!("reference: read {}", path.display());
        return (field, mask.iter().map(|&b| b != 0).collect());
    }
    let bounds = scene.scene.bounds().expect("the scene has triangles");
    let grid = BakeConfig {
        resolution: res,
        ..defaults
    };
    let options = BakeOptions {
        resolution: grid.grid_resolution(bounds.size().to_array()),
        rays_per_voxel: rays,
        cache_rays,
        seed: REFERENCE_SEED,
        ..BakeOptions::default()
    };
    let watch = Stopwatch::start();
    let volume = TransferBaker::new(&scene.scene, options)
        .and_then(|baker| baker.bake(&NoProgress))
        .expect("reference trace");
    eprintln!(
        "reference {:?}, {rays} rays, {cache_rays} cache rays: traced in {:.1} s",
        volume.field.dims(),
        watch.wall().as_secs_f64()
    );
    let mask: Vec<u8> = volume.valid.iter().map(|&v| u8::from(v)).collect();
    if let Err(e) = write_cached(&path, &volume.field).and_then(|()| {
        let partial = mask_path.with_extension("partial");
        std::fs::write(&partial, &mask)?;
        std::fs::rename(partial, &mask_path)
    }) {
        eprintln!("cannot cache {}: {e}", path.display());
    }
    (volume.field, volume.valid)
}

/// One scored view: the reference's render of it and that render's exposure.
struct ViewTarget {
    name: String,
    view: prt_trace::camera::PinholeView,
    image: Rendered,
    tone: ToneMap,
}

/// The scene, its scored views (the first first) and their reference renders, shared by every
/// run.
struct Target<'a> {
    scene: &'a SceneInput,
    tracer: RayTracer,
    sky: Sky,
    views: Vec<ViewTarget>,
}

impl Target<'_> {
    fn render(&self, view: &prt_trace::camera::PinholeView, volume: &LitVolume) -> Rendered {
        let config = RenderConfig {
            width: RENDER_SIZE,
            height: RENDER_SIZE,
        };
        prt_render::render(
            &self.scene.scene,
            &self.tracer,
            view,
            volume,
            &self.sky,
            &config,
            &NoProgress,
        )
        .expect("render")
    }

    /// `volume`'s image error in each scored view.
    fn metrics(&self, volume: &LitVolume) -> Vec<ImageMetrics> {
        self.views
            .iter()
            .map(|v| {
                image_metrics(&v.image, &self.render(&v.view, volume), &v.tone).expect("same size")
            })
            .collect()
    }
}

/// What one bake cost and how its images compare.
#[derive(Debug, Clone)]
struct Row {
    label: String,
    trace_s: f64,
    wall_s: f64,
    cpu_s: f64,
    rays_per_voxel: f64,
    mbd: ImageMetrics,
    traced: ImageMetrics,
    /// Each of `--methods`' image errors in each scored view.
    methods: Vec<(&'static str, Vec<ImageMetrics>)>,
}

fn measure(
    target: &Target<'_>,
    config: &BakeConfig,
    folder: &Path,
    label: &str,
    methods: &[&'static str],
) -> Row {
    let config = BakeConfig {
        container: Some(folder.to_path_buf()),
        ..config.clone()
    };
    let watch = Stopwatch::start();
    let baked = bake(target.scene, &config, &NoProgress).expect("bake");
    let (wall_s, cpu_s) = (watch.wall().as_secs_f64(), watch.cpu());
    let trace_s = baked
        .stage_times
        .iter()
        .find(|(stage, _)| *stage == Stage::Trace)
        .map_or(0.0, |(_, t)| t.as_secs_f64());
    let field = &baked.volume.field;
    let read = read_container(folder, &Limits::default()).expect("container reads back");
    let mbd = read.light(&target.sky, &NoProgress).expect("lit container");
    let traced = LitVolume::from_transfer(field, &baked.volume.valid, &target.sky, &NoProgress)
        .expect("lit trace");
    let stats = &baked.volume.stats;
    let (mbd, traced) = (target.metrics(&mbd), target.metrics(&traced));
    let methods = methods
        .iter()
        .map(|&key| {
            let metrics = match key {
                "mbd" => mbd.clone(),
                "traced" => traced.clone(),
                _ => {
                    // Lit as the bake's report lights the baselines.
                    let baseline = baked
                        .baselines
                        .iter()
                        .find(|b| b.method.key() == key)
                        .expect("the run fits the baselines");
                    let lit = LitVolume::from_model(
                        &baseline.model,
                        field.dims(),
                        field.bounds(),
                        &baked.volume.valid,
                        &target.sky,
                        &NoProgress,
                    )
                    .expect("lit baseline");
                    target.metrics(&lit)
                }
            };
            (key, metrics)
        })
        .collect();
    Row {
        label: label.to_string(),
        trace_s,
        wall_s,
        cpu_s,
        rays_per_voxel: stats.voxel_rays as f64 / stats.valid_voxels().max(1) as f64,
        mbd: mbd[0],
        traced: traced[0],
        methods,
    }
}

/// The per-view table: each setting's views, then their mean, with each method's image error.
fn view_table(rows: &[Row], views: &[ViewTarget]) -> Table {
    let mut header = vec!["setting".to_string(), "view".to_string()];
    for (key, _) in &rows[0].methods {
        let name = METHODS.iter().find(|(k, _)| k == key).map_or(*key, |m| m.1);
        header.extend([
            format!("{name}: FLIP"),
            "mean levels".into(),
            "> 10 levels".into(),
        ]);
    }
    let mut table = Table::new(&header.iter().map(String::as_str).collect::<Vec<_>>());
    for row in rows {
        let means: Vec<ImageMetrics> = row.methods.iter().map(|(_, m)| mean(m)).collect();
        let lines = views
            .iter()
            .enumerate()
            .map(|(i, v)| (v.name.clone(), i))
            .chain((views.len() > 1).then(|| ("mean".to_string(), usize::MAX)));
        for (name, index) in lines {
            let mut cells = vec![row.label.clone(), name];
            for ((_, per_view), mean) in row.methods.iter().zip(&means) {
                let m = per_view.get(index).unwrap_or(mean);
                cells.extend([
                    format!("{:.4}", m.flip),
                    format!("{:.2}", m.mean_levels),
                    format!("{:.1} %", 100.0 * m.share_off),
                ]);
            }
            table.row(cells);
        }
    }
    table
}

/// The mean of each error over the views (ꟻLIP's is what the report ranks by).
fn mean(per_view: &[ImageMetrics]) -> ImageMetrics {
    let n = per_view.len().max(1) as f64;
    let average = |f: fn(&ImageMetrics) -> f64| per_view.iter().map(f).sum::<f64>() / n;
    ImageMetrics {
        flip: average(|m| m.flip),
        mean_levels: average(|m| m.mean_levels),
        share_off: average(|m| m.share_off),
        dark_levels: average(|m| m.dark_levels),
        median_relative: average(|m| m.median_relative),
        pixels: per_view.iter().map(|m| m.pixels).sum(),
    }
}

fn main() {
    let cli = Cli::parse();
    let scene = load_scene_input(&cli.scene).unwrap_or_else(|e| {
        eprintln!("cannot load the scene: {e}");
        std::process::exit(2)
    });
    let base = BakeConfig {
        resolution: cli.res,
        ..BakeConfig::default()
    };
    let methods: Vec<&'static str> = cli
        .methods
        .iter()
        .map(|name| {
            METHODS
                .iter()
                .find(|(key, _)| key == name)
                .map(|(key, _)| *key)
                .ok_or_else(|| format!("{name}: mbd, bpca, cpca or traced"))
        })
        .collect::<Result<_, _>>()
        .unwrap_or_else(|e| {
            eprintln!("--methods: {e}");
            std::process::exit(2);
        });
    let configs: Vec<(String, BakeConfig)> = cli
        .runs
        .iter()
        .map(|run| apply(&base, run).map(|c| (run.clone(), c)))
        .collect::<Result<_, _>>()
        .unwrap_or_else(|e| {
            eprintln!("--run: {e}");
            std::process::exit(2);
        });
    let baselines_scored = methods.iter().any(|m| matches!(*m, "bpca" | "cpca"));
    if let Some((label, _)) = configs
        .iter()
        .find(|(_, c)| baselines_scored && !c.baselines)
    {
        eprintln!("--methods names a baseline, but run {label} does not fit them");
        std::process::exit(2);
    }
    println!("load average before: {}\n", load_average());
    let (field, valid) = reference(&cli.scene, &scene, cli.res);
    let sky = Sky::default();
    let tracer = RayTracer::new(scene.scene.triangles());
    let mut views = prt_render::views(&scene.scene);
    if cli.views == Views::First {
        views.truncate(1);
    }
    if views.is_empty() {
        eprintln!("the scene has no view");
        std::process::exit(2);
    }
    let config = RenderConfig {
        width: RENDER_SIZE,
        height: RENDER_SIZE,
    };
    let lit = LitVolume::from_transfer(&field, &valid, &sky, &NoProgress).expect("lit reference");
    let views: Vec<ViewTarget> = views
        .into_iter()
        .map(|named| {
            let image = prt_render::render(
                &scene.scene,
                &tracer,
                &named.view,
                &lit,
                &sky,
                &config,
                &NoProgress,
            )
            .expect("render");
            ViewTarget {
                name: named.name,
                view: named.view,
                tone: ToneMap::auto(&image),
                image,
            }
        })
        .collect();
    let target = Target {
        scene: &scene,
        tracer,
        sky,
        views,
    };
    println!(
        "{} {:?}, view {}, reference {REFERENCE_RAYS} rays and {REFERENCE_CACHE_RAYS} cache \
         rays of another seed ({REFERENCE_SEED}), traced without the denoiser; image errors at \
         the reference's exposure over surface pixels.\n",
        cli.scene,
        field.dims(),
        target.views[0].name,
    );
    let scratch = Scratch::new("clean_light", &cli.scene);
    let mut table = Table::new(&[
        "setting",
        "trace s",
        "wall s",
        "CPU s",
        "rays/valid voxel",
        "MBD: mean levels",
        "> 10 levels",
        "FLIP",
        "traced: mean levels",
        "> 10 levels",
        "FLIP",
    ]);
    let mut rows = Vec::new();
    for (label, config) in &configs {
        let row = measure(&target, config, scratch.path(), label, &methods);
        eprintln!("{row:?}");
        table.row(vec![
            row.label.clone(),
            format!("{:.2}", row.trace_s),
            format!("{:.2}", row.wall_s),
            format!("{:.2}", row.cpu_s),
            format!("{:.0}", row.rays_per_voxel),
            format!("{:.2}", row.mbd.mean_levels),
            format!("{:.1} %", 100.0 * row.mbd.share_off),
            format!("{:.4}", row.mbd.flip),
            format!("{:.2}", row.traced.mean_levels),
            format!("{:.1} %", 100.0 * row.traced.share_off),
            format!("{:.4}", row.traced.flip),
        ]);
        rows.push(row);
    }
    println!("{}", table.markdown());
    table
        .write_csv(cli.csv.as_deref(), &format!("clean_light_{}", cli.scene))
        .expect("CSV written");
    if methods != ["mbd"] || target.views.len() > 1 {
        println!(
            "Each method's image against the same reference, per view at that view's \
             reference exposure (BPCA and CPCA as fitted, MBD as written):\n"
        );
        let views = view_table(&rows, &target.views);
        println!("{}", views.markdown());
        views
            .write_csv(
                cli.csv.as_deref(),
                &format!("clean_light_{}_views", cli.scene),
            )
            .expect("CSV written");
    }
    if let Some(path) = &cli.plot {
        let points: Vec<PlotPoint> = rows
            .iter()
            .map(|r| (series(&r.label), r.cpu_s, r.mbd.mean_levels))
            .collect();
        let labels = PlotLabels {
            title: &format!(
                "{}: MBD image error against the 16×-ray reference",
                cli.scene
            ),
            x: "process CPU time of the bake (s)",
            y: "mean grey-level error",
            x_ticks: &|v| format!("{v:.0}"),
        };
        plot_lines(&points, &labels, path).expect("plot written");
    }
    println!("load average after: {}", load_average());
}
