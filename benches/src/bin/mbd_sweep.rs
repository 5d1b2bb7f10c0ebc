//! Moving Basis Decomposition against the PCA family on 324-D fields: error vs basis count
//! (paper Figure 5), vs basis-grid resolution (Figure 7), solve times (Figure 8), the solver's
//! convergence, and the exact polish.
//!
//! ```text
//! cargo run --release -p prt-benches --bin mbd_sweep -- <MODE> [--field F] [--n N] [flags]
//! ```
//!
//! Modes: `basis` (error vs rank L at 5³ nodes), `grid` (error vs basis nodes per axis at
//! L = 8), `timing` (16³ / 3³, 32³ / 5³, 64³ / 9³, 32 iterations), `convergence` (the paper's
//! diagonal against the block preconditioner after 4 / 16 / 64 iterations), `floor` (the
//! held-out error of long runs, per averaging window), `polish` (the exact polish after the
//! solver, step by step, beside the baselines' exact errors), `plot` (a sweep's CSV as a
//! log-scale plot). `--help` lists every flag.
//!
//! Every row reports wall time and the process CPU time of the method; the load average is
//! printed before and after. The seam columns are `prt_mbd::error_seams` with the reference
//! blurred by one voxel on traced volumes (their Monte Carlo noise would drown the seams) and
//! not at all on the noise-free synthetic field: "seam excess" is the RMS step of the error at
//! cluster / basis-cell boundaries beyond the jumps inside them, relative to the field's RMS;
//! "seam ratio" the boundary over the interior RMS jump; "seam excess (raw error)" the excess
//! against the unblurred reference.

use std::path::{Path, PathBuf};

use clap::{Parser, Subcommand};
use prt_benches::load_average;
use prt_benches::mbd::{Cost, FieldArgs, Input, basis_nodes, method_enabled};
use prt_benches::{Table, fmt_duration};
use prt_core::{Compressor, FieldModel, GridField, NoProgress, resample_to_grid};
use prt_mbd::expert::{PolishStep, kernel_labels, polish, trilinear_energy};
use prt_mbd::*;

#[derive(Debug, Parser)]
#[command(about = "MBD against the PCA family: Figures 5, 7 and 8, convergence, polish")]
struct Cli {
    #[command(subcommand)]
    mode: Mode,
    #[command(flatten)]
    field: FieldArgs,
    /// Knob values of the `basis` (ranks) and `grid` (nodes per axis) sweeps [default: 2,4,8,16
    /// and 9,7,5,3].
    #[arg(long, value_delimiter = ',', global = true)]
    knobs: Vec<usize>,
    /// Methods to run: MBD, PCA, BPCA, WBPCA, CPCA, VQ [default: all].
    #[arg(long, value_delimiter = ',', global = true)]
    methods: Vec<String>,
    /// Also write each table as CSV into this folder.
    #[arg(long, global = true)]
    csv: Option<PathBuf>,
    /// Rank L (`floor`, `polish`).
    #[arg(long, default_value_t = 8, global = true)]
    rank: usize,
    /// Basis nodes (blocks, clusters) per axis (`floor`, `polish`).
    #[arg(long, default_value_t = 5, global = true)]
    nodes: usize,
    /// Solver iteration cap [default: 64 for the sweeps, 512 for `floor`, 128 for `polish`].
    #[arg(long, global = true)]
    iterations: Option<usize>,
    /// Solver stopping tolerance [default: 0 for `floor`, the solver's otherwise].
    #[arg(long, global = true)]
    tolerance: Option<f64>,
}

