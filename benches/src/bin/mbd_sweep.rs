//! Moving Basis Decomposition against the PCA family on 324-D fields: error vs basis count
//! (paper Figure 5), vs basis-grid resolution (Figure 7), solve times (Figure 8), and the
//! solvers' convergence (error vs iterations and time).
//!
//! `cargo run --release -p prt-benches --bin mbd_sweep -- <basis|grid|timing|convergence|quality|ridge|floor|walls|adaptive|polish|all>`
//!
//! Environment knobs (so that each run stays a few minutes on a shared machine):
//! * `MBD_FIELD=synthetic|cornell|sponza`: the synthetic manifold field (default), the built-in
//!   Cornell box or Sponza (`../shared/scenes/sponza/Sponza.gltf`) traced by prt-trace at
//!   `prt bake`'s defaults (256 rays, 64 cache rays, seed 0), cached under `target/mbd_cache/`
//!   so that reruns skip the trace. Voxels the baker marks invalid (inside geometry; their
//!   transfer is exactly zero) are left out of the seam metric.
//! * `MBD_N`: the field's resolution (longest axis for Cornell; default 32).
//! * `MBD_KNOBS=2,4`: only these ranks (basis sweep) / basis nodes per axis (grid sweep).
//! * `MBD_METHODS=MBD,BPCA`: only these methods (MBD, PCA, BPCA, WBPCA, CPCA, VQ).
//! * `PRT_CSV_DIR=dir`: also write each table as CSV; `mbd_sweep plot TABLE.csv OUT.png TITLE
//!   X_LABEL` then draws relative MSE against the knob, one line per method (log scale).
//!
//! Every row reports wall time and the process CPU time (user + system) of the method; the
//! load average is printed before and after each sweep. The seam columns come from
//! `seam_metric_with(field, reconstruction, labels, SeamOptions { denoise_sigma, valid })`,
//! with the reference blurred by a Gaussian of one voxel on traced volumes (so that their Monte
//! Carlo noise does not drown the seams) and not at all on the noise-free synthetic field:
//! "seam excess" = `excess()`, the RMS step of the error at cluster / basis-cell boundaries
//! beyond the jumps between neighbours inside them, relative to the field's RMS (0 when the
//! boundaries cannot be told from the inside); "seam ratio" = `ratio()`, boundary over interior
//! RMS jump; "seam excess (raw error)": the excess against the unblurred reference.

use std::path::PathBuf;
use std::time::Instant;

use glam::Vec3;
use prt_benches::mbd::{
    CAP, basis_nodes, cached_volume_path, distance_name, env_or, env_usize, load_average,
    read_cached, synthetic_field, voxel_energy, wall_bins, wall_distance, write_cached,
};
use prt_benches::{Table, cpu_seconds, fmt_duration};
use prt_core::{Compressor, FieldModel, GridField, NoProgress, SpatialKernels, resample_to_grid};
use prt_mbd::*;
use prt_trace::{BakeOptions, LoadOptions, Scene, TransferBaker};

/// The transfer vector as four 9 × 9 operators.
const BLOCKS: [usize; 4] = [81, 81, 81, 81];

struct Scores {
    relative_mse: f64,
    operator: f64,
    seam_excess: f64,
    seam_ratio: f64,
    raw_seam_excess: f64,
}

/// A field of the sweeps with its description and the voxels that count for the seam metric.
struct Input {
    field: GridField,
    name: String,
    /// `None`: every voxel (synthetic fields).
    valid: Option<Vec<bool>>,
    /// Blur of the reference for the seam metric: one voxel for traced (noisy) volumes, none
    /// for the noise-free synthetic field, where the blur's own bias (`σ²/2 ∇²f`) would be the
    /// largest error of an accurate method.
    seam_sigma: f64,
}

fn score(model: &dyn FieldModel, input: &Input, labels: &[u32]) -> Scores {
    let field = &input.field;
    let options = EvalOptions {
        blocks: BLOCKS.to_vec(),
        ..EvalOptions::default()
    };
    let e = evaluate(model, field, &options).expect("evaluate");
    let recon = resample_to_grid(model, field.dims(), field.bounds()).expect("resample");
    let seam = |denoise_sigma: f64| {
        let options = SeamOptions {
            denoise_sigma,
            valid: input.valid.as_deref(),
        };
        seam_metric_with(field, &recon, labels, &options).expect("seam")
    };
    let operator = e.block_relative_frobenius.iter().sum::<f64>() / BLOCKS.len() as f64;
    Scores {
        relative_mse: e.relative_mse,
        operator,
        seam_excess: seam(input.seam_sigma).excess(),
        seam_ratio: seam(input.seam_sigma).ratio(),
        raw_seam_excess: seam(0.0).excess(),
    }
}

/// Wall and CPU seconds of one fit.
#[derive(Clone, Copy)]
struct Cost {
    wall: f64,
    cpu: f64,
}

impl Cost {
    fn measure<T>(fit: impl FnOnce() -> T) -> (T, Cost) {
        let (t, cpu) = (Instant::now(), cpu_seconds());
        let value = fit();
        let cost = Cost {
            wall: t.elapsed().as_secs_f64(),
            cpu: cpu_seconds() - cpu,
        };
        (value, cost)
    }
}

/// One sweep's results.
struct Sweep {
    table: Table,
}

impl Sweep {
    fn new() -> Self {
        Self {
            table: Table::new(&HEADER),
        }
    }
}

fn row(sweep: &mut Sweep, knob: usize, method: &str, cost: Cost, s: &Scores, stored: usize) {
    eprintln!(
        "{knob} {method} {:.3} s (CPU {:.2} s), relative MSE {:.3e}",
        cost.wall, cost.cpu, s.relative_mse
    );
    sweep.table.row(vec![
        knob.to_string(),
        method.to_string(),
        fmt_duration(std::time::Duration::from_secs_f64(cost.wall)),
        format!("{:.2} s", cost.cpu),
        format!("{:.3e}", s.relative_mse),
        format!("{:.3e}", s.operator),
        format!("{:.2e}", s.seam_excess),
        format!("{:.2}", s.seam_ratio),
        format!("{:.2e}", s.raw_seam_excess),
        stored.to_string(),
    ]);
}

/// Every method at rank `l` with `b³` basis nodes / blocks / clusters.
/// Whether `MBD_METHODS` (comma-separated, default all) includes `method`.
fn enabled(method: &str) -> bool {
    std::env::var("MBD_METHODS").map_or(true, |list| {
        list.split(',')
            .any(|m| m.trim().eq_ignore_ascii_case(method))
    })
}

