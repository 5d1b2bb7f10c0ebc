//! `prt merge`: assemble a tiled bake's traces, solve MBD once over the whole volume and write
//! the same bake folder as `prt bake`, plus the seam measures across tile borders.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result};
use prt_bake::TileSeams;
use serde_json::json;

use crate::bake::{KeepVolumes, cli_error, write_outputs};
use crate::plan::{load_scene, read_plan};
use crate::progress::{Stage, StageBars};

/// File of the merge's tile measures inside the bake folder.
pub const TILES_REPORT: &str = "tiles.json";

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
    #[arg(long, value_enum, default_value_t = KeepVolumes::Auto)]
    pub keep_volumes: KeepVolumes,
    /// The scene file, when it lives at another path on this machine than in the plan.
    #[arg(long)]
    pub scene: Option<PathBuf>,
}

pub fn run(args: &MergeArgs) -> Result<()> {
    let total = Instant::now();
    let plan = read_plan(&args.plan_dir)?;
    let load = Instant::now();
    let scene = load_scene(&plan, args.scene.as_deref())?;
    let load = load.elapsed();
    let found = prt_bake::scene_hash(&scene.scene);
    if found != plan.scene.hash {
        return Err(prt_bake::TileError::SceneChanged {
            planned: plan.scene.hash.clone(),
            found,
        }
        .into());
    }
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create output folder {}", args.out.display()))?;

    let stage = Stage::start("assemble");
    let assembled = prt_bake::assemble(&plan, &args.plan_dir)?;
    stage.finish();
    let config = prt_bake::BakeConfig {
        container: Some(args.out.join("mbd")),
        ..plan.config.clone()
    };
    let prt_bake::AssembledVolume {
        volume,
        tile_of_voxel,
        halo,
    } = assembled;
    // The volume moves into the bake: the merge holds one copy of it.
    let baked =
        prt_bake::bake_volume(&scene.name, volume, None, &config, &StageBars).map_err(cli_error)?;
    let stage = Stage::start("tile seams");
    let seams = prt_bake::tile_seams(&tile_of_voxel, &baked)?;
    stage.finish();
    write_outputs(&args.out, &scene, &baked, args.keep_volumes, load, total)?;

    let report = tiles_report(&plan, halo, &seams);
    let path = args.out.join(TILES_REPORT);
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

/// The merge's record of the tiling and the seam measures.
fn tiles_report(
    plan: &prt_bake::TilePlan,
    halo: Option<prt_bake::HaloAgreement>,
    seams: &TileSeams,
) -> serde_json::Value {
    json!({
        "tiles": plan.tiles.len(),
        "counts": plan.counts,
        "halo": plan.halo,
        "lattice": plan.lattice_dims,
        "seam_ratio_across_tile_borders": {
            "trace": seams.trace,
            "mbd_error": seams.mbd,
            "mbd_basis": seams.basis,
        },
        "halo_agreement": halo.map(|h| json!({
            "voxels": h.voxels,
            "relative_rms_difference": h.relative_rms_difference,
        })),
    })
}
