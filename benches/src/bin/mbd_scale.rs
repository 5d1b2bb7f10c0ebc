//! MBD solve time and memory at scale, on the smooth synthetic field: the scale test (a 12-D
//! field, linear SH irradiance in RGB, on 512 × 512 × 128 voxels at rank 3: about 10⁸
//! unknowns; target ≤ 20 minutes and ≤ 12 GB) and the paper's Figure 8 size (324-D, 64³
//! voxels, 9³ basis nodes, rank 8, 32 iterations).
//!
//! ```text
//! cargo run --release -p prt-benches --bin mbd_scale                   # the scale test
//! cargo run --release -p prt-benches --bin mbd_scale -- --dims 64,64,64 --dim 324 --rank 8 --nodes 9 --iterations 32 --tolerance 0
//! ```
//!
//! Prints the time and CPU time of building the field, the initialisation and every
//! iteration, the relative MSE (`--eval-samples` jittered samples per voxel), and the peak
//! resident memory (`VmHWM`); run it under `/usr/bin/time -v` for an outside check.

use std::sync::Mutex;
use std::time::Instant;

use clap::Parser;
use prt_benches::{cpu_seconds, load_average, peak_resident_bytes, resident_bytes};
use prt_core::{Aabb, FieldModel, Progress};
use prt_mbd::{Basis, EvalOptions, Mbd, SyntheticField, evaluate};

/// Bytes per GiB.
const GIB: f64 = (1u64 << 30) as f64;

#[derive(Debug, Parser)]
#[command(about = "MBD solve time and memory at scale on the synthetic field")]
struct Cli {
    /// Voxels along x, y, z.
    #[arg(long, value_delimiter = ',', default_value = "512,512,128")]
    dims: Vec<usize>,
    /// Dimension of the field's vectors (12: linear SH in RGB; 324: a transfer volume).
    #[arg(long, default_value_t = 12)]
    dim: usize,
    /// Rank L.
    #[arg(long, default_value_t = 3)]
    rank: usize,
    /// Solver iteration cap.
    #[arg(long, default_value_t = 16)]
    iterations: usize,
    /// Solver stopping tolerance [default: the solver's].
    #[arg(long)]
    tolerance: Option<f64>,
    /// Basis nodes per axis [default: one every `--spacing` voxels].
    #[arg(long)]
    nodes: Option<usize>,
    /// Voxels between basis nodes when `--nodes` is not given.
    #[arg(long, default_value_t = 32)]
    spacing: usize,
    /// Jittered samples per voxel of the final evaluation.
    #[arg(long, default_value_t = 1)]
    eval_samples: usize,
}

/// Prints one line per solver iteration (the solver reports one unit per iteration and the
/// loss as message).
struct IterationLog {
    start: Instant,
    cpu0: f64,
    last_message: Mutex<String>,
}

impl Progress for IterationLog {
    fn set_len(&self, _len: u64) {}

    fn inc(&self, _delta: u64) {
        let message = self
            .last_message
            .lock()
            .map(|m| m.clone())
            .unwrap_or_default();
        eprintln!(
            "  iteration done at {:.1} s (CPU {:.1} s, RSS {:.2} GiB): {message}",
            self.start.elapsed().as_secs_f64(),
            cpu_seconds() - self.cpu0,
            resident_bytes() / GIB,
        );
    }

    fn message(&self, msg: &str) {
        if let Ok(mut m) = self.last_message.lock() {
            *m = msg.to_string();
        }
    }

    fn is_cancelled(&self) -> bool {
        false
    }
}

