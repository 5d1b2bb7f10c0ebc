//! Overbeck's rotating-map experiment: NWA vs BI vs PBI on a cube map rotating about +Y for
//! `stop` frames, then static, measured by the per-frame area-weighted L1 lighting error.
//!
//! `cargo run --release -p prt-benches --bin wavelet_rotation [-- maps... ]`
//! (default maps: probulator_uffizi, probulator_grace, venice_sunset_1k from ../shared/envmaps;
//! speeds 1 and 3 degrees per frame; 64 × 64 faces, RGB, area-weighted selection; lighting
//! area-averaged onto the faces with `Cubemap::default_samples` sub-texel lookups).
//! Environment: `PRT_CSV_DIR` writes per-frame CSVs; `PRT_WAVELET_SIZE` sets the cube face side
//! (default 64; 32 is the 6 × 32 × 32 lighting of the BRDF-factorisation and CPCA codes the
//! thesis built on); `PRT_WAVELET_SPEEDS` the degrees per frame (comma-separated, default
//! `1,3`); `PRT_WAVELET_SAMPLES_X` multiplies the sub-texel lookups per side (default 1; for
//! checking that resampling noise does not drive the results); `PRT_WAVELET_CURVES=0` skips
//! the error-vs-terms sweep; `PRT_WAVELET_WEIGHT=support` selects by `|c|` × support solid angle
//! instead of the basis function's L1 norm (see `selection_weights`).

use std::path::Path;
use std::time::Instant;

use prt_benches::Table;
use prt_sphere::LatLongMap;
use prt_wavelet::analysis::{LightingError, band_energy};
use prt_wavelet::sequence::Rotation;
use prt_wavelet::{Approximator, BandStrategy, CubemapHaar, CubemapLayout, Policy};

const FRAMES: usize = 200;
const STOP: usize = 100;
const WARMUP: usize = 10;

fn load(name: &str) -> Option<LatLongMap> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../shared/envmaps")
        .join(format!("{name}.hdr"));
    let img = image::open(&path).ok()?.into_rgb32f();
    let (w, h) = img.dimensions();
    LatLongMap::new(w as usize, h as usize, img.into_raw()).ok()
}

struct Method {
    name: String,
    approx: Approximator,
    errors: Vec<f64>,
    band_terms: Vec<Vec<usize>>,
    seconds: f64,
}

/// Selection weights: `l1` (default) the L1 norm of each basis function on the sphere
/// (`Weighting::Area`, which bounds the area-weighted L1 error), or `support` (environment
/// `PRT_WAVELET_WEIGHT=support`) that times the support's side in texels, i.e. `|c|` times the
/// support's solid angle for a normalised Haar coefficient — Ng et al.'s "area weighting" read
/// literally, which favours coarse coefficients.
fn selection_weights(layout: &CubemapLayout, size: usize) -> Vec<f32> {
    let support = std::env::var("PRT_WAVELET_WEIGHT").is_ok_and(|w| w == "support");
    layout
        .area_weights()
        .iter()
        .zip(layout.bands())
        .map(|(&w, &b)| {
            if support {
                w * (size >> (b.max(1) - 1)) as f32
            } else {
                w
            }
        })
        .collect()
}

fn method(layout: &CubemapLayout, name: &str, terms: usize, policy: Policy) -> Method {
    let weights = selection_weights(layout, layout.size());
    Method {
        name: name.to_string(),
        approx: Approximator::new(layout.bands().to_vec(), weights, 3, terms, policy)
            .expect("valid config"),
        errors: Vec::new(),
        band_terms: Vec::new(),
        seconds: 0.0,
    }
}

/// PBI over level × face × tile bands (`tiles` per face side; 1 = level × face).
fn fine_method(
    layout: &CubemapLayout,
    tiles: usize,
    name: &str,
    terms: usize,
    policy: Policy,
) -> Method {
    let approx = Approximator::new(
        layout.level_face_tile_bands(tiles).expect("tiles"),
        selection_weights(layout, layout.size()),
        3,
        terms,
        policy,
    )
    .expect("valid config");
    Method {
        name: name.to_string(),
        approx,
        errors: Vec::new(),
        band_terms: Vec::new(),
        seconds: 0.0,
    }
}

