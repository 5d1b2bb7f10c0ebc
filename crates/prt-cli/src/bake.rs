//! `prt bake`: the arguments, then prt-bake's pipeline with progress bars, then the report.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result};
use clap::ValueEnum;
use prt_bake::folder::{KeepVolumes, KeptOutcome};
use prt_bake::memory::MemoryEstimate;
use prt_bake::{Bake, BakeConfig, BakeError, BakeFolder, Layout, Quality, SceneInput};
use prt_texture::Encoding;

use crate::progress::{StageBar, StageBars};
use crate::report::{self, Report};

/// Storage encoding of the written volumes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum EncodingArg {
    /// 32-bit float (lossless).
    F32,
    /// 16-bit float.
    F16,
    /// 16-bit unsigned normalised with per-channel scale and bias.
    Unorm16,
    /// 8-bit unsigned normalised with per-channel scale and bias.
    Unorm8,
}

impl From<EncodingArg> for Encoding {
    fn from(arg: EncodingArg) -> Encoding {
        match arg {
            EncodingArg::F32 => Encoding::F32,
            EncodingArg::F16 => Encoding::F16,
            EncodingArg::Unorm16 => Encoding::Unorm16,
            EncodingArg::Unorm8 => Encoding::Unorm8,
        }
    }
}

/// `--keep-volumes`: [`prt_bake::folder::KeepVolumes`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, ValueEnum)]
pub enum KeepVolumesArg {
    /// Keep them when they take at most 512 MiB (f16).
    #[default]
    Auto,
    /// Always keep them.
    Always,
    /// Never keep them.
    Never,
}

impl From<KeepVolumesArg> for KeepVolumes {
    fn from(arg: KeepVolumesArg) -> Self {
        match arg {
            KeepVolumesArg::Auto => KeepVolumes::Auto,
            KeepVolumesArg::Always => KeepVolumes::Always,
            KeepVolumesArg::Never => KeepVolumes::Never,
        }
    }
}

/// `prt bake --layout`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, ValueEnum)]
pub enum LayoutArg {
    /// The whole box, every voxel traced and fitted.
    Dense,
    /// Bricks with a valid voxel only, masked fits.
    Sparse,
    /// Sparse from 64³ voxels up.
    #[default]
    Auto,
}

impl From<LayoutArg> for Layout {
    fn from(arg: LayoutArg) -> Layout {
        match arg {
            LayoutArg::Dense => Layout::Dense,
            LayoutArg::Sparse => Layout::Sparse,
            LayoutArg::Auto => Layout::Auto,
        }
    }
}

/// A named preset of `prt bake` (`--quality`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, ValueEnum)]
pub enum QualityArg {
    /// The cheapest settings whose image error stays within 10 % of the default's.
    Draft,
    /// `prt bake`'s defaults.
    #[default]
    Default,
    /// The most accurate settings measured at up to 4× the default's time.
    High,
}

impl From<QualityArg> for Quality {
    fn from(arg: QualityArg) -> Quality {
        match arg {
            QualityArg::Draft => Quality::Draft,
            QualityArg::Default => Quality::Default,
            QualityArg::High => Quality::High,
        }
    }
}

/// A knob's help: what it does, then its value in each preset (read from prt-bake, so the help
/// cannot drift from the presets).
fn knob_help(what: &str, value: fn(&BakeConfig) -> String) -> String {
    let [draft, default, high] =
        [Quality::Draft, Quality::Default, Quality::High].map(|q| value(&BakeConfig::preset(q)));
    format!("{what} [default: {default}; draft {draft}, high {high}]")
}

fn encoding_name(config: &BakeConfig) -> String {
    format!("{:?}", config.encoding).to_lowercase()
}

