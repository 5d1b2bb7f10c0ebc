//! prt-linalg beside numpy / scikit-learn / scipy, measured in one run on the same data.
//!
//! ```text
//! cargo run --release -p prt-benches --bin linalg_sweep -- --rows 32768,262144  # faer backend
//! OPENBLAS_NUM_THREADS=1 cargo run --release -p prt-benches --features lapack --bin linalg_sweep
//! cargo run --release -p prt-benches --bin linalg_sweep -- --rows 32768 --only pca [--csv DIR]
//! ```
//!
//! Times are the best of several runs (on both sides). Prints three markdown tables (PCA,
//! k-means per Lloyd iteration, NNLS; `--only` picks one). Ours runs in rayon
//! pools of 1 and 2 threads; the Python references (benches/scripts/linalg_ref.py) run with
//! `OPENBLAS_NUM_THREADS=1` when python3 with numpy is available. PCA accuracy is the rank-16
//! residual relative to the optimal one (thin SVD of the centred data in f64).

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

use clap::Parser;
use ndarray::{Array1, Array2, Axis, s};
use prt_benches::{Table, cpu_seconds, fmt_duration};
use prt_core::NoProgress;
use prt_linalg::synthetic::low_rank_matrix;
use prt_linalg::{
    BACKEND_NAME, KMeansOptions, Pca, PcaMethod, PcaOptions, kmeans, nnls, nnls_gram,
};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;

const D: usize = 324;
const RANK: usize = 16;
const K: usize = 125;
const KMEANS_ROWS: usize = 32768;
const KMEANS_ITERS: usize = 20;

type BoxResult<T> = Result<T, Box<dyn std::error::Error>>;

/// One of the three tables.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum Part {
    /// PCA, rank 16.
    Pca,
    /// k-means, k = 125, per Lloyd iteration.
    Kmeans,
    /// NNLS, per problem.
    Nnls,
}

#[derive(Debug, Parser)]
#[command(about = "prt-linalg beside numpy / scikit-learn / scipy on the same data")]
struct Cli {
    /// Row counts of the PCA table, comma- or space-separated (324 columns each).
    #[arg(long, value_delimiter = ',', num_args = 1.., default_value = "32768,262144")]
    rows: Vec<usize>,
    /// Run one table only (default: all three).
    #[arg(long, value_enum)]
    only: Option<Part>,
    /// Folder for the tables as CSV (linalg_pca.csv, linalg_kmeans.csv, linalg_nnls.csv).
    #[arg(long)]
    csv: Option<PathBuf>,
}

