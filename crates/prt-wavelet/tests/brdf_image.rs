//! BRDF editing on an image: the sparse Daubechies-4 transport's exact path, its sparsification
//! bound, and incremental image updates converging once the edits stop.

mod common;

use common::{apply_edit, edit};
use proptest::prelude::*;
use prt_wavelet::brdf::{
    CurveEditor, CurveRelighter, CurveTransport, beckmann_curve, brush_stroke,
};
use prt_wavelet::{Daubechies4, Policy};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;

/// Random transport rows shaped like traced ones: per pixel and channel a non-negative lobe
/// over the bins (a random centre and width) plus sparse noise, and some black pixels.
fn rows(pixels: usize, bins: usize, seed: u64) -> Vec<f32> {
    let mut rng = Pcg64::seed_from_u64(seed);
    let mut out = vec![0.0f32; pixels * 3 * bins];
    for p in 0..pixels {
        if rng.random_bool(0.1) {
            continue;
        }
        let centre = rng.random_range(0.0..bins as f32);
        let width = rng.random_range(1.0..bins as f32 / 2.0);
        for c in 0..3 {
            let scale = rng.random_range(0.1f32..2.0);
            for b in 0..bins {
                let d = (b as f32 - centre) / width;
                let noise = if rng.random_bool(0.05) {
                    rng.random_range(0.0..0.2)
                } else {
                    0.0
                };
                out[(p * 3 + c) * bins + b] = scale * (-d * d).exp() + noise;
            }
        }
    }
    out
}

fn d4(curve: &[f32]) -> Vec<f32> {
    let mut c = curve.to_vec();
    Daubechies4::new(curve.len())
        .unwrap()
        .forward(&mut c)
        .unwrap();
    c
}

/// `Σ_b T_p[b] f[b]` per pixel and channel, straight from the bin-domain rows, and
/// `‖T_p‖₂ ‖f‖₂`, the scale of the f32 round-off of two orthonormal transforms and a dot product.
fn direct(rows: &[f32], curve: &[f32]) -> (Vec<f64>, Vec<f64>) {
    let norm = |v: &[f32]| v.iter().map(|&x| (x as f64).powi(2)).sum::<f64>().sqrt();
    rows.chunks_exact(curve.len())
        .map(|row| {
            let sum: f64 = row
                .iter()
                .zip(curve)
                .map(|(&t, &f)| t as f64 * f as f64)
                .sum();
            (sum, norm(row) * norm(curve))
        })
        .unzip()
}

#[test]
fn the_exact_path_is_the_direct_sum_over_bins() {
    let (pixels, bins) = (53, 256);
    let rows = rows(pixels, bins, 1);
    let transport = CurveTransport::new(&rows, bins, bins).unwrap();
    assert!(
        transport
            .dropped_energy()
            .iter()
            .flatten()
            .all(|&e| e == 0.0)
    );
    let mut curve = beckmann_curve(0.2, bins).unwrap();
    brush_stroke(&mut curve, 80.0, 20.0, 3.0);
    let image = transport.image(&d4(&curve)).unwrap();
    let (expected, scale) = direct(&rows, &curve);
    for ((got, want), s) in image.iter().zip(&expected).zip(&scale) {
        assert!(
            (*got as f64 - want).abs() <= 1e-5 * s.max(1e-30),
            "{got} vs {want}"
        );
    }
    assert!(CurveTransport::new(&rows[1..], bins, bins).is_err());
    assert!(CurveTransport::new(&rows, 100, 10).is_err());
    assert!(transport.image(&[0.0; 3]).is_err());
}

#[test]
fn sparsification_keeps_the_largest_per_pixel() {
    let (pixels, bins) = (20, 64);
    let rows = rows(pixels, bins, 2);
    for keep in [0, 1, 7, 64] {
        let t = CurveTransport::new(&rows, bins, keep).unwrap();
        assert!(t.nnz() <= keep * pixels, "{keep}: {}", t.nnz());
        assert_eq!(t.bytes(), 16 * t.nnz());
    }
    assert_eq!(CurveTransport::new(&rows, bins, 0).unwrap().nnz(), 0);
}