/// `MBD_KNOBS` (comma-separated) or `default`.
fn knobs(default: &[usize]) -> Vec<usize> {
    std::env::var("MBD_KNOBS")
        .ok()
        .map(|list| {
            list.split(',')
                .filter_map(|k| k.trim().parse().ok())
                .collect()
        })
        .unwrap_or_else(|| default.to_vec())
}

/// Every enabled method at rank `l` with `b³` basis nodes / blocks / clusters (fewer on a short
/// axis, as `prt bake` does).
/// `b` basis nodes per axis, or one per voxel (at least 2) along an axis with fewer voxels.
fn compare(sweep: &mut Sweep, knob: usize, input: &Input, l: usize, b: usize, iterations: usize) {
    let field = &input.field;
    let nodes = basis_nodes(field, b);
    let clusters = nodes.iter().product::<usize>();
    if enabled("MBD") {
        eprintln!("{knob}: fitting MBD");
        let mbd = Mbd {
            basis_nodes: nodes,
            options: MbdOptions {
                rank: l,
                max_iterations: iterations,
                ..MbdOptions::default()
            },
        };
        let ((model, report), cost) = Cost::measure(|| mbd.fit(field, &NoProgress).expect("mbd"));
        eprintln!(
            "{knob}: MBD {} iterations, converged: {}",
            report.history.len(),
            report.converged
        );
        let labels = kernel_labels(model.basis_kernels(), field).expect("labels");
        row(
            sweep,
            knob,
            "MBD",
            cost,
            &score(&model, input, &labels),
            model.stored_scalars(),
        );
    }

    let mut baseline = |name: &str, fit: &dyn Fn() -> ClusterModel| {
        if !enabled(name) {
            return;
        }
        let (m, cost) = Cost::measure(fit);
        row(
            sweep,
            knob,
            name,
            cost,
            &score(&m, input, m.labels()),
            m.stored_scalars(),
        );
    };
    baseline("PCA", &|| {
        GlobalPca { rank: l }
            .compress(field, &NoProgress)
            .expect("pca")
    });
    baseline("BPCA", &|| {
        BlockPca {
            rank: l,
            blocks: nodes,
            window: 1.0,
        }
        .compress(field, &NoProgress)
        .expect("bpca")
    });
    baseline("WBPCA", &|| {
        BlockPca {
            rank: l,
            blocks: nodes,
            window: 2.0,
        }
        .compress(field, &NoProgress)
        .expect("wbpca")
    });
    baseline("CPCA", &|| {
        ClusteredPca::new(l, clusters)
            .compress(field, &NoProgress)
            .expect("cpca")
    });
    baseline("VQ", &|| {
        KMeansVq {
            codewords: (clusters * l).min(field.num_voxels()),
            iterations: 10,
            seed: 0,
        }
        .compress(field, &NoProgress)
        .expect("vq")
    });
}

const HEADER: [&str; 10] = [
    "knob",
    "method",
    "time",
    "CPU time",
    "relative MSE",
    "operator rel. Frobenius (mean of 4 blocks)",
    "seam excess",
    "seam ratio",
    "seam excess (raw error)",
    "stored scalars",
];

/// Field resolution of the basis-count and grid sweeps (`MBD_N`, default 32).
fn sweep_n() -> usize {
    env_or("MBD_N", 32)
}

/// The field of the basis, grid, convergence and quality sweeps (`MBD_FIELD`).
fn sweep_field() -> Input {
    let n = sweep_n();
    let traced = |scene: &str, field: GridField| {
        let [x, y, z] = field.dims();
        let valid = nonzero_voxels(&field);
        let invalid = valid.iter().filter(|v| !**v).count();
        Input {
            name: format!("traced {scene} {x}×{y}×{z} × 324, {invalid} invalid voxels"),
            field,
            valid: Some(valid),
            seam_sigma: 1.0,
        }
    };
    match std::env::var("MBD_FIELD").as_deref() {
        Ok("cornell") => traced("Cornell box", traced_field("cornell", n)),
        Ok("sponza") => traced("Sponza", traced_field("sponza", n)),
        _ => Input {
            field: synthetic_field(n),
            name: format!("synthetic {n}³ × 324"),
            valid: None,
            seam_sigma: 0.0,
        },
    }
}

/// The built-in Cornell box (`scene = "cornell"`) or Sponza (`"sponza"`) traced at `n` voxels
/// along its longest axis with `prt bake`'s defaults, read from the cache when an earlier run
/// wrote it.
fn traced_field(scene_name: &str, n: usize) -> GridField {
    let path = cached_volume_path(scene_name, n);
    if let Some(field) = read_cached(&path) {
        eprintln!("{scene_name} {n}: read {}", path.display());
        return field;
    }
    let scene = if scene_name == "sponza" {
        let path = concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../shared/scenes/sponza/Sponza.gltf"
        );
        Scene::load_gltf(path, &LoadOptions::default())
            .unwrap_or_else(|e| panic!("cannot load Sponza from {path}: {e}"))
    } else {
        Scene::cornell_box()
    };
    let bounds = scene.bounds().expect("the scene has triangles");
    let size = bounds.size().to_array();
    let longest = size.iter().copied().fold(0.0f32, f32::max);
    let resolution = size.map(|s| ((s / longest * n as f32).round() as usize).clamp(2, n));
    let options = BakeOptions {
        resolution,
        ..BakeOptions::default()
    };
    let (volume, cost) = Cost::measure(|| {
        TransferBaker::new(&scene, options)
            .and_then(|baker| baker.bake(&NoProgress))
            .expect("bake")
    });
    eprintln!(
        "{scene_name} {n}: traced {resolution:?} in {:.2} s (CPU {:.2} s)",
        cost.wall, cost.cpu
    );
    if let Err(e) = write_cached(&path, &volume.field) {
        eprintln!("cannot cache {}: {e}", path.display());
    }
    volume.field
}