/// Every frame's texels and Haar coefficients (resampled once, shared by all runs).
fn frames(rotation: &Rotation, size: usize) -> Vec<(Vec<f32>, Vec<f32>)> {
    let mut haar = CubemapHaar::new(size).expect("size");
    (0..FRAMES)
        .map(|t| {
            let texels = rotation.frame(t).expect("frame").into_data();
            let mut coeffs = texels.clone();
            haar.forward(&mut coeffs).expect("transform");
            (texels, coeffs)
        })
        .collect()
}

fn run(frames: &[(Vec<f32>, Vec<f32>)], size: usize, methods: &mut [Method]) {
    let mut metric = LightingError::new(size, 3).expect("size");
    for (texels, coeffs) in frames {
        for m in methods.iter_mut() {
            let start = Instant::now();
            let update = m.approx.step(coeffs).expect("step");
            m.seconds += start.elapsed().as_secs_f64();
            m.band_terms.push(update.terms_per_band());
            let e = metric
                .error(m.approx.approximation(), texels)
                .expect("metric");
            m.errors.push(e);
        }
    }
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len() as f64
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let maps: Vec<String> = if args.is_empty() {
        vec![
            "probulator_uffizi".into(),
            "probulator_grace".into(),
            "venice_sunset_1k".into(),
        ]
    } else {
        args
    };
    let env = |key: &str| std::env::var(key).ok();
    let size: usize = env("PRT_WAVELET_SIZE").map_or(64, |s| s.parse().expect("face side"));
    let speeds: Vec<f32> = env("PRT_WAVELET_SPEEDS").map_or(vec![1.0, 3.0], |s| {
        s.split(',').map(|v| v.parse().expect("degrees")).collect()
    });
    let samples_x: usize =
        env("PRT_WAVELET_SAMPLES_X").map_or(1, |s| s.parse().expect("sample multiplier"));
    let curves_wanted = env("PRT_WAVELET_CURVES").is_none_or(|v| v != "0");
    println!("{size} x {size} faces, speeds {speeds:?} deg/frame, sub-texel lookups x{samples_x}");
    let layout = CubemapLayout::new(size).expect("size");
    let band_header: Vec<String> = std::iter::once("frame".to_string())
        .chain((0..layout.band_count()).map(|b| format!("band {b}")))
        .collect();
    let band_header: Vec<&str> = band_header.iter().map(|s| s.as_str()).collect();
    let mut summary = Table::new(&[
        "map",
        "deg/frame",
        "PBI30",
        "PBI30 < NWA60 (rotating frames)",
        "mean PBI30",
        "mean NWA60",
        "mean NWA100",
        "mean BI30",
        "frames after 50 with PBI30 > BI30",
        "first frame after stop with PBI30 < NWA500",
    ]);
    let mut curves = Table::new(&[
        "map",
        "deg/frame",
        "terms",
        "NWA",
        "BI",
        "PBI L1 test",
        "PBI exhaustive",
        "PBI dealer",
        "PBI dealer, level x face bands",
        "PBI dealer, level x face x quadrant bands",
    ]);
    let mut strategy_table = Table::new(&[
        "map",
        "deg/frame",
        "PBI strategy",
        "mean error rotating",
        "mean error frames 100-130",
        "step time",
    ]);
    for name in &maps {
        let Some(map) = load(name) else {
            eprintln!("skipping {name}: ../shared/envmaps/{name}.hdr not readable");
            continue;
        };
        for &deg in &speeds {
            let rotation =
                Rotation::new(map.clone(), size, deg.to_radians(), STOP).expect("rotation");
            let samples = rotation.samples() * samples_x;
            let rotation = rotation.with_samples(samples).expect("samples");
            let mut methods = vec![
                method(&layout, "PBI30", 30, Policy::PerBand(BandStrategy::L1Test)),
                method(
                    &layout,
                    "PBI30x",
                    30,
                    Policy::PerBand(BandStrategy::Exhaustive),
                ),
                method(&layout, "PBI30d", 30, Policy::PerBand(BandStrategy::Dealer)),
                fine_method(
                    &layout,
                    1,
                    "PBI30 dealer level x face",
                    30,
                    Policy::PerBand(BandStrategy::Dealer),
                ),
                fine_method(
                    &layout,
                    1,
                    "PBI30 L1 test level x face",
                    30,
                    Policy::PerBand(BandStrategy::L1Test),
                ),
                fine_method(
                    &layout,
                    2,
                    "PBI30 dealer level x face x quadrant",
                    30,
                    Policy::PerBand(BandStrategy::Dealer),
                ),
                method(&layout, "BI30", 30, Policy::Incremental),
                method(&layout, "NWA30", 30, Policy::NonIncremental),
                method(&layout, "NWA60", 60, Policy::NonIncremental),
                method(&layout, "NWA100", 100, Policy::NonIncremental),
                method(&layout, "NWA500", 500, Policy::NonIncremental),
            ];
            let first = name == &maps[0] && deg == speeds[0];
            let frames = frames(&rotation, size);
            run(&frames, size, &mut methods);
            let err = |n: &str| &methods.iter().find(|m| m.name == n).expect("method").errors;
            // Two headline PBIs: the thesis' (exhaustive over level bands, optimal per frame for the
            // selection objective) and the best variant (dealer over level x face x quadrant bands).
            let pbi_l1 = err("PBI30");
            let (bi, nwa60, nwa100, nwa500) =
                (err("BI30"), err("NWA60"), err("NWA100"), err("NWA500"));
            let rotating = WARMUP..STOP;
            for (label, key) in [
                ("exhaustive, level bands", "PBI30x"),
                (
                    "dealer, level x face x quadrant",
                    "PBI30 dealer level x face x quadrant",
                ),
            ] {
                let pbi = err(key);
                let wins = rotating.clone().filter(|&t| pbi[t] < nwa60[t]).count();
                let ghost = (50..FRAMES)
                    .filter(|&t| pbi[t] > bi[t] * (1.0 + 1e-9))
                    .count();
                let converge = (STOP..FRAMES)
                    .find(|&t| pbi[t] < nwa500[t])
                    .map_or("never".to_string(), |t| format!("{} (+{})", t, t - STOP));
                let extra = if key == "PBI30x" {
                    let wins_l1 = rotating.clone().filter(|&t| pbi_l1[t] < nwa60[t]).count();
                    format!(" ({wins_l1} L1 test)")
                } else {
                    String::new()
                };
                summary.row(vec![
                    name.clone(),
                    format!("{deg}"),
                    label.to_string(),
                    format!("{wins}/{}{extra}", rotating.len()),
                    format!("{:.4}", mean(&pbi[rotating.clone()])),
                    format!("{:.4}", mean(&nwa60[rotating.clone()])),
                    format!("{:.4}", mean(&nwa100[rotating.clone()])),
                    format!("{:.4}", mean(&bi[rotating.clone()])),
                    format!("{ghost}/{}", FRAMES - 50),
                    converge,
                ]);
            }
            for m in methods.iter().filter(|m| m.name.starts_with("PBI")) {
                strategy_table.row(vec![
                    name.clone(),
                    format!("{deg}"),
                    m.name.clone(),
                    format!("{:.4}", mean(&m.errors[rotating.clone()])),
                    format!("{:.4}", mean(&m.errors[STOP..STOP + 30])),
                    format!("{:.1} µs", m.seconds / FRAMES as f64 * 1e6),
                ]);
            }
            let mut per_frame = Table::new(&[
                "frame",
                "PBI30 L1 test",
                "PBI30 exhaustive",
                "PBI30 dealer",
                "PBI30 dealer level x face",
                "PBI30 L1 test level x face",
                "PBI30 dealer level x face x quadrant",
                "BI30",
                "NWA30",
                "NWA60",
                "NWA100",
                "NWA500",
            ]);
            for t in 0..FRAMES {
                let mut row = vec![t.to_string()];
                row.extend(methods.iter().map(|m| format!("{:.5}", m.errors[t])));
                per_frame.row(row);
            }
            per_frame
                .write_csv_if_requested(&format!("wavelet_rotation_{name}_{deg}deg_{size}"))
                .expect("csv");
            if first {
                let mut usage = Table::new(&band_header);
                for t in [1, 5, 20, 50, 99, 101, 105, 110, 120] {
                    let mut row = vec![t.to_string()];
                    row.extend(methods[0].band_terms[t].iter().map(|c| c.to_string()));
                    usage.row(row);
                }
                println!(
                    "\n### PBI30 (L1 test) terms per band per frame, {name}, {deg} deg/frame (figure 5.3)\n\n{}",
                    usage.markdown()
                );
                let coeffs: Vec<Vec<f32>> = frames[..128].iter().map(|f| f.1.clone()).collect();
                let energy = band_energy(&coeffs, layout.bands()).expect("energy");
                let mut header = band_header.clone();
                header[0] = "temporal level";
                let mut e = Table::new(&header);
                for (lvl, row) in energy.iter().enumerate() {
                    let mut cells = vec![lvl.to_string()];
                    // Each band's energy share per temporal level (columns sum to 1).
                    cells.extend(row.iter().enumerate().map(|(b, v)| {
                        let col: f64 = energy.iter().map(|r| r[b]).sum();
                        format!("{:.2e}", v / col)
                    }));
                    e.row(cells);
                }
                println!(
                    "\n### Spatio-temporal band energy, first 128 frames, {name}, {deg} deg/frame (figure 5.4; share of each spatial band's energy per temporal level)\n\n{}",
                    e.markdown()
                );
            }
            // Error vs terms per frame: mean over rotating frames.
            let budgets: &[usize] = if curves_wanted {
                &[10, 20, 30, 60, 100]
            } else {
                &[]
            };
            for &terms in budgets {
                let mut ms = vec![
                    method(&layout, "NWA", terms, Policy::NonIncremental),
                    method(&layout, "BI", terms, Policy::Incremental),
                    method(&layout, "PBI", terms, Policy::PerBand(BandStrategy::L1Test)),
                    method(
                        &layout,
                        "PBIx",
                        terms,
                        Policy::PerBand(BandStrategy::Exhaustive),
                    ),
                    method(
                        &layout,
                        "PBId",
                        terms,
                        Policy::PerBand(BandStrategy::Dealer),
                    ),
                    fine_method(
                        &layout,
                        1,
                        "PBIf",
                        terms,
                        Policy::PerBand(BandStrategy::Dealer),
                    ),
                    fine_method(
                        &layout,
                        2,
                        "PBIq",
                        terms,
                        Policy::PerBand(BandStrategy::Dealer),
                    ),
                ];
                run(&frames, size, &mut ms);
                let mut row = vec![name.clone(), format!("{deg}"), terms.to_string()];
                row.extend(
                    ms.iter()
                        .map(|m| format!("{:.4}", mean(&m.errors[rotating.clone()]))),
                );
                curves.row(row);
            }
        }
    }
    println!(
        "\n### Rotating map: 100 frames rotating, 100 static (rotating frames = {WARMUP}..{STOP})\n\n{}",
        summary.markdown()
    );
    println!(
        "\n### PBI band strategies (30 terms)\n\n{}",
        strategy_table.markdown()
    );
    println!(
        "\n### Error vs terms per frame (mean area-weighted L1 over rotating frames {WARMUP}..{STOP})\n\n{}",
        curves.markdown()
    );
    summary
        .write_csv_if_requested("wavelet_rotation_summary")
        .expect("csv");
    curves
        .write_csv_if_requested("wavelet_rotation_curves")
        .expect("csv");
}
