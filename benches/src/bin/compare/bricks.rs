//! `compare bricks`: a sparse-brick bake against a dense one of the same scene and seed: voxels,
//! validity, and each method's error against the dense bake's traced volume over its valid
//! voxels.
//!
//! ```text
//! prt bake ../shared/scenes/sponza/Sponza.gltf --res 128 --layout dense --keep-volumes always --out /tmp/bricks/dense128
//! prt bake ../shared/scenes/sponza/Sponza.gltf --res 128 --layout sparse --keep-volumes always --out /tmp/bricks/sparse128
//! cargo run --release -p prt-benches --bin compare -- bricks --dense /tmp/bricks/dense128 --sparse /tmp/bricks/sparse128
//! ```
//!
//! Both bakes keep their volumes (`--keep-volumes always`, f16). The error of a method is
//! `Σ‖f̂ − f‖² / Σ‖f‖²` over the dense bake's valid voxel centres, `f` its traced volume: MBD as
//! written (each bake's container read back) and CPCA (each bake's kept reconstruction). The
//! traced volumes are compared bit for bit (f16) on those voxels. The voxels bricks of 2, 4, 8
//! and 16 voxels would store are counted from the dense bake's validity.
use std::error::Error;
use std::path::PathBuf;

use prt_benches::{Table, model_error_at_centres, relative_mse_at_centres};
use prt_trace::bricks::BrickMap;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Output folder of the dense `prt bake` (with kept volumes).
    #[arg(long)]
    dense: PathBuf,
    /// Output folder of the sparse `prt bake` (with kept volumes).
    #[arg(long)]
    sparse: PathBuf,
}

pub fn run(args: &Args) -> Result<(), Box<dyn Error>> {
    let dense = super::kept_volumes(&args.dense)?;
    let sparse = super::kept_volumes(&args.sparse)?;
    if dense.grid != sparse.grid {
        return Err(format!("grids differ: {:?} vs {:?}", dense.grid, sparse.grid).into());
    }
    let reference = super::traced(&dense)?;
    let sparse_reference = super::traced(&sparse)?;
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
    for folder in [&args.dense, &args.sparse] {
        let container = super::container(folder)?;
        written.push(model_error_at_centres(&container.model, reference, valid)?);
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
