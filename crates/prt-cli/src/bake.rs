//! `prt bake`: scene → 324-D transfer volume → MBD (+ baselines) → KTX2 container + report.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail, ensure};
use clap::ValueEnum;
use prt_core::{Compressor, FieldModel, GridField, resample_to_grid};
use prt_mbd::{BlockPca, ClusterModel, ClusteredPca, EvalOptions, Mbd, MbdOptions, SolveReport};
use prt_trace::{BakeOptions, LoadOptions, Scene, TransferBaker};

use crate::progress::Stage;
use crate::report::{self, ImageMethod, MethodRow, Report};
use crate::seams::{self, LocalBasis, SeamView};

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

/// The transfer vector is four 9 × 9 operators: direct, then indirect R, G, B.
const OPERATOR_BLOCKS: [usize; 4] = [81, 81, 81, 81];

pub fn run(args: &BakeArgs) -> Result<()> {
    validate(args)?;
    let total = Instant::now();
    let mut times: Vec<(&'static str, Duration)> = Vec::new();

    // Scene.
    let t = Instant::now();
    let (scene, scene_name) = load_scene(args.scene.as_deref())?;
    times.push(("load", t.elapsed()));
    let out_dir = args
        .out
        .clone()
        .unwrap_or_else(|| Path::new("prt-out").join(&scene_name));
    std::fs::create_dir_all(&out_dir)
        .with_context(|| format!("cannot create output folder {}", out_dir.display()))?;
    check_writable(&out_dir)?;
    for w in scene.warnings() {
        eprintln!("warning: {w}");
    }
    eprintln!(
        "scene {scene_name}: {} triangles ({} degenerate dropped)",
        scene.triangles().len(),
        scene.degenerate_dropped()
    );

    // Trace.
    let bounds = scene
        .bounds()
        .context("the scene has no triangles to bake")?;
    let resolution = grid_resolution(bounds.size().to_array(), args.res);
    let options = BakeOptions {
        resolution,
        margin: args.margin,
        rays_per_voxel: args.rays,
        cache_rays: args.cache_rays,
        seed: args.seed,
        ..BakeOptions::default()
    };
    let stage = Stage::start("trace");
    let volume = TransferBaker::new(&scene, options)
        .context("cannot set up the baker")?
        .bake(&stage)
        .context("baking failed")?;
    times.push(("trace", stage.finish()));
    let field = &volume.field;

    // Compress: MBD, then the baselines at equal basis count (one basis of rank L per basis node).
    // An axis with fewer voxels than basis nodes gets one node per voxel.
    let dims = field.dims();
    let nodes = [0, 1, 2].map(|k| args.basis_nodes.min(dims[k].max(2)));
    let mbd = Mbd {
        basis_nodes: nodes,
        options: MbdOptions {
            rank: args.rank,
            lambda: args.lambda,
            max_iterations: args.iterations,
            seed: args.seed ^ 0x4D42_4400,
            ..MbdOptions::default()
        },
    };
    let stage = Stage::start("mbd");
    let t = Instant::now();
    let (model, solve_report) = mbd.fit(field, &stage).context("MBD solve failed")?;
    let mbd_time = t.elapsed();
    times.push(("mbd", stage.finish()));

    let mut rows = Vec::new();
    let eval_options = EvalOptions {
        blocks: OPERATOR_BLOCKS.to_vec(),
        seed: args.seed ^ 0xE7A1,
        ..EvalOptions::default()
    };
    let stage = Stage::start("evaluate");
    let (coefficient_kernels, basis_kernels) = mbd.kernels(field)?;
    let mbd_labels = prt_mbd::kernel_labels(&basis_kernels, field)?;
    let mbd_recon = resample_to_grid(&model, field.dims(), field.bounds())?;
    rows.push(method_row(
        "MBD",
        &model,
        field,
        &mbd_recon,
        &mbd_labels,
        &eval_options,
        mbd_time,
    )?);
    times.push(("evaluate", stage.finish()));
    let mut baselines: Vec<(&str, ClusterModel)> = Vec::new();

    if !args.no_baselines {
        let clusters = nodes.iter().product::<usize>();
        let bpca = BlockPca {
            rank: args.rank,
            blocks: nodes,
            window: 1.0,
        };
        let cpca = ClusteredPca {
            seed: args.seed,
            ..ClusteredPca::new(args.rank, clusters)
        };
        let stage = Stage::start("baselines");
        for (key, name, result) in [
            ("bpca", "BPCA", timed(|| bpca.compress(field, &stage))),
            ("cpca", "CPCA", timed(|| cpca.compress(field, &stage))),
        ] {
            let (baseline, seconds): (ClusterModel, Duration) = (
                result.0.with_context(|| format!("{name} failed"))?,
                result.1,
            );
            rows.push(method_row(
                name,
                &baseline,
                field,
                baseline.reconstruction(),
                baseline.labels(),
                &eval_options,
                seconds,
            )?);
            baselines.push((key, baseline));
        }
        times.push(("baselines", stage.finish()));
    }

    let methods: Vec<ImageMethod<'_>> = std::iter::once(ImageMethod {
        key: "mbd",
        reconstruction: &mbd_recon,
        labels: &mbd_labels,
        basis: LocalBasis::Moving {
            kernels: &basis_kernels,
            basis: model.basis(),
        },
    })
    .chain(baselines.iter().map(|(key, b)| ImageMethod {
        key,
        reconstruction: b.reconstruction(),
        labels: b.labels(),
        basis: LocalBasis::Clustered {
            labels: b.labels(),
            bases: b.bases(),
        },
    }))
    .collect();
    // The seam view: each method's basis on the denoised reference (see `seams`); rows are MBD,
    // then the baselines, in the order of `methods`.
    let stage = Stage::start("seams");
    let smoothed = seams::smooth(field, &volume.valid)?;
    let slice_y = field.dims()[1] / 2;
    let views: Vec<SeamView> = methods
        .iter()
        .map(|m| seams::seam_view(&smoothed, &volume.valid, m.labels, &m.basis, slice_y))
        .collect::<Result<_>>()?;
    drop(smoothed);
    for (row, view) in rows.iter_mut().zip(&views) {
        row.denoised_seam_ratio = Some(view.seam_ratio);
    }
    times.push(("seams", stage.finish()));

    // Write the container.
    let stage = Stage::start("write");
    let written = report::write_container(
        &out_dir,
        &model,
        &coefficient_kernels,
        &basis_kernels,
        &volume,
        args,
        &scene_name,
    )
    .context("cannot write the MBD container")?;
    if let Some(row) = rows.first_mut() {
        row.bytes_per_voxel = Some(written.bytes_per_voxel);
    }
    let quantised_row = report::quantised_row(
        &written,
        &coefficient_kernels,
        &basis_kernels,
        field,
        &mbd_labels,
        &eval_options,
    )?;
    rows.insert(1, quantised_row);
    times.push(("write", stage.finish()));

    let stage = Stage::start("report");
    let report = Report {
        scene: scene_name.clone(),
        resolution,
        rank: args.rank,
        basis_nodes: nodes,
        bake: &volume.stats,
        invalid_voxels: volume.valid.iter().filter(|v| !**v).count(),
        solve: &solve_report,
        rows,
        stage_seconds: Vec::new(),
        total_seconds: 0.0,
        slice_y,
    };
    let images = report::write_images(&out_dir, &volume, &methods, &views, slice_y)?;
    times.push(("report", stage.finish()));
    let report = Report {
        stage_seconds: times
            .iter()
            .map(|(k, d)| (k.to_string(), d.as_secs_f64()))
            .collect(),
        total_seconds: total.elapsed().as_secs_f64(),
        ..report
    };
    report::write_report(&out_dir, &report, &images)?;
    print_summary(&report, &out_dir, &solve_report);
    Ok(())
}