/// Relative L2 distance of two images.
fn relative(a: &[f32], b: &[f32]) -> f64 {
    let (num, den) = a.iter().zip(b).fold((0.0, 0.0), |(n, d), (&x, &y)| {
        (n + (x as f64 - y as f64).powi(2), d + (y as f64).powi(2))
    });
    (num / den.max(1e-300)).sqrt()
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(24))]

    #[test]
    fn sparsification_error_is_bounded_by_the_dropped_energy(keep in 1usize..64, seed in 0u64..1000, m in 0.05f32..1.0) {
        let (pixels, bins) = (16, 64);
        let rows = rows(pixels, bins, seed);
        let transport = CurveTransport::new(&rows, bins, keep).unwrap();
        let curve = beckmann_curve(m, bins).unwrap();
        let norm = curve.iter().map(|&f| (f as f64).powi(2)).sum::<f64>().sqrt();
        let image = transport.image(&d4(&curve)).unwrap();
        let (exact, scale) = direct(&rows, &curve);
        for (i, ((got, want), s)) in image.iter().zip(&exact).zip(&scale).enumerate() {
            let bound = (transport.dropped_energy()[i / 3][i % 3] as f64).sqrt() * norm;
            prop_assert!((*got as f64 - want).abs() <= bound * (1.0 + 1e-4) + 1e-5 * s,
                "pixel {} channel {}: {} vs {}, bound {}", i / 3, i % 3, got, want, bound);
        }
    }

    #[test]
    fn bi_images_are_exact_within_nonzeros_over_k_frames_of_the_last_edit(
        start in 0.05f32..1.0,
        edits in prop::collection::vec(edit(-5.0..10.0), 1..6),
        terms in 4usize..64,
        keep in 8usize..256,
    ) {
        let (pixels, bins) = (12, 256);
        let rows = rows(pixels, bins, 7);
        let transport = CurveTransport::new(&rows, bins, keep).unwrap();
        let mut editor = CurveEditor::new(bins, terms).unwrap();
        let mut engine = CurveRelighter::new(transport.clone());
        let mut curve = beckmann_curve(start, bins).unwrap();
        for e in &edits {
            apply_edit(&mut curve, e);
            editor.step(&curve).unwrap();
            engine.apply(editor.update()).unwrap();
        }
        let target = d4(&curve);
        let nonzeros = editor.coefficients().iter().zip(&target).filter(|(a, b)| a != b).count();
        let exact = transport.image(&target).unwrap();
        let bound = nonzeros.div_ceil(terms);
        for frame in 1..=bound.max(1) {
            editor.step(&curve).unwrap();
            engine.apply(editor.update()).unwrap();
            // The engine follows the displayed curve on every frame.
            let shown = transport.image(editor.coefficients()).unwrap();
            prop_assert!(relative(&engine.image(), &shown) <= 1e-5, "frame {}", frame);
        }
        prop_assert_eq!(editor.coefficients(), &target[..]);
        prop_assert!(relative(&engine.image(), &exact) <= 1e-5);
        // Nothing left to change: the next frame reads no transport.
        editor.step(&curve).unwrap();
        prop_assert_eq!(engine.apply(editor.update()).unwrap(), 0);
    }

    #[test]
    fn nwa_images_follow_the_replaced_coefficients(
        edits in prop::collection::vec(edit(-5.0..10.0), 1..6),
        terms in 1usize..40,
    ) {
        let (pixels, bins) = (10, 256);
        let rows = rows(pixels, bins, 11);
        let transport = CurveTransport::new(&rows, bins, 64).unwrap();
        let mut editor = CurveEditor::with_policy(bins, terms, Policy::NonIncremental).unwrap();
        let mut engine = CurveRelighter::new(transport.clone());
        let mut curve = beckmann_curve(0.3, bins).unwrap();
        for e in &edits {
            apply_edit(&mut curve, e);
            editor.step(&curve).unwrap();
            let read = engine.apply(editor.update()).unwrap();
            prop_assert!(editor.update().terms.len() <= terms);
            let shown = transport.image(editor.coefficients()).unwrap();
            prop_assert!(relative(&engine.image(), &shown) <= 1e-5);
            // Old and new terms at most: 2k columns of at most `pixels` entries.
            prop_assert!(read <= 2 * terms * pixels);
        }
    }
}