/// Options of `prt bake`; every knob that trades speed for accuracy is here. A knob left unset
/// takes its value from `--quality`.
#[derive(Debug, clap::Args)]
pub struct BakeArgs {
    /// glTF 2.0 scene to bake; the built-in Cornell box when omitted.
    pub scene: Option<PathBuf>,
    /// Output folder [default: ./prt-out/SCENE/, SCENE being the scene file's name].
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Preset for every knob below; an explicit knob flag overrides it (measured trade in
    /// docs/results.md, "Presets and the curve of error against time").
    #[arg(long, value_enum, default_value_t = QualityArg::Default)]
    pub quality: QualityArg,
    #[arg(long, help = knob_help(
        "Voxels along the longest axis of the scene box (the other axes in proportion)",
        |c| c.resolution.to_string(),
    ))]
    pub res: Option<usize>,
    #[arg(long, help = knob_help(
        "Directions traced per voxel (rounded up to a multiple of 12; of 48 with adaptive \
         sampling or the denoiser)",
        |c| c.rays_per_voxel.to_string(),
    ))]
    pub rays: Option<usize>,
    #[arg(long, help = knob_help(
        "Hemisphere rays per surface-cache point (the one-bounce indirect part)",
        |c| c.cache_rays.to_string(),
    ))]
    pub cache_rays: Option<usize>,
    #[arg(long, value_name = "ERROR|off", value_parser = parse_off_or, help = knob_help(
        "Per-voxel adaptive sampling: a voxel stops once the relative standard error of its \
         transfer is at most ERROR (--rays is then the cap); off: every voxel traces --rays",
        |c| off_or(c.adaptive_error),
    ))]
    pub adaptive_error: Option<OffOr>,
    #[arg(long, help = knob_help(
        "With adaptive sampling, the directions every valid voxel traces at least",
        |c| c.adaptive_min_rays.to_string(),
    ))]
    pub adaptive_min_rays: Option<usize>,
    #[arg(long, value_name = "STRENGTH|off", value_parser = parse_off_or, help = knob_help(
        "The geometry-aware denoiser of the traced volume: how many noise standard deviations \
         of difference between visible neighbours still average; off: none",
        |c| off_or(c.denoise),
    ))]
    pub denoise: Option<OffOr>,
    #[arg(long, help = knob_help(
        "The denoiser's neighbourhood half-width in voxels (1 to 8)",
        |c| c.denoise_radius.to_string(),
    ))]
    pub denoise_radius: Option<usize>,
    #[arg(long, help = knob_help(
        "Margin added around the scene bounds, in metres",
        |c| c.margin.to_string(),
    ))]
    pub margin: Option<f32>,
    #[arg(long, help = knob_help(
        "MBD rank L: moving basis vectors per point",
        |c| c.rank.to_string(),
    ))]
    pub rank: Option<usize>,
    #[arg(long, help = knob_help(
        "MBD basis-grid nodes per axis (at least 2)",
        |c| c.basis_nodes.to_string(),
    ))]
    pub basis_nodes: Option<usize>,
    #[arg(long, help = knob_help(
        "MBD iteration cap (of the coarse solves, with a coarse start)",
        |c| c.max_iterations.to_string(),
    ))]
    pub iterations: Option<usize>,
    /// Times MBD halves the volume and fits it before the full-resolution solve [default: until
    /// it has fewer than 64³ voxels].
    #[arg(long)]
    pub coarse_levels: Option<usize>,
    #[arg(long, help = knob_help(
        "With a coarse start, the full-resolution solve's iteration cap",
        |c| c.full_iterations.to_string(),
    ))]
    pub full_iterations: Option<usize>,
    #[arg(long, help = knob_help(
        "MBD ridge weight λ on the coefficients",
        |c| c.lambda.to_string(),
    ))]
    pub lambda: Option<f32>,
    /// MBD's per-voxel loss weighting: `none` (the paper's loss) or `relative[:EXPONENT[,FLOOR]]`
    /// (each voxel weighted by its magnitude^−EXPONENT, default 1 and floor 0.05 of the mean,
    /// undone exactly after the fit).
    #[arg(long, value_name = "none|relative[:EXPONENT[,FLOOR]]", value_parser = parse_loss_weighting)]
    pub loss_weighting: Option<LossWeightingArg>,
    #[arg(long, value_name = "on|off", value_parser = parse_on_off, help = knob_help(
        "MBD's centre projection: after the solve, each voxel's coefficients re-fitted on its own vector at its centre",
        |c| if c.centre_projection { "on" } else { "off" }.to_string(),
    ))]
    pub centre_projection: Option<bool>,
    #[arg(long, value_enum, help = knob_help("Storage encoding of the written volumes", encoding_name))]
    pub encoding: Option<EncodingArg>,
    /// Skip the blockwise / clustered PCA baselines (faster; the report then has MBD only).
    #[arg(long)]
    pub no_baselines: bool,
    /// Volume layout: `sparse` probes every voxel, traces only the 4³-voxel bricks holding a
    /// valid voxel (the same values as dense there) and fits MBD and clustered PCA on the valid
    /// voxels only; `dense` traces and fits the whole box; `auto` is sparse from 64³ voxels up.
    #[arg(long, value_enum, default_value_t = LayoutArg::Auto)]
    pub layout: LayoutArg,
    /// With a sparse layout, also drop bricks none of whose valid voxels sees geometry within
    /// this many metres (open space far from every surface). Default: keep them.
    #[arg(long, value_name = "METRES")]
    pub brick_max_distance: Option<f32>,
    /// Seed of every random choice (tracing, solver, evaluation).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Memory budget (bytes, or with a K, M, G or T suffix, e.g. 12G): a bake whose estimated
    /// peak is above it is refused before it starts [default: 80 % of physical memory].
    #[arg(long, value_parser = parse_bytes)]
    pub max_memory: Option<u64>,
    /// Write the traced transfer volume and the baselines' reconstructions (f16) into
    /// OUT/volumes/, for `prt export|render --method reference|bpca|cpca`
    /// and the viewer's comparisons.
    #[arg(long, value_enum, default_value_t = KeepVolumesArg::Auto)]
    pub keep_volumes: KeepVolumesArg,
}

