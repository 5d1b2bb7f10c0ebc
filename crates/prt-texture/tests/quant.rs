//! Error bounds of every quantiser, as property tests, and the extremes.

use proptest::prelude::*;
use prt_texture::quant::{RGB9E5_MAX, rgb9e5_decode, rgb9e5_encode, rgb9e5_error_bound};
use prt_texture::{Encoding, TextureError, dequantize, quantize};

const NORMALIZED: [Encoding; 4] = [
    Encoding::Unorm8,
    Encoding::Snorm8,
    Encoding::Unorm16,
    Encoding::Snorm16,
];

/// Values spanning many magnitudes, including 1e-6 .. 1e6 and both signs.
fn wide_value() -> impl Strategy<Value = f32> {
    prop_oneof![
        -1.0f32..1.0,
        (-6i32..7, -1.0f32..1.0).prop_map(|(e, m)| m * 10f32.powi(e)),
        Just(0.0f32),
    ]
}

/// The bound of the module docs: half a step plus a few ulps of the channel's magnitude.
fn normalized_bound(scale: f32, bias: f32, encoding: Encoding, range_max_abs: f32) -> f64 {
    let int_max = match encoding {
        Encoding::Unorm8 => 255.0,
        Encoding::Snorm8 => 127.0,
        Encoding::Unorm16 => 65535.0,
        _ => 32767.0,
    };
    f64::from(scale) / (2.0 * int_max)
        + 4.0 * f64::from(f32::EPSILON) * f64::from(range_max_abs.max(bias.abs()))
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    #[test]
    fn normalized_round_trip_within_half_a_step(
        values in prop::collection::vec(wide_value(), 1..64),
        channels in 1usize..5,
        which in 0usize..4,
    ) {
        let encoding = NORMALIZED[which];
        let n = values.len() / channels * channels;
        prop_assume!(n > 0);
        let values = &values[..n];
        let q = quantize(values, channels, encoding).unwrap();
        let back = dequantize(&q).unwrap();
        for (i, (&x, &y)) in values.iter().zip(&back).enumerate() {
            let r = q.ranges[i % channels];
            let max_abs = values.iter().skip(i % channels).step_by(channels).fold(0f32, |m, v| m.max(v.abs()));
            let bound = normalized_bound(r.scale, r.bias, encoding, max_abs);
            prop_assert!(f64::from((x - y).abs()) <= bound, "{:?} ch {}: {} -> {} (bound {})", encoding, i % channels, x, y, bound);
            prop_assert!(f64::from(r.half_step(encoding)) <= bound);
        }
    }

    #[test]
    fn f16_round_trip_within_its_relative_bound(values in prop::collection::vec(-65000.0f32..65000.0, 1..64)) {
        let q = quantize(&values, 1, Encoding::F16).unwrap();
        let back = dequantize(&q).unwrap();
        for (&x, &y) in values.iter().zip(&back) {
            let bound = (x.abs() * 2f32.powi(-11)).max(2f32.powi(-25));
            prop_assert!((x - y).abs() <= bound, "{} -> {}", x, y);
        }
    }

    #[test]
    fn rgb9e5_round_trip_within_half_a_shared_step(
        rgb in prop::array::uniform3(prop_oneof![0.0f32..RGB9E5_MAX, (0.0f32..1.0, -20i32..16).prop_map(|(m, e)| m * 2f32.powi(e))]),
    ) {
        let back = rgb9e5_decode(rgb9e5_encode(rgb));
        let max = rgb[0].max(rgb[1]).max(rgb[2]);
        let bound = rgb9e5_error_bound(max);
        for c in 0..3 {
            prop_assert!((rgb[c] - back[c]).abs() <= bound, "{:?} -> {:?} (bound {})", rgb, back, bound);
            // relative to the largest channel: at most 2^-8 of it (or the smallest step)
            prop_assert!((rgb[c] - back[c]).abs() <= (max * 2f32.powi(-8)).max(2f32.powi(-24)));
        }
    }

    #[test]
    fn quantized_values_are_fixed_points(values in prop::collection::vec(wide_value(), 4..32), which in 0usize..4) {
        // Quantising already-quantised values with the same ranges reproduces the same bytes.
        let encoding = NORMALIZED[which];
        let q = quantize(&values, 1, encoding).unwrap();
        let back = dequantize(&q).unwrap();
        let again = dequantize(&quantize(&back, 1, encoding).unwrap()).unwrap();
        for (&a, &b) in back.iter().zip(&again) {
            prop_assert!((a - b).abs() <= normalized_bound(q.ranges[0].scale, q.ranges[0].bias, encoding, 1e6) as f32);
        }
    }
}

