//! `compare bricks-adaptive`: whether adaptive resolution pays: how many bricks of B³ voxels of
//! a bake could be stored at half resolution ((B/2)³ coefficient nodes instead of B³) for a
//! given rise of the error as written, and what the brick layout would then store.
//!
//! ```text
//! prt bake ../shared/scenes/sponza/Sponza.gltf --res 128 --layout sparse --keep-volumes always --out /tmp/sponza128
//! cargo run --release -p prt-benches --bin compare -- bricks-adaptive /tmp/sponza128 --edge 4   # and 8
//! ```
//!
//! Per brick with a valid voxel, over its valid voxels: MBD's squared error as written (the
//! container read back, at the voxel centres) and the squared error of the brick's traced values
//! replaced by the trilinear interpolation of the volume at half resolution (2 × 2 × 2 means of
//! the valid voxels). A half-resolution brick is counted as both errors added. Bricks are
//! coarsened in increasing order of the added error until the total error reaches 1 + t times
//! MBD's; the saving is 7/8 of each coarsened brick's coefficient nodes. The brick layout adds
//! an apron: (B+1)³ texels a full brick, (B/2+1)³ a half one, against B³ a brick dense.

use std::error::Error;
use std::path::PathBuf;

use prt_benches::Table;
use prt_core::{FieldModel, GridField};
use prt_mbd::expert::halved_grid;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Output folder of a `prt bake --keep-volumes always`.
    bake: PathBuf,
    /// Brick edge B in voxels (the sparse bake's is 4).
    #[arg(long, default_value_t = 4)]
    edge: usize,
    /// Rises of the total error to try, relative to MBD's as written.
    #[arg(long, value_delimiter = ',', default_value = "0.02,0.05,0.1,0.25")]
    rises: Vec<f64>,
}

pub fn run(args: &Args) -> Result<(), Box<dyn Error>> {
    let kept = super::kept_volumes(&args.bake)?;
    let field = super::traced(&kept)?;
    let valid = &kept.valid;
    let container = super::container(&args.bake)?;
    let dims = field.dims();
    let d = field.dim();

    // The volume at half resolution, means of the valid voxels.
    let (coarse_dims, coarse_bounds) = halved_grid(dims, field.bounds());
    let mut coarse = GridField::new(coarse_dims, coarse_bounds, d)?;
    let mut counts = vec![0u32; coarse.num_voxels()];
    for v in (0..field.num_voxels()).filter(|&v| valid[v]) {
        let [x, y, z] = field.coords(v);
        let c = coarse.index(x / 2, y / 2, z / 2);
        counts[c] += 1;
        for (o, &f) in coarse.voxel_mut(c).iter_mut().zip(field.voxel(v)) {
            *o += f;
        }
    }
    for (c, &n) in counts.iter().enumerate() {
        if n > 0 {
            coarse.voxel_mut(c).iter_mut().for_each(|x| *x /= n as f32);
        }
    }

    // Per brick: (MBD's squared error, the half-resolution squared error).
    let edge = args.edge.max(2);
    let bricks = dims.map(|n| n.div_ceil(edge));
    let mut errors = vec![(0.0f64, 0.0f64, false); bricks.iter().product()];
    let (mut mbd_total, mut energy) = (0.0f64, 0.0f64);
    let (mut model, mut half) = (vec![0.0f32; d], vec![0.0f32; d]);
    for v in (0..field.num_voxels()).filter(|&v| valid[v]) {
        let [x, y, z] = field.coords(v);
        let b = x / edge + bricks[0] * (y / edge + bricks[1] * (z / edge));
        let centre = field.centre_of(v);
        container.model.eval(centre, &mut model)?;
        coarse.sample(centre, &mut half)?;
        let f = field.voxel(v);
        let sq = |g: &[f32]| -> f64 {
            f.iter()
                .zip(g)
                .map(|(&a, &b)| f64::from(a - b).powi(2))
                .sum()
        };
        let (e_mbd, e_half) = (sq(&model), sq(&half));
        errors[b].0 += e_mbd;
        errors[b].1 += e_half;
        errors[b].2 = true;
        mbd_total += e_mbd;
        energy += f.iter().map(|&a| f64::from(a).powi(2)).sum::<f64>();
    }
    let mut live: Vec<(f64, f64)> = errors
        .iter()
        .filter(|e| e.2)
        .map(|&(m, h, _)| (m, h))
        .collect();
    live.sort_by(|a, b| a.1.total_cmp(&b.1));
    let fraction_below = live.iter().filter(|(m, h)| h <= m).count() as f64 / live.len() as f64;
    println!(
        "{}: {} live bricks of {}; MBD's relative error as written at the valid voxel centres \
         {:.4e}; bricks whose half-resolution error is at most MBD's: {:.1} %",
        args.bake.display(),
        live.len(),
        errors.len(),
        mbd_total / energy,
        100.0 * fraction_below
    );
    let mut table = Table::new(&[
        "error rise allowed",
        "bricks at half resolution",
        "coefficient nodes saved",
        "texels per live brick with aprons (dense B³)",
        "relative error",
    ]);
    let (full, half) = ((edge + 1).pow(3) as f64, (edge / 2 + 1).pow(3) as f64);
    for &rise in &args.rises {
        let budget = mbd_total * (1.0 + rise);
        let (mut total, mut coarsened) = (mbd_total, 0usize);
        for &(_, h) in &live {
            if total + h > budget {
                break;
            }
            total += h;
            coarsened += 1;
        }
        table.row(vec![
            format!("{:.0} %", 100.0 * rise),
            format!(
                "{coarsened} ({:.1} %)",
                100.0 * coarsened as f64 / live.len() as f64
            ),
            format!(
                "{:.1} %",
                100.0 * 7.0 * coarsened as f64 / (8.0 * live.len() as f64)
            ),
            format!(
                "{:.1} ({})",
                (full * (live.len() - coarsened) as f64 + half * coarsened as f64)
                    / live.len() as f64,
                edge.pow(3)
            ),
            format!("{:.4e}", total / energy),
        ]);
    }
    println!("{}", table.markdown());
    Ok(())
}
