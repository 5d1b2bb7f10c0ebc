//! Row-column sampling (prt-manylight) on the real VPL scene oracle of prt-trace (Cornell box or
//! Sponza) against the brute-force image: relative RMS error vs elements evaluated, for several
//! VPL clamp distances (the clamp decides how spiky the matrix is).
//!
//! `cargo run --release -p prt-benches --bin manylight_scene -- SCENE WIDTH VPLS CLAMPS [SEEDS] [IMAGE] [UNSEEN] [LIGHT] [BUDGETS]`
//!
//! * `SCENE`: `cornell` (built-in box, lit by its ceiling quad) or `sponza`
//!   (`../shared/scenes/sponza`, sun and sky);
//! * `WIDTH`: the image is `WIDTH × WIDTH`; `VPLS`: about this many VPLs (particles with 2
//!   bounces); `CLAMPS`: comma-separated clamp distances in scene units;
//! * `SEEDS` (default 2): seeds per configuration (mean and max of the error);
//! * `IMAGE`: a PNG path (`-` for none): reference | row-column 300/900 | 10× error, for the
//!   first clamp;
//! * `UNSEEN`: comma-separated treatments of lights no sampled row sees, `sample` (default,
//!   unbiased) and/or `skip` (the paper's estimator), `prt_manylight::UnseenLights`;
//! * `LIGHT`: `direct` (default) adds the direct light of the sun and sky as columns (the sun
//!   and 1024 sky directions, `prt_trace::directional_lights`; none for the Cornell box, whose
//!   direct light is its emitter VPLs); `exact-sun` does the same but evaluates the sun's column
//!   in full (one column, `pixels` elements, counted) and samples the other lights; `indirect`
//!   leaves the matrix to the VPLs alone, so a sun-and-sky scene then has no direct light;
//! * `BUDGETS`: comma-separated `rows/columns` settings to run (default: the six of the paper's
//!   range, 100/200 .. 900/1800).
//!
//! Brute-force images of the VPL columns are cached in `target/manylight_cache/` (keyed by shape
//! and fingerprint), so that only the first run of a (scene, size, VPLs, clamp) pays for them;
//! the directional columns' share of the reference is evaluated column by column on every run.
use std::path::PathBuf;
use std::time::Instant;

use prt_benches::manylight::{Args, Reference, SweepScene, parse_budgets, write_strip};
use prt_benches::{Table, fmt_duration};
use prt_core::metrics::relative_frobenius_error;
use prt_core::{MatrixOracle, NoProgress};
use prt_manylight::{RowColumnConfig, UnseenLights, row_column_sampling};

fn norm(v: &[f32]) -> f64 {
    v.iter().map(|&x| x as f64 * x as f64).sum::<f64>().sqrt()
}

