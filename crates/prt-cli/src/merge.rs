//! `prt merge`: assemble a tiled bake's traces, solve MBD once over the whole volume and write
//! the same bake folder as `prt bake`, plus the seam measures across tile borders.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use prt_bake::BakeFolder;
use prt_bake::tiles::{MapOutcome, MergeStage, TilesReport};

use crate::bake::{KeepVolumesArg, cli_error, write_outputs};
use crate::plan::{limits, load_scene, read_plan};
use crate::progress::{StageBar, StageBars};

/// Options of `prt merge`.
#[derive(Debug, clap::Args)]
pub struct MergeArgs {
    /// Plan folder whose tiles have all finished (`prt bake-tile`).
    pub plan_dir: PathBuf,
    /// Bake folder to write: what `prt bake --out` writes (mbd/, report.md, ...) and tiles.json.
    /// Not with `--map`, nor with `--reduce` but of the coefficients.
    #[arg(long, required_unless_present_any = ["map", "reduce"])]
    pub out: Option<PathBuf>,
    /// Write the assembled traced volume and the baselines' reconstructions (f16) into
    /// OUT/volumes/, as `prt bake --keep-volumes` does.
    #[arg(long, value_enum, default_value_t = KeepVolumesArg::Auto)]
    pub keep_volumes: KeepVolumesArg,
    /// The scene file, when it lives at another path on this machine than in the plan.
    #[arg(long)]
    pub scene: Option<PathBuf>,
    /// Merge in memory bounded by one tile plus the coefficients (rank floats per voxel; the
    /// distributed `--map`/`--reduce` keep no per-voxel array): never assemble the volume; fit
    /// MBD's basis to the volume averaged down below 64³ voxels, refine it by `--sweeps` passes
    /// over the tiles, fit each voxel's coefficients on it. Writes the container, scene.mesh and
    /// tiles.json (no baselines, report or seam views, which need the whole volume).
    #[arg(long, conflicts_with = "keep_volumes")]
    pub stream: bool,
    /// With `--stream`, `--map` or `--reduce`: alternating least-squares sweeps over the tiles
    /// after the coarse fit (every map and reduce of one merge must be given the same).
    #[arg(long)]
    pub sweeps: Option<usize>,
    /// The streamed merge as distributed work: run stage `--stage`'s map for tile `--tile` only
    /// (one worker's task), writing PLAN_DIR/merge/STAGE/tile-INDEX.part. The stages in order:
    /// coarse, sweep-1 ... sweep-K, coefficients; each stage's maps read the basis of the
    /// stage before, written by its `--reduce`.
    #[arg(long, requires_all = ["stage", "tile"], conflicts_with_all = ["reduce", "out", "keep_volumes", "stream"])]
    pub map: bool,
    /// Run stage `--stage`'s reduce: sum every tile's partial in tile order and fit the basis
    /// (PLAN_DIR/merge/STAGE.basis); the coefficients' reduce writes the bake folder (`--out`)
    /// as `--stream` does, the same bytes.
    #[arg(long, requires = "stage", conflicts_with_all = ["keep_volumes", "stream"])]
    pub reduce: bool,
    /// The stage of `--map` or `--reduce`: coarse, sweep-1, ..., sweep-K, coefficients.
    #[arg(long, value_parser = clap::value_parser!(MergeStage))]
    pub stage: Option<MergeStage>,
    /// The tile of `--map`.
    #[arg(long, requires = "map")]
    pub tile: Option<usize>,
}

/// Sweeps when none are given.
const DEFAULT_SWEEPS: usize = 2;