#[derive(Debug, Subcommand)]
enum Mode {
    /// Error vs basis count L (Figure 5), 5³ basis nodes.
    Basis,
    /// Error vs basis nodes per axis (Figure 7), L = 8.
    Grid,
    /// Solve times (Figure 8) on the synthetic field, 32 iterations.
    Timing {
        /// Largest field (16, 32 or 64 voxels per axis).
        #[arg(long, default_value_t = 64)]
        max_n: usize,
    },
    /// The paper's diagonal against the block preconditioner.
    Convergence,
    /// Held-out error of long runs, per averaging window of the iterates.
    Floor {
        /// Averaging windows (0: the last iterate).
        #[arg(long, value_delimiter = ',', default_value = "0,16")]
        windows: Vec<usize>,
        /// Write each run's per-iteration history as CSV into this folder.
        #[arg(long)]
        history_dir: Option<PathBuf>,
    },
    /// The exact polish after the solver, beside the baselines' exact errors.
    Polish {
        /// Polish iteration cap.
        #[arg(long, default_value_t = 16)]
        polish_iterations: usize,
        /// Polish stopping tolerance (0: every iteration).
        #[arg(long, default_value_t = 0.0)]
        polish_tolerance: f64,
    },
    /// Plots a sweep's CSV: relative MSE against the knob, one line per method.
    Plot {
        /// The CSV a sweep wrote.
        csv: PathBuf,
        /// The PNG to write.
        png: PathBuf,
        /// The plot's title.
        title: String,
        /// The x axis' label.
        x_label: String,
    },
}

/// The transfer vector as four 9 × 9 operators.
const BLOCKS: [usize; 4] = [81, 81, 81, 81];

