//! The MBD scale test of issue 5: a smooth synthetic 12-D field (linear SH irradiance, RGB: 4
//! coefficients × 3 channels) on a 512 × 512 × 128 coefficient grid at rank 3, about 10⁸ unknowns.
//! Target: solves in ≤ 20 minutes with ≤ 12 GB peak memory.
//!
//! `cargo run --release -p prt-benches --bin mbd_scale -- [NX NY NZ [ITERATIONS [SPACING]]]`
//!
//! Defaults: 512 512 128, 16 iterations, basis nodes every `SPACING` = 32 voxels (17 × 17 × 5
//! nodes at full size). Prints the time and CPU time of building the field, the
//! initialisation and every iteration, the relative MSE (one jittered sample per voxel), and the
//! peak resident memory (`VmHWM`); run it under `/usr/bin/time -v` for an outside check.

use std::sync::Mutex;
use std::time::Instant;

use prt_benches::cpu_seconds;
use prt_core::{Aabb, FieldModel, Progress};
use prt_mbd::{EvalOptions, Mbd, MbdOptions, SyntheticField, evaluate};

/// Linear SH (4 coefficients) for R, G and B.
const DIM: usize = 12;
const RANK: usize = 3;

/// A `/proc/self/status` memory line (`VmRSS`, `VmHWM`) in GiB.
fn memory_gib(key: &str) -> f64 {
    std::fs::read_to_string("/proc/self/status")
        .unwrap_or_default()
        .lines()
        .find_map(|l| l.strip_prefix(key))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<f64>().ok())
        .map_or(f64::NAN, |kb| kb / (1024.0 * 1024.0))
}

fn load_average() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .map(|s| s.split_whitespace().take(3).collect::<Vec<_>>().join(" "))
        .unwrap_or_else(|_| "unknown".into())
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
            memory_gib("VmRSS:"),
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
    let args: Vec<usize> = std::env::args()
        .skip(1)
        .map(|a| a.parse().expect("arguments are integers"))
        .collect();
    let dims = match args.get(..3) {
        Some(&[x, y, z]) => [x, y, z],
        _ => [512, 512, 128],
    };
    let iterations = args.get(3).copied().unwrap_or(16);
    let spacing = args.get(4).copied().unwrap_or(32).max(1);
    let nodes = dims.map(|n| (n / spacing + 1).max(2));
    let voxels: usize = dims.iter().product();
    let basis_nodes: usize = nodes.iter().product();
    let unknowns = voxels * RANK + basis_nodes * RANK * DIM;
    println!(
        "MBD scale test: {dims:?} × {DIM}, rank {RANK}, basis nodes {nodes:?}, {unknowns} unknowns \
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
        dim: DIM,
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
        memory_gib("VmRSS:")
    );

    let mbd = Mbd {
        basis_nodes: nodes,
        options: MbdOptions {
            rank: RANK,
            max_iterations: iterations,
            ..MbdOptions::default()
        },
    };
    let log = IterationLog {
        start: Instant::now(),
        cpu0: cpu_seconds(),
        last_message: Mutex::new(String::new()),
    };
    let (model, report) = mbd.fit(&field, &log).expect("MBD solve");
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
        memory_gib("VmHWM:")
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
            samples_per_voxel: 1,
            ..EvalOptions::default()
        },
    )
    .expect("evaluate");
    println!(
        "relative MSE {:.4e} (1 jittered sample per voxel, {:.1} s); stored scalars {} ({:.1}% of \
         the field)",
        e.relative_mse,
        t.elapsed().as_secs_f64(),
        model.stored_scalars(),
        100.0 * model.stored_scalars() as f64 / field.data().len() as f64
    );
    println!(
        "total {:.1} s (CPU {:.1} s), peak RSS {:.2} GiB, load average after {}",
        total.elapsed().as_secs_f64(),
        cpu_seconds() - cpu0,
        memory_gib("VmHWM:"),
        load_average()
    );
}