/// Relative MSE against the knob, one line per method, log scale.
fn plot(points: &[(usize, String, f64)], x_label: &str, title: &str, path: &str) {
    use plotters::prelude::*;
    plotters::style::register_font(
        "sans-serif",
        FontStyle::Normal,
        epaint_default_fonts::UBUNTU_LIGHT,
    )
    .map_err(|_| "font")
    .expect("register the plot font");
    let mut methods: Vec<&str> = Vec::new();
    for (_, m, _) in points {
        if !methods.contains(&m.as_str()) {
            methods.push(m);
        }
    }
    let xs = points.iter().map(|p| p.0);
    let (x0, x1) = (xs.clone().min().unwrap_or(0), xs.max().unwrap_or(1));
    let ys = points.iter().map(|p| p.2).filter(|&e| e > 0.0);
    let lo = ys.clone().fold(f64::MAX, f64::min) * 0.5;
    let hi = ys.fold(f64::MIN, f64::max) * 2.0;
    let root = BitMapBackend::new(path, (760, 480)).into_drawing_area();
    root.fill(&WHITE).expect("plot");
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 20))
        .margin(14)
        .x_label_area_size(44)
        .y_label_area_size(80)
        .build_cartesian_2d(x0..x1.max(x0 + 1), (lo..hi).log_scale())
        .expect("plot");
    chart
        .configure_mesh()
        .x_desc(x_label)
        .y_desc("relative MSE")
        .y_label_formatter(&|v| format!("{v:.0e}"))
        .x_label_formatter(&|v| v.to_string())
        .label_style(("sans-serif", 14))
        .draw()
        .expect("plot");
    for (i, method) in methods.iter().enumerate() {
        let colour = Palette99::pick(i).stroke_width(2);
        let line: Vec<(usize, f64)> = points
            .iter()
            .filter(|p| p.1 == *method && p.2 > 0.0)
            .map(|p| (p.0, p.2))
            .collect();
        chart
            .draw_series(LineSeries::new(line.clone(), colour))
            .expect("plot")
            .label(*method)
            .legend(move |(x, y)| PathElement::new([(x, y), (x + 18, y)], colour));
        chart
            .draw_series(line.into_iter().map(|p| Circle::new(p, 3, colour.filled())))
            .expect("plot");
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .label_font(("sans-serif", 14))
        .draw()
        .expect("plot");
    root.present().expect("plot");
    eprintln!("wrote {path}");
}

fn finish(sweep: &Sweep, heading: String, csv: &str) {
    println!("### {heading}\n\n{}", sweep.table.markdown());
    println!("load average after: {}\n", load_average());
    sweep.table.write_csv_if_requested(csv).ok();
}

/// `plot TABLE.csv OUT.png TITLE X_LABEL`: relative MSE of a sweep's CSV against its knob.
fn plot_csv(args: &[String]) {
    let [csv, png, title, x_label] = args else {
        eprintln!("usage: mbd_sweep plot TABLE.csv OUT.png TITLE X_LABEL");
        std::process::exit(2);
    };
    let text = std::fs::read_to_string(csv).expect("read the CSV");
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap_or_default().split(',').collect();
    let column = |name: &str| header.iter().position(|h| *h == name).expect("CSV column");
    let (knob, method, error) = (column("knob"), column("method"), column("relative MSE"));
    let points: Vec<(usize, String, f64)> = lines
        .map(|l| l.split(',').collect::<Vec<_>>())
        .filter_map(|cells| {
            Some((
                cells.get(knob)?.parse().ok()?,
                cells.get(method)?.to_string(),
                cells.get(error)?.parse().ok()?,
            ))
        })
        .collect();
    plot(&points, x_label, title, png);
}

fn basis_count() {
    let input = sweep_field();
    let name = &input.name;
    let mut sweep = Sweep::new();
    for l in knobs(&[2, 4, 8, 16]) {
        compare(&mut sweep, l, &input, l, 5, 64);
    }
    finish(
        &sweep,
        format!("Error vs basis count L ({name}, 5³ basis nodes, MBD ≤ 64 iterations)"),
        "mbd_basis",
    );
}

fn grid_resolution() {
    let input = sweep_field();
    let name = &input.name;
    let mut sweep = Sweep::new();
    for b in knobs(&[9, 7, 5, 3]) {
        compare(&mut sweep, b, &input, 8, b, 64);
    }
    finish(
        &sweep,
        format!("Error vs basis-grid resolution b (b³ nodes; {name}, L = 8, MBD ≤ 64 iterations)"),
        "mbd_grid",
    );
}

fn timing() {
    let mut sweep = Sweep::new();
    let max = env_or("MBD_MAX_N", 64);
    for (n, b) in [(16, 3), (32, 5), (64, 9)] {
        if n <= max {
            let input = Input {
                field: synthetic_field(n),
                name: String::new(),
                valid: None,
                seam_sigma: 0.0,
            };
            compare(&mut sweep, n, &input, 8, b, 32);
        }
    }
    finish(
        &sweep,
        "Timings (324-D, n³ voxels with 3³/5³/9³ nodes, L = 8, MBD 32 iterations)".into(),
        "mbd_timing",
    );
}

fn convergence() {
    let input = sweep_field();
    let f = &input.field;
    let mut table = Table::new(&["solver", "iterations", "time", "relative MSE"]);
    for (name, pre) in [
        ("stochastic, paper diagonal", Preconditioner::Diagonal),
        ("stochastic, lumped diagonal", Preconditioner::Lumped),
        ("stochastic, lumped blocks (default)", Preconditioner::Block),
    ] {
        for iterations in [4, 16, 64] {
            let t = Instant::now();
            let options = MbdOptions {
                rank: 8,
                max_iterations: iterations,
                preconditioner: pre,
                tolerance: 0.0,
                ..MbdOptions::default()
            };
            let (model, _) = Mbd {
                basis_nodes: [5; 3],
                options,
            }
            .fit(f, &NoProgress)
            .expect("mbd");
            let secs = t.elapsed();
            let e = evaluate(&model, f, &EvalOptions::default()).expect("evaluate");
            table.row(vec![
                name.into(),
                iterations.to_string(),
                fmt_duration(secs),
                format!("{:.4e}", e.relative_mse),
            ]);
        }
    }
    for iterations in [1, 2, 4, 8] {
        let t = Instant::now();
        let options = MbdOptions {
            rank: 8,
            max_iterations: iterations,
            tolerance: 0.0,
            ..MbdOptions::default()
        };
        let mbd = Mbd {
            basis_nodes: [5; 3],
            options,
        };
        let (coef, basis) = mbd.kernels(f).expect("kernels");
        let (model, _) = solve_als(f, coef, basis, &mbd.options, &NoProgress).expect("als");
        let secs = t.elapsed();
        let e = evaluate(&model, f, &EvalOptions::default()).expect("evaluate");
        table.row(vec![
            "alternating least squares".into(),
            iterations.to_string(),
            fmt_duration(secs),
            format!("{:.4e}", e.relative_mse),
        ]);
    }
    println!(
        "### Convergence ({}, 5³ nodes, L = 8)\n\n{}",
        input.name,
        table.markdown()
    );
    println!("load average after: {}\n", load_average());
    table.write_csv_if_requested("mbd_convergence").ok();
}

