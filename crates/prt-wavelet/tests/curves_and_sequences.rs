//! BRDF editing convergence, SH PBI, lighting sequences and the analyses.

mod common;

use common::{apply_edit, edit};
use proptest::prelude::*;
use prt_core::metrics::relative_frobenius_error;
use prt_sphere::LatLongMap;
use prt_sphere::envmap::cube_texel_direction;
use prt_wavelet::analysis::{LightingError, band_energy};
use prt_wavelet::brdf::{CurveEditor, beckmann_curve};
use prt_wavelet::sequence::{Interpolation, Rotation};
use prt_wavelet::{
    Cubemap, CubemapHaar, CubemapLayout, ShApproximator, WaveletError, texel_solid_angles,
};

#[test]
fn beckmann_is_normalised_over_projected_area() {
    // ∫ D(θ) cos θ sin θ dθ dφ = 1 over the hemisphere; midpoint rule over 256 bins.
    for m in [0.2f32, 0.5, 1.0] {
        let d = beckmann_curve(m, 4096).unwrap();
        let h = std::f64::consts::FRAC_PI_2 / 4096.0;
        let integral: f64 = d
            .iter()
            .enumerate()
            .map(|(i, &v)| {
                let t = (i as f64 + 0.5) * h;
                v as f64 * t.cos() * t.sin() * h * 2.0 * std::f64::consts::PI
            })
            .sum();
        assert!((integral - 1.0).abs() < 1e-3, "m = {m}: {integral}");
    }
    assert!(beckmann_curve(0.0, 256).is_err());
    assert!(beckmann_curve(f32::NAN, 256).is_err());
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(40))]

    #[test]
    fn brdf_edits_converge_within_nine_frames_at_30_terms(start in 0.05f32..1.0, edits in prop::collection::vec(edit(-20.0..40.0), 1..12)) {
        let mut editor = CurveEditor::new(256, 30).unwrap();
        let mut curve = beckmann_curve(start, 256).unwrap();
        for e in &edits {
            apply_edit(&mut curve, e);
            editor.step(&curve).unwrap();
        }
        let mut errors = Vec::new();
        for _ in 0..9 {
            errors.push(relative_frobenius_error(editor.step(&curve).unwrap(), &curve).unwrap());
        }
        prop_assert!(errors[8] <= 1e-6, "errors after the edits stop: {:?}", errors);
        // The curves are f32: once the error reaches a few f32 epsilons it can move by round-off.
        let floor = 4.0 * f32::EPSILON as f64;
        prop_assert!(errors.windows(2).all(|w| w[1] <= w[0] * (1.0 + 1e-6) + floor), "not monotone: {:?}", errors);
    }
}

#[test]
fn a_large_edit_is_not_exact_after_one_frame() {
    let mut editor = CurveEditor::new(256, 30).unwrap();
    let a = beckmann_curve(0.5, 256).unwrap();
    for _ in 0..9 {
        editor.step(&a).unwrap();
    }
    assert!(relative_frobenius_error(editor.curve(), &a).unwrap() <= 1e-6);
    let b = beckmann_curve(0.08, 256).unwrap();
    let first = relative_frobenius_error(editor.step(&b).unwrap(), &b).unwrap();
    assert!(
        first > 1e-3,
        "one frame of 30 terms cannot fix a roughness jump: {first}"
    );
    assert!(matches!(
        editor.step(&b[..100]),
        Err(WaveletError::LengthMismatch { .. })
    ));
}

#[test]
fn sh_pbi_fills_bands_within_budget_and_converges() {
    let order = 5;
    let mut sh = ShApproximator::new(order, 3, 9, 0.05).unwrap();
    let target: Vec<f32> = (0..3 * order * order)
        .map(|i| ((i * 7919) % 23) as f32 - 11.0)
        .collect();
    let mut frames = 0;
    loop {
        let u = sh.step(&target).unwrap();
        assert!(u.terms.len() <= 9);
        // Whole bands only.
        for l in 0..order {
            let n = u.terms.iter().filter(|t| t.band as usize == l).count();
            assert!(n == 0 || n == 2 * l + 1);
        }
        frames += 1;
        if u.terms.is_empty() {
            break;
        }
        assert!(frames < 10);
    }
    assert_eq!(sh.approximation(), &target[..]);
    // 25 terms in whole bands of 1, 3, 5, 7, 9 at 9 terms per frame: at least ⌈25/9⌉ = 3 frames of
    // work, at most 4 (9 | 7+1 | 5+3 | ...), then one frame with nothing left to do.
    assert!((4..=5).contains(&frames), "{frames} frames");
    // A small change in band 0 only: below tolerance it still gets refreshed with spare budget.
    let mut moved = target.clone();
    moved[0] += 0.01;
    let u = sh.step(&moved).unwrap();
    assert_eq!(u.terms.len(), 1);
    assert!(ShApproximator::new(5, 1, 8, 0.1).is_err());
    assert!(ShApproximator::new(5, 1, 9, f32::NAN).is_err());
}

