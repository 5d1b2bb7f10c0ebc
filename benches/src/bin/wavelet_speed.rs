//! Speed of prt-wavelet's transforms side by side with PyWavelets (called in the same run when
//! python3 with pywt is available), and the relighting engine's cost per frame against the
//! memory-bandwidth bound of what it touches.
//!
//! `cargo run --release -p prt-benches --bin wavelet_speed` (no options; run it with
//! `RAYON_NUM_THREADS=1` for the one-thread relighting figures)

use std::path::Path;
use std::process::Command;
use std::time::Duration;

use prt_benches::{Table, fmt_duration, median_time, read_bandwidth};
use prt_core::{CoreError, MatrixOracle, NoProgress};
use prt_wavelet::{
    Approximator, BandStrategy, CubemapHaar, CubemapLayout, Daubechies4, Policy, Relighter,
    SparseTransport, Weighting,
};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;

fn pywavelets() -> Option<serde_json::Value> {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/wavelet_ref.py");
    let out = Command::new("python3")
        .arg(script)
        .env("OMP_NUM_THREADS", "1")
        .env("OPENBLAS_NUM_THREADS", "1")
        .output()
        .ok()?;
    if !out.status.success() {
        eprintln!(
            "PyWavelets reference unavailable: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        return None;
    }
    serde_json::from_slice(&out.stdout).ok()
}

/// Repetitions of each relighting sequence (the fastest is reported).
const REPEATS: usize = 5;

/// A synthetic wavelet-domain transport: each row holds `per_row` non-zeros, drawn with a bias
/// towards coarse coefficients (low in-face indices), as real transport rows are.
struct SyntheticTransport {
    rows: usize,
    cols: usize,
    per_row: usize,
}

impl MatrixOracle for SyntheticTransport {
    fn rows(&self) -> usize {
        self.rows
    }
    fn cols(&self) -> usize {
        self.cols
    }
    fn eval_row(&self, i: usize, out: &mut [f32]) -> Result<(), CoreError> {
        out.fill(0.0);
        let mut rng = Pcg64::seed_from_u64(i as u64);
        let face_len = self.cols / 6;
        for _ in 0..self.per_row {
            let face = rng.random_range(0..6);
            let u: f32 = rng.random();
            let j = face * face_len + ((u * u * face_len as f32) as usize).min(face_len - 1);
            out[j] = rng.random_range(-1.0f32..1.0) / (1.0 + (j % face_len) as f32).sqrt();
        }
        Ok(())
    }
    fn eval_col(&self, _j: usize, _out: &mut [f32]) -> Result<(), CoreError> {
        Err(CoreError::Invalid {
            what: "synthetic transport",
            why: "rows only".into(),
        })
    }
    fn elements_evaluated(&self) -> u64 {
        0
    }
}

/// CPU time of all the process' threads so far (Linux: the sum of
/// `/proc/self/task/*/schedstat`; zero elsewhere): the relighting apply runs on rayon's pool,
/// not on the calling thread.
fn process_cpu() -> Duration {
    let Ok(tasks) = std::fs::read_dir("/proc/self/task") else {
        return Duration::ZERO;
    };
    tasks
        .filter_map(|t| std::fs::read_to_string(t.ok()?.path().join("schedstat")).ok())
        .filter_map(|s| s.split_whitespace().next()?.parse::<u64>().ok())
        .map(Duration::from_nanos)
        .sum()
}

#[derive(Debug, clap::Parser)]
#[command(about = "Wavelet transforms beside PyWavelets, and the relighting engine's cost")]
struct Cli {}

fn main() {
    <Cli as clap::Parser>::parse();
    let reference = pywavelets();
    let py = |key: &str| {
        reference
            .as_ref()
            .and_then(|r| r[key].as_f64())
            .map(|us| Duration::from_secs_f64(us * 1e-6))
    };

    // Transforms.
    let mut rng = Pcg64::seed_from_u64(1);
    let mut cube: Vec<f32> = (0..6 * 64 * 64).map(|_| rng.random()).collect();
    let mut haar = CubemapHaar::new(64).expect("size");
    let t_haar = median_time(5000, || {
        haar.forward(&mut cube).expect("forward");
        haar.inverse(&mut cube).expect("inverse");
    });
    let mut sig: Vec<f32> = (0..256).map(|_| rng.random()).collect();
    let mut db2 = Daubechies4::new(256).expect("size");
    let t_db2 = median_time(20000, || {
        db2.forward(&mut sig).expect("forward");
        db2.inverse(&mut sig).expect("inverse");
    });
    let mut table = Table::new(&[
        "task",
        "prt-wavelet",
        "PyWavelets (same run)",
        "speed-up",
        "target",
    ]);
    for (task, ours, theirs, target) in [
        (
            "Haar cubemap 6 x 64 x 64 forward + inverse",
            t_haar,
            py("haar_cubemap_us"),
            "<= 50 µs",
        ),
        (
            "db2 periodization, 256 samples, forward + inverse",
            t_db2,
            py("db2_256_us"),
            "<= 3 µs",
        ),
    ] {
        table.row(vec![
            task.into(),
            fmt_duration(ours),
            theirs.map_or("n/a".into(), fmt_duration),
            theirs.map_or("n/a".into(), |t| {
                format!("{:.0}x", t.as_secs_f64() / ours.as_secs_f64())
            }),
            target.into(),
        ]);
    }
    println!("### Transform speed (one thread)\n\n{}", table.markdown());

    // Approximation step and relighting cost per frame.
    let bandwidth = read_bandwidth();
    let size = 64;
    let layout = CubemapLayout::new(size).expect("size");
    let cols = layout.len();
    let oracle = SyntheticTransport {
        rows: 128 * 128,
        cols,
        per_row: 400,
    };
    let transport = SparseTransport::from_oracle(&oracle, 256, &NoProgress).expect("transport");
    println!(
        "\nSynthetic transport: {} pixels x {} coefficients, 256 kept per row, {} entries ({:.1} MB at 4 B each); read bandwidth here {:.1} GB/s; relight apply on {} rayon thread(s)\n",
        transport.rows(),
        cols,
        transport.nnz(),
        transport.nnz() as f64 * 4.0 / 1e6,
        bandwidth / 1e9,
        rayon::current_num_threads()
    );
    // A smooth lighting random walk (coarse coefficients large), RGB.
    let mut lighting: Vec<f32> = (0..3 * cols)
        .map(|i| 1.0 / (1.0 + (i % (size * size)) as f32))
        .collect();
    let frames: Vec<Vec<f32>> = (0..64)
        .map(|_| {
            for (i, v) in lighting.iter_mut().enumerate() {
                *v += rng.random_range(-0.05f32..0.05) / (1.0 + (i % (size * size)) as f32).sqrt();
            }
            lighting.clone()
        })
        .collect();
    let mut relight = Table::new(&[
        "policy",
        "terms",
        "tile rows",
        "approximation step",
        "relight apply (wall)",
        "relight apply (CPU, all threads)",
        "column bytes",
        "image bytes",
        "bandwidth bound (all bytes)",
        "apply CPU / bound",
    ]);
    let untiled = transport.rows();
    for (name, policy, terms, tilings) in [
        ("NWA", Policy::NonIncremental, 30, vec![untiled, 1024]),
        ("NWA", Policy::NonIncremental, 100, vec![untiled, 1024]),
        (
            "BI",
            Policy::Incremental,
            30,
            vec![untiled, 4096, 1024, 256, 64],
        ),
        (
            "BI",
            Policy::Incremental,
            100,
            vec![untiled, 4096, 1024, 256, 64],
        ),
        (
            "PBI L1 test",
            Policy::PerBand(BandStrategy::L1Test),
            30,
            vec![untiled, 1024],
        ),
        (
            "PBI exhaustive",
            Policy::PerBand(BandStrategy::Exhaustive),
            30,
            vec![untiled, 1024],
        ),
        (
            "PBI exhaustive",
            Policy::PerBand(BandStrategy::Exhaustive),
            100,
            vec![untiled, 1024],
        ),
        (
            "PBI dealer",
            Policy::PerBand(BandStrategy::Dealer),
            30,
            vec![untiled, 1024],
        ),
    ] {
        let mut approx = Approximator::for_cubemap(
            &layout,
            3,
            Weighting::Transport(transport.column_l1_norms()),
            terms,
            policy,
        )
        .expect("config");
        let mut t_step = Duration::ZERO;
        let updates: Vec<_> = frames
            .iter()
            .map(|f| {
                let start = std::time::Instant::now();
                let update = approx.step(f).expect("step").clone();
                t_step += start.elapsed();
                update
            })
            .collect();
        for tile_rows in tilings {
            let fresh = Relighter::new(
                transport.clone().with_tile_rows(tile_rows),
                3,
                layout.band_count(),
            )
            .expect("engine");
            // The whole sequence from a fresh engine, REPEATS times; the fastest repetition
            // (least disturbed by the other jobs on the machine) is reported, per frame.
            let (mut t_apply, mut cpu_apply) = (Duration::MAX, Duration::MAX);
            let mut col_bytes = 0usize;
            for _ in 0..REPEATS {
                let mut engine = fresh.clone();
                col_bytes = 0;
                let (cpu, start) = (process_cpu(), std::time::Instant::now());
                for update in &updates {
                    col_bytes += engine.apply(update).expect("apply");
                }
                t_apply = t_apply.min(start.elapsed());
                cpu_apply = cpu_apply.min(process_cpu().saturating_sub(cpu));
            }
            // Each replaced band streams its partial image (read, cleared) and the total
            // (read-modify-write), pixels padded to four floats.
            let img_bytes: usize = updates
                .iter()
                .map(|u| {
                    let replaced = u
                        .modes
                        .iter()
                        .filter(|m| **m == prt_wavelet::BandMode::Replace)
                        .count();
                    replaced * 3 * transport.rows() * 4 * 4
                })
                .sum();
            let n = updates.len() as u32;
            let bound = Duration::from_secs_f64((col_bytes + img_bytes) as f64 / bandwidth) / n;
            relight.row(vec![
                name.into(),
                terms.to_string(),
                if tile_rows == untiled {
                    format!("{tile_rows} (one tile)")
                } else {
                    tile_rows.to_string()
                },
                fmt_duration(t_step / n),
                fmt_duration(t_apply / n),
                fmt_duration(cpu_apply / n),
                format!("{:.0} KB", col_bytes as f64 / n as f64 / 1e3),
                format!("{:.0} KB", img_bytes as f64 / n as f64 / 1e3),
                fmt_duration(bound),
                format!(
                    "{:.2}",
                    (cpu_apply / n).as_secs_f64() / bound.as_secs_f64().max(1e-12)
                ),
            ]);
        }
    }
    println!(
        "### Per-frame cost: approximation step and relighting apply (RGB, 64 frames of a lighting random walk)\n\n{}",
        relight.markdown()
    );
}
