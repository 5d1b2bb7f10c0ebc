//! A sparse-brick bake against a dense one of the same scene and seed: voxels, validity, and
//! each method's error against the dense bake's traced volume over its valid voxels.
//!
//! ```text
//! prt bake ../shared/scenes/sponza/Sponza.gltf --res 128 --layout dense --keep-volumes always --out /tmp/bricks/dense128
//! prt bake ../shared/scenes/sponza/Sponza.gltf --res 128 --layout sparse --keep-volumes always --out /tmp/bricks/sparse128
//! cargo run --release -p prt-benches --bin bricks_compare -- --dense /tmp/bricks/dense128 --sparse /tmp/bricks/sparse128
//! ```
//!
//! Both bakes keep their volumes (`--keep-volumes always`, f16). The error of a method is
//! `Σ‖f̂ − f‖² / Σ‖f‖²` over the dense bake's valid voxel centres, `f` its traced volume: MBD as
//! written (each bake's container read back) and CPCA (each bake's kept reconstruction). The
//! traced volumes are compared bit for bit (f16) on those voxels. The voxels bricks of 2, 4, 8
//! and 16 voxels would store are counted from the dense bake's validity.

use std::path::PathBuf;

use clap::Parser;
use prt_bake::container::read_container;
use prt_bake::volumes::{REFERENCE, read_volumes};
use prt_benches::{Table, relative_mse_at_centres};
use prt_core::FieldModel;
use prt_texture::Limits;
use prt_trace::bricks::BrickMap;

#[derive(Debug, Parser)]
#[command(about = "A sparse-brick bake against a dense one: voxels, validity, errors")]
struct Cli {
    /// Output folder of the dense `prt bake` (with kept volumes).
    #[arg(long)]
    dense: PathBuf,
    /// Output folder of the sparse `prt bake` (with kept volumes).
    #[arg(long)]
    sparse: PathBuf,
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let cli = Cli::parse();
    let limits = Limits {
        max_bytes: 16 << 30,
        ..Limits::default()
    };
    let dense = read_volumes(&cli.dense.join("volumes"), &limits)?;
    let sparse = read_volumes(&cli.sparse.join("volumes"), &limits)?;
    if dense.grid != sparse.grid {
        return Err(format!("grids differ: {:?} vs {:?}", dense.grid, sparse.grid).into());
    }
    let reference = dense.get(REFERENCE).expect("the reference is kept");
    let sparse_reference = sparse.get(REFERENCE).expect("the reference is kept");
    let valid = &dense.valid;
    let count = |m: &[bool]| m.iter().filter(|&&b| b).count();
    let same_validity = dense.valid == sparse.valid;
    let differing = (0..valid.len())
        .filter(|&v| valid[v] && reference.voxel(v) != sparse_reference.voxel(v))
        .count();
    println!(
        "grid {:?} ({} voxels); valid: dense {}, sparse {}, same mask: {same_validity}; \
         valid voxels whose traced value differs (f16): {differing}",
        dense.grid,
        valid.len(),
        count(valid),
        count(&sparse.valid)
    );
    // What other brick edges would store, from the dense bake's validity.
    let mut edges = Table::new(&[
        "brick edge",
        "kept bricks",
        "stored voxels",
        "stored / valid",
    ]);
    for edge in [2, 4, 8, 16] {
        let map = BrickMap::from_voxels(dense.grid, edge, valid);
        edges.row(vec![
            format!("{edge}"),
            format!("{} of {}", map.kept_bricks(), map.bricks()),
            format!("{}", map.stored_voxels()),
            format!("{:.2}", map.stored_voxels() as f64 / count(valid) as f64),
        ]);
    }
    print!("{}", edges.markdown());
    let mut table = Table::new(&["method", "dense bake", "sparse bake", "sparse / dense"]);
    let mut row = |name: &str, a: f64, b: f64| {
        table.row(vec![
            name.to_string(),
            format!("{a:.4e}"),
            format!("{b:.4e}"),
            format!("{:.3}", b / a),
        ]);
    };
    let mut written = Vec::new();
    for folder in [&cli.dense, &cli.sparse] {
        let container = read_container(&folder.join("mbd"), &limits)?;
        let centres: Vec<_> = (0..valid.len()).map(|v| reference.centre_of(v)).collect();
        written.push(relative_mse_at_centres(reference, valid, |v, out| {
            container
                .model
                .eval(centres[v], out)
                .expect("a voxel centre evaluates");
        }));
    }
    row("MBD as written", written[0], written[1]);
    for name in ["cpca", "bpca"] {
        if let (Some(a), Some(b)) = (dense.get(name), sparse.get(name)) {
            let ea =
                relative_mse_at_centres(reference, valid, |v, out| out.copy_from_slice(a.voxel(v)));
            let eb =
                relative_mse_at_centres(reference, valid, |v, out| out.copy_from_slice(b.voxel(v)));
            row(name, ea, eb);
        }
    }
    print!("{}", table.markdown());
    Ok(())
}
