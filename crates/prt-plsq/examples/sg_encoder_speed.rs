//! Progressive updates per second of `SgEncoder` for 12 spherical Gaussians × RGB on one
//! thread, in on-CPU time (the full measurement, beside the generic encoder and the batch
//! encoder, is the `plsq_speed` sweep in prt's benches).
//!
//! Run: `cargo run --release -p prt-plsq --example sg_encoder_speed [-- REPEATS]`
use std::time::Instant;

use glam::Vec3;
use prt_core::NoProgress;
use prt_plsq::{EncoderConfig, SgEncoder};
use prt_sphere::{SgBasis, sampling::halton_sphere};

/// Nanoseconds this thread has run on a CPU (Linux schedstat), if available.
fn thread_cpu_ns() -> Option<u64> {
    std::fs::read_to_string("/proc/thread-self/schedstat")
        .ok()?
        .split_whitespace()
        .next()?
        .parse()
        .ok()
}

fn main() {
    let repeats: usize = std::env::args()
        .nth(1)
        .and_then(|a| a.parse().ok())
        .unwrap_or(500);
    let basis = SgBasis::spiral(12, 6.0).expect("valid lobes");
    let dirs = halton_sphere(20000);
    let values: Vec<f32> = dirs
        .iter()
        .flat_map(|d| {
            [
                1.0 + d.y,
                0.5 + d.dot(Vec3::new(0.6, 0.64, 0.48)).max(0.0),
                0.3,
            ]
        })
        .collect();
    let fit = || {
        let mut enc = SgEncoder::<3>::new(&basis, EncoderConfig::paper()).expect("valid");
        enc.add_samples(&dirs, &values, None, &NoProgress)
            .expect("finite");
        enc.coefficients()[0]
    };
    let mut check = fit();
    let (wall, cpu) = (Instant::now(), thread_cpu_ns());
    for _ in 0..repeats {
        check += std::hint::black_box(fit());
    }
    let wall = wall.elapsed().as_secs_f64() / repeats as f64;
    let cpu = cpu
        .zip(thread_cpu_ns())
        .map(|(a, b)| (b - a) as f64 * 1e-9 / repeats as f64);
    let updates = dirs.len() as f64;
    println!(
        "12 SG x RGB, 20000 samples: wall {:.3} ms ({:.1} M updates/s); on CPU {} (checksum {check})",
        wall * 1e3,
        updates / wall / 1e6,
        cpu.map_or("unavailable".into(), |c| format!(
            "{:.3} ms ({:.1} M updates/s)",
            c * 1e3,
            updates / c / 1e6
        )),
    );
}
