//! `prt merge`: assemble a tiled bake's traces, solve MBD once over the whole volume and write
//! the same bake folder as `prt bake`, plus the seam measures across tile borders.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use prt_bake::BakeFolder;
use prt_bake::tiles::TilesReport;

use crate::bake::{KeepVolumesArg, cli_error, write_outputs};
use crate::plan::{limits, load_scene, read_plan};
use crate::progress::{StageBar, StageBars};

/// Options of `prt merge`.
#[derive(Debug, clap::Args)]
pub struct MergeArgs {
    /// Plan folder whose tiles have all finished (`prt bake-tile`).
    pub plan_dir: PathBuf,
    /// Bake folder to write: what `prt bake --out` writes (mbd/, report.md, ...) and tiles.json.
    #[arg(long)]
    pub out: PathBuf,
    /// Write the assembled traced volume and the baselines' reconstructions (f16) into
    /// OUT/volumes/, as `prt bake --keep-volumes` does.
    #[arg(long, value_enum, default_value_t = KeepVolumesArg::Auto)]
    pub keep_volumes: KeepVolumesArg,
    /// The scene file, when it lives at another path on this machine than in the plan.
    #[arg(long)]
    pub scene: Option<PathBuf>,
    /// Merge in memory bounded by one tile: never assemble the volume; fit MBD's basis to the
    /// volume averaged down below 64³ voxels, refine it by `--sweeps` passes over the tiles, fit
    /// each voxel's coefficients on it. Writes the container, scene.mesh and tiles.json (no baselines, report or seam
    /// views, which need the whole volume).
    #[arg(long, conflicts_with = "keep_volumes")]
    pub stream: bool,
    /// With `--stream`: alternating least-squares sweeps over the tiles after the coarse fit.
    #[arg(long, default_value_t = 2, requires = "stream")]
    pub sweeps: usize,
}

pub fn run(args: &MergeArgs) -> Result<()> {
    let total = Instant::now();
    let plan = read_plan(&args.plan_dir)?;
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
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create output folder {}", args.out.display()))?;
    if args.stream {
        return run_streamed(args, &plan, &scene, total);
    }

    // The in-memory merge holds the whole volume: refuse it over the budget before reading.
    let estimate = prt_bake::MemoryEstimate::for_grid(
        &plan.config,
        plan.lattice_dims,
        scene.scene.triangles().len(),
    );
    let budget = prt_bake::default_memory_budget();
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
        container: Some(BakeFolder::new(&args.out).container_dir()),
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
    write_outputs(&args.out, &scene, &baked, args.keep_volumes, load, total)?;

    let report = TilesReport::of_plan(&plan).with_seams(&seams, halo);
    let path = BakeFolder::new(&args.out).tiles_report();
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

/// `prt merge --stream`: the container, scene.mesh and tiles.json, in memory bounded by a tile.
fn run_streamed(
    args: &MergeArgs,
    plan: &prt_bake::tiles::TilePlan,
    scene: &prt_bake::SceneInput,
    total: Instant,
) -> Result<()> {
    let config = prt_bake::BakeConfig {
        container: Some(BakeFolder::new(&args.out).container_dir()),
        ..plan.config.clone()
    };
    let stage = StageBar::start("streamed merge");
    let merged = prt_bake::tiles::merge_streamed(
        plan,
        &args.plan_dir,
        &scene.name,
        &config,
        args.sweeps,
        &limits(),
        &stage,
    )?;
    stage.finish();
    let mesh = BakeFolder::new(&args.out).scene_mesh();
    prt_trace::write_mesh(&mesh, &scene.scene)
        .with_context(|| format!("cannot write {}", mesh.display()))?;
    let valid = merged.valid.iter().filter(|&&v| v).count();
    let bytes = merged.container.as_ref().map(|c| c.total_bytes);
    let report = TilesReport::of_plan(plan).with_streamed(
        &merged,
        args.sweeps,
        total.elapsed().as_secs_f64(),
    );
    let path = BakeFolder::new(&args.out).tiles_report();
    prt_texture::write_atomic(&path, serde_json::to_string_pretty(&report)?.as_bytes())
        .with_context(|| format!("cannot write {}", path.display()))?;
    let errors: Vec<String> = merged
        .relative_errors
        .iter()
        .map(|e| format!("{e:.3e}"))
        .collect();
    println!(
        "streamed merge of {} tiles: basis fitted on {:?} voxels, relative error at the valid \
         voxel centres {} (coarse fit, then after each sweep); {} valid voxels, {} bytes \
         written; total {:.1} s",
        plan.tiles.len(),
        merged.coarse_dims,
        errors.join(" → "),
        valid,
        bytes.unwrap_or(0),
        total.elapsed().as_secs_f64()
    );
    println!("wrote {}", path.display());
    Ok(())
}
