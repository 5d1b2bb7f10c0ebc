//! `prt plan`: cut a bake into tiles for independent workers (`prt bake-tile`), merged by
//! `prt merge`.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use prt_bake::memory::MemoryEstimate;
use prt_bake::tiles::{PlanWritten, SurfaceCacheWritten, TilePlan};
use prt_bake::{BakeFolder, SceneInput};
use prt_texture::Limits;

use crate::bake::{BakeArgs, KeepVolumesArg, cli_error};
use crate::progress::StageBar;

/// Options of `prt plan`: the scene and every knob of `prt bake`, the tiling and the halo.
#[derive(Debug, clap::Args)]
pub struct PlanArgs {
    #[command(flatten)]
    pub bake: BakeArgs,
    /// Tiles along x, y and z, e.g. 2,2,1 (at most one per voxel along an axis).
    #[arg(long, value_parser = parse_counts)]
    pub tiles: [usize; 3],
    /// Voxels each tile traces beyond its own on every side. The merge keeps each voxel from
    /// the tile that owns it and compares the overlap (two independent traces) as a measure of
    /// the Monte Carlo noise at tile borders; 0 traces no voxel twice. With the denoiser a
    /// worker also traces a margin of its radius, filters and drops it (the kept voxels are
    /// filtered as in `prt bake`).
    #[arg(long, default_value_t = 0)]
    pub halo: usize,
    /// Replace the plan the output folder holds when it differs from this one, removing its
    /// tiles and worker logs (without it such a folder is refused; the same plan again is left
    /// as it is, with its finished tiles).
    #[arg(long)]
    pub replace: bool,
}

/// `X,Y,Z` of positive integers.
fn parse_counts(text: &str) -> Result<[usize; 3], String> {
    let parts: Vec<&str> = text.split(',').map(str::trim).collect();
    let numbers: Vec<usize> = parts
        .iter()
        .map(|p| p.parse::<usize>().ok().filter(|&n| n > 0))
        .collect::<Option<_>>()
        .ok_or_else(|| format!("{text:?} is not three positive integers like 2,2,1"))?;
    <[usize; 3]>::try_from(numbers)
        .map_err(|_| format!("{text:?} is not three positive integers like 2,2,1"))
}

/// The scene a plan names: its glTF file (or `over`, a copy of it elsewhere) or the built-in
/// Cornell box.
pub fn load_scene(plan: &TilePlan, over: Option<&Path>) -> Result<SceneInput> {
    let path = over
        .map(Path::to_path_buf)
        .or_else(|| plan.scene.path.clone());
    match path {
        Some(path) => SceneInput::load_gltf(&path).map_err(cli_error),
        None => Ok(SceneInput::cornell_box()),
    }
}

/// The limits the plan and tile readers of `prt plan`, `bake-tile` and `merge` apply: the
/// default dimensions, and as many bytes as the larger of the default (1 GiB) and this
/// machine's memory budget (a tile is read whole).
pub fn limits() -> Limits {
    let limits = Limits::default();
    Limits {
        max_bytes: limits
            .max_bytes
            .max(prt_bake::memory::default_memory_budget()),
        ..limits
    }
}

/// Reads the plan in `plan_dir`, with the folder in the message when it cannot.
pub fn read_plan(plan_dir: &Path) -> Result<TilePlan> {
    TilePlan::read(plan_dir, &limits()).with_context(|| {
        format!(
            "cannot read the plan in {} (write one with `prt plan`)",
            plan_dir.display()
        )
    })
}

fn gib(bytes: u64) -> f64 {
    bytes as f64 / f64::from(1u32 << 30)
}

