//! A small version of the rotating-map experiment on a real environment map from
//! ../shared/envmaps (ignored, with the reason, when build.rs found the folder absent).

use std::path::Path;

use prt_sphere::LatLongMap;
use prt_wavelet::analysis::LightingError;
use prt_wavelet::sequence::Rotation;
use prt_wavelet::{Approximator, BandStrategy, CubemapHaar, CubemapLayout, Policy, Weighting};

/// `../shared/envmaps/<name>`. Tests that call this are ignored when build.rs found the
/// folder absent, so here the map must be readable.
fn load(name: &str) -> LatLongMap {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/envmaps")
        .join(name);
    let img = image::open(&path)
        .unwrap_or_else(|e| {
            panic!(
                "cannot read {} ({e}); the test runs because PRT_REQUIRE_SHARED=1 or because \
                 ../shared/envmaps was there when it was built",
                path.display()
            )
        })
        .into_rgb32f();
    let (w, h) = img.dimensions();
    LatLongMap::new(w as usize, h as usize, img.into_raw()).expect("finite HDR")
}

#[test]
#[cfg_attr(
    prt_skip_shared_envmaps,
    ignore = "needs ../shared/envmaps, absent at build time (PRT_REQUIRE_SHARED=1 requires it)"
)]
fn pbi_on_a_rotating_envmap_beats_nwa_and_converges_after_the_stop() {
    let map = load("probulator_uffizi.hdr");
    let (size, stop, frames, terms) = (16, 30, 60, 12);
    let rotation = Rotation::new(map, size, 2f32.to_radians(), stop).unwrap();
    let layout = CubemapLayout::new(size).unwrap();
    let mut haar = CubemapHaar::new(size).unwrap();
    let mut metric = LightingError::new(size, 3).unwrap();
    let mk = |terms, policy| {
        Approximator::for_cubemap(&layout, 3, Weighting::Area, terms, policy).unwrap()
    };
    let mut pbi = mk(terms, Policy::PerBand(BandStrategy::Exhaustive));
    let mut nwa = mk(terms, Policy::NonIncremental);
    let mut nwa_big = mk(10 * terms, Policy::NonIncremental);
    let (mut sum_pbi, mut sum_nwa) = (0.0, 0.0);
    let mut after_stop = Vec::new();
    for t in 0..frames {
        let texels = rotation.frame(t).unwrap().into_data();
        let mut coeffs = texels.clone();
        haar.forward(&mut coeffs).unwrap();
        let mut error = |a: &mut Approximator| {
            a.step(&coeffs).unwrap();
            metric.error(a.approximation(), &texels).unwrap()
        };
        let (e_pbi, e_nwa, e_big) = (error(&mut pbi), error(&mut nwa), error(&mut nwa_big));
        if (5..stop).contains(&t) {
            sum_pbi += e_pbi;
            sum_nwa += e_nwa;
        }
        if t >= stop {
            after_stop.push((e_pbi, e_big));
        }
    }
    assert!(
        sum_pbi < 0.9 * sum_nwa,
        "rotating: PBI {sum_pbi} vs NWA {sum_nwa}"
    );
    // Static lighting: PBI keeps improving and overtakes NWA with ten times the terms.
    let overtakes = after_stop.iter().position(|(p, b)| p < b);
    assert!(overtakes.is_some_and(|f| f <= 25), "{after_stop:?}");
    assert!(
        after_stop
            .windows(2)
            .all(|w| w[1].0 <= w[0].0 * (1.0 + 1e-6))
    );
    // 30 static frames of 12 terms cannot fetch all 1536 coefficients, but the error must fall
    // at least fivefold from the stop (measured: 9.5x).
    assert!(
        after_stop[after_stop.len() - 1].0 < 0.2 * after_stop[0].0,
        "{after_stop:?}"
    );
}
