//! `prt bake`: the arguments, then prt-bake's pipeline with progress bars, then the report.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result};
use clap::ValueEnum;
use prt_bake::{Bake, BakeConfig, BakeError, SceneInput};
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

/// Options of `prt bake`; every knob that trades speed for accuracy is here.
#[derive(Debug, clap::Args)]
pub struct BakeArgs {
    /// glTF 2.0 scene to bake; the built-in Cornell box when omitted.
    pub scene: Option<PathBuf>,
    /// Output folder [default: ./prt-out/SCENE/, SCENE being the scene file's name].
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Voxels along the longest axis of the scene box (the other axes in proportion).
    #[arg(long, default_value_t = 32)]
    pub res: usize,
    /// Directions traced per voxel (rounded up to a multiple of 12).
    #[arg(long, default_value_t = 256)]
    pub rays: usize,
    /// Hemisphere rays per surface-cache point (the one-bounce indirect part).
    #[arg(long, default_value_t = 64)]
    pub cache_rays: usize,
    /// Margin added around the scene bounds, in metres.
    #[arg(long, default_value_t = 0.0)]
    pub margin: f32,
    /// MBD rank L: moving basis vectors per point.
    #[arg(long, default_value_t = 8)]
    pub rank: usize,
    /// MBD basis-grid nodes per axis (at least 2).
    #[arg(long, default_value_t = 5)]
    pub basis_nodes: usize,
    /// MBD iteration cap.
    #[arg(long, default_value_t = 64)]
    pub iterations: usize,
    /// MBD ridge weight λ on the coefficients.
    #[arg(long, default_value_t = 1e-4)]
    pub lambda: f32,
    /// Storage encoding of the written volumes.
    #[arg(long, value_enum, default_value_t = EncodingArg::F16)]
    pub encoding: EncodingArg,
    /// Skip the blockwise / clustered PCA baselines (faster; the report then has MBD only).
    #[arg(long)]
    pub no_baselines: bool,
    /// Seed of every random choice (tracing, solver, evaluation).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
}

impl BakeArgs {
    /// The pipeline's configuration, writing the container into `container`.
    fn config(&self, container: Option<PathBuf>) -> BakeConfig {
        BakeConfig {
            resolution: self.res,
            rays_per_voxel: self.rays,
            cache_rays: self.cache_rays,
            margin: self.margin,
            rank: self.rank,
            basis_nodes: self.basis_nodes,
            max_iterations: self.iterations,
            lambda: self.lambda,
            encoding: self.encoding.into(),
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