/// Is MBD short of the baselines because it is not converged, badly started or over-regularised?
/// MBD variants at rank `MBD_L` (default 8) on `MBD_B`³ (default 5³) basis nodes beside BPCA and
/// CPCA of the same budget, with the loss after 16 / 32 / 64 / 128 iterations.
fn quality() {
    let input = sweep_field();
    let f = &input.field;
    let (l, b) = (env_usize("MBD_L", 8), env_usize("MBD_B", 5));
    let nodes = basis_nodes(f, b);
    let mut table = Table::new(&[
        "method",
        "iterations",
        "CPU time",
        "relative MSE",
        "seam excess",
        "seam ratio",
        "seam excess (raw error)",
        "loss after 1 / 16 / 32 / 64 / 128 iterations",
    ]);
    let mut add = |name: &str,
                   iterations: String,
                   cost: Cost,
                   model: &dyn FieldModel,
                   labels: &[u32],
                   losses: String| {
        let s = score(model, &input, labels);
        eprintln!("{name}: {:.3e} in {:.1} s CPU", s.relative_mse, cost.cpu);
        table.row(vec![
            name.into(),
            iterations,
            format!("{:.2} s", cost.cpu),
            format!("{:.3e}", s.relative_mse),
            format!("{:.2e}", s.seam_excess),
            format!("{:.2}", s.seam_ratio),
            format!("{:.2e}", s.raw_seam_excess),
            losses,
        ]);
    };
    let variants: [(&str, MbdOptions); 5] = [
        (
            "MBD (default, ≤ 64)",
            MbdOptions {
                max_iterations: 64,
                ..MbdOptions::default()
            },
        ),
        (
            "MBD, 128 iterations, no early stop",
            MbdOptions {
                max_iterations: 128,
                tolerance: 0.0,
                ..MbdOptions::default()
            },
        ),
        (
            "MBD, local-PCA start",
            MbdOptions {
                max_iterations: 64,
                init: Init::LocalPca,
                ..MbdOptions::default()
            },
        ),
        (
            "MBD, λ = 1e-6",
            MbdOptions {
                max_iterations: 64,
                lambda: 1e-6,
                ..MbdOptions::default()
            },
        ),
        (
            "MBD, λ = 1e-2",
            MbdOptions {
                max_iterations: 64,
                lambda: 1e-2,
                ..MbdOptions::default()
            },
        ),
    ];
    for (name, options) in variants {
        if !enabled("MBD") {
            continue;
        }
        let mbd = Mbd {
            basis_nodes: nodes,
            options: MbdOptions { rank: l, ..options },
        };
        let ((model, report), cost) = Cost::measure(|| mbd.fit(f, &NoProgress).expect("mbd"));
        let labels = kernel_labels(model.basis_kernels(), f).expect("labels");
        let losses = [1, 16, 32, 64, 128]
            .map(|i| {
                report
                    .history
                    .get(i - 1)
                    .map_or("–".into(), |r| format!("{:.4e}", r.loss_after))
            })
            .join(" / ");
        add(
            name,
            report.history.len().to_string(),
            cost,
            &model,
            &labels,
            losses,
        );
    }
    if enabled("ALS") && nodes.iter().product::<usize>() * l <= ALS_MAX_BASIS_UNKNOWNS {
        let mbd = Mbd {
            basis_nodes: nodes,
            options: MbdOptions {
                rank: l,
                max_iterations: 8,
                ..MbdOptions::default()
            },
        };
        let (coef, basis) = mbd.kernels(f).expect("kernels");
        let ((model, report), cost) =
            Cost::measure(|| solve_als(f, coef, basis, &mbd.options, &NoProgress).expect("als"));
        let labels = kernel_labels(model.basis_kernels(), f).expect("labels");
        add(
            "ALS (voxel centres)",
            report.history.len().to_string(),
            cost,
            &model,
            &labels,
            "–".into(),
        );
    }
    let clusters = nodes.iter().product::<usize>();
    if enabled("BPCA") {
        let (m, cost) = Cost::measure(|| {
            BlockPca {
                rank: l,
                blocks: nodes,
                window: 1.0,
            }
            .compress(f, &NoProgress)
            .expect("bpca")
        });
        add("BPCA", "–".into(), cost, &m, m.labels(), "–".into());
    }
    if enabled("CPCA") {
        let (m, cost) = Cost::measure(|| {
            ClusteredPca::new(l, clusters)
                .compress(f, &NoProgress)
                .expect("cpca")
        });
        add("CPCA", "–".into(), cost, &m, m.labels(), "–".into());
    }
    println!(
        "### MBD variants ({}, L = {l}, {b}³ basis nodes)\n\n{}",
        input.name,
        table.markdown()
    );
    println!("load average after: {}\n", load_average());
}