struct Scores {
    relative_mse: f64,
    operator: f64,
    seam_excess: f64,
    seam_ratio: f64,
    raw_seam_excess: f64,
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
        error_seams(field, &recon, labels, &options).expect("seam")
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

fn row(table: &mut Table, knob: usize, method: &str, cost: Cost, s: &Scores, stored: usize) {
    eprintln!(
        "{knob} {method} {:.3} s (CPU {:.2} s), relative MSE {:.3e}",
        cost.wall, cost.cpu, s.relative_mse
    );
    table.row(vec![
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

/// Fits one baseline.
type BaselineFit = Box<dyn Fn(&GridField) -> PiecewisePcaModel>;

/// The baselines at rank `l` on `nodes` blocks / `nodes` clusters: (name, fit).
fn baselines(l: usize, nodes: [usize; 3]) -> Vec<(&'static str, BaselineFit)> {
    // BPCA (window 1) and WBPCA (window 2) differ only in their blending window.
    let block = |window: f32| -> BaselineFit {
        Box::new(move |f: &GridField| {
            BlockPca {
                rank: l,
                blocks: nodes,
                window,
                loss_weighting: None,
            }
            .compress(f, &NoProgress)
            .expect("blockwise PCA")
        })
    };
    let clusters = nodes.iter().product::<usize>();
    vec![
        (
            "PCA",
            Box::new(move |f: &GridField| {
                GlobalPca { rank: l }.compress(f, &NoProgress).expect("pca")
            }),
        ),
        ("BPCA", block(1.0)),
        ("WBPCA", block(2.0)),
        (
            "CPCA",
            Box::new(move |f: &GridField| {
                ClusteredPca::new(l, clusters)
                    .compress(f, &NoProgress)
                    .expect("cpca")
            }),
        ),
        (
            "VQ",
            Box::new(move |f: &GridField| {
                KMeansVq {
                    codewords: (clusters * l).min(f.num_voxels()),
                    iterations: 10,
                    seed: 0,
                }
                .compress(f, &NoProgress)
                .expect("vq")
            }),
        ),
    ]
}

/// Every enabled method at rank `l` with `b³` basis nodes / blocks / clusters (fewer on a short
/// axis, as `prt bake` does).
fn compare(
    cli: &Cli,
    table: &mut Table,
    knob: usize,
    input: &Input,
    l: usize,
    b: usize,
    iterations: usize,
) {
    let field = &input.field;
    let nodes = basis_nodes(field, b);
    let enabled = |m: &str| {
        method_enabled(
            &cli.methods,
            &["MBD", "PCA", "BPCA", "WBPCA", "CPCA", "VQ"],
            m,
        )
    };
    if enabled("MBD") {
        eprintln!("{knob}: fitting MBD");
        let mut mbd = Mbd::new(l, Basis::HatGrid { nodes });
        mbd.solver.max_iterations = iterations;
        if let Some(tolerance) = cli.tolerance {
            mbd.solver.tolerance = tolerance;
        }
        let (fit, cost) = Cost::measure(|| mbd.fit(field, &NoProgress).expect("mbd"));
        eprintln!(
            "{knob}: MBD {} iterations, converged: {}",
            fit.solve.history.len(),
            fit.solve.converged
        );
        let labels = kernel_labels(fit.model.basis_kernels(), field).expect("labels");
        row(
            table,
            knob,
            "MBD",
            cost,
            &score(&fit.model, input, &labels),
            fit.model.stored_scalars(),
        );
    }
    for (name, fit) in baselines(l, nodes) {
        if enabled(name) {
            let (m, cost) = Cost::measure(|| fit(field));
            row(
                table,
                knob,
                name,
                cost,
                &score(&m, input, m.labels()),
                m.stored_scalars(),
            );
        }
    }
}

fn finish(cli: &Cli, table: &Table, heading: String, csv: &str) {
    println!("### {heading}\n\n{}", table.markdown());
    println!("load average after: {}\n", load_average());
    if let Err(e) = table.write_csv(cli.csv.as_deref(), csv) {
        eprintln!("cannot write {csv}.csv: {e}");
    }
}

/// Relative MSE against the knob, one line per method, log scale.
fn plot(points: &[(usize, String, f64)], x_label: &str, title: &str, path: &Path) {
    let points: Vec<prt_benches::PlotPoint> = points
        .iter()
        .map(|(knob, method, error)| (method.clone(), *knob as f64, *error))
        .collect();
    let labels = prt_benches::PlotLabels {
        title,
        x: x_label,
        y: "relative MSE",
        x_ticks: &|v| format!("{v}"),
    };
    prt_benches::plot_lines(&points, &labels, path).expect("plot");
    eprintln!("wrote {}", path.display());
}

/// Relative MSE of a sweep's CSV against its knob.
fn plot_csv(csv: &Path, png: &Path, title: &str, x_label: &str) {
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

fn knobs(cli: &Cli, default: &[usize]) -> Vec<usize> {
    if cli.knobs.is_empty() {
        default.to_vec()
    } else {
        cli.knobs.clone()
    }
}

fn basis_count(cli: &Cli) {
    let input = cli.field.load();
    let iterations = cli.iterations.unwrap_or(64);
    let mut table = Table::new(&HEADER);
    for l in knobs(cli, &[2, 4, 8, 16]) {
        compare(cli, &mut table, l, &input, l, 5, iterations);
    }
    let name = &input.name;
    finish(
        cli,
        &table,
        format!("Error vs basis count L ({name}, 5³ basis nodes, MBD ≤ {iterations} iterations)"),
        "mbd_basis",
    );
}

fn grid_resolution(cli: &Cli) {
    let input = cli.field.load();
    let iterations = cli.iterations.unwrap_or(64);
    let mut table = Table::new(&HEADER);
    for b in knobs(cli, &[9, 7, 5, 3]) {
        compare(cli, &mut table, b, &input, 8, b, iterations);
    }
    let name = &input.name;
    finish(
        cli,
        &table,
        format!(
            "Error vs basis-grid resolution b (b³ nodes; {name}, L = 8, MBD ≤ {iterations} iterations)"
        ),
        "mbd_grid",
    );
}

fn timing(cli: &Cli, max_n: usize) {
    let iterations = cli.iterations.unwrap_or(32);
    let mut table = Table::new(&HEADER);
    for (n, b) in [(16, 3), (32, 5), (64, 9)] {
        if n <= max_n {
            let input = Input {
                field: prt_benches::mbd::synthetic_field(n),
                name: String::new(),
                valid: None,
                seam_sigma: 0.0,
            };
            compare(cli, &mut table, n, &input, 8, b, iterations);
        }
    }
    finish(
        cli,
        &table,
        format!(
            "Timings (324-D, n³ voxels with 3³/5³/9³ nodes, L = 8, MBD {iterations} iterations)"
        ),
        "mbd_timing",
    );
}

fn convergence(cli: &Cli) {
    let input = cli.field.load();
    let f = &input.field;
    let mut table = Table::new(&["solver", "iterations", "time", "relative MSE"]);
    for (name, preconditioner) in [
        ("stochastic, paper diagonal", Preconditioner::Diagonal),
        ("stochastic, lumped blocks (default)", Preconditioner::Block),
    ] {
        for iterations in [4, 16, 64] {
            let mut mbd = Mbd::new(8, Basis::HatGrid { nodes: [5; 3] });
            mbd.solver = SolverOptions {
                max_iterations: iterations,
                preconditioner,
                tolerance: 0.0,
                ..SolverOptions::default()
            };
            let (fit, cost) = Cost::measure(|| mbd.fit(f, &NoProgress).expect("mbd"));
            let e = evaluate(&fit.model, f, &EvalOptions::default()).expect("evaluate");
            table.row(vec![
                name.into(),
                iterations.to_string(),
                fmt_duration(std::time::Duration::from_secs_f64(cost.wall)),
                format!("{:.4e}", e.relative_mse),
            ]);
        }
    }
    finish(
        cli,
        &table,
        format!("Convergence ({}, 5³ nodes, L = 8)", input.name),
        "mbd_convergence",
    );
}

fn floor(cli: &Cli, windows: &[usize], history_dir: Option<&Path>) {
    let input = cli.field.load();
    let f = &input.field;
    let (l, b) = (cli.rank, cli.nodes);
    let iterations = cli.iterations.unwrap_or(512);
    let nodes = basis_nodes(f, b);
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
    for &average_window in windows {
        let mut mbd = Mbd::new(l, Basis::HatGrid { nodes });
        mbd.solver = SolverOptions {
            max_iterations: iterations,
            tolerance: cli.tolerance.unwrap_or(0.0),
            average_window,
            ..SolverOptions::default()
        };
        let (fit, cost) = Cost::measure(|| mbd.fit(f, &NoProgress).expect("mbd"));
        let report = &fit.solve;
        let e = evaluate(&fit.model, f, &EvalOptions::default()).expect("evaluate");
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
        if let Some(dir) = history_dir {
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
            let path = dir.join(format!("floor_{average_window}.csv"));
            if let Err(e) = std::fs::create_dir_all(dir).and_then(|()| std::fs::write(&path, csv)) {
                eprintln!("cannot write {}: {e}", path.display());
            }
        }
    }
    finish(
        cli,
        &table,
        format!("Long runs ({}, L = {l}, {b}³ basis nodes)", input.name),
        "mbd_floor",
    );
}

fn polish_sweep(cli: &Cli, polish_iterations: usize, polish_tolerance: f64) {
    let input = cli.field.load();
    let f = &input.field;
    let (l, b) = (cli.rank, cli.nodes);
    let nodes = basis_nodes(f, b);
    let mut mbd = Mbd::new(l, Basis::HatGrid { nodes });
    mbd.solver.max_iterations = cli.iterations.unwrap_or(128);
    if let Some(tolerance) = cli.tolerance {
        mbd.solver.tolerance = tolerance;
    }
    let (fit, solve_cost) = Cost::measure(|| mbd.fit(f, &NoProgress).expect("mbd"));
    let labels = kernel_labels(fit.model.basis_kernels(), f).expect("labels");
    let solved = score(&fit.model, &input, &labels);
    let scores = |s: &Scores| {
        format!(
            "evaluate {:.4e}, seam excess {:.2e} (ratio {:.2})",
            s.relative_mse, s.seam_excess, s.seam_ratio
        )
    };
    let options = PolishOptions {
        iterations: polish_iterations,
        tolerance: polish_tolerance,
        ..PolishOptions::default()
    };
    let ((polished, report), polish_cost) =
        Cost::measure(|| polish(f, fit.model, &options, &NoProgress).expect("polish"));
    let mut table = Table::new(&[
        "step",
        "exact relative MSE",
        "exact loss (data + ridge)",
        "CG iterations",
        "seconds since the polish started (wall)",
    ]);
    let initial = report.initial;
    table.row(vec![
        format!("stochastic solver, {} iterations", fit.solve.history.len()),
        format!("{:.4e}", initial.relative_mse()),
        format!("{:.6e}", initial.loss()),
        "–".into(),
        "0".into(),
    ]);
    let mut iteration = 0;
    for r in &report.history {
        iteration += usize::from(r.step == PolishStep::Coefficients);
        table.row(vec![
            format!(
                "iteration {iteration} {:?}{}",
                r.step,
                if r.accepted { "" } else { " (rejected)" }
            ),
            format!("{:.4e}", r.loss.relative_mse()),
            format!("{:.6e}", r.loss.loss()),
            r.cg_iterations.to_string(),
            format!("{:.1}", r.elapsed),
        ]);
    }
    let polished_scores = score(&polished, &input, &labels);
    println!(
        "### Exact polish ({}, L = {l}, {b}³ basis nodes)\n\n{}",
        input.name,
        table.markdown()
    );
    println!(
        "stochastic solve: {} iterations, {:.1} s CPU ({:.1} s wall), {}, exact {:.4e}",
        fit.solve.history.len(),
        solve_cost.cpu,
        solve_cost.wall,
        scores(&solved),
        initial.relative_mse()
    );
    println!(
        "polish: {iteration} iterations, {:.1} s CPU ({:.1} s wall), {}, exact {:.4e}",
        polish_cost.cpu,
        polish_cost.wall,
        scores(&polished_scores),
        report.last().relative_mse()
    );
    let energy = trilinear_energy(f);
    for (name, fit) in baselines(l, nodes) {
        if !method_enabled(&cli.methods, &["BPCA", "WBPCA", "CPCA"], name) {
            continue;
        }
        let (m, cost) = Cost::measure(|| fit(f));
        // The baselines are trilinear interpolations of their voxel reconstructions, so the
        // trilinear energy of the difference is their exact error.
        let diff = GridField::from_data(
            f.dims(),
            f.bounds(),
            m.reconstruct().expect("reconstruction").data() - f.data(),
        )
        .expect("difference grid");
        println!(
            "{name}: {:.1} s CPU, {}, exact {:.4e}",
            cost.cpu,
            scores(&score(&m, &input, m.labels())),
            trilinear_energy(&diff) / energy
        );
    }
    println!("load average after: {}\n", load_average());
}

fn main() {
    let cli = Cli::parse();
    if let Mode::Plot {
        csv,
        png,
        title,
        x_label,
    } = &cli.mode
    {
        plot_csv(csv, png, title, x_label);
        return;
    }
    println!(
        "threads: {}, load average before: {}\n",
        rayon::current_num_threads(),
        load_average()
    );
    match &cli.mode {
        Mode::Basis => basis_count(&cli),
        Mode::Grid => grid_resolution(&cli),
        Mode::Timing { max_n } => timing(&cli, *max_n),
        Mode::Convergence => convergence(&cli),
        Mode::Floor {
            windows,
            history_dir,
        } => floor(&cli, windows, history_dir.as_deref()),
        Mode::Polish {
            polish_iterations,
            polish_tolerance,
        } => polish_sweep(&cli, *polish_iterations, *polish_tolerance),
        Mode::Plot { .. } => unreachable!("handled above"),
    }
}