/// `12G`, `800M`, `64K`, `1T` or a plain number of bytes.
fn parse_bytes(text: &str) -> Result<u64, String> {
    let text = text.trim();
    let (digits, unit) = match text.char_indices().find(|(_, c)| c.is_ascii_alphabetic()) {
        Some((i, _)) => text.split_at(i),
        None => (text, ""),
    };
    let shift = match unit
        .to_ascii_uppercase()
        .trim_end_matches("IB")
        .trim_end_matches('B')
    {
        "" => 0,
        "K" => 10,
        "M" => 20,
        "G" => 30,
        "T" => 40,
        other => return Err(format!("unknown unit {other:?} (K, M, G or T)")),
    };
    let value: f64 = digits
        .trim()
        .parse()
        .map_err(|_| format!("{text:?} is not a size like 12G"))?;
    if !(value.is_finite() && value > 0.0) {
        return Err(format!("{text:?} is not a positive size"));
    }
    Ok((value * (1u64 << shift) as f64) as u64)
}

/// Below this share of valid voxels (outside geometry) a bake warns: its scores then describe
/// little of the volume.
const LOW_VALID_FRACTION: f64 = 0.05;

/// Trace rate assumed for the up-front estimate, per thread: about what the built-in Cornell
/// box traces on this project's machine (larger scenes trace slower).
const ASSUMED_RAYS_PER_SECOND_PER_THREAD: f64 = 6.0e6;

/// `--loss-weighting`: `none`, or `relative[:EXPONENT[,FLOOR]]`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LossWeightingArg(Option<prt_mbd::LossWeighting>);

fn parse_loss_weighting(spec: &str) -> Result<LossWeightingArg, String> {
    prt_mbd::LossWeighting::parse(spec)
        .map(LossWeightingArg)
        .map_err(|e| e.to_string())
}

