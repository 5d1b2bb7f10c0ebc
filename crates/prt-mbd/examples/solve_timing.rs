//! Wall and CPU time of MBD fits on the synthetic 324-D field (`harmonics: 4`, seed 1), with a
//! fixed number of iterations (tolerance 0), and the relative MSE of the result:
//!
//! `cargo run --release -p prt-mbd --example solve_timing -- <n> <basis nodes> <iterations> <ranks>`
//!
//! e.g. `-- 64 9 32 8` (the paper's Figure 8 size) or `-- 16 5 64 8,16` (rank sweep). CPU time
//! is the process's user + system time during the fit (Linux `/proc/self/stat`), summed over
//! threads. `MBD_HISTORY=1` also prints the loss of every iteration; `MBD_PLAIN=1` turns off
//! momentum and iterate averaging (the session-3 solver, for same-load comparisons).
use std::time::Instant;

use prt_core::{Aabb, NoProgress};
use prt_mbd::*;

/// User + system CPU seconds of this process so far (None where `/proc` is unavailable).
fn cpu_seconds() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    // Fields after the command name: state is field 3, utime 14, stime 15 (clock ticks).
    let fields: Vec<&str> = stat.rsplit(')').next()?.split_whitespace().collect();
    let ticks = |i: usize| fields.get(i)?.parse::<f64>().ok();
    Some((ticks(11)? + ticks(12)?) / 100.0)
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let arg =
        |i: usize, default: usize| args.get(i).and_then(|a| a.parse().ok()).unwrap_or(default);
    let (n, nodes, iterations) = (arg(0, 64), arg(1, 9), arg(2, 32));
    let ranks: Vec<usize> = args
        .get(3)
        .map(|s| s.split(',').filter_map(|r| r.parse().ok()).collect())
        .unwrap_or_else(|| vec![8]);
    let field = SyntheticField {
        dims: [n; 3],
        dim: 324,
        harmonics: 4,
        seed: 1,
    }
    .build(Aabb::UNIT)
    .expect("synthetic field");
    println!(
        "{n}³ × 324, {nodes}³ basis nodes, {iterations} iterations, {} threads",
        rayon::current_num_threads()
    );
    for rank in ranks {
        let mut options = MbdOptions {
            rank,
            max_iterations: iterations,
            tolerance: 0.0,
            ..MbdOptions::default()
        };
        if std::env::var_os("MBD_PLAIN").is_some() {
            options.momentum_basis = 0.0;
            options.momentum_coefficients = 0.0;
            options.average_window = 0;
        }
        let (wall, cpu) = (Instant::now(), cpu_seconds());
        let (model, report) = Mbd {
            basis_nodes: [nodes; 3],
            options,
        }
        .fit(&field, &NoProgress)
        .expect("fit");
        let wall = wall.elapsed().as_secs_f64();
        let cpu = match (cpu, cpu_seconds()) {
            (Some(a), Some(b)) => format!("{:.2} s", b - a),
            _ => "n/a".into(),
        };
        let error = evaluate(&model, &field, &EvalOptions::default())
            .expect("evaluate")
            .relative_mse;
        println!(
            "L = {rank}: wall {wall:.3} s, CPU {cpu}, init {:.3} s, relative MSE {error:.3e}",
            report.init_seconds
        );
        if std::env::var_os("MBD_HISTORY").is_some() {
            for (i, r) in report.history.iter().enumerate() {
                println!(
                    "  {i:3}: {:.5e} -> {:.5e}, step {}",
                    r.loss_before, r.loss_after, r.step
                );
            }
        }
    }
}