/// Where does the stochastic solver end, and how fast does it get there? Rank `MBD_L` (8) on
/// `MBD_B`³ (5³) nodes, `MBD_ITERS` (512) iterations (stopping rule off unless `MBD_TOL` is
/// set), for each averaging
/// window in `MBD_WINDOWS` (default `0,16`; 0 = the last iterate) and momentum `MBD_MB`,
/// `MBD_MC` (percent; default the solver's), samples per voxel `MBD_SPV` (default 1) and ridge
/// `MBD_LAMBDA` (default the solver's). The error at the checkpoints is the solver's
/// held-out relative error of the averaged iterates, so one run gives the whole curve; the
/// last column is `evaluate`'s relative MSE of the returned model. With `MBD_HISTORY_DIR` the
/// per-iteration history is written as CSV.
fn floor() {
    let input = sweep_field();
    let f = &input.field;
    let (l, b) = (env_usize("MBD_L", 8), env_usize("MBD_B", 5));
    let iterations = env_usize("MBD_ITERS", 512);
    let nodes = basis_nodes(f, b);
    let windows: Vec<usize> = std::env::var("MBD_WINDOWS")
        .unwrap_or_else(|_| "0,16".into())
        .split(',')
        .filter_map(|v| v.trim().parse().ok())
        .collect();
    let checkpoints: Vec<usize> = [8, 16, 32, 64, 128, 256, 512, 1024, 2048]
        .into_iter()
        .filter(|&c| c <= iterations)
        .collect();
    let mut header = vec![
        "average window".to_string(),
        "iterations run".into(),
        "CPU time".into(),
    ];
    header.extend(checkpoints.iter().map(|c| format!("held-out error at {c}")));
    header.push("final relative MSE (evaluate)".into());
    let header: Vec<&str> = header.iter().map(String::as_str).collect();
    let mut table = Table::new(&header);
    for average_window in windows {
        let mbd = Mbd {
            basis_nodes: nodes,
            options: MbdOptions {
                rank: l,
                max_iterations: iterations,
                tolerance: env_or("MBD_TOL", 0.0),
                average_window,
                jitter: env_usize("MBD_JITTER", 1) != 0,
                momentum_basis: env_usize("MBD_MB", 90) as f32 / 100.0,
                momentum_coefficients: env_usize("MBD_MC", 60) as f32 / 100.0,
                samples_per_voxel: env_usize("MBD_SPV", 1),
                lambda: env_or("MBD_LAMBDA", MbdOptions::default().lambda),
                ..MbdOptions::default()
            },
        };
        let ((model, report), cost) = Cost::measure(|| mbd.fit(f, &NoProgress).expect("mbd"));
        let e = evaluate(&model, f, &EvalOptions::default()).expect("evaluate");
        let mut cells = vec![
            average_window.to_string(),
            report.history.len().to_string(),
            format!("{:.1} s", cost.cpu),
        ];
        cells.extend(checkpoints.iter().map(|&c| {
            report.history[..c.min(report.history.len())]
                .iter()
                .rev()
                .find_map(|r| r.held_out)
                .map_or("–".into(), |h| format!("{h:.3e}"))
        }));
        cells.push(format!("{:.4e}", e.relative_mse));
        eprintln!("window {average_window}: {cells:?}");
        table.row(cells);
        if let Ok(dir) = std::env::var("MBD_HISTORY_DIR") {
            let mut csv = String::from(
                "iteration,elapsed,loss_before,data_before,loss_after,held_out,step\n",
            );
            for (i, r) in report.history.iter().enumerate() {
                csv += &format!(
                    "{i},{},{},{},{},{},{}\n",
                    r.elapsed,
                    r.loss_before,
                    r.data_before,
                    r.loss_after,
                    r.held_out.map_or(String::new(), |h| h.to_string()),
                    r.step
                );
            }
            let path = PathBuf::from(dir).join(format!("floor_{average_window}.csv"));
            std::fs::create_dir_all(path.parent().unwrap_or(std::path::Path::new("."))).ok();
            std::fs::write(&path, csv).ok();
        }
    }
    println!(
        "### Long runs ({}, L = {l}, {b}³ basis nodes)\n\n{}",
        input.name,
        table.markdown()
    );
    println!("load average after: {}\n", load_average());
}

/// Fits BPCA, WBPCA and CPCA (those `MBD_METHODS` enables) at rank `l` on `nodes` blocks /
/// `nodes` clusters and hands each model to `each` with its name and cost.
fn block_and_clustered_pca(
    f: &GridField,
    l: usize,
    nodes: [usize; 3],
    each: &mut dyn FnMut(&str, Cost, &ClusterModel),
) {
    for (name, window) in [("BPCA", 1.0), ("WBPCA", 2.0)] {
        if enabled(name) {
            let (m, cost) = Cost::measure(|| {
                BlockPca {
                    rank: l,
                    blocks: nodes,
                    window,
                }
                .compress(f, &NoProgress)
                .expect("block PCA")
            });
            each(name, cost, &m);
        }
    }
    if enabled("CPCA") {
        let (m, cost) = Cost::measure(|| {
            ClusteredPca::new(l, nodes.iter().product())
                .compress(f, &NoProgress)
                .expect("cpca")
        });
        each("CPCA", cost, &m);
    }
}

