//! Where LightSlice's error sits, with the sun as an exact column and `UnseenLights::Skip` (as
//! in `manylight_methods … slice-skip exact-sun`): the error is split into the seen lights' part
//! (estimate − exact sum of every light some sampled row sees, evaluated in full here) and the
//! unseen lights' bias (their exact sum, what `Skip` leaves out), image-wide and per slice.
//!
//! `cargo run --release -p prt-benches --bin manylight_slices -- SCENE WIDTH VPLS CLAMP ROWS/COLS [SEEDS] [FIRST_SEED] [GLOBAL_PERCENT] [TOP] [IMAGE] [ADAPTIVE_PERCENT] [SPLIT] [GUIDE_PERCENT] [PROBES]`
//!
//! Per seed: the realised error, its seen and unseen parts (in % of ‖reference‖), the share of
//! the squared error in the worst 1%, 5% and 25% of the slices, and the `TOP` (default 8) worst
//! slices with their pixels, share of the reference's energy, local relative error and seen /
//! unseen parts. `IMAGE` (a PNG path) gets, for the first seed: reference | estimate | 10× the
//! seen part's error | 10× the unseen lights' sum | the `TOP` worst slices (white, sampled rows
//! black) over the reference (`-` for none). `ADAPTIVE_PERCENT`: as in `manylight_methods`; `SPLIT`: `largest` (default) or `spread`
//! (`SliceSplit`); `GUIDE_PERCENT` (default 0: none) and `PROBES` (default 8, `all`): LightSlice
//! with the shading guide (`light_slice_guided`, `ShadingGuide`).
//! Costs the seen lights' full columns (a few thousand) per seed.

use prt_benches::manylight::{Args, Reference, SceneOracle, SweepScene, write_strip};
use prt_core::metrics::relative_frobenius_error;
use prt_core::{MatrixOracle, NoProgress};
use prt_manylight::{
    LightSliceConfig, ReducedMatrix, SliceSplit, UnseenLights, light_slice, light_slice_guided,
};
use rayon::prelude::*;