/// A number or `off` (`--adaptive-error`, `--denoise`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OffOr(Option<f32>);

fn parse_off_or(spec: &str) -> Result<OffOr, String> {
    if spec == "off" {
        return Ok(OffOr(None));
    }
    spec.parse::<f32>()
        .map(|v| OffOr(Some(v)))
        .map_err(|e| format!("{spec}: expected a number or off ({e})"))
}

/// `on` or `off` (`--centre-projection`).
fn parse_on_off(spec: &str) -> Result<bool, String> {
    match spec {
        "on" => Ok(true),
        "off" => Ok(false),
        _ => Err(format!("{spec}: expected on or off")),
    }
}

fn off_or(value: Option<f32>) -> String {
    value.map_or("off".into(), |v| v.to_string())
}

impl BakeArgs {
    /// The pipeline's configuration: the preset, each explicit knob over it, writing the
    /// container into `container`.
    pub(crate) fn config(&self, container: Option<PathBuf>) -> BakeConfig {
        let preset = BakeConfig::preset(self.quality.into());
        BakeConfig {
            resolution: self.res.unwrap_or(preset.resolution),
            rays_per_voxel: self.rays.unwrap_or(preset.rays_per_voxel),
            cache_rays: self.cache_rays.unwrap_or(preset.cache_rays),
            adaptive_error: self.adaptive_error.map_or(preset.adaptive_error, |a| a.0),
            adaptive_min_rays: self.adaptive_min_rays.unwrap_or(preset.adaptive_min_rays),
            denoise: self.denoise.map_or(preset.denoise, |d| d.0),
            denoise_radius: self.denoise_radius.unwrap_or(preset.denoise_radius),
            margin: self.margin.unwrap_or(preset.margin),
            rank: self.rank.unwrap_or(preset.rank),
            basis_nodes: self.basis_nodes.unwrap_or(preset.basis_nodes),
            max_iterations: self.iterations.unwrap_or(preset.max_iterations),
            coarse_levels: self.coarse_levels.or(preset.coarse_levels),
            full_iterations: self.full_iterations.unwrap_or(preset.full_iterations),
            lambda: self.lambda.unwrap_or(preset.lambda),
            loss_weighting: self
                .loss_weighting
                .map_or(preset.loss_weighting, |arg| arg.0),
            centre_projection: self.centre_projection.unwrap_or(preset.centre_projection),
            encoding: self.encoding.map_or(preset.encoding, Encoding::from),
            baselines: !self.no_baselines,
            seed: self.seed,
            max_memory: Some(
                self.max_memory
                    .unwrap_or_else(prt_bake::memory::default_memory_budget),
            ),
            container,
            layout: self.layout.into(),
            brick_max_distance: self.brick_max_distance,
        }
    }
}

/// The flag that sets a field of [`BakeConfig`], for error messages.
fn flag(field: &str) -> &str {
    match field {
        "resolution" => "--res",
        "rays_per_voxel" => "--rays",
        "cache_rays" => "--cache-rays",
        "adaptive_error" => "--adaptive-error",
        "adaptive_min_rays" => "--adaptive-min-rays",
        "denoise" => "--denoise",
        "denoise_radius" => "--denoise-radius",
        "margin" => "--margin",
        "rank" => "--rank",
        "basis_nodes" => "--basis-nodes",
        "max_iterations" => "--iterations",
        "full_iterations" => "--full-iterations",
        "lambda" => "--lambda",
        "brick_max_distance" => "--brick-max-distance",
        other => other,
    }
}

/// A bake error, with a configuration field named by its flag.
pub(crate) fn cli_error(error: BakeError) -> anyhow::Error {
    match error {
        BakeError::InvalidConfig { field, why } => anyhow::anyhow!("{} {why}", flag(field)),
        // The library's message names BakeOptions' fields; prt bake sets the margin alone.
        BakeError::Trace(prt_trace::TraceError::NoValidVoxels {
            voxels,
            invalid,
            skipped,
        }) => anyhow::anyhow!(
            "baking failed: no valid voxel: {invalid} of {voxels} are inside geometry and \
             {skipped} outside the scene; grow the margin ({}) so that voxels lie in open space",
            flag("margin")
        ),
        other => other.into(),
    }
}

