//! The production configuration of Moving Basis Decomposition (Silvennoinen & Sloan 2021,
//! §5.1) on an outdoor scene: rank-3 hybrid MBD (basis on a 2D grid over the terrain,
//! coefficients in a 3D volume) of linear-SH irradiance (L1 RGB, 12-D) lit by a sky, written
//! as 8-bit textures at node resolution and read back; against BPCA, CPCA and k-means VQ near
//! the same storage, MBD at rank 8 and MBD with a full 3D hat basis.
//!
//! ```text
//! cargo run --release -p prt-benches --bin mbd_production
//! cargo run --release -p prt-benches --bin mbd_production -- --scene gas_station --n 96
//! ```
//!
//! The target: the scene's transfer volume (`--rays` directions and `--cache-rays` per voxel,
//! seed 0; cached in target/mbd_cache/) lit by `--sky` (`sun`: prt's default sky plus a sun, or
//! `default`), as irradiance L1 SH (`prt_bake::production::irradiance_l1`); invalid voxels (under the
//! terrain, inside buildings) filled from their valid neighbours before every fit
//! (`prt_bake::production::fill_invalid`). Errors are relative MSE `Σ‖f̂ − f‖² / Σ‖f‖²` at the centres of
//! the valid voxels against the traced target, in f32 and as written at 8 bits (unorm with
//! per-channel scale and bias): MBD hybrid rows through `prt_bake::production::write_production` and
//! `read_production`; the other rows quantised in memory with the same encoding. Bytes per
//! voxel count texel payloads (coefficients padded to RGBA texels for MBD, one byte per
//! coefficient and label for the baselines) and, for the rows written, every file.
//!
//! Rows (`--rows`, default all): `prod` (the production configuration of
//! `ProductionConfig::for_grid`: rank 3, coefficients at half resolution in x and z, basis every
//! 8 voxels), `coarse-y` (coefficients also halved along y), `full` (coefficients at voxel
//! resolution), `basis-9` / `basis-33` (basis grid every 16 / 4 voxels), `rank8`, `hat3d`
//! (rank 3 with a 3D hat basis of 3 nodes along y), `bpca1`, `bpca3` (blocks of 8 × 8 columns ×
//! half the height), `cpca1`, `cpca3` (256 clusters, so one byte of label), `vq` (256
//! codewords).

use std::path::PathBuf;
use std::time::Instant;

use clap::Parser;
use prt_bake::production::{
    ProductionConfig, ProductionContents, ProductionModel, fill_invalid, fit_production,
    irradiance_l1, read_production, texel_bytes, write_production,
};
use prt_benches::mbd::{read_cached, write_cached};
use prt_benches::{
    Stopwatch, Table, cache_dir, load_average, load_scene, model_error_at_centres,
    relative_mse_at_centres,
};
use prt_core::{Aabb, Compressor, GridField, NoProgress, SpatialKernels, glam::Vec3};
use prt_kernels::HatGrid;
use prt_mbd::{BlockPca, ClusteredPca, KMeansVq, MbdModel, PiecewisePcaModel, SolverOptions};
use prt_sphere::Sky;
use prt_texture::{Encoding, Limits, dequantize, quantize};
use prt_trace::sh::sh9;
use prt_trace::{BakeOptions, Scene, TransferBaker};

