//! Speed of progressive least-squares encoding (prt-plsq) against its targets, and the
//! speed/accuracy trade of LS, NNLS and progressive variants.
//!
//! Run: `cargo run --release -p prt-benches --bin plsq_speed -- [--only single|batch|curves|profile] [--csv DIR]`
//! (default: all three sections; `profile` loops the 12 SG × RGB fit for `perf`).
//!
//! 1. Progressive updates per second, 12 SG × RGB, one thread (target >= 20 M/s) and the whole
//!    20000-sample fit (Probulator: 16-21 ms; target <= 1 ms).
//! 2. Batch encoder scaling from 1 to 2 threads (target >= 1.8x).
//! 3. RMSE vs samples and vs time on wells (Probulator's error definition) for LS, NNLS and
//!    progressive (Jacobi, Gauss-Seidel, acceleration 1..5).
use std::path::{Path, PathBuf};
use std::time::Duration;

use clap::Parser;
use glam::Vec3;
use prt_benches::{
    Table, cpu_seconds, fmt_duration, load_average, load_envmap, median_time, thread_cpu_ns,
};
use prt_core::NoProgress;
use prt_plsq::{
    BatchEncoder, Denominator, EncoderConfig, LatLongFrame, ProgressiveEncoder, SgEncoder, Sweep,
    Update, radiance_rmse, reference, sample_nearest,
};
use prt_sphere::SgBasis;
use prt_sphere::sampling::{halton_sphere, sobol_sphere};

fn signal(d: Vec3) -> [f32; 3] {
    let sun = (8.0 * (d.dot(Vec3::new(0.6, 0.64, 0.48)) - 1.0)).exp();
    [
        0.2 + 0.5 * d.y.max(0.0) + 3.0 * sun,
        0.3 + 0.3 * d.y + sun,
        0.5 + 0.1 * d.x,
    ]
}

/// Mean on-CPU time of `f`, run until at least 0.5 s of CPU time has accumulated (schedstat is
/// only updated at scheduler ticks, so single short runs cannot be timed this way), or `None`
/// without schedstat.
fn mean_cpu_time<T>(mut f: impl FnMut() -> T) -> Option<Duration> {
    std::hint::black_box(f());
    let t0 = thread_cpu_ns()?;
    let mut reps = 0u64;
    loop {
        std::hint::black_box(f());
        reps += 1;
        let spent = thread_cpu_ns()? - t0;
        if spent >= 500_000_000 {
            return Some(Duration::from_nanos(spent / reps));
        }
    }
}

fn cfg(accel: f32, sweep: Sweep) -> EncoderConfig {
    EncoderConfig {
        update: Update::Residual {
            acceleration: accel,
        },
        denominator: Denominator::LerpFromOne,
        sweep,
        ..EncoderConfig::paper()
    }
}

/// A section of the run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum Section {
    /// 1. Single-thread progressive speed (run with RAYON_NUM_THREADS=1).
    Single,
    /// 2. Batch encoder scaling from 1 to 2 threads.
    Batch,
    /// 3. RMSE vs samples and time on wells.
    Curves,
    /// Loops the 12 SG × RGB fit 2000 times, for `perf` (not part of the default run).
    Profile,
}

#[derive(Debug, Parser)]
#[command(about = "Speed of progressive least-squares encoding and the speed/accuracy trade")]
struct Cli {
    /// Run one section only (default: single, batch and curves).
    #[arg(long, value_enum)]
    only: Option<Section>,
    /// Folder for the tables as CSV (plsq_speed_single.csv, _batch.csv, _accuracy.csv).
    #[arg(long)]
    csv: Option<PathBuf>,
}

fn main() {
    let cli = Cli::parse();
    let run = |section: Section| cli.only.is_none_or(|o| o == section);
    let csv = cli.csv.as_deref();
    let basis = SgBasis::spiral(12, 6.0).expect("valid lobes");
    let n = 20000;
    let dirs = halton_sphere(n);
    let values: Vec<f32> = dirs.iter().flat_map(|d| signal(*d)).collect();
    if cli.only == Some(Section::Profile) {
        let mut sum = 0.0;
        for _ in 0..2000 {
            let mut enc = SgEncoder::<3>::new(&basis, cfg(1.0, Sweep::GaussSeidel)).expect("ok");
            enc.add_samples(&dirs, &values, None, &NoProgress)
                .expect("finite");
            sum += enc.coefficients()[0];
        }
        println!("{sum}");
        return;
    }
    if run(Section::Single) {
        single_thread(&basis, &dirs, &values, csv);
    }
    if run(Section::Batch) {
        batch_scaling(&basis, csv);
    }
    if run(Section::Curves) {
        curves(&basis, csv);
    }
}