fn main() {
    let args = Args::from_env();
    let scene_name = args.text(0).unwrap_or("cornell");
    let width: usize = args.parsed(1, 128);
    let target_vpls: usize = args.parsed(2, 50_000);
    let clamps: Vec<f32> = args
        .text(3)
        .map(|a| a.split(',').filter_map(|c| c.parse().ok()).collect())
        .unwrap_or_else(|| vec![0.05]);
    let seeds: u64 = args.parsed(4, 2);
    let image_path = args.text(5).filter(|a| *a != "-").map(PathBuf::from);
    let policies: Vec<(&str, UnseenLights)> = {
        let wanted = args.text(6).unwrap_or("sample");
        [
            ("sample", UnseenLights::Sample),
            ("skip", UnseenLights::Skip),
        ]
        .into_iter()
        .filter(|(key, _)| wanted.split(',').any(|w| w == *key))
        .collect()
    };
    let light = args.text(7).unwrap_or("direct");
    let direct = light != "indirect";
    let budgets = parse_budgets(args.text(8));

    let Some(setup) = SweepScene::load(scene_name, width, target_vpls) else {
        return;
    };
    let directional = if direct { setup.sun_sky() } else { Vec::new() };
    let vpls = &setup.vpls;
    println!(
        "{scene_name}: {width} × {width} pixels, {} VPLs + {} directional lights, {} threads",
        vpls.len(),
        directional.len(),
        rayon::current_num_threads()
    );

    let mut table = Table::new(&[
        "clamp",
        "unseen lights",
        "rows / columns",
        "elements",
        "fewer elements than brute force",
        "time (mean)",
        "relative RMS error (mean of seeds)",
        "max over seeds",
        "unseen lights (mean)",
        "error / ‖sampled lights' image‖ (mean)",
    ]);
    for (c, &clamp) in clamps.iter().enumerate() {
        let start = Instant::now();
        let Reference {
            image: reference,
            vpl_image,
            ..
        } = setup.reference(&directional, clamp);
        let oracle = setup.oracle(clamp, &directional);
        let (n, m) = (oracle.rows(), oracle.cols());
        let mut column = vec![0.0f32; 3 * n];
        println!(
            "clamp {clamp}: ‖indirect (VPL columns)‖ / ‖reference‖ = {:.4}",
            norm(&vpl_image) / norm(&reference)
        );
        // `exact-sun`: the first directional light (the sun) as an exact column, the rest
        // sampled.
        let exact = usize::from(light == "exact-sun" && !directional.is_empty());
        let sampled = setup.oracle(clamp, &directional[exact..]);
        let mut exact_image = vec![0.0f32; 3 * n];
        // ‖reference‖ / ‖reference − exact columns‖: the error relative to the sampled part.
        let sampled_scale = |exact_image: &[f32]| {
            let rest: Vec<f32> = reference
                .iter()
                .zip(exact_image)
                .map(|(r, e)| r - e)
                .collect();
            norm(&reference) / norm(&rest)
        };
        for j in vpls.len()..vpls.len() + exact {
            oracle.eval_col(j, &mut column).expect("directional column");
            let lit = column
                .chunks(3)
                .filter(|p| p.iter().any(|&v| v > 0.0))
                .count();
            println!(
                "exact column {j}: {lit} of {n} pixels lit ({:.2}%), ‖column‖ / ‖reference‖ = {:.3}",
                100.0 * lit as f64 / n as f64,
                norm(&column) / norm(&reference)
            );
            for (e, &c) in exact_image.iter_mut().zip(&column) {
                *e += c;
            }
        }
        println!(
            "clamp {clamp}: brute force {} ({:.3e} elements; 0 s when cached)",
            fmt_duration(start.elapsed()),
            (n * m) as f64
        );
        let brute = (n * m) as f64;
        let scale = sampled_scale(&exact_image);
        for ((policy_name, policy), (rows, columns)) in policies
            .iter()
            .flat_map(|&p| budgets.iter().map(move |&c| (p, c)))
        {
            if rows > n || columns > m {
                continue;
            }
            let (mut errors, mut elements, mut unseen) = (Vec::new(), 0u64, 0usize);
            let start = Instant::now();
            let mut first_image = None;
            for seed in 0..seeds {
                let config = RowColumnConfig::new(rows, columns)
                    .with_seed(seed + 7)
                    .with_unseen(policy);
                let mut estimate =
                    row_column_sampling(&sampled, &config, &NoProgress).expect("valid config");
                for (v, &e) in estimate.image.iter_mut().zip(&exact_image) {
                    *v += e;
                }
                elements += estimate.elements + (exact * n) as u64;
                unseen += estimate.unseen_lights;
                errors.push(
                    relative_frobenius_error(&estimate.image, &reference)
                        .expect("images of equal size"),
                );
                if first_image.is_none() {
                    first_image = Some(estimate.image);
                }
            }
            let runs = seeds.max(1);
            let time = start.elapsed() / runs as u32;
            let elements = elements as f64 / runs as f64;
            let mean = errors.iter().sum::<f64>() / errors.len() as f64;
            let max = errors.iter().copied().fold(0.0, f64::max);
            table.row(vec![
                format!("{clamp}"),
                policy_name.to_string(),
                format!("{rows} / {columns}"),
                format!("{elements:.3e}"),
                format!("{:.1}×", brute / elements),
                fmt_duration(time),
                format!("{:.2}%", 100.0 * mean),
                format!("{:.2}%", 100.0 * max),
                format!("{:.0}", unseen as f64 / runs as f64),
                format!("{:.2}%", 100.0 * mean * scale),
            ]);
            if let (0, (300, 900), Some(path), Some(image)) =
                (c, (rows, columns), &image_path, first_image)
            {
                let difference: Vec<f32> = reference
                    .iter()
                    .zip(&image)
                    .map(|(a, b)| 10.0 * (a - b).abs())
                    .collect();
                write_strip(path, width, &reference, &[image, difference]);
            }
        }
    }
    println!("\n{}", table.markdown());
}
