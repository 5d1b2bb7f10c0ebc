//! Transforms against PyWavelets' vectors, and their laws (perfect reconstruction, Parseval,
//! linearity, closed forms) as property tests.

use proptest::prelude::*;
use prt_wavelet::{
    Cubemap, CubemapHaar, CubemapLayout, Daubechies4, Haar2d, WaveletError, band_of_2d,
    haar_forward, haar_inverse, texel_solid_angles,
};
use serde_json::Value;

fn vectors() -> Value {
    serde_json::from_str(include_str!("data/pywt_vectors.json"))
        .expect("committed test data parses")
}

fn floats(v: &Value) -> Vec<f32> {
    v.as_array()
        .expect("array")
        .iter()
        .map(|x| x.as_f64().expect("number") as f32)
        .collect()
}

fn max_abs_diff(a: &[f32], b: &[f32]) -> f32 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max)
}

#[test]
fn db2_matches_pywavelets_periodization() {
    let cases = vectors()["db2"].as_array().expect("db2 cases").clone();
    assert!(cases.len() >= 12);
    for case in cases {
        let input = floats(&case["input"]);
        let expected = floats(&case["coeffs"]);
        let levels = case["levels"].as_u64().expect("levels") as usize;
        let mut t = Daubechies4::with_levels(input.len(), levels).expect("valid");
        let mut x = input.clone();
        t.forward(&mut x).expect("forward");
        assert!(
            max_abs_diff(&x, &expected) < 2e-5,
            "n={} levels={levels}: {x:?} vs {expected:?}",
            input.len()
        );
        t.inverse(&mut x).expect("inverse");
        assert!(max_abs_diff(&x, &input) < 2e-5);
    }
}

#[test]
fn haar_1d_and_2d_match_pywavelets() {
    let v = vectors();
    for case in v["haar1d"].as_array().expect("haar1d") {
        let mut x = floats(&case["input"]);
        haar_forward(&mut x).expect("forward");
        assert!(max_abs_diff(&x, &floats(&case["coeffs"])) < 2e-5);
    }
    for case in v["haar2d"].as_array().expect("haar2d") {
        let n = case["size"].as_u64().expect("size") as usize;
        let mut x = floats(&case["input"]);
        Haar2d::new(n)
            .expect("size")
            .forward(&mut x)
            .expect("forward");
        assert!(
            max_abs_diff(&x, &floats(&case["coeffs"])) < 2e-5,
            "size {n}"
        );
    }
}

#[test]
fn bad_sizes_are_typed_errors() {
    assert!(matches!(
        Daubechies4::new(96),
        Err(WaveletError::NotPowerOfTwo { len: 96, .. })
    ));
    assert!(matches!(
        Daubechies4::new(1),
        Err(WaveletError::NotPowerOfTwo { len: 1, .. })
    ));
    assert!(matches!(
        Daubechies4::with_levels(16, 5),
        Err(WaveletError::Invalid { .. })
    ));
    assert!(matches!(
        haar_forward(&mut [1.0; 6]),
        Err(WaveletError::NotPowerOfTwo { len: 6, .. })
    ));
    assert!(matches!(
        Haar2d::new(12),
        Err(WaveletError::NotPowerOfTwo { len: 12, .. })
    ));
    let mut t = Daubechies4::new(16).expect("valid");
    assert!(matches!(
        t.forward(&mut [0.0; 8]),
        Err(WaveletError::LengthMismatch {
            expected: 16,
            got: 8,
            ..
        })
    ));
    assert!(matches!(
        Cubemap::new(12, 1, vec![0.0; 6 * 144]),
        Err(WaveletError::NotPowerOfTwo { .. })
    ));
    let face = vec![0.0f32; 4 * 4 * 3];
    let short = vec![0.0f32; 4 * 3 * 3];
    let faces: Vec<&[f32]> = vec![&face, &face, &face, &short, &face, &face];
    assert!(matches!(
        Cubemap::from_faces(4, 3, &faces),
        Err(WaveletError::LengthMismatch {
            what: "cube face",
            ..
        })
    ));
    assert!(matches!(
        Cubemap::from_faces(4, 3, &faces[..5]),
        Err(WaveletError::LengthMismatch {
            what: "cube faces",
            ..
        })
    ));
}

#[test]
fn non_finite_lighting_names_the_texel() {
    let mut data = vec![1.0f32; 2 * 6 * 16];
    // channel 1, face 3, texel (x 2, y 1)
    data[6 * 16 + 3 * 16 + 4 + 2] = f32::NAN;
    assert_eq!(
        Cubemap::new(4, 2, data),
        Err(WaveletError::NonFiniteTexel {
            face: 3,
            x: 2,
            y: 1,
            channel: 1
        })
    );
    let face = vec![1.0f32; 16 * 3];
    let mut bad = face.clone();
    bad[(2 * 4 + 1) * 3 + 2] = f32::INFINITY;
    let faces: Vec<&[f32]> = vec![&face, &face, &face, &face, &bad, &face];
    assert_eq!(
        Cubemap::from_faces(4, 3, &faces),
        Err(WaveletError::NonFiniteTexel {
            face: 4,
            x: 1,
            y: 2,
            channel: 2
        })
    );
}

