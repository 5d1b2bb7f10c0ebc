//! Speed/accuracy trade of the transfer baker: relative error against a high-sample reference
//! versus directions per voxel (and time), and versus surface-cache rays, on the Cornell box.
//!
//! `cargo run --release -p prt-benches --bin trace_error -- --grid 16 [--csv DIR]` (the default)
use std::path::PathBuf;
use std::time::Instant;

use clap::Parser;
use prt_benches::{RelativeError, Table, fmt_duration};
use prt_core::NoProgress;
use prt_trace::expert::block;
use prt_trace::{BakeOptions, Scene, TransferBaker, TransferVolume};

fn bake(scene: &Scene, options: BakeOptions) -> (TransferVolume, std::time::Duration) {
    let t = Instant::now();
    let v = TransferBaker::new(scene, options)
        .and_then(|b| b.bake(&NoProgress))
        .expect("Cornell bakes");
    (v, t.elapsed())
}

/// Relative Frobenius error `‖x - ref‖ / ‖ref‖` over voxels valid in both, for the direct block
/// and the three indirect blocks.
fn rel_error(x: &TransferVolume, reference: &TransferVolume) -> (f64, f64) {
    let (mut direct, mut indirect) = (RelativeError::default(), RelativeError::default());
    for v in 0..x.field.num_voxels() {
        if !(x.valid[v] && reference.valid[v]) {
            continue;
        }
        let (a, b) = (x.field.voxel(v), reference.field.voxel(v));
        let split = block(0).end;
        direct.add(&a[..split], &b[..split]);
        indirect.add(&a[split..], &b[split..]);
    }
    (direct.relative_rms(), indirect.relative_rms())
}

#[derive(Debug, Parser)]
#[command(about = "Transfer baker error against a 4096-ray reference vs rays and cache rays")]
struct Cli {
    /// Voxels along each axis of the Cornell box volume.
    #[arg(long, default_value_t = 16)]
    grid: usize,
    /// Folder for the tables as CSV (trace_error_rays.csv, trace_error_cache.csv).
    #[arg(long)]
    csv: Option<PathBuf>,
}

fn main() {
    let cli = Cli::parse();
    let res = cli.grid;
    let scene = Scene::cornell_box();
    let base = BakeOptions {
        resolution: [res; 3],
        ..Default::default()
    };
    let (reference, t_ref) = bake(
        &scene,
        BakeOptions {
            rays_per_voxel: 4096,
            cache_rays: 512,
            seed: 1000,
            ..base.clone()
        },
    );
    eprintln!(
        "reference: {res}³, 4104 rays/voxel, 512 cache rays, {}",
        fmt_duration(t_ref)
    );

    let mut table = Table::new(&[
        "rays/voxel",
        "time",
        "direct rel. error",
        "indirect rel. error",
        "Mrays/s",
    ]);
    for rays in [12, 24, 48, 96, 192, 384, 768, 1536] {
        let (v, t) = bake(
            &scene,
            BakeOptions {
                rays_per_voxel: rays,
                seed: 1,
                ..base.clone()
            },
        );
        let (ed, ei) = rel_error(&v, &reference);
        table.row(vec![
            v.stats.rays_per_voxel.to_string(),
            fmt_duration(t),
            format!("{ed:.4}"),
            format!("{ei:.4}"),
            format!("{:.2}", v.stats.mrays_per_second()),
        ]);
    }
    println!("Cornell box {res}³, cache rays 64 (default), reference seed differs\n");
    println!("{}", table.markdown());
    if let Err(e) = table.write_csv(cli.csv.as_deref(), "trace_error_rays") {
        eprintln!("could not write the CSV: {e}");
    }

    let mut table = Table::new(&[
        "cache rays",
        "cache sides evaluated",
        "total time",
        "indirect rel. error",
    ]);
    for cache_rays in [8, 16, 32, 64, 128, 256] {
        let (v, t) = bake(
            &scene,
            BakeOptions {
                rays_per_voxel: 768,
                cache_rays,
                seed: 1,
                ..base.clone()
            },
        );
        let (_, ei) = rel_error(&v, &reference);
        table.row(vec![
            cache_rays.to_string(),
            v.stats.cache_evaluated.to_string(),
            fmt_duration(t),
            format!("{ei:.4}"),
        ]);
    }
    println!("Cornell box {res}³, 768 rays per voxel\n");
    println!("{}", table.markdown());
    if let Err(e) = table.write_csv(cli.csv.as_deref(), "trace_error_cache") {
        eprintln!("could not write the CSV: {e}");
    }
}
