//! Times `polish` on the synthetic 324-D field (wall and process CPU):
//! `cargo run --release -p prt-mbd --example polish_timing -- [n] [basis nodes] [rank] [sweeps] [solver iterations]`
//! `[-log10 CG tolerance]` (default 32 5 8 4 128 8).

use std::time::Instant;

use prt_core::{Aabb, NoProgress};
use prt_mbd::{Mbd, MbdOptions, PolishOptions, SyntheticField, polish};

fn arg(i: usize, default: usize) -> usize {
    std::env::args()
        .nth(i)
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

/// Process CPU time (user + system) in seconds.
fn cpu_seconds() -> f64 {
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    let fields: Vec<&str> = stat
        .rsplit(')')
        .next()
        .unwrap_or("")
        .split_whitespace()
        .collect();
    let ticks: f64 = [11, 12]
        .iter()
        .filter_map(|&i| fields.get(i).and_then(|v| v.parse::<f64>().ok()))
        .sum();
    ticks / 100.0
}

fn main() {
    let (n, b, rank, sweeps, iterations) =
        (arg(1, 32), arg(2, 5), arg(3, 8), arg(4, 4), arg(5, 128));
    let field = SyntheticField {
        dims: [n; 3],
        dim: 324,
        harmonics: 4,
        seed: 1,
    }
    .build(Aabb::UNIT)
    .expect("field");
    let mbd = Mbd {
        basis_nodes: [b; 3],
        options: MbdOptions {
            rank,
            max_iterations: iterations,
            ..MbdOptions::default()
        },
    };
    let (model, _) = mbd.fit(&field, &NoProgress).expect("fit");
    let options = PolishOptions {
        sweeps,
        cg_tolerance: 10f64.powi(-(arg(6, 8) as i32)),
        tolerance: 0.0,
        ..PolishOptions::default()
    };
    let (wall, cpu) = (Instant::now(), cpu_seconds());
    let (_, report) = polish(&field, model, &options, &NoProgress).expect("polish");
    println!(
        "{n}³ / {b}³ / L = {rank}: {sweeps} sweeps in {:.2} s wall, {:.2} s CPU; exact relative MSE {:.4e} -> {:.4e}",
        wall.elapsed().as_secs_f64(),
        cpu_seconds() - cpu,
        report.initial.relative_mse(),
        report.last().relative_mse()
    );
    for r in &report.history {
        println!(
            "{:?} {:.4e} cg {} at {:.2} s",
            r.step,
            r.loss.relative_mse(),
            r.cg_iterations,
            r.elapsed
        );
    }
}