pub fn run(args: &MergeArgs) -> Result<()> {
    let total = Instant::now();
    let plan = read_plan(&args.plan_dir)?;
    let distributed = args.map || args.reduce;
    if args.sweeps.is_some() && !(args.stream || distributed) {
        bail!("--sweeps is an option of the streamed merge: --stream, --map or --reduce");
    }
    if (args.stage.is_some() || args.tile.is_some()) && !distributed {
        bail!("--stage and --tile are options of --map and --reduce");
    }
    let sweeps = args.sweeps.unwrap_or(DEFAULT_SWEEPS);
    let stage = args.stage.unwrap_or(MergeStage::Coefficients);
    if args.map {
        let tile = args.tile.unwrap_or(0);
        let outcome = prt_bake::tiles::map_tile(
            &plan,
            &args.plan_dir,
            &plan.config,
            sweeps,
            stage,
            tile,
            &limits(),
        )?;
        match outcome {
            MapOutcome::Written { path, bytes } => {
                println!(
                    "{stage} tile {tile}: wrote {} ({bytes} bytes)",
                    path.display()
                )
            }
            MapOutcome::AlreadyDone { path } => {
                println!("{stage} tile {tile}: {} is current", path.display())
            }
        }
        return Ok(());
    }
    if args.reduce && stage != MergeStage::Coefficients && args.out.is_some() {
        bail!(
            "--out goes with the coefficients' reduce, which writes the bake folder; {stage}'s writes PLAN_DIR/merge/{stage}.basis"
        );
    }
    if args.reduce && stage != MergeStage::Coefficients {
        let stage_bar = StageBar::start("reduce");
        let outcome = prt_bake::tiles::reduce_stage(
            &plan,
            &args.plan_dir,
            &plan.config,
            sweeps,
            stage,
            &limits(),
            &stage_bar,
        )?;
        stage_bar.finish();
        let basis = &outcome.basis;
        println!(
            "{stage}: reduced {} tiles into {} ({} bytes){}; {:.1} s",
            plan.tiles.len(),
            outcome.path.display(),
            outcome.bytes,
            match (basis.relative_errors.last(), basis.basis_solves.last()) {
                (Some(error), Some(solve)) => format!(
                    "; relative error of the basis before {error:.3e}, basis solve {} \
                     conjugate-gradient iterations",
                    solve.iterations
                ),
                _ => format!(", coarse fit on {:?} voxels", basis.coarse_dims),
            },
            total.elapsed().as_secs_f64()
        );
        return Ok(());
    }
    let Some(out) = &args.out else {
        bail!("the coefficients' reduce writes the bake folder: give --out");
    };
    let load = Instant::now();
    let scene = load_scene(&plan, args.scene.as_deref())?;
    let load = load.elapsed();
    let found = prt_bake::scene_hash(&scene.scene);
    if found != plan.scene.hash {
        return Err(prt_bake::tiles::TileError::SceneChanged {
            planned: plan.scene.hash.clone(),
            found,
        }
        .into());
    }
    std::fs::create_dir_all(out)
        .with_context(|| format!("cannot create output folder {}", out.display()))?;
    if args.stream || args.reduce {
        return run_streamed(
            &args.plan_dir,
            out,
            sweeps,
            args.reduce,
            &plan,
            scene,
            total,
        );
    }

    // The in-memory merge holds the whole volume: refuse it over the budget before reading.
    let estimate = prt_bake::memory::MemoryEstimate::for_grid(
        &plan.config,
        plan.lattice_dims,
        scene.scene.triangles().len(),
    );
    let budget = prt_bake::memory::default_memory_budget();
    if estimate.total() > budget {
        bail!(
            "merging in memory needs about {:.2} GiB, over this machine's budget of {:.2} GiB; \
             merge with --stream, which holds one tile",
            estimate.total() as f64 / f64::from(1u32 << 30),
            budget as f64 / f64::from(1u32 << 30)
        );
    }
    let stage = StageBar::start("assemble");
    let assembled = prt_bake::tiles::assemble(&plan, &args.plan_dir, &limits())?;
    stage.finish();
    let config = prt_bake::BakeConfig {
        container: Some(BakeFolder::new(out).container_dir()),
        ..plan.config.clone()
    };
    let prt_bake::tiles::AssembledVolume {
        volume,
        tile_of_voxel,
        halo,
    } = assembled;
    // The volume moves into the bake: the merge holds one copy of it.
    let baked =
        prt_bake::bake_volume(&scene.name, volume, None, &config, &StageBars).map_err(cli_error)?;
    let stage = StageBar::start("tile seams");
    let seams = prt_bake::tiles::tile_seams(&tile_of_voxel, &baked)?;
    stage.finish();
    write_outputs(out, &scene, &baked, args.keep_volumes, load, total)?;

    let report = TilesReport::of_plan(&plan).with_seams(&seams, halo);
    let path = BakeFolder::new(out).tiles_report();
    prt_texture::write_atomic(&path, serde_json::to_string_pretty(&report)?.as_bytes())
        .with_context(|| format!("cannot write {}", path.display()))?;
    println!(
        "tile borders: seam ratio of the trace {:.3}, of MBD's error {:.3}, of MBD's basis {:.3} \
         (about 1: no seam){}",
        seams.trace,
        seams.mbd,
        seams.basis,
        match halo {
            Some(h) => format!(
                "; halo: {} voxels traced twice differ by {:.2} % RMS (Monte Carlo noise)",
                h.voxels,
                100.0 * h.relative_rms_difference
            ),
            None => String::new(),
        }
    );
    println!("wrote {}", path.display());
    Ok(())
}

