//! Is the rotating-map experiment driven by resampling noise? For each map and face size, the
//! per-band weighted L1 norm `Σ wᵢ |Δcᵢ|` (area weights, summed over RGB, mean over 9 angles) of
//! - the frame itself,
//! - the resampling noise: the frame as the experiment builds it (`Cubemap::default_samples`
//!   sub-texel lookups per side) minus the same frame with twice as many per side,
//! - the frame-to-frame change at 1 and 3 degrees per frame,
//!
//! so that noise can be compared with the change an incremental update has to follow.
//!
//! `cargo run --release -p prt-benches --bin wavelet_resample [-- maps...]`
//!
//! With `PRT_WAVELET_SERIES=map,deg,size` it prints instead, for frames 1..100 of that rotation,
//! each band's frame-to-frame change `Σ w|c_t − c_{t−1}|` as a share of the band's own norm, to
//! show which frames are temporally incoherent at which levels.

use std::path::Path;

use prt_benches::Table;
use prt_sphere::LatLongMap;
use prt_wavelet::{Cubemap, CubemapHaar, CubemapLayout};

fn load(name: &str) -> Option<LatLongMap> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../shared/envmaps")
        .join(format!("{name}.hdr"));
    let img = image::open(&path).ok()?.into_rgb32f();
    let (w, h) = img.dimensions();
    LatLongMap::new(w as usize, h as usize, img.into_raw()).ok()
}

/// `Σ wᵢ |aᵢ − bᵢ|` per band over all channel planes.
fn band_norms(layout: &CubemapLayout, a: &[f32], b: Option<&[f32]>) -> Vec<f64> {
    let n = layout.len();
    let mut out = vec![0.0; layout.band_count()];
    for (k, &x) in a.iter().enumerate() {
        let i = k % n;
        let d = b.map_or(x, |b| x - b[k]);
        out[layout.bands()[i] as usize] += (layout.area_weights()[i] * d.abs()) as f64;
    }
    out
}

/// Per-frame, per-band relative change of one rotation (see the module docs).
fn series(spec: &str) {
    let parts: Vec<&str> = spec.split(',').collect();
    let [name, deg, size] = parts[..] else {
        eprintln!("PRT_WAVELET_SERIES wants map,deg,size");
        return;
    };
    let (deg, size): (f32, usize) = (deg.parse().expect("degrees"), size.parse().expect("size"));
    let Some(map) = load(name) else {
        eprintln!("skipping {name}: ../shared/envmaps/{name}.hdr not readable");
        return;
    };
    let layout = CubemapLayout::new(size).expect("size");
    let mut haar = CubemapHaar::new(size).expect("size");
    let samples = Cubemap::default_samples(map.width(), size);
    let mut frame = |t: usize| {
        let angle = (deg * t as f32).to_radians();
        let mut c = Cubemap::from_lat_long(&map, size, angle, samples)
            .expect("frame")
            .into_data();
        haar.forward(&mut c).expect("transform");
        c
    };
    let mut header = vec!["frame".to_string()];
    header.extend((0..layout.band_count()).map(|b| format!("band {b}")));
    let header: Vec<&str> = header.iter().map(|s| s.as_str()).collect();
    let mut table = Table::new(&header);
    let mut previous = frame(0);
    for t in 1..100 {
        let current = frame(t);
        let change = band_norms(&layout, &current, Some(&previous));
        let norm = band_norms(&layout, &current, None);
        let mut row = vec![t.to_string()];
        row.extend(
            change
                .iter()
                .zip(&norm)
                .map(|(c, n)| format!("{:.3}", c / n)),
        );
        table.row(row);
        previous = current;
    }
    println!(
        "\n### Relative change per frame and band, {name}, {deg} deg/frame, {size} x {size} faces\n\n{}",
        table.markdown()
    );
}

fn main() {
    if let Ok(spec) = std::env::var("PRT_WAVELET_SERIES") {
        series(&spec);
        return;
    }
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
    let angles: Vec<f32> = (1..=9)
        .map(|t| (10.0 * t as f32 + 0.37).to_radians())
        .collect();
    for size in [64usize, 32] {
        let layout = CubemapLayout::new(size).expect("size");
        let mut haar = CubemapHaar::new(size).expect("size");
        let mut header = vec!["map".to_string(), "quantity".to_string()];
        header.extend((0..layout.band_count()).map(|b| format!("band {b}")));
        header.push("all bands".into());
        let header: Vec<&str> = header.iter().map(|s| s.as_str()).collect();
        let mut table = Table::new(&header);
        for name in &maps {
            let Some(map) = load(name) else {
                eprintln!("skipping {name}: ../shared/envmaps/{name}.hdr not readable");
                continue;
            };
            let samples = Cubemap::default_samples(map.width(), size);
            let mut coeffs = |angle: f32, samples: usize| {
                let mut c = Cubemap::from_lat_long(&map, size, angle, samples)
                    .expect("frame")
                    .into_data();
                haar.forward(&mut c).expect("transform");
                c
            };
            let labels = [
                format!("frame ({samples}x{samples} lookups per texel)"),
                format!(
                    "resampling noise ({samples}x{samples} vs {0}x{0})",
                    2 * samples
                ),
                "change per frame at 1 deg/frame".to_string(),
                "change per frame at 3 deg/frame".to_string(),
            ];
            let mut sums = vec![vec![0.0f64; layout.band_count()]; labels.len()];
            for &angle in &angles {
                let frame = coeffs(angle, samples);
                let fine = coeffs(angle, 2 * samples);
                let back1 = coeffs(angle - 1f32.to_radians(), samples);
                let back3 = coeffs(angle - 3f32.to_radians(), samples);
                for (sum, norms) in sums.iter_mut().zip([
                    band_norms(&layout, &frame, None),
                    band_norms(&layout, &frame, Some(&fine)),
                    band_norms(&layout, &frame, Some(&back1)),
                    band_norms(&layout, &frame, Some(&back3)),
                ]) {
                    for (s, v) in sum.iter_mut().zip(norms) {
                        *s += v / angles.len() as f64;
                    }
                }
            }
            for (label, sum) in labels.iter().zip(&sums) {
                let mut row = vec![name.clone(), label.clone()];
                row.extend(sum.iter().map(|v| format!("{v:.3e}")));
                row.push(format!("{:.3e}", sum.iter().sum::<f64>()));
                table.row(row);
            }
        }
        println!(
            "\n### Weighted L1 per band (Σ w|Δc|, RGB summed, mean over 9 angles), {size} x {size} faces\n\n{}",
            table.markdown()
        );
    }
}
