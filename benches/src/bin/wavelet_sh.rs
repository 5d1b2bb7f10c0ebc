//! PBI for spherical-harmonic lighting (Overbeck's chapter 8): a rotating environment map
//! projected onto SH of order 10 (100 coefficients per channel), updated with a budget of terms
//! per frame by tolerance-driven band filling, against the non-incremental budget (the lowest
//! whole bands that fit). Error: relative L2 of the SH lighting vector.
//!
//! `cargo run --release -p prt-benches --bin wavelet_sh` (no options: uffizi and grace at 1
//! and 3°/frame, budgets 30 and 50)

use clap::Parser;
use prt_benches::{Table, load_envmap};
use prt_sphere::envmap::cube_texel_direction;
use prt_wavelet::sequence::Rotation;
use prt_wavelet::{ShApproximator, texel_solid_angles};

const ORDER: usize = 10;
const SIZE: usize = 32;
const FRAMES: usize = 200;
const STOP: usize = 100;

fn project(rotation: &Rotation, t: usize, omega: &[f32], basis: &[Vec<f32>]) -> Vec<f32> {
    let texels = rotation.frame(t).expect("frame").into_data();
    let plane = 6 * SIZE * SIZE;
    let mut sh = vec![0.0f64; 3 * ORDER * ORDER];
    for i in 0..plane {
        for c in 0..3 {
            let w = (texels[c * plane + i] * omega[i]) as f64;
            for (k, &y) in basis[i].iter().enumerate() {
                sh[c * ORDER * ORDER + k] += w * y as f64;
            }
        }
    }
    sh.into_iter().map(|v| v as f32).collect()
}

fn rel_l2(a: &[f32], b: &[f32]) -> f64 {
    let e: f64 = a
        .iter()
        .zip(b)
        .map(|(x, y)| (*x as f64 - *y as f64).powi(2))
        .sum();
    let n: f64 = b.iter().map(|y| (*y as f64).powi(2)).sum();
    (e / n).sqrt()
}

#[derive(Debug, Parser)]
#[command(about = "PBI for spherical-harmonic lighting on a rotating map")]
struct Cli {}

fn main() {
    Cli::parse();
    let omega = texel_solid_angles(SIZE);
    let basis: Vec<Vec<f32>> = (0..6 * SIZE * SIZE)
        .map(|i| {
            let (face, t) = (i / (SIZE * SIZE), i % (SIZE * SIZE));
            let mut y = vec![0.0f32; ORDER * ORDER];
            prt_sphere::eval_sh(
                ORDER,
                cube_texel_direction(face, t % SIZE, t / SIZE, SIZE),
                &mut y,
            );
            y
        })
        .collect();
    let mut table = Table::new(&[
        "map",
        "deg/frame",
        "budget",
        "truncation (bands that fit)",
        "SH PBI tol 0.01",
        "SH PBI tol 0",
        "PBI frames to exact after stop",
    ]);
    for name in ["probulator_uffizi", "probulator_grace"] {
        let map = match load_envmap(name) {
            Ok(map) => map,
            Err(e) => {
                eprintln!("skipping {name}: {e}");
                continue;
            }
        };
        for deg in [1.0f32, 3.0] {
            let rotation =
                Rotation::new(map.clone(), SIZE, deg.to_radians(), STOP).expect("rotation");
            let frames: Vec<Vec<f32>> = (0..FRAMES)
                .map(|t| project(&rotation, t, &omega, &basis))
                .collect();
            for budget in [30usize, 50] {
                // Non-incremental: the lowest whole bands that fit in the budget, refreshed every frame.
                let fit = (0..=ORDER)
                    .take_while(|b| b * b <= budget)
                    .last()
                    .unwrap_or(0);
                let mut errs = [0.0f64; 3];
                let mut exact_at = None;
                let mut pbi = ShApproximator::new(ORDER, 3, budget, 0.01).expect("config");
                let mut pbi0 = ShApproximator::new(ORDER, 3, budget, 0.0).expect("config");
                for (t, f) in frames.iter().enumerate() {
                    let mut trunc = f.clone();
                    for c in 0..3 {
                        trunc[c * ORDER * ORDER + fit * fit..(c + 1) * ORDER * ORDER].fill(0.0);
                    }
                    pbi.step(f).expect("step");
                    pbi0.step(f).expect("step");
                    if (10..STOP).contains(&t) {
                        errs[0] += rel_l2(&trunc, f);
                        errs[1] += rel_l2(pbi.approximation(), f);
                        errs[2] += rel_l2(pbi0.approximation(), f);
                    }
                    if t >= STOP && exact_at.is_none() && pbi.approximation() == &f[..] {
                        exact_at = Some(t - STOP + 1);
                    }
                }
                let n = (STOP - 10) as f64;
                table.row(vec![
                    name.into(),
                    format!("{deg}"),
                    budget.to_string(),
                    format!("{:.4} ({fit} bands)", errs[0] / n),
                    format!("{:.4}", errs[1] / n),
                    format!("{:.4}", errs[2] / n),
                    exact_at.map_or("not within 100".into(), |f| f.to_string()),
                ]);
            }
        }
    }
    println!(
        "### SH PBI (order {ORDER}, RGB): mean relative L2 error over rotating frames 10..{STOP}\n\n{}",
        table.markdown()
    );
}