/// `prt merge --stream` (every stage here) or `--reduce --stage coefficients` (the last stage's
/// reduce, from the partials): scene.mesh first (the scene is dropped before the merge), then the
/// container and tiles.json, in memory bounded by a tile plus, for `--stream`, the coefficients.
fn run_streamed(
    plan_dir: &Path,
    out: &Path,
    sweeps: usize,
    from_partials: bool,
    plan: &prt_bake::tiles::TilePlan,
    scene: prt_bake::SceneInput,
    total: Instant,
) -> Result<()> {
    let mesh = BakeFolder::new(out).scene_mesh();
    prt_trace::mesh::write_mesh(&mesh, &scene.scene)
        .with_context(|| format!("cannot write {}", mesh.display()))?;
    let scene_name = scene.name;
    let config = prt_bake::BakeConfig {
        container: Some(BakeFolder::new(out).container_dir()),
        ..plan.config.clone()
    };
    let stage = StageBar::start("streamed merge");
    let merge = if from_partials {
        prt_bake::tiles::merge_from_partials
    } else {
        prt_bake::tiles::merge_streamed
    };
    let merged = merge(
        plan,
        plan_dir,
        &scene_name,
        &config,
        sweeps,
        &limits(),
        &stage,
    )?;
    stage.finish();
    let valid = merged.valid_voxels;
    let bytes = merged.container.as_ref().map(|c| c.total_bytes);
    let report =
        TilesReport::of_plan(plan).with_streamed(&merged, sweeps, total.elapsed().as_secs_f64());
    let path = BakeFolder::new(out).tiles_report();
    prt_texture::write_atomic(&path, serde_json::to_string_pretty(&report)?.as_bytes())
        .with_context(|| format!("cannot write {}", path.display()))?;
    let history = |errors: &[f64]| {
        let errors: Vec<String> = errors.iter().map(|e| format!("{e:.3e}")).collect();
        errors.join(" → ")
    };
    println!(
        "streamed merge of {} tiles: basis fitted on {:?} voxels, relative error at the valid \
         voxel centres {} (coarse fit, then after each sweep){}; {} valid voxels, {} bytes \
         written; total {:.1} s",
        plan.tiles.len(),
        merged.coarse_dims,
        history(&merged.relative_errors),
        match config.loss_weighting {
            Some(_) => format!(
                ", of the loss-weighted vectors {}",
                history(&merged.weighted_errors)
            ),
            None => String::new(),
        },
        valid,
        bytes.unwrap_or(0),
        total.elapsed().as_secs_f64()
    );
    println!("wrote {}", path.display());
    Ok(())
}
