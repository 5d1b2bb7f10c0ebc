//! Moving Basis Decomposition against the PCA family on synthetic 324-D fields: error vs basis
//! count (paper Figure 5), vs basis-grid resolution (Figure 7), solve times (Figure 8), and the
//! solvers' convergence (error vs iterations and time).
//!
//! `cargo run --release -p prt-benches --bin mbd_sweep -- <basis|grid|timing|convergence|all>`

use std::time::Instant;

use prt_benches::{Table, fmt_duration};
use prt_core::{Aabb, Compressor, FieldModel, GridField, NoProgress, resample_to_grid};
use prt_mbd::*;

const DIM: usize = 324;
/// The transfer vector as four 9 × 9 operators.
const BLOCKS: [usize; 4] = [81, 81, 81, 81];

fn field(n: usize) -> GridField {
    SyntheticField {
        dims: [n; 3],
        dim: DIM,
        harmonics: 4,
        seed: 1,
    }
    .build(Aabb::UNIT)
    .expect("synthetic field")
}

struct Scores {
    relative_mse: f64,
    operator: f64,
    seam: f64,
}

fn score(model: &dyn FieldModel, field: &GridField, labels: &[u32]) -> Scores {
    let options = EvalOptions {
        blocks: BLOCKS.to_vec(),
        ..EvalOptions::default()
    };
    let e = evaluate(model, field, &options).expect("evaluate");
    let recon = resample_to_grid(model, field.dims(), field.bounds()).expect("resample");
    let seam = seam_metric(field, &recon, labels).expect("seam");
    let operator = e.block_relative_frobenius.iter().sum::<f64>() / BLOCKS.len() as f64;
    Scores {
        relative_mse: e.relative_mse,
        operator,
        seam: seam.boundary,
    }
}

fn row(table: &mut Table, knob: String, method: &str, seconds: f64, s: &Scores, stored: usize) {
    eprintln!(
        "{knob} {method} {seconds:.3} s, relative MSE {:.3e}",
        s.relative_mse
    );
    table.row(vec![
        knob,
        method.to_string(),
        fmt_duration(std::time::Duration::from_secs_f64(seconds)),
        format!("{:.3e}", s.relative_mse),
        format!("{:.3e}", s.operator),
        format!("{:.3e}", s.seam),
        stored.to_string(),
    ]);
}

/// Every method at rank `l` with `b³` basis nodes / blocks / clusters.
fn compare(
    table: &mut Table,
    knob: String,
    field: &GridField,
    l: usize,
    b: usize,
    iterations: usize,
    with_cpca: bool,
) {
    let t = Instant::now();
    eprintln!("{knob}: fitting MBD");
    let mbd = Mbd {
        basis_nodes: [b; 3],
        options: MbdOptions {
            rank: l,
            max_iterations: iterations,
            ..MbdOptions::default()
        },
    };
    let (model, _) = mbd.fit(field, &NoProgress).expect("mbd");
    let secs = t.elapsed().as_secs_f64();
    let labels = kernel_labels(model.basis_kernels(), field).expect("labels");
    row(
        table,
        knob.clone(),
        "MBD",
        secs,
        &score(&model, field, &labels),
        model.stored_scalars(),
    );

    let mut baseline = |name: &str, fit: &dyn Fn() -> ClusterModel| {
        let t = Instant::now();
        let m = fit();
        let secs = t.elapsed().as_secs_f64();
        row(
            table,
            knob.clone(),
            name,
            secs,
            &score(&m, field, m.labels()),
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
            blocks: [b; 3],
            window: 1.0,
        }
        .compress(field, &NoProgress)
        .expect("bpca")
    });
    baseline("WBPCA", &|| {
        BlockPca {
            rank: l,
            blocks: [b; 3],
            window: 2.0,
        }
        .compress(field, &NoProgress)
        .expect("wbpca")
    });
    if with_cpca {
        baseline("CPCA", &|| {
            ClusteredPca::new(l, b * b * b)
                .compress(field, &NoProgress)
                .expect("cpca")
        });
    }
    baseline("VQ", &|| {
        KMeansVq {
            codewords: (b * b * b * l).min(field.num_voxels()),
            iterations: 10,
            seed: 0,
        }
        .compress(field, &NoProgress)
        .expect("vq")
    });
}

