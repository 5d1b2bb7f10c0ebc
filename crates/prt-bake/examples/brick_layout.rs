//! Re-writes a bake's MBD container dense and in bricks (4 and 8 cells) and prints, per layout,
//! the bytes written and how far the model read back is from the dense one: coefficients on the
//! live nodes (must be equal) and f̂ at the valid voxel centres (relative squared error).
//!
//! `cargo run --release -p prt-bake --example brick_layout BAKE_DIR [SCRATCH_DIR]`

use std::error::Error;
use std::path::PathBuf;

use prt_bake::container::read_container;
use prt_bake::container::{
    CoefficientLayout, ContainerContents, LayoutConfig, layout_bytes, node_liveness,
    write_container_with,
};
use prt_core::FieldModel;
use prt_texture::Limits;

fn main() -> Result<(), Box<dyn Error>> {
    let mut args = std::env::args().skip(1);
    let bake = PathBuf::from(
        args.next()
            .ok_or("usage: brick_layout BAKE_DIR [SCRATCH_DIR]")?,
    );
    let scratch = args
        .next()
        .map(PathBuf::from)
        .unwrap_or_else(|| std::env::temp_dir().join("prt-brick-layout"));
    let source = read_container(&bake.join("mbd"), &Limits::default())?;
    let model = &source.model;
    let kernels = model.coefficient_kernels();
    let live = node_liveness(kernels, source.grid, &source.valid)?;
    let voxels = source.valid.len();
    let valid = source.valid.iter().filter(|&&v| v).count();
    let nodes = kernels.nodes();
    let rank = model.coefficients().ncols();
    println!(
        "{}: grid {:?}, {voxels} voxels, {valid} valid ({:.1} %), rank {rank}, {:?}",
        bake.display(),
        source.grid,
        100.0 * valid as f64 / voxels as f64,
        source.encoding
    );
    let contents = ContainerContents {
        model,
        grid: source.grid,
        valid: &source.valid,
        scene: source.attribute_str("scene").unwrap_or("scene"),
        lambda: 0.0,
        encoding: source.encoding,
    };
    let mut dense_model = None;
    println!(
        "| layout | live bricks | coefficients (B) | all files (B) | B/voxel | B/valid voxel | live nodes equal | f̂ rel. sq. diff on valid voxels |"
    );
    println!("|---|---|---|---|---|---|---|---|");
    for (name, layout, size) in [
        ("dense", CoefficientLayout::Dense, 4),
        ("bricks 4", CoefficientLayout::Bricks, 4),
        ("bricks 8", CoefficientLayout::Bricks, 8),
        ("auto", CoefficientLayout::Auto, 4),
    ] {
        let folder = scratch.join(name.replace(' ', ""));
        let config = LayoutConfig {
            layout,
            brick_size: size,
            live_nodes: Some(&live),
        };
        let report = write_container_with(&folder, &contents, &config)?;
        let coefficient_bytes: u64 = report
            .manifest
            .arrays
            .iter()
            .filter(|a| a.name == "coefficients")
            .map(|a| a.bytes + a.bricks.as_ref().map_or(0, |b| b.indirection_bytes))
            .sum();
        let estimate = layout_bytes(nodes, rank, source.encoding, size, &live)?;
        let back = read_container(&folder, &Limits::default())?.model;
        let dense = dense_model.get_or_insert_with(|| back.clone());
        let equal = live
            .iter()
            .enumerate()
            .filter(|(_, l)| **l)
            .all(|(n, _)| back.coefficients().row(n) == dense.coefficients().row(n));
        let (mut diff, mut norm) = (0.0f64, 0.0f64);
        let (mut a, mut b) = (vec![0.0; model.dim()], vec![0.0; model.dim()]);
        for (v, _) in source.valid.iter().enumerate().filter(|(_, ok)| **ok) {
            let g = source.grid;
            let node = [v % g[0], v / g[0] % g[1], v / (g[0] * g[1])];
            let x = kernels
                .node_position(node)
                .ok_or("voxel outside the node grid")?;
            back.eval(x, &mut a)?;
            dense.eval(x, &mut b)?;
            for (p, q) in a.iter().zip(&b) {
                diff += f64::from(p - q).powi(2);
                norm += f64::from(*q).powi(2);
            }
        }
        println!(
            "| {name} | {} / {} | {coefficient_bytes} | {} | {:.2} | {:.2} | {equal} | {:.3e} |",
            estimate.live_bricks,
            estimate.bricks_total,
            report.total_bytes,
            report.total_bytes as f64 / voxels as f64,
            report.total_bytes as f64 / valid as f64,
            diff / norm.max(f64::MIN_POSITIVE),
        );
    }
    Ok(())
}