pub fn run(args: &BakeArgs) -> Result<()> {
    args.config(None).validate().map_err(cli_error)?;
    let total = Instant::now();

    let load = Instant::now();
    let scene = match &args.scene {
        Some(path) => SceneInput::load_gltf(path).map_err(cli_error)?,
        None => SceneInput::cornell_box(),
    };
    let load = load.elapsed();
    check_size(args, &scene)?;
    let out_dir = args
        .out
        .clone()
        .unwrap_or_else(|| Path::new("prt-out").join(&scene.name));
    std::fs::create_dir_all(&out_dir)
        .with_context(|| format!("cannot create output folder {}", out_dir.display()))?;
    check_writable(&out_dir)?;
    for w in scene.scene.warnings() {
        eprintln!("warning: {w}");
    }
    eprintln!(
        "scene {}: {} triangles ({} degenerate dropped)",
        scene.name,
        scene.scene.triangles().len(),
        scene.scene.degenerate_dropped()
    );

    let config = args.config(Some(BakeFolder::new(&out_dir).container_dir()));
    let baked = prt_bake::bake(&scene, &config, &StageBars).map_err(cli_error)?;
    if let Some(bricks) = &baked.bricks {
        let s = &bricks.stats;
        eprintln!(
            "sparse bricks: {} of {} bricks of {}³ kept; voxels probed {}, traced {}, stored {} \
             (dense: {}); probe pass {:.1} s",
            bricks.map.kept_bricks(),
            bricks.map.bricks(),
            bricks.map.edge(),
            s.probed_voxels,
            s.traced_voxels,
            s.stored_voxels,
            baked.volume.stats.voxels,
            s.probe_time.as_secs_f64()
        );
    }
    write_outputs(&out_dir, &scene, &baked, args.keep_volumes, load, total)
}

/// Everything `prt bake` writes beside the container once the pipeline ran: the kept volumes,
/// the scene mesh, the report and its images; then the summary on stdout. `load` is the scene's
/// load time and `total` the start of the whole command, for the report's times.
pub(crate) fn write_outputs(
    out_dir: &Path,
    scene: &SceneInput,
    baked: &Bake,
    keep: KeepVolumesArg,
    load: std::time::Duration,
    total: Instant,
) -> Result<()> {
    let valid = baked.volume.stats.valid_fraction();
    if valid < LOW_VALID_FRACTION {
        eprintln!(
            "warning: only {:.1} % of the voxels are outside geometry; the scores cover those \
             alone (a larger --margin or --res gives more)",
            100.0 * valid
        );
    }

    keep_volumes(&BakeFolder::new(out_dir), baked, keep.into())?;
    let mesh = BakeFolder::new(out_dir).scene_mesh();
    prt_trace::mesh::write_mesh(&mesh, &scene.scene)
        .with_context(|| format!("cannot write {}", mesh.display()))?;

    let stage = StageBar::start("report");
    let images = report::write_images(out_dir, baked)?;
    let renders = report::write_renders(out_dir, baked, &scene.scene, &BakeFolder::new(out_dir))?;
    let report_time = stage.finish();
    let stage_seconds = std::iter::once(("load".to_string(), load))
        .chain(
            baked
                .stage_times
                .iter()
                .map(|(stage, time)| (stage.name().to_string(), *time)),
        )
        .chain(std::iter::once(("report".to_string(), report_time)))
        .map(|(name, time)| (name, time.as_secs_f64()))
        .collect();
    let report = Report {
        scene: &scene.name,
        bake: baked,
        stage_seconds,
        total_seconds: total.elapsed().as_secs_f64(),
    };
    report::write_report(out_dir, &report, &images, renders.as_ref())?;
    print_summary(&report, out_dir, baked, renders.as_ref());
    Ok(())
}