fn timed<T>(f: impl FnOnce() -> T) -> (T, Duration) {
    let t = Instant::now();
    let value = f();
    (value, t.elapsed())
}

fn validate(args: &BakeArgs) -> Result<()> {
    ensure!(
        args.res >= 2,
        "--res must be at least 2 voxels (got {})",
        args.res
    );
    ensure!(args.rays >= 1, "--rays must be at least 1");
    ensure!(args.cache_rays >= 1, "--cache-rays must be at least 1");
    ensure!(
        args.basis_nodes >= 2,
        "--basis-nodes must be at least 2 (got {})",
        args.basis_nodes
    );
    ensure!(
        (1..=324).contains(&args.rank),
        "--rank must be between 1 and the transfer dimension 324 (got {})",
        args.rank
    );
    ensure!(args.iterations >= 1, "--iterations must be at least 1");
    ensure!(
        args.lambda.is_finite() && args.lambda >= 0.0,
        "--lambda must be finite and >= 0"
    );
    ensure!(
        args.margin.is_finite() && args.margin >= 0.0,
        "--margin must be finite and >= 0"
    );
    Ok(())
}

fn load_scene(path: Option<&Path>) -> Result<(Scene, String)> {
    let Some(path) = path else {
        return Ok((Scene::cornell_box(), "cornell_box".to_string()));
    };
    if !path.exists() {
        bail!("scene file {} does not exist", path.display());
    }
    let name = path
        .file_stem()
        .map(|s| s.to_string_lossy().to_lowercase())
        .unwrap_or_else(|| "scene".into());
    let scene = Scene::load_gltf(path, &LoadOptions::default())
        .with_context(|| format!("cannot load {} as glTF", path.display()))?;
    if scene.triangles().is_empty() {
        bail!("{} has no triangles to bake", path.display());
    }
    Ok((scene, name))
}

/// Voxels per axis: `res` along the longest side of the box, the others in proportion (>= 2).
fn grid_resolution(size: [f32; 3], res: usize) -> [usize; 3] {
    let longest = size.iter().copied().fold(0.0f32, f32::max);
    size.map(|s| {
        if longest > 0.0 {
            ((s / longest * res as f32).round() as usize).clamp(2, res)
        } else {
            res
        }
    })
}

fn check_writable(dir: &Path) -> Result<()> {
    let probe = dir.join(".prt-write-probe");
    std::fs::write(&probe, b"")
        .with_context(|| format!("output folder {} is not writable", dir.display()))?;
    let _ = std::fs::remove_file(probe);
    Ok(())
}

fn method_row(
    name: &str,
    model: &dyn FieldModel,
    field: &GridField,
    reconstruction: &GridField,
    labels: &[u32],
    eval_options: &EvalOptions,
    time: Duration,
) -> Result<MethodRow> {
    let evaluation = prt_mbd::evaluate(model, field, eval_options)?;
    let seams = prt_mbd::seam_metric(field, reconstruction, labels)?;
    Ok(MethodRow {
        name: name.to_string(),
        relative_mse: evaluation.relative_mse,
        operator_frobenius: evaluation.block_relative_frobenius,
        seam_boundary: seams.boundary,
        seam_interior: seams.interior,
        denoised_seam_ratio: None,
        stored_scalars: model.stored_scalars(),
        bytes_per_voxel: None,
        voxels: field.num_voxels(),
        seconds: time.as_secs_f64(),
    })
}

fn print_summary(report: &Report<'_>, out_dir: &Path, solve: &SolveReport) {
    println!("\n{}", report::table_markdown(&report.rows));
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