#[test]
fn constant_map_has_one_coefficient_per_face() {
    let n = 16;
    let mut data = vec![3.0f32; 6 * n * n];
    CubemapHaar::new(n)
        .expect("size")
        .forward(&mut data)
        .expect("forward");
    for face in 0..6 {
        let f = &data[face * n * n..(face + 1) * n * n];
        // The scaling coefficient of an orthonormal transform of a constant c on n² texels is c·n.
        assert!((f[0] - 3.0 * n as f32).abs() < 1e-4);
        assert!(f[1..].iter().all(|v| v.abs() < 1e-5));
    }
}

#[test]
fn layout_bands_and_area_weights() {
    let n = 8;
    let layout = CubemapLayout::new(n).expect("size");
    assert_eq!(layout.band_count(), 4);
    assert_eq!(layout.len(), 6 * 64);
    assert_eq!(band_of_2d(0, 0), 0);
    assert_eq!(band_of_2d(1, 0), 1);
    assert_eq!(band_of_2d(1, 1), 1);
    assert_eq!(band_of_2d(3, 2), 2);
    assert_eq!(band_of_2d(7, 0), 3);
    // Per face: 1 scaling + 3·4^(j−1) details in band j.
    let per_band: Vec<usize> = (0..4)
        .map(|b| {
            layout.bands()[..64]
                .iter()
                .filter(|&&x| x as usize == b)
                .count()
        })
        .collect();
    assert_eq!(per_band, vec![1, 3, 12, 48]);
    let fine = layout.level_face_bands();
    assert_eq!(fine.len(), layout.len());
    for (i, &b) in fine.iter().enumerate() {
        assert_eq!(b as usize, 6 * layout.bands()[i] as usize + i / 64);
    }
    assert_eq!(*fine.iter().max().unwrap() as usize, 6 * 4 - 1);
    // Area weights are the basis functions' L1 norms on the sphere: computed directly here from
    // the texel solid angles and the inverse transform of a unit coefficient.
    let omega = texel_solid_angles(n);
    let total: f64 = omega.iter().map(|&w| w as f64).sum();
    assert!((total - 4.0 * std::f64::consts::PI).abs() < 1e-5);
    let mut haar = CubemapHaar::new(n).expect("size");
    for i in [0usize, 1, 9, 18, 27, 63, 64 * 2 + 5, 64 * 5 + 62] {
        let mut e = vec![0.0f32; 6 * 64];
        e[i] = 1.0;
        haar.inverse(&mut e).expect("inverse");
        let l1: f64 = e
            .iter()
            .zip(&omega)
            .map(|(v, w)| (v.abs() * w) as f64)
            .sum();
        assert!(
            (l1 - layout.area_weights()[i] as f64).abs() < 1e-6,
            "coefficient {i}: {l1}"
        );
    }
}

#[test]
fn tile_bands_keep_each_support_inside_one_tile() {
    let n = 8;
    let layout = CubemapLayout::new(n).expect("size");
    assert_eq!(
        layout.level_face_tile_bands(1).expect("tiles"),
        layout.level_face_bands()
    );
    let bands = layout.level_face_tile_bands(2).expect("tiles");
    // Levels 0 and 1 span the face: one band per level and face; levels 2 and 3: four each.
    assert_eq!(*bands.iter().max().unwrap() as usize + 1, 2 * 6 + 2 * 6 * 4);
    let mut haar = CubemapHaar::new(n).expect("size");
    let mut tile_of_band = vec![None; 60];
    for i in 0..6 * n * n {
        if layout.bands()[i] < 2 {
            continue;
        }
        let mut e = vec![0.0f32; 6 * n * n];
        e[i] = 1.0;
        haar.inverse(&mut e).expect("inverse");
        let mut tiles: Vec<(usize, usize, usize)> = e
            .iter()
            .enumerate()
            .filter(|(_, v)| **v != 0.0)
            .map(|(t, _)| (t / (n * n), (t % n) / (n / 2), (t % (n * n)) / n / (n / 2)))
            .collect();
        tiles.dedup();
        assert_eq!(tiles.len(), 1, "coefficient {i} spans {tiles:?}");
        let b = bands[i] as usize;
        assert_eq!(
            *tile_of_band[b].get_or_insert(tiles[0]),
            tiles[0],
            "band {b}"
        );
    }
    assert!(layout.level_face_tile_bands(0).is_err());
    assert!(layout.level_face_tile_bands(3).is_err());
    assert!(layout.level_face_tile_bands(16).is_err());
    let big = CubemapLayout::new(256).expect("size");
    assert!(
        big.level_face_tile_bands(2).is_ok(),
        "12 + 7 x 6 x 4 = 180 bands"
    );
    assert!(
        big.level_face_tile_bands(4).is_err(),
        "18 + 6 x 6 x 16 > 256 bands"
    );
}

