//! Row-column sampling and LightSlice (prt-manylight) against brute force on a synthetic VPL
//! matrix: relative RMS image error vs elements evaluated and time, for the paper's
//! rows/columns settings (100/200 .. 900/1800). LightSlice runs with slices = rows and
//! local clusters = columns, the same element budget.
//!
//! `cargo run --release -p prt-benches --bin manylight_sweep [-- WIDTH LIGHTS SEEDS]`
//! (defaults 256 × 256 pixels, 100000 lights, 2 seeds per setting).
use std::sync::Mutex;
use std::time::{Duration, Instant};

use prt_benches::{Table, fmt_duration};
use prt_core::metrics::relative_frobenius_error;
use prt_core::{MatrixOracle, NoProgress, Progress};
use prt_manylight::{
    LightSliceConfig, RowColumnConfig, SyntheticVplOracle, brute_force, light_slice,
    row_column_sampling,
};

/// A progress handle that records when each stage message arrives, to split the time into
/// reduced matrix / clustering / columns.
#[derive(Default)]
struct PhaseTimes {
    marks: Mutex<Vec<Instant>>,
}

impl Progress for PhaseTimes {
    fn set_len(&self, _len: u64) {}
    fn inc(&self, _delta: u64) {}
    fn message(&self, _msg: &str) {
        if let Ok(mut marks) = self.marks.lock() {
            marks.push(Instant::now());
        }
    }
    fn is_cancelled(&self) -> bool {
        false
    }
}

fn main() {
    let args: Vec<usize> = std::env::args()
        .skip(1)
        .filter_map(|a| a.parse().ok())
        .collect();
    let width = args.first().copied().unwrap_or(256);
    let lights = args.get(1).copied().unwrap_or(100_000);
    let seeds = args.get(2).copied().unwrap_or(2).max(1) as u64;
    let oracle = SyntheticVplOracle::new(width, width, lights, 1);
    let (n, m) = (oracle.rows(), oracle.cols());
    println!(
        "synthetic VPL matrix: {n} pixels x {m} lights (RGB), {} threads",
        rayon::current_num_threads()
    );

    let start = Instant::now();
    let reference = brute_force(&oracle, &NoProgress).expect("finite synthetic matrix");
    let brute_time = start.elapsed();
    let brute_elements = (n * m) as f64;
    println!(
        "brute force: {} ({brute_elements:.3e} elements)\n",
        fmt_duration(brute_time)
    );

    let mut table = Table::new(&[
        "method",
        "rows / columns",
        "elements",
        "fewer elements than brute force",
        "time (reduced / clustering / columns or slices)",
        "speed-up (time)",
        "relative RMS error (mean of seeds)",
        "max over seeds",
    ]);
    for (rows, columns) in [(100, 200), (300, 900), (432, 864), (600, 1200), (900, 1800)] {
        if rows > n || columns > m {
            continue;
        }
        for method in ["row-column", "LightSlice"] {
            let mut errors = Vec::new();
            let mut total = Duration::ZERO;
            let mut phases = [Duration::ZERO; 3];
            let mut elements = 0;
            for seed in 0..seeds {
                let times = PhaseTimes::default();
                let start = Instant::now();
                let (image, evaluated) = if method == "row-column" {
                    let config = RowColumnConfig::new(rows, columns).with_seed(seed);
                    let e = row_column_sampling(&oracle, &config, &times).expect("valid config");
                    (e.image, e.elements)
                } else {
                    let config = LightSliceConfig::new(rows, columns).with_seed(seed);
                    let e = light_slice(&oracle, &config, &times).expect("valid config");
                    (e.image, e.elements)
                };
                let end = Instant::now();
                total += end - start;
                let marks = times.marks.lock().map(|m| m.clone()).unwrap_or_default();
                if let [reduced, cluster, columns] = marks[..] {
                    phases[0] += cluster - reduced;
                    phases[1] += columns - cluster;
                    phases[2] += end - columns;
                }
                elements = evaluated;
                errors.push(
                    relative_frobenius_error(&image, &reference).expect("images of equal size"),
                );
            }
            let k = seeds as u32;
            let mean_error = errors.iter().sum::<f64>() / errors.len() as f64;
            let max_error = errors.iter().copied().fold(0.0, f64::max);
            table.row(vec![
                method.to_string(),
                format!("{rows} / {columns}"),
                format!("{elements:.3e}", elements = elements as f64),
                format!("{:.1}x", brute_elements / elements as f64),
                format!(
                    "{} ({} / {} / {})",
                    fmt_duration(total / k),
                    fmt_duration(phases[0] / k),
                    fmt_duration(phases[1] / k),
                    fmt_duration(phases[2] / k)
                ),
                format!(
                    "{:.1}x",
                    brute_time.as_secs_f64() / (total / k).as_secs_f64()
                ),
                format!("{:.2}%", 100.0 * mean_error),
                format!("{:.2}%", 100.0 * max_error),
            ]);
            eprintln!("done {method} {rows} / {columns}");
        }
    }
    print!("{}", table.markdown());
    if let Err(e) = table.write_csv_if_requested("manylight_sweep") {
        eprintln!("could not write CSV: {e}");
    }
}