pub fn run(args: &PlanArgs) -> Result<()> {
    if args.bake.keep_volumes != KeepVolumesArg::Auto {
        bail!("--keep-volumes is a flag of `prt merge`, which writes the bake folder");
    }
    let config = args.bake.config(Some(PathBuf::from(BakeFolder::CONTAINER)));
    config.validate().map_err(cli_error)?;
    let scene = match &args.bake.scene {
        Some(path) => SceneInput::load_gltf(path).map_err(cli_error)?,
        None => SceneInput::cornell_box(),
    };
    // The in-memory merge solves the whole volume in one process; say now when it will not fit.
    let merge_note = match (scene.scene.bounds(), config.max_memory) {
        (Some(bounds), Some(budget)) => {
            let estimate = MemoryEstimate::new(
                &config,
                bounds.size().to_array(),
                scene.scene.triangles().len(),
            );
            (estimate.total() > budget).then(|| {
                format!(
                    "note: merging in memory needs about {:.2} GiB, over this machine's budget of \
                     {:.2} GiB: merge with `prt merge --stream`, which holds one tile",
                    gib(estimate.total()),
                    gib(budget)
                )
            })
        }
        _ => None,
    };
    let plan = prt_bake::tiles::plan_tiles(
        &scene,
        args.bake.scene.as_deref(),
        &config,
        args.tiles,
        args.halo,
    )?;
    let out = args
        .bake
        .out
        .clone()
        .unwrap_or_else(|| Path::new("prt-out").join(&scene.name));
    let written = prt_bake::tiles::write_plan(&plan, &out, args.replace, &limits())?;
    let path = out.join(prt_bake::tiles::PLAN_FILE);
    let largest = (0..plan.tiles.len())
        .filter_map(|i| prt_bake::tiles::tile_trace_box(&plan, i).ok())
        .map(|traced| traced.len())
        .max()
        .unwrap_or(0);
    println!(
        "planned {} tiles ({}×{}×{}) of the {}×{}×{} lattice of {}, halo {}, largest tile {} \
         voxels traced",
        plan.tiles.len(),
        plan.counts[0],
        plan.counts[1],
        plan.counts[2],
        plan.lattice_dims[0],
        plan.lattice_dims[1],
        plan.lattice_dims[2],
        plan.scene.name,
        plan.halo,
        largest
    );
    match written {
        PlanWritten::New => println!("wrote {}", path.display()),
        PlanWritten::Unchanged => {
            let done = (0..plan.tiles.len())
                .filter(|&i| {
                    prt_bake::tiles::tile_status(&plan, &out, i)
                        .is_ok_and(|s| s == prt_bake::tiles::TileStatus::Done)
                })
                .count();
            println!(
                "{} already holds this plan: left as it is, with its {done} finished tiles",
                out.display()
            );
        }
        PlanWritten::Replaced { removed_tiles } => println!(
            "wrote {}, replacing the plan it held and removing its {removed_tiles} tile folders",
            path.display()
        ),
    }
    let stage = StageBar::start("surface cache");
    let (cache, cache_written) =
        prt_bake::tiles::ensure_surface_cache(&plan, &out, &scene, true, &limits(), &stage)?;
    stage.finish();
    let cache_path = out.join(prt_bake::tiles::SURFACE_CACHE_FILE);
    match cache_written {
        SurfaceCacheWritten::Current => println!(
            "{} is this plan's shared surface cache: kept",
            cache_path.display()
        ),
        SurfaceCacheWritten::Evaluated { replaced } => println!(
            "wrote {}: the surface cache every tile shares, {} points, {} entries (those the \
             tiles' first rays hit, {:.2e} rays) evaluated with {:.2e} rays in {:.2} s{}",
            cache_path.display(),
            cache.points(),
            cache.evaluated(),
            cache.visibility_rays as f64,
            (cache.rays - cache.visibility_rays) as f64,
            cache.time.as_secs_f64(),
            replaced.map_or(String::new(), |why| format!(" (replacing one: {why})"))
        ),
    }
    if let Some(note) = merge_note {
        println!("{note}");
    }
    println!(
        "next: prt bake-tile {} --tile I for I in 0..{} (or --all), then prt merge {} --out BAKE_DIR",
        out.display(),
        plan.tiles.len(),
        out.display()
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_are_three_positive_integers() {
        assert_eq!(parse_counts("2,2,1"), Ok([2, 2, 1]));
        assert_eq!(parse_counts(" 4, 1 ,2"), Ok([4, 1, 2]));
        for bad in ["2,2", "2,2,0", "a,b,c", "1,2,3,4", ""] {
            assert!(parse_counts(bad).is_err(), "{bad}");
        }
    }
}
