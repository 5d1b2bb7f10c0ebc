//! The filterable MBD layout as written: bytes per voxel and error of the lit target
//! (incident radiance SH9 RGB under the default sky) and of the raw 324-D transfer, against
//! BPCA and CPCA at equal storage; and the time of the lighting pass per sky change.
//!
//! ```text
//! cargo run --release -p prt-benches --bin mbd_filterable -- --scene cornell --res 32
//! cargo run --release -p prt-benches --bin mbd_filterable -- --scene sponza --res 64
//! ```
//!
//! The traced volume is `prt bake`'s (256 rays, 64 cache rays, seed 0), cached in
//! `target/mbd_cache/`. MBD is fitted as `prt bake` fits it (5 basis nodes per axis, λ 1e-4,
//! 64 iterations), written with `prt_bake::container::write_container` in each encoding and read back
//! with `read_container` (the layout's own decode). Errors are relative squared errors
//! `Σ‖f̂ − f‖² / Σ‖f‖²` over every voxel centre, `f` the traced volume (raw) or its lit SH9
//! (lit, with `prt_trace::lit::incident_radiance`); MBD's lit value is `prt_bake::light_basis::light_basis` then
//! the lit model, the renderer's path. BPCA and CPCA have the same number of bases (one per
//! basis node) and rank, so the same scalars; their bytes are counted at the encoding's bytes
//! per scalar (plus one byte per voxel of CPCA labels), not written. The lighting pass is
//! timed on one thread (median of `--reps`).

use std::path::PathBuf;
use std::time::Duration;

use clap::Parser;
use prt_bake::container::ContainerContents;
use prt_bake::container::{read_container, write_container};
use prt_bake::light_basis::{LightBasisConfig, light_basis};
use prt_benches::mbd::traced_field;
use prt_benches::{RelativeError, Table, cache_dir, fmt_duration, median_time};
use prt_core::{Compressor, FieldModel, GridField, NoProgress};
use prt_kernels::HatGrid;
use prt_mbd::{Basis, BasisKernels, BlockPca, ClusteredPca, Mbd, MbdModel, SolverOptions};
use prt_sphere::Sky;
use prt_texture::{Encoding, Limits};

#[derive(Debug, Parser)]
#[command(
    about = "The filterable MBD layout as written: bytes per voxel, lit and raw error against BPCA / CPCA, lighting time"
)]
struct Cli {
    /// Scene: `cornell` or `town` (built in) or `sponza` (../shared/scenes/sponza).
    #[arg(long, default_value = "cornell")]
    scene: String,
    /// Voxels along the longest axis.
    #[arg(long, default_value_t = 32)]
    res: usize,
    /// MBD ranks L.
    #[arg(long, value_delimiter = ',', default_value = "3,8")]
    ranks: Vec<usize>,
    /// Basis nodes (BPCA blocks) per axis; CPCA gets as many clusters as nodes in all.
    #[arg(long, default_value_t = 5)]
    nodes: usize,
    /// Encodings to write (f32, f16, unorm16, unorm8).
    #[arg(long, value_delimiter = ',', default_value = "f16,unorm16,unorm8")]
    encodings: Vec<String>,
    /// Repetitions of the timed lighting pass.
    #[arg(long, default_value_t = 200)]
    reps: usize,
    /// Also write the tables as CSV into this folder.
    #[arg(long)]
    csv: Option<PathBuf>,
}

fn parse_encoding(name: &str) -> Encoding {
    match name.trim() {
        "f32" => Encoding::F32,
        "f16" => Encoding::F16,
        "unorm16" => Encoding::Unorm16,
        "unorm8" => Encoding::Unorm8,
        other => panic!("unknown encoding {other} (f32, f16, unorm16, unorm8)"),
    }
}

fn bytes_per_scalar(encoding: Encoding) -> f64 {
    match encoding {
        Encoding::F32 => 4.0,
        Encoding::F16 | Encoding::Unorm16 | Encoding::Snorm16 => 2.0,
        _ => 1.0,
    }
}

/// Relative squared errors `(raw, lit)` against the field over its voxels: `raw(v, out)` gives
/// a method's 324-D value at voxel `v`, `light(v, raw value, out)` its lit SH9 RGB.
fn errors(
    field: &GridField,
    sky: &Sky,
    mut raw: impl FnMut(usize, &mut [f32]),
    mut light: impl FnMut(usize, &[f32], &mut [f32; 27]),
) -> (f64, f64) {
    let (mut raw_sum, mut lit_sum) = (RelativeError::default(), RelativeError::default());
    let mut values = vec![0.0f32; field.dim()];
    let mut lit = [0.0f32; 27];
    for v in 0..field.num_voxels() {
        let reference = field.voxel(v);
        raw(v, &mut values);
        raw_sum.add(&values, reference);
        light(v, &values, &mut lit);
        let target = prt_trace::lit::incident_radiance(reference, sky);
        lit_sum.add(&lit, target.as_flattened());
    }
    (raw_sum.relative_mse(), lit_sum.relative_mse())
}

/// The lit value of a 324-D vector.
fn lit_of(values: &[f32], sky: &Sky, out: &mut [f32; 27]) {
    out.copy_from_slice(prt_trace::lit::incident_radiance(values, sky).as_flattened());
}