fn main() {
    let args = Args::from_env();
    let scene_name = args.text(0).unwrap_or("sponza");
    let width: usize = args.parsed(1, 256);
    let target: usize = args.parsed(2, 100_000);
    let clamp: f32 = args.parsed(3, 1.58);
    let (rows, cols) = args.budget(4, (400, 1300));
    let seeds: u64 = args.parsed(5, 3);
    let first_seed: u64 = args.parsed(6, 1);
    let global_percent: usize = args.parsed(7, 50);
    let top: usize = args.parsed(8, 8);
    let image_path = args
        .text(9)
        .filter(|a| *a != "-")
        .map(std::path::PathBuf::from);
    let adaptive: u32 = args.parsed(10, 0);
    let split = match args.text(11) {
        Some("spread") => SliceSplit::Spread,
        _ => SliceSplit::Largest,
    };
    let guide_percent: u32 = args.parsed(12, 0);
    let probes = match args.text(13) {
        Some("all") => usize::MAX,
        _ => args.parsed(13, 8usize).max(1),
    };
    let Some(setup) = SweepScene::load(scene_name, width, target) else {
        return;
    };
    let directional = setup.sun_sky();
    let Reference {
        image: reference,
        sun,
        ..
    } = setup.reference(&directional, clamp);
    let exact = usize::from(!directional.is_empty());
    let inner = setup.oracle(clamp, &directional[exact..]);
    let oracle = SceneOracle {
        inner,
        gbuffer: &setup.gbuffer,
    };
    let (n, m) = (oracle.rows(), oracle.cols());
    let reference_norm = norm2(&reference).sqrt();
    println!(
        "{scene_name} {width}², {m} sampled lights (+{exact} exact), clamp {clamp}, {rows}/{cols}, \
         global {global_percent}%, adaptive {adaptive}%, {split:?} split, shading guide \
         {guide_percent}% on {probes} probes\n"
    );
    for seed in first_seed..first_seed + seeds {
        let config = LightSliceConfig {
            global_clusters: (cols * global_percent / 100).max(1),
            ..LightSliceConfig::new(rows, cols)
        }
        .with_seed(seed)
        .with_unseen(UnseenLights::Skip)
        .with_adaptive_percent(adaptive.min(100))
        .with_split(split);
        let estimate = if guide_percent > 0 {
            let guided = config.with_shading_guide(guide_percent.min(99), probes);
            light_slice_guided(&oracle, &guided, &NoProgress).expect("valid")
        } else {
            light_slice(&oracle, &config, &NoProgress).expect("valid")
        };
        let mut image = estimate.image.clone();
        for (v, &s) in image.iter_mut().zip(&sun) {
            *v += s;
        }
        let error = relative_frobenius_error(&image, &reference).expect("same size");
        // The exact sum of the seen lights (non-zero reduced column on the sampled rows).
        let reduced =
            ReducedMatrix::sample(&oracle, estimate.rows.clone(), &NoProgress).expect("rows");
        let seen: Vec<usize> = (0..m).filter(|&j| reduced.norms()[j] > 0.0).collect();
        let seen_sum = seen
            .par_chunks(64)
            .map(|chunk| {
                let mut acc = vec![0.0f64; 3 * n];
                let mut column = vec![0.0f32; 3 * n];
                for &j in chunk {
                    oracle.eval_col(j, &mut column).expect("column");
                    for (a, &c) in acc.iter_mut().zip(&column) {
                        *a += c as f64;
                    }
                }
                acc
            })
            .reduce(
                || vec![0.0f64; 3 * n],
                |mut a, b| {
                    for (x, y) in a.iter_mut().zip(&b) {
                        *x += y;
                    }
                    a
                },
            );
        // Seen part: estimate − seen lights' sum; unseen part: reference − sun − seen sum.
        let seen_error: Vec<f64> = estimate
            .image
            .iter()
            .zip(&seen_sum)
            .map(|(&e, &s)| e as f64 - s)
            .collect();
        let unseen_sum: Vec<f64> = reference
            .iter()
            .zip(&sun)
            .zip(&seen_sum)
            .map(|((&r, &s), &t)| r as f64 - s as f64 - t)
            .collect();
        println!(
            "seed {seed}: error {:.2}%, seen part {:.2}%, unseen bias {:.2}%, {} of {m} lights seen",
            100.0 * error,
            100.0 * norm2(&seen_error).sqrt() / reference_norm,
            100.0 * norm2(&unseen_sum).sqrt() / reference_norm,
            seen.len()
        );
        // Per slice: squared total error, seen part, unseen part, reference energy.
        let total_sq: f64 = image
            .iter()
            .zip(&reference)
            .map(|(&a, &b)| (a as f64 - b as f64).powi(2))
            .sum();
        let mut per_slice: Vec<(usize, f64, f64, f64, f64)> = estimate
            .slices
            .iter()
            .enumerate()
            .map(|(s, pixels)| {
                let (mut e, mut se, mut ue, mut r) = (0.0, 0.0, 0.0, 0.0);
                for &i in pixels {
                    for c in 3 * i..3 * i + 3 {
                        e += (image[c] as f64 - reference[c] as f64).powi(2);
                        se += seen_error[c].powi(2);
                        ue += unseen_sum[c].powi(2);
                        r += (reference[c] as f64).powi(2);
                    }
                }
                (s, e, se, ue, r)
            })
            .collect();
        per_slice.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
        let share = |fraction: f64| {
            let k = ((per_slice.len() as f64 * fraction).ceil() as usize).max(1);
            100.0 * per_slice[..k].iter().map(|p| p.1).sum::<f64>() / total_sq
        };
        println!(
            "  share of the squared error in the worst 1% / 5% / 25% of {} slices: {:.0}% / {:.0}% / {:.0}%",
            per_slice.len(),
            share(0.01),
            share(0.05),
            share(0.25)
        );
        let reference_sq = reference_norm * reference_norm;
        if let (Some(path), true) = (&image_path, seed == first_seed) {
            let mut mask = reference.clone();
            for &(s, ..) in per_slice.iter().take(top) {
                for &i in &estimate.slices[s] {
                    mask[3 * i..3 * i + 3].fill(1e9);
                }
            }
            for &i in &estimate.rows {
                mask[3 * i..3 * i + 3].fill(0.0);
            }
            let times10 = |v: &[f64]| v.iter().map(|x| (10.0 * x.abs()) as f32).collect();
            let panels = vec![
                image.clone(),
                times10(&seen_error),
                times10(&unseen_sum),
                mask,
            ];
            write_strip(path, width, &reference, &panels);
        }
        for &(s, e, se, ue, r) in per_slice.iter().take(top) {
            println!(
                "  slice {s:4}: {:4} pixels, {:5.1}% of the error², {:5.2}% of the reference², \
                 local error {:6.1}% (seen {:6.1}%, unseen {:5.1}%), {} clusters",
                estimate.slices[s].len(),
                100.0 * e / total_sq,
                100.0 * r / reference_sq,
                100.0 * (e / r).sqrt(),
                100.0 * (se / r).sqrt(),
                100.0 * (ue / r).sqrt(),
                estimate.clusters_per_slice[s]
            );
        }
    }
}

fn norm2<T: Copy + Into<f64>>(v: &[T]) -> f64 {
    v.iter().map(|&x| x.into() * x.into()).sum()
}