fn signal(max_log2: u32) -> impl Strategy<Value = Vec<f32>> {
    (0..=max_log2).prop_flat_map(|k| prop::collection::vec(-1.0e3f32..1.0e3, 1usize << k))
}

fn energy(x: &[f32]) -> f64 {
    x.iter().map(|&v| v as f64 * v as f64).sum()
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]

    #[test]
    fn haar_1d_reconstructs_and_keeps_energy(x in signal(9)) {
        let mut y = x.clone();
        haar_forward(&mut y).unwrap();
        let e = energy(&x);
        prop_assert!((energy(&y) - e).abs() <= 1e-5 * e + 1e-6);
        haar_inverse(&mut y).unwrap();
        prop_assert!(max_abs_diff(&x, &y) <= 1e-3);
    }

    #[test]
    fn db2_reconstructs_and_keeps_energy(x in signal(9).prop_filter("two samples", |x| x.len() >= 2)) {
        let mut t = Daubechies4::new(x.len()).unwrap();
        let mut y = x.clone();
        t.forward(&mut y).unwrap();
        let e = energy(&x);
        prop_assert!((energy(&y) - e).abs() <= 1e-5 * e + 1e-6);
        t.inverse(&mut y).unwrap();
        prop_assert!(max_abs_diff(&x, &y) <= 2e-3);
    }

    #[test]
    fn db2_is_linear(x in prop::collection::vec(-10.0f32..10.0, 64), y in prop::collection::vec(-10.0f32..10.0, 64), a in -3.0f32..3.0) {
        let mut t = Daubechies4::new(64).unwrap();
        let mut combo: Vec<f32> = x.iter().zip(&y).map(|(p, q)| a * p + q).collect();
        let (mut tx, mut ty) = (x.clone(), y.clone());
        t.forward(&mut combo).unwrap();
        t.forward(&mut tx).unwrap();
        t.forward(&mut ty).unwrap();
        let expect: Vec<f32> = tx.iter().zip(&ty).map(|(p, q)| a * p + q).collect();
        prop_assert!(max_abs_diff(&combo, &expect) <= 1e-3);
    }

    #[test]
    fn cubemap_haar_reconstructs_keeps_energy_and_is_linear(
        k in 0u32..=4, seed in any::<u64>(), a in -4.0f32..4.0, channels in 1usize..=3
    ) {
        let n = 1usize << k;
        let len = channels * 6 * n * n;
        // A deterministic pseudo-random map with huge dynamic range (1e-6 .. 1e6).
        let mut state = seed | 1;
        let mut next = || { state ^= state << 13; state ^= state >> 7; state ^= state << 17; state };
        let x: Vec<f32> = (0..len).map(|_| { let r = next(); 10f32.powf((r % 13) as f32 - 6.0) * if r & 64 == 0 { 1.0 } else { -1.0 } }).collect();
        let y: Vec<f32> = (0..len).map(|_| (next() % 1000) as f32 / 100.0).collect();
        let mut haar = CubemapHaar::new(n).unwrap();
        let mut tx = x.clone();
        haar.forward(&mut tx).unwrap();
        let e = energy(&x);
        prop_assert!((energy(&tx) - e).abs() <= 1e-5 * e);
        let mut back = tx.clone();
        haar.inverse(&mut back).unwrap();
        // f32 rounding is relative to the largest magnitude mixed into a coefficient.
        let peak = x.iter().fold(0.0f32, |m, v| m.max(v.abs()));
        for (p, q) in back.iter().zip(&x) {
            prop_assert!((p - q).abs() <= 1e-6 * peak);
        }
        let mut combo: Vec<f32> = y.iter().zip(&x).map(|(p, q)| a * p + q * 1e-6).collect();
        let mut ty = y.clone();
        let mut tx_small: Vec<f32> = x.iter().map(|q| q * 1e-6).collect();
        haar.forward(&mut combo).unwrap();
        haar.forward(&mut ty).unwrap();
        haar.forward(&mut tx_small).unwrap();
        for i in 0..len {
            prop_assert!((combo[i] - (a * ty[i] + tx_small[i])).abs() <= 1e-3);
        }
    }
}

#[test]
fn one_texel_faces_are_the_identity() {
    let layout = CubemapLayout::new(1).unwrap();
    assert_eq!(layout.band_count(), 1);
    assert_eq!(layout.bands(), &[0u8; 6]);
    for &w in layout.area_weights() {
        assert!((w as f64 - 4.0 * std::f64::consts::PI / 6.0).abs() < 1e-6);
    }
    let mut data = vec![1.0f32, -2.0, 3.0, 4.0, 5.0, 6.0];
    CubemapHaar::new(1).unwrap().forward(&mut data).unwrap();
    assert_eq!(data, vec![1.0, -2.0, 3.0, 4.0, 5.0, 6.0]);
    assert!(matches!(
        CubemapHaar::new(4).unwrap().forward(&mut [0.0; 95]),
        Err(WaveletError::LengthMismatch { .. })
    ));
}