/// Refuses a bake over the memory budget before anything is written, and says up front what a
/// large bake will take.
fn check_size(args: &BakeArgs, scene: &SceneInput) -> Result<()> {
    let Some(bounds) = scene.scene.bounds() else {
        return Ok(()); // the pipeline reports the empty scene
    };
    let config = args.config(Some(PathBuf::from(BakeFolder::CONTAINER)));
    let (size, triangles) = (bounds.size().to_array(), scene.scene.triangles().len());
    let estimate = MemoryEstimate::new(&config, size, triangles);
    let budget = config.max_memory.unwrap_or(u64::MAX);
    estimate
        .check(&config, size, triangles, budget)
        .map_err(cli_error)?;
    let gib = |bytes: u64| bytes as f64 / f64::from(1u32 << 30);
    if estimate.total() > 1 << 30 {
        eprintln!(
            "memory: about {:.1} GiB at the peak (budget {:.1} GiB)",
            gib(estimate.total()),
            gib(budget)
        );
    }
    let rays = estimate.voxels as f64 * config.rays_per_voxel as f64;
    let seconds = rays / (ASSUMED_RAYS_PER_SECOND_PER_THREAD * rayon_threads() as f64);
    if seconds > 60.0 {
        eprintln!(
            "trace: {rays:.2e} voxel rays, about {:.0} min at {:.0} Mrays/s per thread on {} \
             threads (the Cornell box's rate here; larger scenes trace slower)",
            seconds / 60.0,
            ASSUMED_RAYS_PER_SECOND_PER_THREAD / 1e6,
            rayon_threads()
        );
    }
    Ok(())
}

/// Writes the kept volumes as `policy` says, and says what it did.
fn keep_volumes(folder: &BakeFolder, baked: &Bake, policy: KeepVolumes) -> Result<()> {
    let stage = StageBar::start("volumes");
    match folder.keep_volumes(baked, policy)? {
        KeptOutcome::Written(_) => {
            stage.finish();
        }
        KeptOutcome::OverAutoLimit { bytes } => eprintln!(
            "volumes: not kept ({:.0} MiB over the automatic limit of {} MiB; --keep-volumes \
             always keeps them)",
            bytes as f64 / f64::from(1u32 << 20),
            KeepVolumes::AUTO_BYTES >> 20
        ),
        KeptOutcome::NotAsked => {}
    }
    Ok(())
}

/// The threads the bake will run on.
fn rayon_threads() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}

fn check_writable(dir: &Path) -> Result<()> {
    let probe = dir.join(".prt-write-probe");
    prt_texture::write_atomic(&probe, b"")
        .with_context(|| format!("output folder {} is not writable", dir.display()))?;
    let _ = std::fs::remove_file(probe);
    Ok(())
}

fn print_summary(
    report: &Report<'_>,
    out_dir: &Path,
    baked: &Bake,
    renders: Option<&report::RenderSummary>,
) {
    let solve = &baked.mbd.report;
    if let Some(renders) = renders {
        let ranked: Vec<String> = report::rank_by_flip(&renders.views)
            .iter()
            .map(|(key, flip)| format!("{} {flip:.4}", key.to_uppercase()))
            .collect();
        println!(
            "\nImage error (mean ꟻLIP over {} views, best first): {}",
            renders.views.len(),
            ranked.join(", ")
        );
    }
    println!("\n{}", report::table_markdown(&baked.comparison));
    println!(
        "MBD: {} iterations{}; stages: {}; total {:.1} s",
        solve.history.len(),
        if solve.converged { " (converged)" } else { "" },
        report
            .stage_seconds
            .iter()
            .map(|(k, s)| format!("{k} {s:.2} s"))
            .collect::<Vec<_>>()
            .join(", "),
        report.total_seconds
    );
    println!("wrote {}", out_dir.join("report.md").display());
}

