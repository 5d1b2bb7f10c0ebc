//! `compare stream`: the streamed merge (`prt merge --stream`) against the in-memory merge of
//! the same tiles: each bake's container read back, scored against the assembled traced volume.
//!
//! ```text
//! prt plan ../shared/scenes/sponza/Sponza.gltf --res 128 --tiles 2,1,2 --halo 1 --out /tmp/plan128
//! prt bake-tile /tmp/plan128 --all --workers 2
//! prt merge /tmp/plan128 --stream --sweeps 4 --out /tmp/stream128
//! prt merge /tmp/plan128 --out /tmp/memory128
//! cargo run --release -p prt-benches --bin compare -- stream --plan /tmp/plan128 /tmp/memory128 /tmp/stream128
//! ```
//!
//! Two errors per bake, both over the valid voxels of the assembled volume: at the voxel
//! centres (what the streamed merge minimises) and `prt_mbd::evaluate`'s relative MSE over
//! jittered samples (the bake report's, invalid voxels included as zeros).
use std::error::Error;
use std::path::PathBuf;

use prt_bake::BakeFolder;
use prt_bake::tiles::{TilePlan, assemble};
use prt_benches::{Table, model_error_at_centres};
use prt_mbd::{EvalOptions, evaluate};
use prt_texture::Limits;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// The plan folder whose tiles the bakes merged.
    #[arg(long)]
    plan: PathBuf,
    /// Bake folders (each with its container) to score.
    bakes: Vec<PathBuf>,
}

pub fn run(args: &Args) -> Result<(), Box<dyn Error>> {
    let plan = TilePlan::read(&args.plan, &Limits::default())?;
    // Our own tiles: any size this machine holds.
    let tiles = Limits {
        max_bytes: u64::MAX,
        ..Limits::default()
    };
    let volume = assemble(&plan, &args.plan, &tiles)?.volume;
    let (field, valid) = (&volume.field, &volume.valid);
    let mut table = Table::new(&[
        "bake",
        "relative error, valid voxel centres",
        "relative MSE, jittered (report's)",
        "container bytes per valid voxel",
    ]);
    let valid_count = valid.iter().filter(|&&v| v).count();
    for bake in &args.bakes {
        let container = super::container(bake)?;
        let at_centres = model_error_at_centres(&container.model, field, valid)?;
        let jittered = evaluate(&container.model, field, &EvalOptions::default())?;
        let bytes: u64 = std::fs::read_dir(BakeFolder::new(bake).container_dir())?
            .filter_map(Result::ok)
            .filter_map(|e| e.metadata().ok())
            .map(|m| m.len())
            .sum();
        table.row(vec![
            bake.display().to_string(),
            format!("{at_centres:.4e}"),
            format!("{:.4e}", jittered.relative_mse),
            format!("{:.2}", bytes as f64 / valid_count as f64),
        ]);
    }
    println!("{}", table.markdown());
    Ok(())
}