#[test]
fn sh_tolerance_prioritises_stale_bands() {
    let order = 3;
    let mut sh = ShApproximator::new(order, 1, 5, 0.1).unwrap();
    let mut target = vec![1.0f32; 9];
    for _ in 0..4 {
        sh.step(&target).unwrap();
    }
    assert_eq!(sh.approximation(), &target[..]);
    // Band 2 changes a lot, band 1 a little: budget 5 fits only band 2 (5 terms).
    target[1] += 0.001;
    for v in &mut target[4..9] {
        *v += 3.0;
    }
    let u = sh.step(&target).unwrap();
    assert!(u.terms.iter().all(|t| t.band == 2));
    assert_eq!(u.terms.len(), 5);
}

/// A lat-long RGB map of f(d) = (2 + d.x + 0.5 d.z) × (1, 2, 3).
fn linear_map(w: usize, h: usize) -> LatLongMap {
    LatLongMap::from_fn(w, h, |d| {
        (2.0 + d.x + 0.5 * d.z) * glam::Vec3::new(1.0, 2.0, 3.0)
    })
    .unwrap()
}

#[test]
fn rotation_moves_the_map_about_y_and_stops() {
    let (size, angle) = (16, 0.7f32);
    let rot = Rotation::new(linear_map(512, 256), size, angle, 3).unwrap();
    assert_eq!(rot.angle(10), 3.0 * angle);
    assert_eq!(rot.samples(), Cubemap::default_samples(512, size));
    let frame = rot.frame(1).unwrap();
    let plane = 6 * size * size;
    for face in 0..6 {
        for y in 0..size {
            for x in 0..size {
                let d = cube_texel_direction(face, x, y, size);
                // Content moves towards increasing θ: L'(θ) = L(θ − α).
                let theta = d.x.atan2(-d.z) - angle;
                let r = (d.x * d.x + d.z * d.z).sqrt();
                let src = glam::Vec3::new(r * theta.sin(), d.y, -r * theta.cos());
                let expect = 2.0 + src.x + 0.5 * src.z;
                for c in 0..3 {
                    let got = frame.data()[c * plane + (face * size + y) * size + x];
                    // The texel mean of a linear function is its value at the texel's mean
                    // direction, which sits within (texel angle)^2 / 8 = 2e-3 of the centre.
                    assert!(
                        (got - (c + 1) as f32 * expect).abs() < 3e-3 * (c + 1) as f32,
                        "face {face} ({x},{y}) channel {c}: {got} vs {expect}"
                    );
                }
            }
        }
    }
    assert_eq!(rot.frame(3).unwrap(), rot.frame(50).unwrap());
    assert!(Rotation::new(linear_map(8, 4), 6, 0.1, 1).is_err());
    assert!(Rotation::new(linear_map(8, 4), 8, f32::NAN, 1).is_err());
    assert!(rot.clone().with_samples(0).is_err());
}

#[test]
fn rotating_by_one_texel_shifts_the_map_by_one_column() {
    let (w, h) = (64, 32);
    let value = |x: usize, y: usize| ((x * 7 + y * 13) % 11) as f32 + 0.5;
    let data = |shift: usize| -> Vec<f32> {
        (0..h)
            .flat_map(|y| (0..w).flat_map(move |x| [value((x + w - shift) % w, y); 3]))
            .collect()
    };
    let map = LatLongMap::new(w, h, data(0)).unwrap();
    let shifted = LatLongMap::new(w, h, data(1)).unwrap();
    let step = std::f32::consts::TAU / w as f32;
    let a = Cubemap::from_lat_long(&map, 8, step, 3).unwrap();
    let b = Cubemap::from_lat_long(&shifted, 8, 0.0, 3).unwrap();
    for (i, (x, y)) in a.data().iter().zip(b.data()).enumerate() {
        assert!((x - y).abs() < 1e-3, "texel {i}: {x} vs {y}");
    }
    assert!(Cubemap::from_lat_long(&map, 8, 0.0, 0).is_err());
    assert!(Cubemap::from_lat_long(&map, 6, 0.0, 1).is_err());
}

