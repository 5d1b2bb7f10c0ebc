//! Interpolation between two environment maps (a lighting cross-fade over 50 frames, then 50
//! static): NWA vs BI vs PBI, area-weighted L1 lighting error.
//!
//! `cargo run --release -p prt-benches --bin wavelet_blend` (no options: uffizi → grace and
//! pisa → venice, 64 × 64 faces)

use clap::Parser;
use prt_benches::{Table, load_envmap};
use prt_wavelet::analysis::LightingError;
use prt_wavelet::sequence::Interpolation;
use prt_wavelet::{
    Approximator, BandStrategy, Cubemap, CubemapHaar, CubemapLayout, Policy, Weighting,
};

const SIZE: usize = 64;
const BLEND: usize = 50;
const FRAMES: usize = 100;

/// The map `name` of ../shared/envmaps on the experiment's cube faces, or why not.
fn load(name: &str) -> Result<Cubemap, String> {
    let map = load_envmap(name)?;
    Cubemap::from_lat_long(&map, SIZE, 0.0, Cubemap::default_samples(map.width(), SIZE))
        .map_err(|e| format!("{name}: {e}"))
}

#[derive(Debug, Parser)]
#[command(about = "Interpolation between two environment maps: NWA vs BI vs PBI")]
struct Cli {}

fn main() {
    Cli::parse();
    let layout = CubemapLayout::new(SIZE).expect("size");
    let methods: [(&str, usize, Policy); 7] = [
        ("NWA30", 30, Policy::NonIncremental),
        ("NWA60", 60, Policy::NonIncremental),
        ("NWA100", 100, Policy::NonIncremental),
        ("NWA500", 500, Policy::NonIncremental),
        ("BI30", 30, Policy::Incremental),
        ("PBI30 L1 test", 30, Policy::PerBand(BandStrategy::L1Test)),
        (
            "PBI30 exhaustive",
            30,
            Policy::PerBand(BandStrategy::Exhaustive),
        ),
    ];
    let mut header = vec!["blend"];
    header.extend(methods.iter().map(|m| m.0));
    header.push("first static frame with PBI30 exhaustive < NWA500");
    let mut table = Table::new(&header);
    for (a, b) in [
        ("probulator_uffizi", "probulator_grace"),
        ("probulator_pisa", "venice_sunset_1k"),
    ] {
        let (from, to) = match (load(a), load(b)) {
            (Ok(from), Ok(to)) => (from, to),
            (Err(e), _) | (_, Err(e)) => {
                eprintln!("skipping {a} -> {b}: {e}");
                continue;
            }
        };
        let blend = Interpolation::new(from, to, BLEND).expect("blend");
        let mut approx: Vec<Approximator> = methods
            .iter()
            .map(|&(_, terms, policy)| {
                Approximator::for_cubemap(&layout, 3, Weighting::Area, terms, policy)
                    .expect("config")
            })
            .collect();
        let mut haar = CubemapHaar::new(SIZE).expect("size");
        let mut metric = LightingError::new(SIZE, 3).expect("size");
        let mut errors = vec![Vec::new(); methods.len()];
        for t in 0..FRAMES {
            let texels = blend.frame(t).expect("frame").into_data();
            let mut coeffs = texels.clone();
            haar.forward(&mut coeffs).expect("transform");
            for (m, e) in approx.iter_mut().zip(&mut errors) {
                m.step(&coeffs).expect("step");
                e.push(metric.error(m.approximation(), &texels).expect("metric"));
            }
        }
        // Mean over the blending frames after a 5-frame warm-up.
        let mut row = vec![format!("{a} -> {b}")];
        row.extend(errors.iter().map(|e| {
            format!(
                "{:.4}",
                e[5..BLEND].iter().sum::<f64>() / (BLEND - 5) as f64
            )
        }));
        let first = (BLEND..FRAMES).find(|&t| errors[6][t] < errors[3][t]);
        row.push(first.map_or("never".into(), |t| format!("{t} (+{})", t - BLEND + 1)));
        table.row(row);
    }
    println!(
        "### Cross-fade between two maps over {BLEND} frames (mean area-weighted L1 over frames 5..{BLEND}), then static\n\n{}",
        table.markdown()
    );
}
