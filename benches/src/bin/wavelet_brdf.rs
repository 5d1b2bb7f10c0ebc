//! BRDF editing in Daubechies-4 with basic incremental updates (Overbeck's chapter 4): frames
//! until the displayed curve is exact (relative RMS <= 1e-6) after each kind of edit, at 30 terms
//! per frame, and the error per frame after the edit.
//!
//! `cargo run --release -p prt-benches --bin wavelet_brdf` (no options)

use prt_benches::Table;
use prt_core::metrics::relative_frobenius_error;
use prt_wavelet::brdf::{CurveEditor, beckmann_curve, brush_stroke};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;

const BINS: usize = 256;

/// Runs `edits` (one frame each) then holds the last curve; returns the error per held frame.
fn run(terms: usize, start: &[f32], edits: &[Vec<f32>], hold: usize) -> Vec<f64> {
    let mut editor = CurveEditor::new(BINS, terms).expect("editor");
    for _ in 0..16 {
        editor.step(start).expect("step");
    }
    for e in edits {
        editor.step(e).expect("step");
    }
    let last = edits.last().expect("edits");
    (0..hold)
        .map(|_| relative_frobenius_error(editor.step(last).expect("step"), last).unwrap())
        .collect()
}

#[derive(Debug, clap::Parser)]
#[command(about = "BRDF editing in Daubechies-4 with basic incremental updates")]
struct Cli {}

fn main() {
    <Cli as clap::Parser>::parse();
    let mut rng = Pcg64::seed_from_u64(2006);
    let base = beckmann_curve(0.3, BINS).expect("curve");
    let mut scenarios: Vec<(String, Vec<Vec<f32>>)> = Vec::new();
    for (from, to) in [(0.3f32, 0.05f32), (0.3, 0.9), (0.05, 1.5)] {
        // A roughness slider dragged over 10 frames.
        let edits = (1..=10)
            .map(|f| beckmann_curve(from + (to - from) * f as f32 / 10.0, BINS).expect("curve"))
            .collect();
        scenarios.push((
            format!("roughness {from} -> {to}, dragged over 10 frames"),
            edits,
        ));
        scenarios.push((
            format!("roughness {from} -> {to}, one jump"),
            vec![beckmann_curve(to, BINS).expect("curve")],
        ));
    }
    for strokes in [1usize, 5, 20] {
        let mut curve = base.clone();
        let edits = (0..strokes)
            .map(|_| {
                brush_stroke(
                    &mut curve,
                    rng.random_range(0.0..BINS as f32),
                    rng.random_range(2.0..40.0),
                    rng.random_range(-0.5..2.0),
                );
                curve.clone()
            })
            .collect();
        scenarios.push((
            format!("{strokes} free-hand strokes (one per frame)"),
            edits,
        ));
    }
    let noise: Vec<f32> = (0..BINS).map(|_| rng.random_range(0.0..5.0)).collect();
    scenarios.push((
        "white-noise curve (all 256 coefficients non-zero)".into(),
        vec![noise],
    ));

    let mut table = Table::new(&[
        "edit",
        "frames to rel. RMS <= 1e-6 (30 terms)",
        "rel. RMS after 1",
        "after 3",
        "after 6",
        "after 9",
    ]);
    let mut worst = 0;
    for (name, edits) in &scenarios {
        let e = run(30, &base, edits, 12);
        let frames = e.iter().position(|&x| x <= 1e-6).map(|p| p + 1);
        worst = worst.max(frames.unwrap_or(usize::MAX));
        table.row(vec![
            name.clone(),
            frames.map_or("> 12".into(), |f| f.to_string()),
            format!("{:.2e}", e[0]),
            format!("{:.2e}", e[2]),
            format!("{:.2e}", e[5]),
            format!("{:.2e}", e[8]),
        ]);
    }
    println!(
        "### BRDF editing, 256 bins, Daubechies-4, BI (frames counted after the last edit frame)\n\n{}",
        table.markdown()
    );
    println!("worst case: {worst} frames (bound ⌈256 / 30⌉ = 9)\n");

    let mut curve_table = Table::new(&[
        "terms per frame",
        "frames to exact (worst scenario)",
        "mean rel. RMS over first 3 frames",
    ]);
    for terms in [10usize, 20, 30, 60, 128] {
        let (mut worst, mut early) = (0usize, 0.0f64);
        for (_, edits) in &scenarios {
            let e = run(terms, &base, edits, 64);
            worst = worst.max(
                e.iter()
                    .position(|&x| x <= 1e-6)
                    .map_or(usize::MAX, |p| p + 1),
            );
            early += e[..3].iter().sum::<f64>() / 3.0;
        }
        curve_table.row(vec![
            terms.to_string(),
            worst.to_string(),
            format!("{:.2e}", early / scenarios.len() as f64),
        ]);
    }
    println!(
        "### Terms per frame vs convergence\n\n{}",
        curve_table.markdown()
    );
}
