//! Times the pieces of an MBD fit and its baselines on a synthetic 324-D field:
//! `cargo run --release -p prt-mbd --example profile -- 32 5 8`.
use std::time::Instant;

use prt_core::{Aabb, Compressor, NoProgress};
use prt_mbd::*;

fn main() {
    let args: Vec<usize> = std::env::args()
        .skip(1)
        .filter_map(|a| a.parse().ok())
        .collect();
    let (n, b, l) = (
        args.first().copied().unwrap_or(32),
        args.get(1).copied().unwrap_or(5),
        args.get(2).copied().unwrap_or(8),
    );
    let t = Instant::now();
    let field = SyntheticField {
        dims: [n; 3],
        dim: 324,
        harmonics: 4,
        seed: 1,
    }
    .build(Aabb::UNIT)
    .unwrap();
    println!("field {:.3}s", t.elapsed().as_secs_f64());
    for pre in [
        Preconditioner::Diagonal,
        Preconditioner::Lumped,
        Preconditioner::Block,
    ] {
        let t = Instant::now();
        let options = MbdOptions {
            rank: l,
            max_iterations: 32,
            tolerance: 0.0,
            preconditioner: pre,
            ..MbdOptions::default()
        };
        let (model, report) = Mbd {
            basis_nodes: [b; 3],
            options,
        }
        .fit(&field, &NoProgress)
        .unwrap();
        println!(
            "mbd {pre:?} {:.3}s (init {:.3}s, {} iterations)",
            t.elapsed().as_secs_f64(),
            report.init_seconds,
            report.history.len()
        );
        for r in report.history.iter().step_by(4) {
            println!(
                "  {:.4e} -> {:.4e} step {} t {:.3}",
                r.loss_before, r.loss_after, r.step, r.elapsed
            );
        }
        let t = Instant::now();
        let e = evaluate(&model, &field, &EvalOptions::default()).unwrap();
        println!(
            "evaluate {:.3}s relmse {:.4e}",
            t.elapsed().as_secs_f64(),
            e.relative_mse
        );
    }
    let t = Instant::now();
    let bpca = BlockPca {
        rank: l,
        blocks: [b; 3],
        window: 1.0,
    }
    .compress(&field, &NoProgress)
    .unwrap();
    println!("bpca {:.3}s", t.elapsed().as_secs_f64());
    let t = Instant::now();
    let e = evaluate(&bpca, &field, &EvalOptions::default()).unwrap();
    println!(
        "evaluate {:.3}s relmse {:.4e}",
        t.elapsed().as_secs_f64(),
        e.relative_mse
    );
    let t = Instant::now();
    let cpca = ClusteredPca::new(l, b * b * b)
        .compress(&field, &NoProgress)
        .unwrap();
    println!(
        "cpca {:.3}s relmse {:.4e}",
        t.elapsed().as_secs_f64(),
        evaluate(&cpca, &field, &EvalOptions::default())
            .unwrap()
            .relative_mse
    );
}
