//! `prt bake`: the arguments, then prt-bake's pipeline with progress bars, then the report.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result};
use clap::ValueEnum;
use prt_bake::{Bake, BakeConfig, BakeError, Quality, SceneInput};
use prt_texture::Encoding;

use crate::progress::{Stage, StageBars};
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

/// A named preset of `prt bake` (`--quality`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, ValueEnum)]
pub enum QualityArg {
    /// The cheapest settings whose error stays close to the default's.
    Draft,
    /// `prt bake`'s defaults.
    #[default]
    Default,
    /// More work where it still lowers the error.
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
    /// docs/results.md, "The main job's speed/accuracy trade").
    #[arg(long, value_enum, default_value_t = QualityArg::Default)]
    pub quality: QualityArg,
    #[arg(long, help = knob_help(
        "Voxels along the longest axis of the scene box (the other axes in proportion)",
        |c| c.resolution.to_string(),
    ))]
    pub res: Option<usize>,
    #[arg(long, help = knob_help(
        "Directions traced per voxel (rounded up to a multiple of 12)",
        |c| c.rays_per_voxel.to_string(),
    ))]
    pub rays: Option<usize>,
    #[arg(long, help = knob_help(
        "Hemisphere rays per surface-cache point (the one-bounce indirect part)",
        |c| c.cache_rays.to_string(),
    ))]
    pub cache_rays: Option<usize>,
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
    #[arg(long, help = knob_help("MBD iteration cap", |c| c.max_iterations.to_string()))]
    pub iterations: Option<usize>,
    #[arg(long, help = knob_help(
        "MBD ridge weight λ on the coefficients",
        |c| c.lambda.to_string(),
    ))]
    pub lambda: Option<f32>,
    #[arg(long, value_enum, help = knob_help("Storage encoding of the written volumes", encoding_name))]
    pub encoding: Option<EncodingArg>,
    /// Skip the blockwise / clustered PCA baselines (faster; the report then has MBD only).
    #[arg(long)]
    pub no_baselines: bool,
    /// Seed of every random choice (tracing, solver, evaluation).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
}

impl BakeArgs {
    /// The pipeline's configuration: the preset, each explicit knob over it, writing the
    /// container into `container`.
    fn config(&self, container: Option<PathBuf>) -> BakeConfig {
        let preset = BakeConfig::preset(self.quality.into());
        BakeConfig {
            resolution: self.res.unwrap_or(preset.resolution),
            rays_per_voxel: self.rays.unwrap_or(preset.rays_per_voxel),
            cache_rays: self.cache_rays.unwrap_or(preset.cache_rays),
            margin: self.margin.unwrap_or(preset.margin),
            rank: self.rank.unwrap_or(preset.rank),
            basis_nodes: self.basis_nodes.unwrap_or(preset.basis_nodes),
            max_iterations: self.iterations.unwrap_or(preset.max_iterations),
            lambda: self.lambda.unwrap_or(preset.lambda),
            encoding: self.encoding.map_or(preset.encoding, Encoding::from),
            baselines: !self.no_baselines,
            seed: self.seed,
            container,
        }
    }
}

/// The flag that sets a field of [`BakeConfig`], for error messages.
fn flag(field: &str) -> &str {
    match field {
        "resolution" => "--res",
        "rays_per_voxel" => "--rays",
        "cache_rays" => "--cache-rays",
        "margin" => "--margin",
        "rank" => "--rank",
        "basis_nodes" => "--basis-nodes",
        "max_iterations" => "--iterations",
        "lambda" => "--lambda",
        other => other,
    }
}

/// A bake error, with a configuration field named by its flag.
fn cli_error(error: BakeError) -> anyhow::Error {
    match error {
        BakeError::InvalidConfig { field, why } => anyhow::anyhow!("{} {why}", flag(field)),
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

    let config = args.config(Some(out_dir.join("mbd")));
    let baked = prt_bake::bake(&scene, &config, &StageBars).map_err(cli_error)?;

    let stage = Stage::start("report");
    let images = report::write_images(&out_dir, &baked)?;
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
        bake: &baked,
        stage_seconds,
        total_seconds: total.elapsed().as_secs_f64(),
    };
    report::write_report(&out_dir, &report, &images)?;
    print_summary(&report, &out_dir, &baked);
    Ok(())
}

fn check_writable(dir: &Path) -> Result<()> {
    let probe = dir.join(".prt-write-probe");
    prt_texture::write_atomic(&probe, b"")
        .with_context(|| format!("output folder {} is not writable", dir.display()))?;
    let _ = std::fs::remove_file(probe);
    Ok(())
}

fn print_summary(report: &Report<'_>, out_dir: &Path, baked: &Bake) {
    let solve = &baked.mbd.report;
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

    #[derive(Debug, Parser)]
    struct Bake {
        #[command(flatten)]
        args: BakeArgs,
    }

    fn config(flags: &[&str]) -> BakeConfig {
        let argv = std::iter::once("bake").chain(flags.iter().copied());
        Bake::try_parse_from(argv)
            .expect("flags parse")
            .args
            .config(None)
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
            help.contains(&format!("high {}]", high.resolution)),
            "{help}"
        );
    }
}