#[test]
fn area_averaging_keeps_a_small_bright_source_steady_under_rotation() {
    // One bright lat-long texel (1.4 degrees) seen by 5.6-degree cube texels.
    let (w, h, size) = (256, 128, 16);
    let (sx, sy) = (40, 50);
    let mut data = vec![0.0f32; 3 * w * h];
    data[3 * (sy * w + sx)..3 * (sy * w + sx) + 3].fill(1000.0);
    let map = LatLongMap::new(w, h, data).unwrap();
    let exact = 1000.0 * map.texel_solid_angle(sy);
    let omega = texel_solid_angles(size);
    let energy = |samples: usize, angle: f32| -> f64 {
        let cube = Cubemap::from_lat_long(&map, size, angle, samples).unwrap();
        cube.data()[..omega.len()]
            .iter()
            .zip(&omega)
            .map(|(l, o)| (l * o) as f64)
            .sum()
    };
    let samples = Cubemap::default_samples(w, size);
    let (mut lo, mut hi) = (f64::MAX, 0.0f64);
    let (mut lo1, mut hi1) = (f64::MAX, 0.0f64);
    for k in 0..24 {
        let angle = 0.3f32.to_radians() * k as f32;
        let e = energy(samples, angle) / exact;
        let e1 = energy(1, angle) / exact;
        (lo, hi) = (lo.min(e), hi.max(e));
        (lo1, hi1) = (lo1.min(e1), hi1.max(e1));
    }
    // Bilinear spreading conserves the integral up to the solid-angle change over two texels.
    assert!(lo > 0.95 && hi < 1.05, "area-averaged energy {lo}..{hi}");
    // One point sample per texel misses the source (or overweights it) depending on the angle.
    assert!(
        (1.0 - lo1).max(hi1 - 1.0) > 0.5,
        "point-sampled energy {lo1}..{hi1}"
    );
}

#[test]
fn interpolation_hits_both_ends() {
    let a = Cubemap::new(2, 1, vec![1.0; 24]).unwrap();
    let b = Cubemap::new(2, 1, vec![3.0; 24]).unwrap();
    let s = Interpolation::new(a.clone(), b.clone(), 5).unwrap();
    assert_eq!(s.frame(0).unwrap(), a);
    assert_eq!(s.frame(4).unwrap(), b);
    assert_eq!(s.frame(9).unwrap(), b);
    assert!(s.frame(2).unwrap().data().iter().all(|&v| v == 2.0));
    assert!(Interpolation::new(a.clone(), Cubemap::new(4, 1, vec![0.0; 96]).unwrap(), 5).is_err());
    assert!(Interpolation::new(a.clone(), b, 1).is_err());
}

#[test]
fn lighting_error_and_band_energy() {
    let n = 4;
    let mut haar = CubemapHaar::new(n).unwrap();
    let texels: Vec<f32> = (0..6 * n * n).map(|i| (i % 7) as f32).collect();
    let mut coeffs = texels.clone();
    haar.forward(&mut coeffs).unwrap();
    let mut metric = LightingError::new(n, 1).unwrap();
    assert!(metric.error(&coeffs, &texels).unwrap() < 1e-6);
    // L̃ = 0: the solid-angle-weighted mean of |L|.
    let omega = prt_wavelet::texel_solid_angles(n);
    let mean: f64 = texels
        .iter()
        .zip(&omega)
        .map(|(l, w)| (l * w) as f64)
        .sum::<f64>()
        / (4.0 * std::f64::consts::PI);
    assert!((metric.error(&vec![0.0; 6 * n * n], &texels).unwrap() - mean).abs() < 1e-5);

    let layout = CubemapLayout::new(n).unwrap();
    let frames: Vec<Vec<f32>> = (0..8)
        .map(|t| coeffs.iter().map(|c| c * (1.0 + 0.1 * t as f32)).collect())
        .collect();
    let energy = band_energy(&frames, layout.bands()).unwrap();
    assert_eq!(energy.len(), 4);
    assert_eq!(energy[0].len(), 3);
    let total: f64 = frames.iter().flatten().map(|&v| v as f64 * v as f64).sum();
    let table: f64 = energy.iter().flatten().sum();
    assert!((table - total).abs() < 1e-4 * total);
    // A static sequence has all of its energy at temporal level 0.
    let still = vec![coeffs.clone(); 8];
    let e = band_energy(&still, layout.bands()).unwrap();
    assert!(e[1..].iter().flatten().all(|&v| v < 1e-6 * total));
    assert!(band_energy(&frames[..6], layout.bands()).is_err());
}
