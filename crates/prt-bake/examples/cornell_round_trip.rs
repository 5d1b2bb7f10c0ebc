//! Bakes the built-in Cornell box at a small size, writes the MBD container, reads it back and
//! evaluates the transfer f̂(x) at the centre of the box, in memory and as read back.
//!
//! `cargo run --release -p prt-bake --example cornell_round_trip [OUT_FOLDER]`

use std::error::Error;
use std::path::{Path, PathBuf};

use prt_bake::container::{MbdContainer, read_container};
use prt_bake::{BakeConfig, SceneInput, bake};
use prt_core::{FieldModel, NoProgress, glam::Vec3};
use prt_kernels::HatGrid;
use prt_mbd::MbdModel;
use prt_texture::Limits;

/// What the round trip produced.
pub struct RoundTrip {
    /// Where f̂ was evaluated.
    pub point: Vec3,
    /// The model in memory (f32).
    pub model: MbdModel<HatGrid, HatGrid>,
    /// The container read back (f16 by default).
    pub container: MbdContainer,
    /// f̂(point) of the model in memory.
    pub in_memory: Vec<f32>,
    /// f̂(point) of the model read back.
    pub read_back: Vec<f32>,
}

/// Bakes a small Cornell box into `out` and reads it back.
pub fn run(out: &Path) -> Result<RoundTrip, Box<dyn Error>> {
    let config = BakeConfig {
        resolution: 8,
        rays_per_voxel: 48,
        cache_rays: 16,
        rank: 4,
        basis_nodes: 3,
        max_iterations: 16,
        baselines: false,
        container: Some(out.to_path_buf()),
        ..BakeConfig::default()
    };
    let scene = SceneInput::cornell_box();
    let baked = bake(&scene, &config, &NoProgress)?;
    let container = read_container(out, &Limits::default())?;
    let point = baked.volume.field.bounds().centre();
    let model = baked.mbd.model;
    let mut in_memory = vec![0.0; model.dim()];
    model.eval(point, &mut in_memory)?;
    let mut read_back = vec![0.0; container.model.dim()];
    container.model.eval(point, &mut read_back)?;
    Ok(RoundTrip {
        point,
        model,
        container,
        in_memory,
        read_back,
    })
}

#[allow(dead_code)] // the test includes this file for `run` only
fn main() -> Result<(), Box<dyn Error>> {
    let out = std::env::args_os()
        .nth(1)
        .map(PathBuf::from)
        .unwrap_or_else(|| std::env::temp_dir().join("prt-bake-cornell"));
    let trip = run(&out)?;
    println!(
        "wrote {} ({:?}, rank {}, {} valid voxels of {})",
        out.display(),
        trip.container.encoding,
        trip.container.model.rank(),
        trip.container.valid.iter().filter(|v| **v).count(),
        trip.container.valid.len()
    );
    println!("f̂({}) first 9 components (direct, row 0):", trip.point);
    println!("  in memory : {:?}", &trip.in_memory[..9]);
    println!("  read back : {:?}", &trip.read_back[..9]);
    Ok(())
}
