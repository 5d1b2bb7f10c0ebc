//! Finished bakes compared: tiled against single-process bakes, streamed against in-memory
//! merges, sparse-brick against dense bakes, and what half-resolution bricks would cost. Every
//! subcommand reads bake folders (`prt bake`, `prt merge`; `--keep-volumes always` where it
//! needs the traced volume) and prints markdown tables.
//!
//! ```text
//! cargo run --release -p prt-benches --bin compare -- tiles --prt target/release/prt --scene ../shared/scenes/sponza/Sponza.gltf --res 48 --tiles 1,2,4,8,16 --single [--csv DIR]
//! cargo run --release -p prt-benches --bin compare -- stream --plan /tmp/plan128 /tmp/memory128 /tmp/stream128
//! cargo run --release -p prt-benches --bin compare -- bricks --dense /tmp/bricks/dense128 --sparse /tmp/bricks/sparse128
//! cargo run --release -p prt-benches --bin compare -- bricks-adaptive /tmp/sponza128 --edge 4
//! ```
//!
//! Each subcommand's module says what it measures and how its bakes are made; errors are
//! relative squared errors `Σ‖f̂ − f‖² / Σ‖f‖²` over valid voxels
//! ([`prt_benches::model_error_at_centres`] for a container as written).
use std::error::Error;
use std::path::Path;

use clap::{Parser, Subcommand};
use prt_bake::BakeFolder;
use prt_bake::container::MbdContainer;
use prt_bake::volumes::{KeptVolumes, REFERENCE};
use prt_benches::large_file_limits;
use prt_core::GridField;

mod bricks;
mod bricks_adaptive;
mod stream;
mod tiles;

#[derive(Debug, Parser)]
#[command(
    about = "Finished bakes compared: tiled, streamed, sparse bricks, half-resolution bricks"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Tiled bakes measured per tile and in the merge; with --single, against single-process bakes.
    Tiles(tiles::Args),
    /// Streamed against in-memory merges of one tiled bake.
    Stream(stream::Args),
    /// A sparse-brick bake against a dense one: voxels, validity, errors.
    Bricks(bricks::Args),
    /// How many bricks could be stored at half resolution, for what error.
    BricksAdaptive(bricks_adaptive::Args),
}

fn main() -> Result<(), Box<dyn Error>> {
    match Cli::parse().command {
        Command::Tiles(args) => tiles::run(&args),
        Command::Stream(args) => stream::run(&args),
        Command::Bricks(args) => bricks::run(&args),
        Command::BricksAdaptive(args) => bricks_adaptive::run(&args),
    }
}

/// A bake folder's kept volumes (`prt bake --keep-volumes always`).
fn kept_volumes(bake: &Path) -> Result<KeptVolumes, Box<dyn Error>> {
    Ok(BakeFolder::new(bake).read_volumes(&large_file_limits())?)
}

/// The traced volume among a bake's kept volumes.
fn traced(kept: &KeptVolumes) -> Result<&GridField, Box<dyn Error>> {
    Ok(kept
        .get(REFERENCE)
        .ok_or("the bake kept no reference volume")?)
}

/// A bake folder's MBD container as written.
fn container(bake: &Path) -> Result<MbdContainer, Box<dyn Error>> {
    Ok(BakeFolder::new(bake).read_container(&large_file_limits())?)
}