fn single_thread(basis: &SgBasis, dirs: &[Vec3], values: &[f32], csv: Option<&Path>) {
    let n = dirs.len();

    // 1. Single-thread progressive speed: wall time and on-CPU time (the machine is shared).
    let mut t1 = Table::new(&[
        "encoder (12 SG × RGB, 20000 samples, 1 thread)",
        "fit time (wall)",
        "fit time (on CPU)",
        "updates/s (on CPU)",
    ]);
    let row = |t1: &mut Table, name: String, wall: Duration, cpu: Option<Duration>| {
        let rate = cpu.map_or("–".to_string(), |c| {
            format!("{:.1} M", n as f64 / c.as_secs_f64() / 1e6)
        });
        t1.row(vec![
            name,
            fmt_duration(wall),
            cpu.map_or("–".into(), fmt_duration),
            rate,
        ]);
    };
    for (name, c) in [
        (
            "progressive, Gauss-Seidel, α = 1 (paper)",
            cfg(1.0, Sweep::GaussSeidel),
        ),
        (
            "progressive, acceleration 3, Gauss-Seidel",
            cfg(3.0, Sweep::GaussSeidel),
        ),
        ("progressive, Jacobi", cfg(1.0, Sweep::Jacobi)),
        (
            "running average (Probulator)",
            EncoderConfig::probulator_running_average(),
        ),
    ] {
        let fast = || {
            let mut enc = SgEncoder::<3>::new(basis, c).expect("valid");
            enc.add_samples(dirs, values, None, &NoProgress)
                .expect("finite");
            enc.total_weight()
        };
        row(
            &mut t1,
            format!("SgEncoder: {name}"),
            median_time(31, fast),
            mean_cpu_time(fast),
        );
        let generic = || {
            let mut enc = ProgressiveEncoder::new(basis, 3, c).expect("valid");
            enc.add_samples(dirs, values, None, &NoProgress)
                .expect("finite");
            enc.coefficients()[0]
        };
        row(
            &mut t1,
            format!("generic ProgressiveEncoder: {name}"),
            median_time(7, generic),
            mean_cpu_time(generic),
        );
    }
    let ls = || reference::least_squares_samples(basis, dirs, values, 3).expect("ok")[0];
    let name = "LS over the samples (normal equations + Cholesky)";
    row(&mut t1, name.into(), median_time(7, ls), mean_cpu_time(ls));
    let nn = || reference::nnls_samples(basis, dirs, values, 3).expect("ok")[0];
    row(
        &mut t1,
        "NNLS over the samples".into(),
        median_time(7, nn),
        mean_cpu_time(nn),
    );
    println!("{}", t1.markdown());
    if let Err(e) = t1.write_csv(csv, "plsq_speed_single") {
        eprintln!("could not write the CSV: {e}");
    }
}