#[derive(Debug, Parser)]
#[command(
    about = "Rank-3 hybrid MBD of L1 irradiance on an outdoor scene, written at 8 bits, \
                   against BPCA / CPCA / VQ near the same storage"
)]
struct Cli {
    /// `town` (prt-trace's built-in outdoor town, 128 × 16 × 128 voxels of 1 m over
    /// [-64, -1, -64]–[64, 15, 64]) or `gas_station` (../shared/scenes, `--n` voxels along its
    /// longest axis over its bounds).
    #[arg(long, default_value = "town")]
    scene: String,
    /// Voxels along the longest axis (gas_station only).
    #[arg(long, default_value_t = 128)]
    n: usize,
    /// Directions per voxel of the trace.
    #[arg(long, default_value_t = 264)]
    rays: usize,
    /// Cosine rays per surface-cache point of the trace.
    #[arg(long, default_value_t = 64)]
    cache_rays: usize,
    /// `sun` (prt's default sky plus a sun towards (0.5, 0.7, 0.3), irradiance (6, 5.7, 5.1)
    /// on a surface facing it) or `default` (prt's default sky).
    #[arg(long, default_value = "sun")]
    sky: String,
    /// Rows to run (see the binary's documentation); empty: all.
    #[arg(long, value_delimiter = ',')]
    rows: Vec<String>,
    /// Coefficient nodes x,y,z of the production row [default: `ProductionConfig::for_grid`].
    #[arg(long, value_delimiter = ',')]
    coefficients: Option<Vec<usize>>,
    /// Basis nodes x,z of the production row [default: `ProductionConfig::for_grid`].
    #[arg(long, value_delimiter = ',')]
    basis: Option<Vec<usize>>,
    /// Solver iteration cap of every MBD row.
    #[arg(long, default_value_t = 128)]
    iterations: usize,
    /// Where the production container is written (default: a folder under target/).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Also write the table as CSV into this folder.
    #[arg(long)]
    csv: Option<PathBuf>,
}

/// The sky of `--sky`.
fn sky(name: &str) -> Sky {
    let mut sky = Sky::default();
    match name {
        "default" => {}
        "sun" => {
            // A sun as a direction delta of irradiance E: its SH coefficients are E · Y_j(ω).
            let direction = Vec3::new(0.5, 0.7, 0.3).normalize();
            let y = sh9(direction);
            for (c, e) in [6.0f32, 5.7, 5.1].into_iter().enumerate() {
                for (s, yj) in sky.sh[c].iter_mut().zip(y) {
                    *s += e * yj;
                }
            }
        }
        other => {
            eprintln!("unknown --sky {other} (sun or default)");
            std::process::exit(2);
        }
    }
    sky
}

/// The scene, its grid box and voxel counts.
fn scene_and_grid(cli: &Cli) -> (Scene, Aabb, [usize; 3]) {
    match cli.scene.as_str() {
        "town" => (
            Scene::outdoor_town(),
            Aabb::new(Vec3::new(-64.0, -1.0, -64.0), Vec3::new(64.0, 15.0, 64.0)),
            [128, 16, 128],
        ),
        name => {
            let scene = load_scene(name).unwrap_or_else(|e| {
                eprintln!("{e}");
                std::process::exit(2);
            });
            let bounds = scene.bounds().unwrap_or_else(|| {
                eprintln!("{name} has no triangles");
                std::process::exit(2);
            });
            let size = bounds.size().to_array();
            let longest = size.iter().copied().fold(0.0f32, f32::max);
            let dims = size.map(|s| ((s / longest * cli.n as f32).round() as usize).max(2));
            (scene, bounds, dims)
        }
    }
}

/// The traced irradiance target (zeros in invalid voxels), read from the cache when an earlier
/// run wrote it.
fn traced_target(cli: &Cli, sky: &Sky) -> GridField {
    let (scene, bounds, dims) = scene_and_grid(cli);
    let [x, y, z] = dims;
    let path = cache_dir("mbd_cache").join(format!(
        "production_{}_{x}x{y}x{z}_r{}_c{}_{}.f32",
        cli.scene, cli.rays, cli.cache_rays, cli.sky
    ));
    if let Some(field) = read_cached(&path) {
        eprintln!("read {}", path.display());
        return field;
    }
    let options = BakeOptions {
        resolution: dims,
        bounds: Some(bounds),
        margin: bounds.size().max_element(),
        rays_per_voxel: cli.rays,
        cache_rays: cli.cache_rays,
        ..BakeOptions::default()
    };
    let start = Instant::now();
    let volume = TransferBaker::new(&scene, options)
        .and_then(|baker| baker.bake(&NoProgress))
        .expect("bake");
    println!(
        "traced {} {dims:?} ({} triangles, bounds {:?}–{:?}) in {:.1} s, {:.1} % of voxels valid",
        cli.scene,
        scene.triangles().len(),
        bounds.min.to_array(),
        bounds.max.to_array(),
        start.elapsed().as_secs_f64(),
        100.0 * volume.stats.valid_fraction()
    );
    let target = irradiance_l1(&volume.field, sky).expect("irradiance");
    if let Err(e) = write_cached(&path, &target) {
        eprintln!("cannot cache {}: {e}", path.display());
    }
    target
}