/// MBD with its basis kernels where the scene is (`scene_adapted_basis`: Shepard kernels at
/// weighted k-means centres of the valid voxels, radius = distance to the `MBD_NEIGHBOURS`-th
/// (default: `AdaptedBasisOptions`'s) nearest centre, enlarged to cover the box) against MBD on the regular `MBD_B`³ (5³) hat
/// grid, BPCA and CPCA, all with `MBD_B`³ nodes / blocks / clusters at rank `MBD_L` (8), MBD
/// with the default solver (≤ `MBD_ITERS` = 128 iterations). Methods (`MBD_METHODS`): MBD,
/// SHEPARD-U (uniform placement), SHEPARD-E (energy), SHEPARD-V (local variation),
/// SHEPARD-GRID (the same Shepard kernels at the hat grid's nodes, one radius: the distance to
/// the `MBD_NEIGHBOURS`-th nearest node; separates the kernel shape from the placement), BPCA,
/// WBPCA, CPCA.
/// Reports the jittered relative MSE and its ratio to CPCA's, the error at valid voxel centres,
/// its share by distance to the nearest invalid voxel (as in `walls`), and the seam metric
/// against the basis kernels' (largest-weight) labels.
fn adaptive() {
    let input = sweep_field();
    let f = &input.field;
    let Some(valid) = input.valid.as_deref() else {
        eprintln!("adaptive: needs a traced field (MBD_FIELD=cornell|sponza)");
        return;
    };
    let (l, b) = (env_usize("MBD_L", 8), env_usize("MBD_B", 5));
    let iterations = env_usize("MBD_ITERS", 128);
    let neighbours = env_usize("MBD_NEIGHBOURS", AdaptedBasisOptions::default().neighbours);
    let nodes = basis_nodes(f, b);
    let count = nodes.iter().product::<usize>();
    let distance = wall_distance(f, valid);
    let energy = |keep: &dyn Fn(usize) -> bool| voxel_energy(f, keep);
    let total = energy(&|_| true);
    let valid_energy = energy(&|v| valid[v]);
    struct Result {
        name: String,
        iterations: String,
        cost: Cost,
        scores: Scores,
        bins: [f64; CAP + 1],
    }
    let mut results: Vec<Result> = Vec::new();
    let mut add = |name: String,
                   iterations: String,
                   cost: Cost,
                   model: &dyn FieldModel,
                   labels: &[u32]| {
        let scores = score(model, &input, labels);
        let bins = wall_bins(f, model, &distance);
        eprintln!(
            "{name}: {iterations} iterations, {:.1} s (CPU {:.1} s), relative MSE {:.3e}, seam ratio {:.2}",
            cost.wall, cost.cpu, scores.relative_mse, scores.seam_ratio
        );
        results.push(Result {
            name,
            iterations,
            cost,
            scores,
            bins,
        });
    };
    let options = MbdOptions {
        rank: l,
        max_iterations: iterations,
        ..MbdOptions::default()
    };
    let mbd = Mbd {
        basis_nodes: nodes,
        options: options.clone(),
    };
    let mut hat_model = None;
    if enabled("MBD") {
        let ((model, report), cost) = Cost::measure(|| mbd.fit(f, &NoProgress).expect("mbd"));
        let labels = kernel_labels(model.basis_kernels(), f).expect("labels");
        hat_model = Some(model.clone());
        add(
            format!("MBD, {b}³ hat grid"),
            report.history.len().to_string(),
            cost,
            &model,
            &labels,
        );
    }
    for (key, placement) in [
        ("SHEPARD-U", Placement::Uniform),
        ("SHEPARD-E", Placement::Energy),
        ("SHEPARD-V", Placement::Variation),
    ] {
        if !enabled(key) {
            continue;
        }
        let adapted = AdaptedBasisOptions {
            placement,
            neighbours,
            ..AdaptedBasisOptions::default()
        };
        let ((model, report), cost) = Cost::measure(|| {
            let basis = scene_adapted_basis(f, valid, count, &adapted).expect("adapted basis");
            let (coefficients, _) = mbd.kernels(f).expect("kernels");
            solve(f, coefficients, basis, &options, &NoProgress).expect("mbd")
        });
        let basis = model.basis_kernels();
        let radii = basis.radii();
        let mean_radius = radii.iter().map(|&r| f64::from(r)).sum::<f64>() / radii.len() as f64;
        let labels = kernel_labels(basis, f).expect("labels");
        // Kernels non-zero at each voxel centre: the work per sample of the basis terms.
        let mut w = prt_core::KernelWeights::default();
        let support: Vec<usize> = (0..f.num_voxels())
            .map(|v| {
                basis.eval(f.centre_of(v), &mut w).expect("covered");
                w.len()
            })
            .collect();
        let mean_support = support.iter().sum::<usize>() as f64 / support.len() as f64;
        // Control: the hat-grid model (continuous, labels unrelated to these kernels) scored
        // on these kernels' labels shows what the seam metric reads from where the labels'
        // boundaries lie rather than from steps of the model.
        let control = hat_model.as_ref().map_or(String::new(), |hat| {
            format!(
                "; hat MBD on these labels: seam excess {:.2e}",
                score(hat, &input, &labels).seam_excess
            )
        });
        add(
            format!(
                "MBD, {count} Shepard kernels, {placement:?} placement (k = {neighbours}; radius mean {:.2} voxels, max {:.2}; {mean_support:.1} kernels per voxel centre, at most {}{control})",
                mean_radius / f64::from(f.voxel_size().max_element()),
                f64::from(
                    radii.iter().copied().fold(0.0f32, f32::max) / f.voxel_size().max_element()
                ),
                support.iter().max().unwrap_or(&0)
            ),
            report.history.len().to_string(),
            cost,
            &model,
            &labels,
        );
    }
    if enabled("SHEPARD-GRID") {
        let (_, hat) = mbd.kernels(f).expect("kernels");
        let centres: Vec<Vec3> = (0..hat.len()).filter_map(|i| hat.centre(i)).collect();
        let mut distances: Vec<f32> = centres.iter().map(|c| c.distance(centres[0])).collect();
        distances.sort_unstable_by(f32::total_cmp);
        // The corner node has the fewest near neighbours: every node has at least
        // `neighbours` others within this radius.
        let radius = distances[neighbours.min(distances.len() - 1)];
        let ((model, report), cost) = Cost::measure(|| {
            let basis = prt_kernels::Shepard::with_radius(centres, radius).expect("shepard");
            let (coefficients, _) = mbd.kernels(f).expect("kernels");
            solve(f, coefficients, basis, &options, &NoProgress).expect("mbd")
        });
        let labels = kernel_labels(model.basis_kernels(), f).expect("labels");
        add(
            format!(
                "MBD, {count} Shepard kernels at the {b}³ grid nodes (radius {:.2} voxels)",
                radius / f.voxel_size().max_element()
            ),
            report.history.len().to_string(),
            cost,
            &model,
            &labels,
        );
    }
    block_and_clustered_pca(f, l, nodes, &mut |name, cost, m| {
        add(name.into(), "–".into(), cost, m, m.labels())
    });
    let cpca = results
        .iter()
        .find(|r| r.name == "CPCA")
        .map(|r| r.scores.relative_mse);
    let mut header = vec![
        "method".to_string(),
        "iterations".into(),
        "time (CPU)".into(),
        "relative MSE (jittered)".into(),
        "/ CPCA".into(),
        "valid only (centres)".into(),
    ];
    header.extend((1..=CAP).map(|d| {
        let share = energy(&|v| distance[v] == d) / total;
        // + 0.0: an empty bin's sum is -0.0.
        format!(
            "distance {} ({:.0} % of energy)",
            distance_name(d),
            100.0 * share + 0.0
        )
    }));
    header.extend([
        "seam excess".into(),
        "seam ratio".into(),
        "seam excess (raw error)".into(),
    ]);
    let header: Vec<&str> = header.iter().map(String::as_str).collect();
    let mut table = Table::new(&header);
    for r in &results {
        let mut cells = vec![
            r.name.clone(),
            r.iterations.clone(),
            format!("{:.1} s ({:.1} s)", r.cost.wall, r.cost.cpu),
            format!("{:.3e}", r.scores.relative_mse),
            cpca.map_or("–".into(), |c| {
                format!("{:.2}", r.scores.relative_mse / c)
            }),
            format!("{:.3e}", r.bins[1..].iter().sum::<f64>() / valid_energy),
        ];
        cells.extend(r.bins[1..].iter().map(|&x| format!("{:.2e}", x / total)));
        cells.extend([
            format!("{:.2e}", r.scores.seam_excess),
            format!("{:.2}", r.scores.seam_ratio),
            format!("{:.2e}", r.scores.raw_seam_excess),
        ]);
        table.row(cells);
    }
    println!(
        "### Basis kernels where the scene is ({}, L = {l}, {count} basis kernels)\n\n{}",
        input.name,
        table.markdown()
    );
    println!("load average after: {}\n", load_average());
}