fn batch_scaling(basis: &SgBasis, csv: Option<&Path>) {
    // 2. Batch scaling, two workloads:
    //  - runs: a 128 × 128 lightmap, a pass of 64 samples per texel in one `add_sample_runs`
    //    call (each block of 16 texels takes its 64 samples while its state is in cache);
    //  - rounds (the earlier measurement): 65536 encoders, 16 rounds of one sample each
    //    through `add_samples`, which streams the whole state through memory per round.
    let mut t2 = Table::new(&[
        "workload",
        "threads",
        "wall time (median)",
        "CPU time (process)",
        "updates/s (wall)",
        "speed-up (wall)",
        "load average (1 min)",
    ]);
    let cfg = cfg(1.0, Sweep::GaussSeidel);
    let rounds_workload = {
        let (encoders, rounds) = (65536usize, 16usize);
        let d = sobol_sphere(encoders * rounds / 16, 1);
        let d: Vec<Vec3> = (0..encoders * rounds)
            .map(|i| d[(i * 7919) % d.len()])
            .collect();
        let v: Vec<f32> = d.iter().flat_map(|x| signal(*x)).collect();
        (encoders, rounds, d, v)
    };
    let runs_workload = {
        let (encoders, per) = (16384usize, 64usize);
        let d = sobol_sphere(encoders * per, 2);
        let v: Vec<f32> = d.iter().flat_map(|x| signal(*x)).collect();
        (encoders, per, d, v)
    };
    for workload in ["runs", "rounds"] {
        let mut base = 0.0;
        for threads in [1usize, 2] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .expect("pool");
            let fit = || match workload {
                "runs" => {
                    let (encoders, per, d, v) = &runs_workload;
                    let mut batch = BatchEncoder::new_sg(basis, 3, *encoders, cfg).expect("valid");
                    batch.add_sample_runs(*per, d, v, None).expect("finite");
                    batch.total_weight(0)
                }
                _ => {
                    let (encoders, rounds, d, v) = &rounds_workload;
                    let mut batch = BatchEncoder::new_sg(basis, 3, *encoders, cfg).expect("valid");
                    for r in 0..*rounds {
                        let range = r * encoders..(r + 1) * encoders;
                        batch
                            .add_samples(
                                &d[range.clone()],
                                &v[3 * range.start..3 * range.end],
                                None,
                            )
                            .expect("finite");
                    }
                    batch.total_weight(0)
                }
            };
            let updates = match workload {
                "runs" => runs_workload.0 * runs_workload.1,
                _ => rounds_workload.0 * rounds_workload.1,
            };
            let reps = 9;
            let (t, cpu) = pool.install(|| {
                let c0 = cpu_seconds();
                // `median_time` runs `fit` once more to warm up.
                let t = median_time(reps, fit);
                let cpu = Some((cpu_seconds() - c0) / (reps + 1) as f64)
                    .filter(|c| c.is_finite())
                    .map(Duration::from_secs_f64);
                (t, cpu)
            });
            let secs = t.as_secs_f64();
            if threads == 1 {
                base = secs;
            }
            let label = match workload {
                "runs" => "16384 encoders × 64-sample run, one call",
                _ => "65536 encoders × 16 one-sample rounds (earlier)",
            };
            t2.row(vec![
                label.into(),
                threads.to_string(),
                fmt_duration(t),
                cpu.map_or("–".into(), fmt_duration),
                format!("{:.1} M", updates as f64 / secs / 1e6),
                format!("{:.2}x", base / secs),
                // The 1-minute figure.
                load_average()
                    .split_whitespace()
                    .next()
                    .unwrap_or_default()
                    .to_string(),
            ]);
        }
    }
    println!("{}", t2.markdown());
    if let Err(e) = t2.write_csv(csv, "plsq_speed_batch") {
        eprintln!("could not write the CSV: {e}");
    }
}

fn curves(basis: &SgBasis, csv: Option<&Path>) {
    // 3. Speed/accuracy curves on wells.
    let map = match load_envmap("probulator_wells") {
        Ok(map) => map,
        Err(e) => {
            println!("skipping the accuracy curves: {e}");
            return;
        }
    };
    // Probulator's frame and error definition (prt_plsq::probulator).
    let frame = LatLongFrame::Probulator;
    let all_dirs = halton_sphere(20000);
    let all_vals = sample_nearest(&map, &all_dirs, frame);
    let rmse = |c: &[f32]| radiance_rmse(&map, basis, c, false, frame).unwrap_or(f64::NAN);
    let mut t3 = Table::new(&["method", "N", "time", "RMSE (wells)"]);
    for &count in &[64usize, 256, 1024, 4096, 20000] {
        let (d, v) = (&all_dirs[..count], &all_vals[..3 * count]);
        let reps = if count > 4096 { 5 } else { 21 };
        let mut out = Vec::new();
        let t = median_time(reps, || {
            out = reference::least_squares_samples(basis, d, v, 3).expect("ok");
        });
        t3.row(vec![
            "LS".into(),
            count.to_string(),
            fmt_duration(t),
            format!("{:.5}", rmse(&out)),
        ]);
        let t = median_time(reps, || {
            out = reference::nnls_samples(basis, d, v, 3).expect("ok");
        });
        t3.row(vec![
            "NNLS".into(),
            count.to_string(),
            fmt_duration(t),
            format!("{:.5}", rmse(&out)),
        ]);
        for (name, c) in [
            ("progressive Jacobi α=1", cfg(1.0, Sweep::Jacobi)),
            ("progressive GS α=1", cfg(1.0, Sweep::GaussSeidel)),
            ("progressive GS α=2", cfg(2.0, Sweep::GaussSeidel)),
            ("progressive GS α=3", cfg(3.0, Sweep::GaussSeidel)),
            ("progressive GS α=4", cfg(4.0, Sweep::GaussSeidel)),
            ("progressive GS α=5", cfg(5.0, Sweep::GaussSeidel)),
        ] {
            let t = median_time(reps, || {
                let mut enc = SgEncoder::<3>::new(basis, c).expect("valid");
                enc.add_samples(d, v, None, &NoProgress).expect("finite");
                out = enc.coefficients();
            });
            t3.row(vec![
                name.into(),
                count.to_string(),
                fmt_duration(t),
                format!("{:.5}", rmse(&out)),
            ]);
        }
    }
    println!("{}", t3.markdown());
    if let Err(e) = t3.write_csv(csv, "plsq_speed_accuracy") {
        eprintln!("could not write the CSV: {e}");
    }
}
