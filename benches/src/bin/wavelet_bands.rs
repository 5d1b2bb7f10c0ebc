//! Per-band error breakdown of the rotating-map experiment: where NWA and PBI spend their terms
//! and where their error is, band (wavelet level) by band, averaged over the rotating frames.
//!
//! `cargo run --release -p prt-benches --bin wavelet_bands [-- map deg/frame samples]`
//! (default: probulator_grace at 1 degree per frame, `Cubemap::default_samples` sub-texel
//! lookups per side; 64 × 64 faces, RGB, area-weighted selection). `samples = 1` is the point
//! sampling that aliases small bright sources.
//!
//! For each method and band: mean terms per frame, the share of frames the band was replaced,
//! and the band's error, measured as the area-weighted L1 of the texels reconstructed with the
//! approximation in that band only (every other band exact).

use std::path::Path;

use prt_benches::Table;
use prt_sphere::LatLongMap;
use prt_wavelet::analysis::LightingError;
use prt_wavelet::sequence::Rotation;
use prt_wavelet::{
    Approximator, BandMode, BandStrategy, CubemapHaar, CubemapLayout, Policy, Weighting,
};

const SIZE: usize = 64;
const STOP: usize = 100;
const WARMUP: usize = 10;

struct Stats {
    name: &'static str,
    approx: Approximator,
    terms: Vec<f64>,
    replaced: Vec<f64>,
    band_error: Vec<f64>,
    total_error: f64,
    objective: f64,
}