/// Where is each method's error on a traced volume? MBD (default solver, ≤ `MBD_ITERS` = 128
/// iterations), BPCA, WBPCA and CPCA (`MBD_METHODS` selects) at rank `MBD_L` (8), `MBD_B`³ (5³)
/// nodes / blocks / clusters, each fit's wall and CPU time on stderr; every method's
/// reconstruction is sampled at the voxel centres and its squared error summed by the voxel's
/// distance to the nearest invalid voxel (Chebyshev, in voxels: 0 = invalid, 1 = touching an
/// invalid voxel, ..., capped at 4). The same bins and
/// the same normalisation (the field's total energy) for every method; "valid only" is the
/// relative MSE at valid voxel centres against the valid voxels' energy.
fn walls() {
    let input = sweep_field();
    let f = &input.field;
    let Some(valid) = input.valid.as_deref() else {
        eprintln!("walls: needs a traced field (MBD_FIELD=cornell|sponza)");
        return;
    };
    let (l, b) = (env_usize("MBD_L", 8), env_usize("MBD_B", 5));
    let iterations = env_usize("MBD_ITERS", 128);
    let nodes = basis_nodes(f, b);
    let distance = wall_distance(f, valid);
    let energy = |keep: &dyn Fn(usize) -> bool| voxel_energy(f, keep);
    let total = energy(&|_| true);
    let mut header = vec!["method".to_string(), "relative MSE (jittered)".into()];
    header.push("valid only (centres)".into());
    header.extend((0..=CAP).map(|d| {
        let count = distance.iter().filter(|&&x| x == d).count();
        let share = energy(&|v| distance[v] == d) / total;
        format!(
            "distance {} ({count} voxels, {:.0} % of energy)",
            distance_name(d),
            100.0 * share + 0.0
        )
    }));
    let header: Vec<&str> = header.iter().map(String::as_str).collect();
    let mut table = Table::new(&header);
    let mut add = |name: &str, model: &dyn FieldModel| {
        let e = evaluate(model, f, &EvalOptions::default()).expect("evaluate");
        let bins = wall_bins(f, model, &distance);
        let valid_only = bins[1..].iter().sum::<f64>() / energy(&|v| valid[v]);
        let mut cells = vec![
            name.to_string(),
            format!("{:.3e}", e.relative_mse),
            format!("{valid_only:.3e}"),
        ];
        cells.extend(bins.iter().map(|&x| format!("{:.2e}", x / total)));
        eprintln!("{cells:?}");
        table.row(cells);
    };
    if enabled("MBD") {
        let mbd = Mbd {
            basis_nodes: nodes,
            options: MbdOptions {
                rank: l,
                max_iterations: iterations,
                ..MbdOptions::default()
            },
        };
        let ((model, report), cost) = Cost::measure(|| mbd.fit(f, &NoProgress).expect("mbd"));
        eprintln!("MBD {:.1} s (CPU {:.1} s)", cost.wall, cost.cpu);
        add(
            &format!(
                "MBD ({} of ≤ {iterations} iterations)",
                report.history.len()
            ),
            &model,
        );
    }
    block_and_clustered_pca(f, l, nodes, &mut |name, cost, m| {
        eprintln!("{name} {:.1} s (CPU {:.1} s)", cost.wall, cost.cpu);
        add(name, m);
    });
    println!(
        "### Error by distance to the nearest invalid voxel ({}, L = {l}, {b}³ nodes), share of the field's energy at voxel centres\n\n{}",
        input.name,
        table.markdown()
    );
    println!("load average after: {}\n", load_average());
}

/// MBD at rank 8 and 16 with the default and a 100× smaller ridge λ, beside the global PCA of the
/// same rank that MBD starts from: does the solver end above its own starting point, and is the
/// ridge the cause?
fn ridge() {
    let n = sweep_n();
    let f = synthetic_field(n);
    let mut table = Table::new(&[
        "L",
        "λ",
        "iterations",
        "CPU time",
        "MBD relative MSE",
        "RMS coefficient",
        "global PCA (start) relative MSE",
    ]);
    for l in [8, 16] {
        let pca = GlobalPca { rank: l }
            .compress(&f, &NoProgress)
            .expect("pca");
        let start = evaluate(&pca, &f, &EvalOptions::default()).expect("evaluate");
        for lambda in [1e-4f32, 1e-6] {
            let mbd = Mbd {
                basis_nodes: [5; 3],
                options: MbdOptions {
                    rank: l,
                    lambda,
                    max_iterations: 64,
                    ..MbdOptions::default()
                },
            };
            let ((model, report), cost) = Cost::measure(|| mbd.fit(&f, &NoProgress).expect("mbd"));
            let e = evaluate(&model, &f, &EvalOptions::default()).expect("evaluate");
            let c = model.coefficients();
            let rms =
                (c.iter().map(|&v| f64::from(v).powi(2)).sum::<f64>() / c.len() as f64).sqrt();
            table.row(vec![
                l.to_string(),
                format!("{lambda:e}"),
                report.history.len().to_string(),
                format!("{:.2} s", cost.cpu),
                format!("{:.3e}", e.relative_mse),
                format!("{rms:.3}"),
                format!("{:.3e}", start.relative_mse),
            ]);
        }
    }
    println!(
        "### MBD vs its global-PCA start ({n}³ × 324, 5³ nodes)\n\n{}",
        table.markdown()
    );
    println!("load average after: {}\n", load_average());
}

