//! The many-light scene side of prt-trace on the Cornell box: VPL tracing throughput, G-buffer,
//! oracle row / column cost, the brute-force reference image, and row-column sampling
//! (prt-manylight) on the real scene oracle against it (relative RMS error vs elements).
//!
//! `cargo run --release -p prt-benches --bin manylight_scene [-- WIDTH PARTICLES]`
//! (defaults 128 × 128 pixels, 20000 particles with 2 bounces ≈ 4·10^4 VPLs).
use std::time::Instant;

use prt_benches::{Table, fmt_duration, median_time};
use prt_core::metrics::relative_frobenius_error;
use prt_core::{MatrixOracle, NoProgress};
use prt_manylight::{RowColumnConfig, row_column_sampling};
use prt_trace::{GBuffer, PinholeView, RayTracer, Scene, VplOptions, VplOracle, trace_vpls};

fn main() {
    let args: Vec<usize> = std::env::args()
        .skip(1)
        .filter_map(|a| a.parse().ok())
        .collect();
    let width = args.first().copied().unwrap_or(128);
    let particles = args.get(1).copied().unwrap_or(20_000);
    let scene = Scene::cornell_box();
    let tracer = RayTracer::new(scene.triangles());
    println!("Cornell box, {} threads\n", rayon::current_num_threads());

    let mut tracing = Table::new(&["particles", "VPLs (≤ 2 bounces)", "time", "M particles/s"]);
    for n in [10_000, 100_000, 1_000_000] {
        let options = VplOptions {
            particles: n,
            max_bounces: 2,
            seed: 1,
            ..Default::default()
        };
        let mut count = 0;
        let t = median_time(3, || {
            let v = trace_vpls(&scene, &tracer, &options, &NoProgress).expect("lit scene");
            count = v.len();
        });
        tracing.row(vec![
            n.to_string(),
            count.to_string(),
            fmt_duration(t),
            format!("{:.2}", n as f64 / t.as_secs_f64() / 1e6),
        ]);
    }
    println!("{}", tracing.markdown());

    let options = VplOptions {
        particles,
        max_bounces: 2,
        seed: 1,
        ..Default::default()
    };
    let vpls = trace_vpls(&scene, &tracer, &options, &NoProgress).expect("lit scene");
    let view = PinholeView::for_scene(&scene).expect("non-empty scene");
    let start = Instant::now();
    let gbuffer = GBuffer::render(&scene, &tracer, &view, width, width).expect("valid size");
    let gbuffer_time = start.elapsed();
    let oracle = VplOracle::new(&tracer, &gbuffer, &vpls, 0.05, 1e-4).expect("finite input");
    let (n, m) = (oracle.rows(), oracle.cols());
    let mut row = vec![0.0; 3 * m];
    let mut col = vec![0.0; 3 * n];
    let row_time = median_time(9, || oracle.eval_row(n / 2 + width / 2, &mut row));
    let col_time = median_time(9, || oracle.eval_col(m / 3, &mut col));
    oracle.reset_count();
    let start = Instant::now();
    let reference = oracle.reference_image(&NoProgress).expect("finite oracle");
    let brute_time = start.elapsed();
    let brute = (n * m) as f64;
    println!(
        "{width} × {width} pixels (G-buffer {}), {m} VPLs: eval_row {} ({:.1} M elements/s), \
         eval_col {} ({:.1} M elements/s), brute force {} ({brute:.3e} elements, {:.1} M elements/s)\n",
        fmt_duration(gbuffer_time),
        fmt_duration(row_time),
        m as f64 / row_time.as_secs_f64() / 1e6,
        fmt_duration(col_time),
        n as f64 / col_time.as_secs_f64() / 1e6,
        fmt_duration(brute_time),
        brute / brute_time.as_secs_f64() / 1e6,
    );

    let mut table = Table::new(&[
        "rows / columns",
        "elements",
        "fewer elements than brute force",
        "time",
        "speed-up (time)",
        "relative RMS error",
    ]);
    for (rows, columns) in [(100, 200), (300, 900), (600, 1200), (900, 1800)] {
        if rows > n || columns > m {
            continue;
        }
        let config = RowColumnConfig::new(rows, columns).with_seed(7);
        let start = Instant::now();
        let estimate = row_column_sampling(&oracle, &config, &NoProgress).expect("valid config");
        let time = start.elapsed();
        table.row(vec![
            format!("{rows} / {columns}"),
            format!("{:.3e}", estimate.elements as f64),
            format!("{:.1}×", brute / estimate.elements as f64),
            fmt_duration(time),
            format!("{:.1}×", brute_time.as_secs_f64() / time.as_secs_f64()),
            format!(
                "{:.4}",
                relative_frobenius_error(&estimate.image, &reference)
                    .expect("images of equal size")
            ),
        ]);
    }
    println!("{}", table.markdown());
}