const HEADER: [&str; 7] = [
    "knob",
    "method",
    "time",
    "relative MSE",
    "operator rel. Frobenius (mean of 4 blocks)",
    "seam (boundary jump)",
    "stored scalars",
];

/// Field resolution of the basis-count and grid sweeps (`MBD_N`, default 32).
fn sweep_n() -> usize {
    std::env::var("MBD_N")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(32)
}

fn basis_count() {
    let f = field(sweep_n());
    let mut table = Table::new(&HEADER);
    for l in [2, 4, 8, 16] {
        compare(&mut table, format!("L = {l}"), &f, l, 5, 64, true);
    }
    println!(
        "### Error vs basis count ({}³ × 324, 5³ basis nodes)\n\n{}",
        sweep_n(),
        table.markdown()
    );
    table.write_csv_if_requested("mbd_basis").ok();
}

fn grid_resolution() {
    let f = field(sweep_n());
    let mut table = Table::new(&HEADER);
    for b in [9, 7, 5, 3] {
        compare(&mut table, format!("{b}³"), &f, 8, b, 64, true);
    }
    println!(
        "### Error vs basis-grid resolution ({}³ × 324, L = 8)\n\n{}",
        sweep_n(),
        table.markdown()
    );
    table.write_csv_if_requested("mbd_grid").ok();
}

fn timing() {
    let mut table = Table::new(&HEADER);
    let sizes: Vec<(usize, usize)> = match std::env::var("MBD_MAX_N")
        .ok()
        .and_then(|v| v.parse::<usize>().ok())
    {
        Some(max) => [(16, 3), (32, 5), (64, 9)]
            .into_iter()
            .filter(|&(n, _)| n <= max)
            .collect(),
        None => vec![(16, 3), (32, 5), (64, 9)],
    };
    for (n, b) in sizes {
        let f = field(n);
        compare(
            &mut table,
            format!("{n}³/{b}³"),
            &f,
            8,
            b,
            32,
            std::env::var("MBD_SKIP_CPCA").is_err() || n < 64,
        );
    }
    println!(
        "### Timings (324-D, L = 8, MBD 32 iterations, CPCA 8 rounds)\n\n{}",
        table.markdown()
    );
    table.write_csv_if_requested("mbd_timing").ok();
}

fn convergence() {
    let f = field(32);
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
            .fit(&f, &NoProgress)
            .expect("mbd");
            let secs = t.elapsed();
            let e = evaluate(&model, &f, &EvalOptions::default()).expect("evaluate");
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
        let (coef, basis) = mbd.kernels(&f).expect("kernels");
        let (model, _) = solve_als(&f, coef, basis, &mbd.options, &NoProgress).expect("als");
        let secs = t.elapsed();
        let e = evaluate(&model, &f, &EvalOptions::default()).expect("evaluate");
        table.row(vec![
            "alternating least squares".into(),
            iterations.to_string(),
            fmt_duration(secs),
            format!("{:.4e}", e.relative_mse),
        ]);
    }
    println!(
        "### Convergence (32³ × 324, 5³ nodes, L = 8)\n\n{}",
        table.markdown()
    );
    table.write_csv_if_requested("mbd_convergence").ok();
}

fn main() {
    let mode = std::env::args().nth(1).unwrap_or_else(|| "all".into());
    println!("threads: {}\n", rayon::current_num_threads());
    match mode.as_str() {
        "basis" => basis_count(),
        "grid" => grid_resolution(),
        "timing" => timing(),
        "convergence" => convergence(),
        _ => {
            basis_count();
            grid_resolution();
            timing();
            convergence();
        }
    }
}