/// `values` (`channels` per row) through 8-bit unorm with per-channel scale and bias.
fn as_unorm8(values: &[f32], channels: usize) -> Vec<f32> {
    let q = quantize(values, channels, Encoding::Unorm8).expect("quantise");
    dequantize(&q).expect("dequantise")
}

/// One row of the table.
struct Row {
    config: String,
    texel_bytes_per_voxel: f64,
    file_bytes_per_voxel: Option<f64>,
    error: f64,
    error_8bit: f64,
    /// Wall and process CPU seconds of the fit.
    seconds: (f64, f64),
    note: String,
}

fn enabled(cli: &Cli, key: &str) -> bool {
    cli.rows.is_empty() || cli.rows.iter().any(|r| r.eq_ignore_ascii_case(key))
}

/// Evaluates an MBD model at voxel `v`'s centre.
fn main() {
    let cli = Cli::parse();
    let sky = sky(&cli.sky);
    println!(
        "mbd_production: scene {}, sky {}, {} threads, load average {}",
        cli.scene,
        cli.sky,
        rayon::current_num_threads(),
        load_average()
    );
    let raw = traced_target(&cli, &sky);
    let valid = prt_mbd::expert::nonzero_voxels(&raw);
    let voxels = raw.num_voxels();
    let valid_count = valid.iter().filter(|v| **v).count();
    let target = fill_invalid(&raw, &valid).expect("fill");
    let dims = target.dims();
    println!(
        "target: {dims:?} voxels × 12 (L1 irradiance RGB), {valid_count} valid ({:.1} %); f32 \
         storage 48 B/voxel",
        100.0 * valid_count as f64 / voxels as f64
    );
    let solver = SolverOptions {
        max_iterations: cli.iterations,
        ..SolverOptions::default()
    };
    let mut production = ProductionConfig {
        solver,
        ..ProductionConfig::for_grid(dims)
    };
    if let Some(&[x, y, z]) = cli.coefficients.as_deref() {
        production.coefficient_nodes = [x, y, z];
    }
    if let Some(&[x, z]) = cli.basis.as_deref() {
        production.basis_nodes = [x, z];
    }
    let out = cli
        .out
        .clone()
        .unwrap_or_else(|| cache_dir("mbd_production").join(&cli.scene));
    let mut rows = Vec::new();

    // Hybrid MBD rows: (key, name, config), each fitted, written, read back.
    let half_y = ProductionConfig {
        coefficient_nodes: [
            production.coefficient_nodes[0],
            dims[1].div_ceil(2).max(2),
            production.coefficient_nodes[2],
        ],
        ..production.clone()
    };
    let full = ProductionConfig {
        coefficient_nodes: dims,
        ..production.clone()
    };
    let basis_every = |step: usize| ProductionConfig {
        basis_nodes: [dims[0], dims[2]].map(|n| (n - 1) / step + 2),
        ..production.clone()
    };
    let rank8 = ProductionConfig {
        rank: 8,
        ..production.clone()
    };
    let hybrid = [
        ("prod", "production", production.clone()),
        ("coarse-y", "coefficients halved along y too", half_y),
        ("full", "coefficients at voxel resolution", full),
        ("basis-9", "basis every 16 voxels", basis_every(16)),
        ("basis-33", "basis every 4 voxels", basis_every(4)),
        ("rank8", "rank 8", rank8),
    ];
    for (key, name, config) in hybrid {
        if !enabled(&cli, key) {
            continue;
        }
        let watch = Stopwatch::start();
        let fit = fit_production(&target, &config, &NoProgress).expect("fit");
        let seconds = (watch.wall().as_secs_f64(), watch.cpu());
        let error = model_error_at_centres(&fit.model, &raw, &valid).expect("eval");
        let folder = out.join(key);
        let contents = ProductionContents {
            model: &fit.model,
            grid: dims,
            scene: &cli.scene,
            sky: &sky,
            encoding: Encoding::Unorm8,
        };
        let report = write_production(&folder, &contents).expect("write");
        let back = read_production(&folder, &Limits::default()).expect("read back");
        let written: &ProductionModel = &back.model;
        let error_8bit = model_error_at_centres(written, &raw, &valid).expect("eval");
        let [cx, cy, cz] = config.coefficient_nodes;
        let [bx, bz] = config.basis_nodes;
        rows.push(Row {
            config: format!(
                "MBD hybrid rank {}, {name}: coefficients {cx}×{cy}×{cz}, basis {bx}×{bz}",
                config.rank
            ),
            texel_bytes_per_voxel: texel_bytes(&back.manifest) as f64 / voxels as f64,
            file_bytes_per_voxel: Some(report.bytes_per_voxel(voxels as u64)),
            error,
            error_8bit,
            seconds,
            note: format!(
                "{} iterations{}",
                fit.report.history.len(),
                if key == "prod" {
                    format!(", written to {}", folder.display())
                } else {
                    String::new()
                }
            ),
        });
        print_row(rows.last());
    }

    if enabled(&cli, "hat3d") {
        // The same coefficients with a full 3D hat basis (3 nodes along y) for contrast.
        let (coefficients, _) =
            prt_bake::production::production_kernels(&target, &production).expect("kernels");
        let [bx, bz] = production.basis_nodes;
        let basis = HatGrid::new([bx, 3, bz], coefficients.domain()).expect("basis");
        let watch = Stopwatch::start();
        let (model, report) = prt_mbd::expert::solve(
            &target,
            coefficients,
            basis,
            production.rank,
            &production.solver,
            &NoProgress,
        )
        .expect("fit");
        let seconds = (watch.wall().as_secs_f64(), watch.cpu());
        let error = model_error_at_centres(&model, &raw, &valid).expect("eval");
        let rank = production.rank;
        let (c, b) = (model.coefficients(), model.basis());
        let padded = rank.div_ceil(4) * 4;
        let mut coefficient_texels = vec![0.0f32; c.nrows() * padded];
        for (texel, row) in coefficient_texels.chunks_exact_mut(padded).zip(c.rows()) {
            texel[..rank].iter_mut().zip(row).for_each(|(t, &x)| *t = x);
        }
        let c8: Vec<f32> = as_unorm8(&coefficient_texels, padded)
            .chunks_exact(padded)
            .flat_map(|t| t[..rank].to_vec())
            .collect();
        let b8 = as_unorm8(b.as_slice().expect("standard layout"), rank * 12);
        let quantised = MbdModel::new(
            model.coefficient_kernels().clone(),
            model.basis_kernels().clone(),
            ndarray::Array2::from_shape_vec(c.dim(), c8).expect("shape"),
            ndarray::Array3::from_shape_vec(b.dim(), b8).expect("shape"),
        )
        .expect("model");
        let error_8bit = model_error_at_centres(&quantised, &raw, &valid).expect("eval");
        let bytes = c.nrows() * padded + b.len();
        rows.push(Row {
            config: format!(
                "MBD rank {rank}, 3D hat basis {bx}×3×{bz}, coefficients as production"
            ),
            texel_bytes_per_voxel: bytes as f64 / voxels as f64,
            file_bytes_per_voxel: None,
            error,
            error_8bit,
            seconds,
            note: format!("{} iterations", report.history.len()),
        });
        print_row(rows.last());
    }

    // Baselines, near the same storage: blocks of 8 × 8 columns × half the height; 256
    // clusters (one byte of label); 256 codewords.
    let blocks = [dims[0].div_ceil(8), 2, dims[2].div_ceil(8)];
    let [kx, ky, kz] = blocks;
    let baseline = |key: &str| -> (String, PiecewisePcaModel) {
        let rank = if key.ends_with('3') { 3 } else { 1 };
        match key {
            "bpca1" | "bpca3" => (
                format!("BPCA rank {rank}, {kx}×{ky}×{kz} blocks"),
                BlockPca {
                    rank,
                    blocks,
                    window: 1.0,
                    loss_weighting: None,
                }
                .compress(&target, &NoProgress)
                .expect("BPCA"),
            ),
            "cpca1" | "cpca3" => (
                format!("CPCA rank {rank}, 256 clusters"),
                ClusteredPca::new(rank, 256)
                    .compress(&target, &NoProgress)
                    .expect("CPCA"),
            ),
            _ => (
                "k-means VQ, 256 codewords (CPCA rank 0)".into(),
                KMeansVq {
                    codewords: 256,
                    iterations: 32,
                    seed: 0,
                }
                .compress(&target, &NoProgress)
                .expect("VQ"),
            ),
        }
    };
    for key in ["bpca1", "bpca3", "cpca1", "cpca3", "vq"] {
        if !enabled(&cli, key) {
            continue;
        }
        let watch = Stopwatch::start();
        let (config, model) = baseline(key);
        let seconds = (watch.wall().as_secs_f64(), watch.cpu());
        let reconstruction = model.reconstruct().expect("reconstruction");
        let error = relative_mse_at_centres(&raw, &valid, |v, out| {
            out.copy_from_slice(reconstruction.voxel(v))
        });
        let (bases, coefficients, labels) = (model.bases(), model.coefficients(), model.labels());
        let (clusters, rank, d) = bases.dim();
        let is_vq = key == "vq";
        let b8 = as_unorm8(bases.as_slice().expect("standard layout"), rank * d);
        // VQ stores no coefficients (they are all 1).
        let c8 = if is_vq {
            coefficients.iter().copied().collect()
        } else {
            as_unorm8(coefficients.as_slice().expect("standard layout"), rank)
        };
        let error_8bit = relative_mse_at_centres(&raw, &valid, |v, out| {
            out.fill(0.0);
            let basis = &b8[labels[v] as usize * rank * d..][..rank * d];
            for (l, &c) in c8[v * rank..(v + 1) * rank].iter().enumerate() {
                for (o, &b) in out.iter_mut().zip(&basis[l * d..(l + 1) * d]) {
                    *o += c * b;
                }
            }
        });
        let label_bytes = if key.starts_with("bpca") {
            0 // the block is implied by the position
        } else if clusters <= 256 {
            1
        } else {
            2
        };
        let coefficient_bytes = if is_vq { 0 } else { rank };
        let bytes = voxels * (label_bytes + coefficient_bytes) + bases.len();
        rows.push(Row {
            config,
            texel_bytes_per_voxel: bytes as f64 / voxels as f64,
            file_bytes_per_voxel: None,
            error,
            error_8bit,
            seconds,
            note: String::new(),
        });
        print_row(rows.last());
    }

    let mut table = Table::new(&[
        "configuration",
        "bytes/voxel (texels)",
        "bytes/voxel (files)",
        "compression vs 48 B f32",
        "rel. MSE f32",
        "rel. MSE 8-bit (as written)",
        "fit wall / CPU",
        "note",
    ]);
    for row in &rows {
        table.row(vec![
            row.config.clone(),
            format!("{:.3}", row.texel_bytes_per_voxel),
            row.file_bytes_per_voxel
                .map_or("–".into(), |b| format!("{b:.3}")),
            format!(
                "{:.1}:1",
                48.0 / row
                    .file_bytes_per_voxel
                    .unwrap_or(row.texel_bytes_per_voxel)
            ),
            format!("{:.3e}", row.error),
            format!("{:.3e}", row.error_8bit),
            format!("{:.1} s / {:.1} s", row.seconds.0, row.seconds.1),
            row.note.clone(),
        ]);
    }
    println!("\n{}", table.markdown());
    if let Err(e) = table.write_csv(cli.csv.as_deref(), &format!("mbd_production_{}", cli.scene)) {
        eprintln!("cannot write the CSV: {e}");
    }
}

fn print_row(row: Option<&Row>) {
    if let Some(r) = row {
        eprintln!(
            "{}: {:.3} B/voxel, rel. MSE {:.3e} (8-bit {:.3e}), {:.1} s (CPU {:.1} s)",
            r.config, r.texel_bytes_per_voxel, r.error, r.error_8bit, r.seconds.0, r.seconds.1
        );
    }
}