/// Optimisation or representation? MBD with the default solver (≤ `MBD_ITERS` = 128
/// iterations, ridge `MBD_LAMBDA`, default 1e-4, stopping tolerance `MBD_TOL`, default the
/// solver's; 1e-2 is the early hand-off of `PolishedMbd`; sample seed `MBD_SEED`) at rank `MBD_L` (8) on `MBD_B`³ (5³) nodes,
/// then `polish` (exact alternating solves of the continuous loss) for `MBD_SWEEPS` (16)
/// sweeps, with its tolerance `MBD_PTOL` (default 0: all sweeps), ridge `MBD_PLAMBDA` (default
/// `PolishOptions`' 1e-8; the solver's 1e-4 dominates the loss near the optimum, so the polish
/// then trades coefficient scale for basis scale instead of lowering the error) and
/// acceleration `MBD_ACCEL` (`none`, `extrapolation` or `cg`, the default). Prints the exact relative MSE after every
/// half-step with the wall time, `evaluate`'s estimate and the seam metric before and after,
/// and BPCA / WBPCA / CPCA as `MBD_METHODS` enables (exact errors through `trilinear_energy`).
/// With `MBD_HISTORY_DIR` the error curve of both phases is written to
/// `<MBD_HISTORY_NAME, default polish>.csv` there.
fn polish_sweep() {
    let input = sweep_field();
    let f = &input.field;
    let (l, b) = (env_usize("MBD_L", 8), env_usize("MBD_B", 5));
    let iterations = env_usize("MBD_ITERS", 128);
    let nodes = basis_nodes(f, b);
    let options = MbdOptions {
        rank: l,
        max_iterations: iterations,
        lambda: env_or("MBD_LAMBDA", MbdOptions::default().lambda),
        tolerance: env_or("MBD_TOL", MbdOptions::default().tolerance),
        seed: env_or("MBD_SEED", MbdOptions::default().seed),
        ..MbdOptions::default()
    };
    let mbd = Mbd {
        basis_nodes: nodes,
        options,
    };
    let ((model, report), solve_cost) = Cost::measure(|| mbd.fit(f, &NoProgress).expect("mbd"));
    let labels = kernel_labels(model.basis_kernels(), f).expect("labels");
    let solved = score(&model, &input, &labels);
    // `evaluate`'s estimate and the seam metric (on the denoised reference for traced fields).
    let scores = |s: &Scores| {
        format!(
            "evaluate {:.4e}, seam excess {:.2e} (ratio {:.2})",
            s.relative_mse, s.seam_excess, s.seam_ratio
        )
    };
    let polish_options = PolishOptions {
        sweeps: env_usize("MBD_SWEEPS", 16),
        lambda: env_or("MBD_PLAMBDA", PolishOptions::default().lambda),
        tolerance: env_or("MBD_PTOL", 0.0),
        acceleration: prt_benches::mbd::polish_acceleration(),
        ..PolishOptions::default()
    };
    let ((polished, polish_report), polish_cost) =
        Cost::measure(|| polish(f, model, &polish_options, &NoProgress).expect("polish"));
    let mut table = Table::new(&[
        "step",
        "exact relative MSE",
        "exact loss (data + ridge)",
        "CG iterations",
        "seconds since the polish started (wall)",
    ]);
    let initial = polish_report.initial;
    table.row(vec![
        format!("stochastic solver, {} iterations", report.history.len()),
        format!("{:.4e}", initial.relative_mse()),
        format!("{:.6e}", initial.loss()),
        "–".into(),
        "0".into(),
    ]);
    let mut sweep = 0;
    for r in &polish_report.history {
        sweep += usize::from(r.step == PolishStep::Basis);
        table.row(vec![
            format!(
                "sweep {sweep} {:?}{}",
                r.step,
                if r.accepted { "" } else { " (rejected)" }
            ),
            format!("{:.4e}", r.loss.relative_mse()),
            format!("{:.6e}", r.loss.loss()),
            r.cg_iterations.to_string(),
            format!("{:.1}", r.elapsed),
        ]);
    }
    if let Ok(dir) = std::env::var("MBD_HISTORY_DIR") {
        write_two_phase_history(
            &PathBuf::from(dir).join(format!(
                "{}.csv",
                std::env::var("MBD_HISTORY_NAME").unwrap_or_else(|_| "polish".into())
            )),
            &report,
            &solve_cost,
            &polish_report,
            &polish_cost,
        );
    }
    let polished_scores = score(&polished, &input, &labels);
    println!(
        "### Exact polish ({}, L = {l}, {b}³ basis nodes)\n\n{}",
        input.name,
        table.markdown()
    );
    println!(
        "stochastic solve: {} iterations, {:.1} s CPU ({:.1} s wall), {}, exact {:.4e}",
        report.history.len(),
        solve_cost.cpu,
        solve_cost.wall,
        scores(&solved),
        initial.relative_mse()
    );
    println!(
        "polish: {} half-steps, {:.1} s CPU ({:.1} s wall), {}, exact {:.4e}",
        polish_report.history.len(),
        polish_cost.cpu,
        polish_cost.wall,
        scores(&polished_scores),
        polish_report.last().relative_mse()
    );
    let energy = trilinear_energy(f);
    block_and_clustered_pca(f, l, nodes, &mut |name, cost, m| {
        // The baselines are trilinear interpolations of their voxel reconstructions, so the
        // trilinear energy of the difference is their exact error.
        let diff = GridField::from_data(f.dims(), f.bounds(), m.reconstruction().data() - f.data())
            .expect("difference grid");
        println!(
            "{name}: {:.1} s CPU, {}, exact {:.4e}",
            cost.cpu,
            scores(&score(m, &input, m.labels())),
            trilinear_energy(&diff) / energy
        );
    });
    println!("load average after: {}\n", load_average());
}

/// The error curve of a two-phase fit as CSV (`phase,step,cpu,wall,relative_mse`): the
/// solver's held-out error at every measurement, then the exact error after every polish
/// sweep. The records carry wall time only, so `cpu` scales it by each phase's CPU / wall.
fn write_two_phase_history(
    path: &std::path::Path,
    solve: &SolveReport,
    solve_cost: &Cost,
    polish: &PolishReport,
    polish_cost: &Cost,
) {
    let scale = |c: &Cost| if c.wall > 0.0 { c.cpu / c.wall } else { 1.0 };
    let (solve_scale, polish_scale) = (scale(solve_cost), scale(polish_cost));
    let mut csv = String::from("phase,step,cpu,wall,relative_mse\n");
    for (i, r) in solve.history.iter().enumerate() {
        if let Some(h) = r.held_out {
            csv += &format!(
                "solver,{},{},{},{h}\n",
                i + 1,
                r.elapsed * solve_scale,
                r.elapsed
            );
        }
    }
    let mut sweep = 0;
    for (k, r) in polish.history.iter().enumerate() {
        let next_is_basis = polish
            .history
            .get(k + 1)
            .is_none_or(|n| n.step == PolishStep::Basis);
        sweep += usize::from(r.step == PolishStep::Basis);
        if next_is_basis {
            csv += &format!(
                "polish,{sweep},{},{},{}\n",
                solve_cost.cpu + r.elapsed * polish_scale,
                solve_cost.wall + r.elapsed,
                r.loss.relative_mse()
            );
        }
    }
    std::fs::create_dir_all(path.parent().unwrap_or(std::path::Path::new("."))).ok();
    std::fs::write(path, csv).ok();
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let mode = args.first().cloned().unwrap_or_else(|| "all".into());
    if mode == "plot" {
        plot_csv(&args[1..]);
        return;
    }
    println!(
        "threads: {}, load average before: {}\n",
        rayon::current_num_threads(),
        load_average()
    );
    match mode.as_str() {
        "basis" => basis_count(),
        "grid" => grid_resolution(),
        "timing" => timing(),
        "convergence" => convergence(),
        "quality" => quality(),
        "ridge" => ridge(),
        "floor" => floor(),
        "walls" => walls(),
        "adaptive" => adaptive(),
        "polish" => polish_sweep(),
        _ => {
            basis_count();
            grid_resolution();
            timing();
            convergence();
        }
    }
}