fn main() {
    let cli = Cli::parse();
    let [x, y, z] = cli.dims[..] else {
        eprintln!("--dims takes three voxel counts, e.g. 512,512,128");
        std::process::exit(2);
    };
    let dims = [x, y, z];
    let (dim, rank, iterations) = (cli.dim, cli.rank, cli.iterations);
    let nodes = match cli.nodes {
        Some(n) => [n; 3],
        None => dims.map(|n| (n / cli.spacing.max(1) + 1).max(2)),
    };
    let voxels: usize = dims.iter().product();
    let basis_nodes: usize = nodes.iter().product();
    let unknowns = voxels * rank + basis_nodes * rank * dim;
    println!(
        "MBD scale test: {dims:?} × {dim}, rank {rank}, basis nodes {nodes:?}, {unknowns} unknowns \
         ({:.3e}), ≤ {iterations} iterations, {} threads, load average before {}",
        unknowns as f64,
        rayon::current_num_threads(),
        load_average()
    );

    let total = Instant::now();
    let cpu0 = cpu_seconds();
    // Box proportional to the grid (cubic voxels), so the field's smoothness per voxel is the
    // same along every axis.
    let longest = dims.iter().copied().max().unwrap_or(1) as f32;
    let bounds = Aabb::new(
        glam::Vec3::ZERO,
        glam::Vec3::from_array(dims.map(|n| n as f32 / longest)),
    );
    let field = SyntheticField {
        dims,
        dim,
        harmonics: 4,
        seed: 1,
    }
    .build(bounds)
    .expect("synthetic field");
    let build = (total.elapsed().as_secs_f64(), cpu_seconds() - cpu0);
    println!(
        "field: {:.1} s (CPU {:.1} s), {:.2} GiB of f32, RSS {:.2} GiB",
        build.0,
        build.1,
        field.data().len() as f64 * 4.0 / (1u64 << 30) as f64,
        resident_bytes() / GIB
    );

    let mut mbd = Mbd::new(rank, Basis::HatGrid { nodes });
    mbd.solver.max_iterations = iterations;
    if let Some(tolerance) = cli.tolerance {
        mbd.solver.tolerance = tolerance;
    }
    let log = IterationLog {
        start: Instant::now(),
        cpu0: cpu_seconds(),
        last_message: Mutex::new(String::new()),
    };
    let fit = mbd.fit(&field, &log).expect("MBD solve");
    let (model, report) = (fit.model, fit.solve);
    let solve_wall = log.start.elapsed().as_secs_f64();
    let solve_cpu = cpu_seconds() - log.cpu0;
    let iteration_seconds = report.history.last().map_or(0.0, |r| r.elapsed) - report.init_seconds;
    println!(
        "solve: {solve_wall:.1} s (CPU {solve_cpu:.1} s): init {:.1} s, {} iterations in {:.1} s \
         ({:.1} s each), converged: {}, peak RSS so far {:.2} GiB",
        report.init_seconds,
        report.history.len(),
        iteration_seconds,
        iteration_seconds / report.history.len().max(1) as f64,
        report.converged,
        peak_resident_bytes() / GIB
    );
    for (i, r) in report.history.iter().enumerate() {
        println!(
            "  iteration {:>2}: loss {:.4e} -> {:.4e}, step {}, at {:.1} s",
            i + 1,
            r.loss_before,
            r.loss_after,
            r.step,
            r.elapsed
        );
    }

    let t = Instant::now();
    let e = evaluate(
        &model,
        &field,
        &EvalOptions {
            samples_per_voxel: cli.eval_samples,
            ..EvalOptions::default()
        },
    )
    .expect("evaluate");
    println!(
        "relative MSE {:.4e} ({} jittered samples per voxel, {:.1} s); stored scalars {} ({:.1}% \
         of the field)",
        e.relative_mse,
        cli.eval_samples,
        t.elapsed().as_secs_f64(),
        model.stored_scalars(),
        100.0 * model.stored_scalars() as f64 / field.data().len() as f64
    );
    println!(
        "total {:.1} s (CPU {:.1} s), peak RSS {:.2} GiB, load average after {}",
        total.elapsed().as_secs_f64(),
        cpu_seconds() - cpu0,
        peak_resident_bytes() / GIB,
        load_average()
    );
}