fn fit_mbd(field: &GridField, rank: usize, nodes: [usize; 3]) -> MbdModel<HatGrid, HatGrid> {
    let defaults = prt_bake::BakeConfig::default();
    let mbd = Mbd {
        solver: SolverOptions {
            lambda: defaults.lambda,
            max_iterations: defaults.max_iterations,
            ..SolverOptions::default()
        },
        ..Mbd::new(rank, Basis::HatGrid { nodes })
    };
    let fit = mbd.fit(field, &NoProgress).expect("MBD fit");
    let (c, b, coefficients, basis) = fit.model.into_parts();
    let BasisKernels::HatGrid(b) = b else {
        unreachable!("a hat-grid basis was asked for")
    };
    MbdModel::new(c, b, coefficients, basis).expect("model")
}

fn main() {
    let cli = Cli::parse();
    let field = traced_field(&cli.scene, cli.res);
    let dims = field.dims();
    let voxels = field.num_voxels();
    let nodes = [0, 1, 2].map(|k| cli.nodes.min(dims[k].max(2)));
    let sky = Sky::default();
    let encodings: Vec<Encoding> = cli.encodings.iter().map(|e| parse_encoding(e)).collect();
    println!(
        "{} {dims:?} ({voxels} voxels), basis grid {nodes:?}, default sky\n",
        cli.scene
    );
    let mut table = Table::new(&[
        "rank",
        "method",
        "bytes/voxel",
        "lit rel. sq. error",
        "raw 324-D rel. sq. error",
    ]);
    let mut timing = Table::new(&["rank", "basis nodes × rank", "lighting pass (1 thread)"]);
    let valid = vec![true; voxels];
    for &rank in &cli.ranks {
        eprintln!("rank {rank}: fitting MBD, BPCA, CPCA");
        let model = fit_mbd(&field, rank, nodes);
        let mut eval = |m: &MbdModel<HatGrid, HatGrid>, name: String, bytes: Option<f64>| {
            let lit_model = light_basis(
                m,
                &LightBasisConfig {
                    sky,
                    ..LightBasisConfig::default()
                },
            )
            .expect("light")
            .model(m)
            .expect("lit model");
            let (raw, lit) = errors(
                &field,
                &sky,
                |v, out| m.eval(field.centre_of(v), out).expect("eval"),
                |v, _, out| lit_model.eval(field.centre_of(v), out).expect("lit eval"),
            );
            table.row(vec![
                rank.to_string(),
                name,
                bytes.map_or("–".into(), |b| format!("{b:.2}")),
                format!("{lit:.3e}"),
                format!("{raw:.3e}"),
            ]);
        };
        eval(&model, "MBD in memory (f32)".into(), None);
        for &encoding in &encodings {
            let folder = cache_dir("mbd_filterable")
                .join(format!("{}_{}_l{rank}_{encoding:?}", cli.scene, cli.res));
            let report = write_container(
                &folder,
                &ContainerContents {
                    model: &model,
                    grid: dims,
                    valid: &valid,
                    scene: &cli.scene,
                    lambda: prt_bake::BakeConfig::default().lambda,
                    encoding,
                },
            )
            .expect("write");
            let written = read_container(&folder, &Limits::default())
                .expect("read back")
                .model;
            eval(
                &written,
                format!("MBD filterable, as written ({encoding:?})"),
                Some(report.bytes_per_voxel(voxels as u64)),
            );
        }
        let blocks = BlockPca {
            rank,
            blocks: nodes,
            window: 1.0,
            loss_weighting: None,
        }
        .compress(&field, &NoProgress)
        .expect("BPCA");
        let clusters = ClusteredPca::new(rank, nodes.iter().product())
            .compress(&field, &NoProgress)
            .expect("CPCA");
        for (name, baseline, label_bytes) in [("BPCA", &blocks, 0.0), ("CPCA", &clusters, 1.0)] {
            let recon = baseline.reconstruct().expect("reconstruction");
            let (raw, lit) = errors(
                &field,
                &sky,
                |v, out| out.copy_from_slice(recon.voxel(v)),
                |_, values, out| lit_of(values, &sky, out),
            );
            let scalars = baseline.stored_scalars() as f64 / voxels as f64;
            let bytes: Vec<String> = encodings
                .iter()
                .map(|&e| format!("{:.2}", scalars * bytes_per_scalar(e) + label_bytes))
                .collect();
            table.row(vec![
                rank.to_string(),
                format!("{name} (counted at {})", cli.encodings.join(" / ")),
                bytes.join(" / "),
                format!("{lit:.3e}"),
                format!("{raw:.3e}"),
            ]);
        }

        let config = LightBasisConfig {
            sky,
            ..LightBasisConfig::default()
        };
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .expect("one thread");
        let time: Duration =
            pool.install(|| median_time(cli.reps, || light_basis(&model, &config).expect("light")));
        timing.row(vec![
            rank.to_string(),
            format!("{} × {rank}", nodes.iter().product::<usize>()),
            fmt_duration(time),
        ]);
    }
    println!("{}", table.markdown());
    println!("{}", timing.markdown());
    if let Some(dir) = &cli.csv {
        let _ = table.write_csv(Some(dir), &format!("mbd_filterable_{}", cli.scene));
        let _ = timing.write_csv(Some(dir), &format!("mbd_filterable_{}_light", cli.scene));
    }
}