fn load(path: &Path) -> Option<LatLongMap> {
    let img = image::open(path).ok()?.into_rgb32f();
    let (w, h) = img.dimensions();
    LatLongMap::new(w as usize, h as usize, img.into_raw()).ok()
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let name = args.first().map_or("probulator_grace", |s| s.as_str());
    let deg: f32 = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(1.0);
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../shared/envmaps")
        .join(format!("{name}.hdr"));
    let Some(map) = load(&path) else {
        eprintln!("skipping: {} not readable", path.display());
        return;
    };
    let layout = CubemapLayout::new(SIZE).expect("size");
    let bands = layout.band_count();
    let mut rotation = Rotation::new(map, SIZE, deg.to_radians(), STOP).expect("rotation");
    if let Some(samples) = args.get(2).and_then(|s| s.parse().ok()) {
        rotation = rotation.with_samples(samples).expect("samples");
    }
    let samples = rotation.samples();
    let frame = |t: usize| rotation.frame(t).expect("frame").into_data();
    let mk = |name, terms, policy| Stats {
        name,
        approx: Approximator::for_cubemap(&layout, 3, Weighting::Area, terms, policy)
            .expect("config"),
        terms: vec![0.0; bands],
        replaced: vec![0.0; bands],
        band_error: vec![0.0; bands],
        total_error: 0.0,
        objective: 0.0,
    };
    let quadrant_bands = layout.level_face_tile_bands(2).expect("tiles");
    let fine = |name, bands: Vec<u8>, policy| Stats {
        name,
        approx: Approximator::new(bands, layout.area_weights().to_vec(), 3, 30, policy)
            .expect("config"),
        terms: vec![0.0; layout.band_count()],
        replaced: vec![0.0; layout.band_count()],
        band_error: vec![0.0; layout.band_count()],
        total_error: 0.0,
        objective: 0.0,
    };
    let mut methods = vec![
        mk(
            "PBI30 exhaustive",
            30,
            Policy::PerBand(BandStrategy::Exhaustive),
        ),
        mk("PBI30 dealer", 30, Policy::PerBand(BandStrategy::Dealer)),
        fine(
            "PBI30 dealer level x face",
            layout.level_face_bands(),
            Policy::PerBand(BandStrategy::Dealer),
        ),
        fine(
            "PBI30 dealer level x face x quadrant",
            quadrant_bands,
            Policy::PerBand(BandStrategy::Dealer),
        ),
        mk("BI30", 30, Policy::Incremental),
        mk("NWA30", 30, Policy::NonIncremental),
        mk("NWA60", 60, Policy::NonIncremental),
        mk("NWA100", 100, Policy::NonIncremental),
    ];
    let mut haar = CubemapHaar::new(SIZE).expect("size");
    let mut metric = LightingError::new(SIZE, 3).expect("size");
    let n = layout.len();
    let mut mixed = vec![0.0f32; 3 * n];
    let mut counted = 0.0;
    let mut energy = Vec::new();
    let omega = prt_wavelet::texel_solid_angles(SIZE);
    // Per band: weighted L1 of the frame-to-frame change and of the lighting itself.
    let (mut change, mut magnitude) = (vec![0.0f64; bands], vec![0.0f64; bands]);
    let mut previous: Option<Vec<f32>> = None;
    for t in 0..STOP {
        let texels = frame(t);
        let mut coeffs = texels.clone();
        haar.forward(&mut coeffs).expect("transform");
        let measure = t >= WARMUP;
        energy.push(
            texels
                .iter()
                .enumerate()
                .map(|(i, v)| (v * omega[i % n]) as f64)
                .sum::<f64>(),
        );
        if let (Some(p), true) = (&previous, measure) {
            for j in 0..3 * n {
                let (b, w) = (
                    layout.bands()[j % n] as usize,
                    layout.area_weights()[j % n] as f64,
                );
                change[b] += w * (coeffs[j] - p[j]).abs() as f64;
                magnitude[b] += w * coeffs[j].abs() as f64;
            }
        }
        previous = Some(coeffs.clone());
        if measure {
            counted += 1.0;
        }
        for m in &mut methods {
            let update = m.approx.step(&coeffs).expect("step").clone();
            if !measure {
                continue;
            }
            m.objective += update.residual;
            for term in &update.terms {
                m.terms[layout.bands()[term.index as usize] as usize] += 1.0;
            }
            if update.modes.len() == bands {
                for (b, mode) in update.modes.iter().enumerate() {
                    if *mode == BandMode::Replace {
                        m.replaced[b] += 1.0;
                    }
                }
            }
            let approx = m.approx.approximation();
            m.total_error += metric.error(approx, &texels).expect("metric");
            for b in 0..bands {
                for (j, v) in mixed.iter_mut().enumerate() {
                    *v = if layout.bands()[j % n] as usize == b {
                        approx[j]
                    } else {
                        coeffs[j]
                    };
                }
                m.band_error[b] += metric.error(&mixed, &texels).expect("metric");
            }
        }
    }
    let mut header = vec![
        "method".to_string(),
        "total error".to_string(),
        "objective".to_string(),
    ];
    for b in 0..bands {
        header.push(format!("band {b}: terms / replaced / error"));
    }
    let header: Vec<&str> = header.iter().map(|s| s.as_str()).collect();
    let mut table = Table::new(&header);
    for m in &methods {
        let mut row = vec![
            m.name.to_string(),
            format!("{:.4}", m.total_error / counted),
            format!("{:.4}", m.objective / counted),
        ];
        for b in 0..bands {
            row.push(format!(
                "{:.1} / {:.0}% / {:.4}",
                m.terms[b] / counted,
                100.0 * m.replaced[b] / counted,
                m.band_error[b] / counted
            ));
        }
        table.row(row);
    }
    let mut row = vec![
        "frame-to-frame change / magnitude".to_string(),
        String::new(),
        String::new(),
    ];
    row.extend((0..bands).map(|b| format!("{:.3}", change[b] / magnitude[b])));
    table.row(row);
    let (lo, hi) = energy
        .iter()
        .fold((f64::MAX, f64::MIN), |(a, b), &e| (a.min(e), b.max(e)));
    println!("total radiant energy over frames: min {lo:.4}, max {hi:.4}");
    println!(
        "\n### Per-band breakdown, {name}, {deg} deg/frame, {samples}x{samples} samples per texel, mean over rotating frames {WARMUP}..{STOP}\n\n{}",
        table.markdown()
    );
}