#[test]
fn nan_and_inf_are_rejected_with_their_index() {
    for encoding in [
        Encoding::F32,
        Encoding::F16,
        Encoding::Unorm8,
        Encoding::Snorm16,
        Encoding::Rgb9e5,
    ] {
        let mut v = vec![1.0f32; 6];
        v[4] = f32::NAN;
        let err = quantize(&v, 3, encoding).unwrap_err();
        assert!(
            matches!(err, TextureError::NonFinite { index: 4, .. }),
            "{encoding:?}: {err:?}"
        );
        v[4] = f32::INFINITY;
        assert!(matches!(
            quantize(&v, 3, encoding),
            Err(TextureError::NonFinite { index: 4, .. })
        ));
    }
}

#[test]
fn out_of_range_values_are_typed_errors() {
    assert!(matches!(
        quantize(&[1e5], 1, Encoding::F16),
        Err(TextureError::OutOfRange { index: 0, .. })
    ));
    assert!(matches!(
        quantize(&[0.0, -1.0, 0.0], 3, Encoding::Rgb9e5),
        Err(TextureError::OutOfRange { index: 1, .. })
    ));
    assert!(matches!(
        quantize(&[0.0, 1e6, 0.0], 3, Encoding::Rgb9e5),
        Err(TextureError::OutOfRange { index: 1, .. })
    ));
    assert!(quantize(&[0.0; 4], 4, Encoding::Rgb9e5).is_err());
    assert!(quantize(&[0.0; 5], 2, Encoding::Unorm8).is_err());
    assert!(quantize(&[0.0; 5], 0, Encoding::Unorm8).is_err());
}

#[test]
fn constant_and_empty_channels_are_exact() {
    for encoding in NORMALIZED {
        let v = [3.25f32, -7.5, 3.25, -7.5, 3.25, -7.5];
        let q = quantize(&v, 2, encoding).unwrap();
        assert_eq!(q.ranges[0].scale, 0.0);
        assert_eq!(dequantize(&q).unwrap(), v);
        let empty = quantize(&[], 3, encoding).unwrap();
        assert!(empty.bytes.is_empty() && dequantize(&empty).unwrap().is_empty());
    }
}

#[test]
fn extremes_of_the_range_are_exact_and_a_single_spike_keeps_the_zeros() {
    // Min and max of a channel map to the end points of the integer range, so they are stored
    // within float rounding; a lone 1e6 among zeros leaves the zeros exactly zero (unorm).
    let mut v = vec![0.0f32; 100];
    v[37] = 1e6;
    for encoding in [Encoding::Unorm8, Encoding::Unorm16] {
        let back = dequantize(&quantize(&v, 1, encoding).unwrap()).unwrap();
        assert_eq!(back[0], 0.0);
        assert!((back[37] - 1e6).abs() <= 1e6 * 4.0 * f32::EPSILON);
    }
    let tiny = [1e-6f32, 2e-6, 3e-6];
    let back = dequantize(&quantize(&tiny, 1, Encoding::Unorm16).unwrap()).unwrap();
    for (a, b) in tiny.iter().zip(&back) {
        assert!((a - b).abs() <= 2e-6 / 65535.0 + 1e-12);
    }
}

#[test]
fn rgb9e5_known_values() {
    // Exactly representable values survive; the maximum packs to all ones but the exponent bit.
    assert_eq!(
        rgb9e5_decode(rgb9e5_encode([1.0, 0.5, 0.25])),
        [1.0, 0.5, 0.25]
    );
    assert_eq!(
        rgb9e5_decode(rgb9e5_encode([RGB9E5_MAX, 0.0, 0.0])),
        [RGB9E5_MAX, 0.0, 0.0]
    );
    assert_eq!(rgb9e5_encode([0.0; 3]), 0);
    assert_eq!(rgb9e5_encode([-5.0, f32::NAN, 0.0]), 0);
    assert_eq!(rgb9e5_decode(rgb9e5_encode([1e9, 0.0, 0.0]))[0], RGB9E5_MAX);
}