fn main() -> BoxResult<()> {
    let cli = Cli::parse();
    let rows = cli.rows;
    let wanted = |part: Part| cli.only.is_none_or(|o| o == part);
    let csv = cli.csv.as_deref();
    let max_rows = rows
        .iter()
        .copied()
        .max()
        .unwrap_or(KMEANS_ROWS)
        .max(KMEANS_ROWS);
    let dir = std::env::temp_dir().join(format!("prt_linalg_sweep_{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let python = python_available();
    println!(
        "backend: {BACKEND_NAME}; python references: {}\n",
        if python { "yes" } else { "no (numpy missing)" }
    );

    eprintln!("generating {max_rows} x {D} (rank 40, spectrum 0.8^i, noise 1e-3)...");
    let data = low_rank_matrix(max_rows, D, 40, 0.8, 1e-3, 0.0, 1)?;

    if wanted(Part::Pca) {
        let pca_table = pca_sweep(&data, &rows, &dir, python)?;
        println!(
            "### PCA, rank {RANK}, {D} columns\n\n{}",
            pca_table.markdown()
        );
        pca_table.write_csv(csv, "linalg_pca")?;
    }

    if wanted(Part::Kmeans) {
        let km_table = kmeans_sweep(&data, &dir, python)?;
        println!(
            "### k-means, k = {K}, {KMEANS_ROWS} x {D}, per Lloyd iteration\n\n{}",
            km_table.markdown()
        );
        km_table.write_csv(csv, "linalg_kmeans")?;
    }

    if wanted(Part::Nnls) {
        let nnls_table = nnls_sweep(&dir, python)?;
        println!("### NNLS, per problem\n\n{}", nnls_table.markdown());
        nnls_table.write_csv(csv, "linalg_nnls")?;
    }

    std::fs::remove_dir_all(&dir)?;
    Ok(())
}

/// Best of `reps` runs after a warm-up: on a shared machine the minimum is the run least
/// disturbed by other load, for us and for the references alike (the script does the same).
fn best_time<T>(reps: usize, mut f: impl FnMut() -> T) -> Duration {
    std::hint::black_box(f());
    best_time_no_warmup(reps, f)
}

/// [`best_time`] plus the mean CPU time per run (of the whole process: the calling thread
/// waits while a pool's worker runs, so for a one-thread pool this is the worker's time).
fn best_and_cpu_time<T>(reps: usize, mut f: impl FnMut() -> T) -> (Duration, f64) {
    std::hint::black_box(f());
    let cpu0 = cpu_seconds();
    let best = best_time_no_warmup(reps, f);
    (best, (cpu_seconds() - cpu0) / reps.max(1) as f64)
}

fn best_time_no_warmup<T>(reps: usize, mut f: impl FnMut() -> T) -> Duration {
    (0..reps.max(1))
        .map(|_| {
            let t = std::time::Instant::now();
            std::hint::black_box(f());
            t.elapsed()
        })
        .min()
        .unwrap_or_default()
}

fn python_available() -> bool {
    Command::new("python3")
        .args(["-c", "import numpy"])
        .output()
        .is_ok_and(|o| o.status.success())
}

fn script() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/linalg_ref.py")
}

/// Runs the reference script with one BLAS thread; returns its JSON lines.
fn run_reference(args: &[String]) -> BoxResult<Vec<serde_json::Value>> {
    let out = Command::new("python3")
        .arg(script())
        .args(args)
        .env("OPENBLAS_NUM_THREADS", "1")
        .env("OMP_NUM_THREADS", "1")
        .env("MKL_NUM_THREADS", "1")
        .output()?;
    if !out.status.success() {
        eprintln!(
            "reference script failed: {}",
            String::from_utf8_lossy(&out.stderr)
        );
    }
    Ok(String::from_utf8_lossy(&out.stdout)
        .lines()
        .filter_map(|l| serde_json::from_str(l).ok())
        .collect())
}

fn write_f32(path: &Path, a: ndarray::ArrayView2<'_, f32>) -> std::io::Result<()> {
    let bytes: Vec<u8> = a.iter().flat_map(|v| v.to_le_bytes()).collect();
    std::fs::write(path, bytes)
}

fn in_pool<T: Send>(threads: usize, f: impl FnOnce() -> T + Send) -> T {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .map(|pool| pool.install(f))
        .unwrap_or_else(|e| panic!("thread pool: {e}"))
}

/// The optimal rank-`RANK` residual: squared singular values of the centred f64 data beyond
/// the first `RANK` (Eckart-Young).
fn optimal_residual(x: ndarray::ArrayView2<'_, f32>) -> BoxResult<f64> {
    let x64 = x.mapv(f64::from);
    let mean = x64.mean_axis(Axis(0)).ok_or("empty")?;
    let centred = &x64 - &mean.insert_axis(Axis(0));
    drop(x64);
    let s = prt_linalg::thin_svd(centred.view())?.s;
    Ok(s.iter().skip(RANK).map(|v| v * v).sum())
}

fn pca_sweep(data: &Array2<f32>, rows: &[usize], dir: &Path, python: bool) -> BoxResult<Table> {
    let mut table = Table::new(&[
        "rows",
        "implementation",
        "threads",
        "time",
        "speed-up vs numpy",
        "CPU time",
        "CPU speed-up vs numpy",
        "residual / optimal - 1",
    ]);
    let methods = [
        ("covariance", PcaMethod::Covariance),
        ("covariance f64 products", PcaMethod::CovarianceF64),
        (
            "randomized q=1",
            PcaMethod::Randomized {
                oversample: 10,
                power_iters: 1,
                seed: 0,
            },
        ),
        (
            "randomized q=2",
            PcaMethod::Randomized {
                oversample: 10,
                power_iters: 2,
                seed: 0,
            },
        ),
    ];
    for &n in rows {
        let x = data.slice(s![..n, ..]);
        eprintln!("PCA {n} rows: optimal residual (thin SVD)...");
        let best = optimal_residual(x)?;
        let reps = if n > 100_000 { 3 } else { 5 };
        let mut refs = Vec::new();
        if python {
            let file = dir.join(format!("x_{n}.f32"));
            write_f32(&file, x)?;
            eprintln!("PCA {n} rows: python references...");
            refs = run_reference(&[
                "pca".into(),
                file.display().to_string(),
                n.to_string(),
                D.to_string(),
                RANK.to_string(),
                reps.to_string(),
            ])?;
            std::fs::remove_file(&file)?;
        }
        let numpy = refs
            .iter()
            .find(|r| r["method"].as_str().is_some_and(|m| m.starts_with("numpy")))
            .and_then(|r| r["time_s"].as_f64());
        let numpy_cpu = refs
            .iter()
            .find(|r| r["method"].as_str().is_some_and(|m| m.starts_with("numpy")))
            .and_then(|r| r["cpu_s"].as_f64());
        let speedup = |t: f64| numpy.map_or("-".into(), |np| format!("{:.2}x", np / t));
        let cpu_speedup = |t: f64| numpy_cpu.map_or("-".into(), |np| format!("{:.2}x", np / t));
        let cpu_cell = |t: Option<f64>| t.map_or("-".into(), |t| format!("{:.0} ms", t * 1e3));
        for r in &refs {
            let t = r["time_s"].as_f64().unwrap_or(f64::NAN);
            let cpu = r["cpu_s"].as_f64();
            let res = r["residual"].as_f64().unwrap_or(f64::NAN);
            table.row(vec![
                n.to_string(),
                r["method"].as_str().unwrap_or("?").to_string(),
                "1".into(),
                fmt_duration(Duration::from_secs_f64(t)),
                speedup(t),
                cpu_cell(cpu),
                cpu.map_or("-".into(), cpu_speedup),
                format!("{:.2e}", res / best - 1.0),
            ]);
        }
        for (name, method) in methods {
            for threads in [1, 2] {
                eprintln!("PCA {n} rows: ours, {name}, {threads} thread(s)...");
                let opts = PcaOptions { method };
                let fit = || Pca::fit(x, RANK, &opts, &NoProgress);
                let (t, cpu) = in_pool(threads, || best_and_cpu_time(reps, fit));
                let pca = fit()?;
                let res = pca.residual_energy(x)?;
                table.row(vec![
                    n.to_string(),
                    format!("prt-linalg {name} ({BACKEND_NAME})"),
                    threads.to_string(),
                    fmt_duration(t),
                    speedup(t.as_secs_f64()),
                    cpu_cell(Some(cpu)),
                    if threads == 1 {
                        cpu_speedup(cpu)
                    } else {
                        "-".into()
                    },
                    format!("{:.2e}", res / best - 1.0),
                ]);
            }
        }
    }
    Ok(table)
}

fn kmeans_sweep(data: &Array2<f32>, dir: &Path, python: bool) -> BoxResult<Table> {
    let mut table = Table::new(&[
        "implementation",
        "threads",
        "time per iteration",
        "iterations",
        "objective after them",
    ]);
    let x = data.slice(s![..KMEANS_ROWS, ..]);
    let run = |iters: usize| {
        kmeans(
            x,
            K,
            &KMeansOptions {
                max_iters: iters,
                tol: 0.0,
                seed: 0,
            },
            &NoProgress,
        )
    };
    // One iteration returns the k-means++ seeds: the common starting point of both sides.
    let seeds = run(1)?.centroids;
    for threads in [1, 2] {
        eprintln!("k-means: ours, {threads} thread(s)...");
        let (t1, tn, result) = in_pool(threads, || {
            let t1 = best_time(3, || run(1));
            let tn = best_time(1, || run(1 + KMEANS_ITERS));
            (t1, tn, run(1 + KMEANS_ITERS))
        });
        let result = result?;
        let iters = result.history.len().saturating_sub(1).max(1);
        let per_iter = tn.saturating_sub(t1).as_secs_f64() / iters as f64;
        table.row(vec![
            format!("prt-linalg ({BACKEND_NAME})"),
            threads.to_string(),
            fmt_duration(Duration::from_secs_f64(per_iter)),
            (iters + 1).to_string(),
            format!("{:.6e}", result.objective),
        ]);
    }
    if python {
        let file = dir.join("km_x.f32");
        let init = dir.join("km_init.f32");
        write_f32(&file, x)?;
        write_f32(&init, seeds.view())?;
        eprintln!("k-means: scikit-learn...");
        for r in run_reference(&[
            "kmeans".into(),
            file.display().to_string(),
            KMEANS_ROWS.to_string(),
            D.to_string(),
            init.display().to_string(),
            K.to_string(),
            KMEANS_ITERS.to_string(),
        ])? {
            table.row(vec![
                r["method"].as_str().unwrap_or("?").to_string(),
                "1".into(),
                fmt_duration(Duration::from_secs_f64(
                    r["time_s"].as_f64().unwrap_or(f64::NAN),
                )),
                r["iterations"].to_string(),
                format!("{:.6e}", r["objective"].as_f64().unwrap_or(f64::NAN)),
            ]);
        }
    }
    Ok(table)
}

fn nnls_sweep(dir: &Path, python: bool) -> BoxResult<Table> {
    let mut table = Table::new(&[
        "problem",
        "implementation",
        "time per problem",
        "sum of all x",
    ]);
    let count = 200;
    let mut rng = Pcg64::seed_from_u64(5);
    for (m, n) in [(12, 12), (1000, 12)] {
        let problems: Vec<(Array2<f64>, Array1<f64>)> = (0..count)
            .map(|_| {
                let a = Array2::from_shape_simple_fn((m, n), || rng.random_range(-1.0..1.0));
                let b = Array1::from_shape_simple_fn(m, || rng.random_range(-1.0..1.0));
                (a, b)
            })
            .collect();
        let t = best_time(5, || {
            problems
                .iter()
                .filter(|(a, b)| nnls(a.view(), b.view()).is_ok())
                .count()
        });
        let sum: f64 = problems
            .iter()
            .map(|(a, b)| nnls(a.view(), b.view()).map_or(f64::NAN, |s| s.x.sum()))
            .sum();
        table.row(vec![
            format!("{m} x {n} design"),
            format!("prt-linalg nnls ({BACKEND_NAME})"),
            fmt_duration(t / count as u32),
            format!("{sum:.6}"),
        ]);
        let grams: Vec<(Array2<f64>, Array1<f64>)> = problems
            .iter()
            .map(|(a, b)| (a.t().dot(a), a.t().dot(b)))
            .collect();
        let t = best_time(5, || {
            grams
                .iter()
                .filter(|(g, c)| nnls_gram(g.view(), c.view()).is_ok())
                .count()
        });
        let sum: f64 = grams
            .iter()
            .map(|(g, c)| nnls_gram(g.view(), c.view()).map_or(f64::NAN, |s| s.x.sum()))
            .sum();
        table.row(vec![
            format!("{n} x {n} Gram of the {m} x {n} design"),
            "prt-linalg nnls_gram".into(),
            fmt_duration(t / count as u32),
            format!("{sum:.6}"),
        ]);
        if python {
            let file = dir.join(format!("nnls_{m}.f64"));
            let bytes: Vec<u8> = problems
                .iter()
                .flat_map(|(a, b)| {
                    a.iter()
                        .chain(b.iter())
                        .flat_map(|v| v.to_le_bytes())
                        .collect::<Vec<_>>()
                })
                .collect();
            std::fs::write(&file, bytes)?;
            for r in run_reference(&[
                "nnls".into(),
                file.display().to_string(),
                count.to_string(),
                m.to_string(),
                n.to_string(),
                "5".into(),
            ])? {
                table.row(vec![
                    format!("{m} x {n} design"),
                    r["method"].as_str().unwrap_or("?").to_string(),
                    fmt_duration(Duration::from_secs_f64(
                        r["time_s"].as_f64().unwrap_or(f64::NAN),
                    )),
                    format!("{:.6}", r["x_sum"].as_f64().unwrap_or(f64::NAN)),
                ]);
            }
        }
    }
    Ok(table)
}