#[cfg(test)]
mod tests {
    use clap::{CommandFactory, Parser};

    use super::*;

    #[test]
    fn no_valid_voxel_names_the_margin_flag() {
        let error = BakeError::Trace(prt_trace::TraceError::NoValidVoxels {
            voxels: 8,
            invalid: 8,
            skipped: 0,
        });
        let message = cli_error(error).to_string();
        assert!(message.contains("--margin"), "{message}");
        assert!(!message.contains("BakeOptions"), "{message}");
    }

    #[derive(Debug, Parser)]
    struct Bake {
        #[command(flatten)]
        args: BakeArgs,
    }

    #[test]
    fn the_sampling_and_denoiser_flags_parse_and_switch_off() {
        let tuned = config(&[
            "--adaptive-error",
            "0.1",
            "--adaptive-min-rays",
            "192",
            "--denoise",
            "2.5",
            "--denoise-radius",
            "2",
        ]);
        assert_eq!(tuned.adaptive_error, Some(0.1));
        assert_eq!(tuned.adaptive_min_rays, 192);
        assert_eq!(tuned.denoise, Some(2.5));
        assert_eq!(tuned.denoise_radius, 2);
        let off = config(&["--adaptive-error", "off", "--denoise", "off"]);
        assert_eq!((off.adaptive_error, off.denoise), (None, None));
        assert!(parse_off_or("of").is_err());
    }

    #[test]
    fn the_loss_weighting_flag_parses_and_defaults_to_relative() {
        use prt_mbd::LossWeighting;
        assert_eq!(config(&[]).loss_weighting, Some(LossWeighting::default()));
        assert_eq!(config(&["--loss-weighting", "none"]).loss_weighting, None);
        assert_eq!(
            config(&["--loss-weighting", "relative:0.5"]).loss_weighting,
            Some(LossWeighting {
                exponent: 0.5,
                ..LossWeighting::default()
            })
        );
        assert_eq!(
            config(&["--loss-weighting", "relative:1.5,0.2"]).loss_weighting,
            Some(LossWeighting {
                exponent: 1.5,
                floor: 0.2
            })
        );
        for bad in ["relativ", "relative:", "relative:1,2,3", "absolute"] {
            let argv = ["bake", "--loss-weighting", bad];
            assert!(Bake::try_parse_from(argv).is_err(), "{bad}");
        }
    }

    /// The configuration the flags give, without the memory budget (the machine's).
    fn config(flags: &[&str]) -> BakeConfig {
        let argv = std::iter::once("bake").chain(flags.iter().copied());
        let config = Bake::try_parse_from(argv)
            .expect("flags parse")
            .args
            .config(None);
        assert!(config.max_memory.is_some(), "prt bake always has a budget");
        BakeConfig {
            max_memory: None,
            ..config
        }
    }

    #[test]
    fn no_flags_bake_with_the_defaults() {
        assert_eq!(config(&[]), BakeConfig::default());
        assert_eq!(config(&["--quality", "default"]), BakeConfig::default());
    }

    #[test]
    fn an_explicit_knob_overrides_the_preset() {
        let draft = BakeConfig::preset(Quality::Draft);
        assert_eq!(config(&["--quality", "draft"]), draft);
        let tuned = config(&["--quality", "draft", "--rays", "300", "--encoding", "f32"]);
        assert_eq!(
            tuned,
            BakeConfig {
                rays_per_voxel: 300,
                encoding: Encoding::F32,
                ..draft
            }
        );
        assert!(!config(&["--quality", "high", "--no-baselines"]).baselines);
    }

    #[test]
    fn the_help_lists_every_presets_value() {
        let help = Bake::command().render_help().to_string();
        let high = BakeConfig::preset(Quality::High);
        assert!(
            help.contains(&format!("high {}]", high.rays_per_voxel)),
            "{help}"
        );
    }
}
