//! Radiance HDR: round trips, RLE, the shared environment maps, and the `image` crate as an
//! independent decoder of what we write.

use std::path::Path;

use proptest::prelude::*;
use prt_texture::hdr::{
    RgbImage, decode_hdr, encode_hdr, rgbe_decode, rgbe_encode, rgbe_error_bound,
};
use prt_texture::{Limits, TextureError};

/// The `.hdr` files of `../shared/envmaps`, sorted. Tests that call this are ignored when
/// build.rs found the folder absent, so here it must be readable.
fn envmaps() -> Vec<std::path::PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/envmaps");
    let entries = std::fs::read_dir(&dir).unwrap_or_else(|e| {
        panic!(
            "cannot read {} ({e}); the test runs because PRT_REQUIRE_SHARED=1 or because it \
             was there when it was built",
            dir.display()
        )
    });
    let mut files: Vec<_> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "hdr"))
        .collect();
    files.sort();
    files
}

fn image_crate_decode(bytes: &[u8]) -> (u32, u32, Vec<f32>) {
    use image::ImageDecoder;
    let decoder = image::codecs::hdr::HdrDecoder::new(std::io::Cursor::new(bytes)).unwrap();
    let (w, h) = decoder.dimensions();
    let mut buf = vec![0u8; decoder.total_bytes() as usize];
    decoder.read_image(&mut buf).unwrap();
    let data = buf
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect();
    (w, h, data)
}

#[test]
#[cfg_attr(
    prt_skip_shared_envmaps,
    ignore = "needs ../shared/envmaps, absent at build time (PRT_REQUIRE_SHARED=1 requires it)"
)]
fn shared_envmaps_decode_like_the_image_crate_and_round_trip() {
    let files = envmaps();
    assert!(!files.is_empty());
    for path in files {
        let bytes = std::fs::read(&path).unwrap();
        let ours = decode_hdr(&bytes, &Limits::default())
            .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        let (w, h, theirs) = image_crate_decode(&bytes);
        assert_eq!((ours.width, ours.height), (w, h), "{}", path.display());
        // Both decoders compute m * 2^(e-136) in floating point: identical up to 1 ulp.
        for (a, b) in ours.data.iter().zip(&theirs) {
            assert!(
                (a - b).abs() <= b.abs() * 2.0 * f32::EPSILON,
                "{}: {a} vs {b}",
                path.display()
            );
        }
        // Decoded values are exactly representable: writing and reading is lossless.
        let again = decode_hdr(&encode_hdr(&ours).unwrap(), &Limits::default()).unwrap();
        assert_eq!(again, ours, "{}", path.display());
    }
}

#[test]
fn the_image_crate_reads_what_we_write() {
    let data: Vec<f32> = (0..3 * 40 * 7)
        .map(|i| ((i * 7919) % 1000) as f32 * 0.37)
        .collect();
    let image = RgbImage::new(40, 7, data).unwrap();
    let bytes = encode_hdr(&image).unwrap();
    let ours = decode_hdr(&bytes, &Limits::default()).unwrap();
    let (w, h, theirs) = image_crate_decode(&bytes);
    assert_eq!((w, h), (40, 7));
    assert_eq!(ours.data, theirs);
}

#[test]
fn limits_refuse_huge_images_before_allocating() {
    let header = b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 5000 +X 5000\n";
    let err = decode_hdr(header, &Limits::small()).unwrap_err();
    assert!(matches!(err, TextureError::TooLarge { .. }), "{err:?}");
    let limits = Limits {
        max_bytes: 1000,
        ..Limits::small()
    };
    let err = decode_hdr(b"#?RADIANCE\n\n-Y 100 +X 100\n", &limits).unwrap_err();
    assert!(
        matches!(
            err,
            TextureError::TooLarge {
                what: "decoded HDR bytes",
                ..
            }
        ),
        "{err:?}"
    );
}

#[test]
fn non_finite_pixels_are_rejected_and_negatives_clamp() {
    let err =
        encode_hdr(&RgbImage::new(1, 2, vec![0.0, 1.0, 2.0, 3.0, f32::INFINITY, 0.0]).unwrap())
            .unwrap_err();
    assert!(matches!(err, TextureError::NonFinite { index: 4, .. }));
    assert_eq!(rgbe_decode(rgbe_encode([-1.0, 2.0, 0.0])), [0.0, 2.0, 0.0]);
    assert_eq!(rgbe_encode([0.0; 3]), [0; 4]);
}

#[test]
fn old_style_rle_and_flat_files_decode() {
    // Two flat pixels, then an old-style run repeating the second one 3 times.
    let mut bytes = b"#?RADIANCE\n\n-Y 1 +X 5\n".to_vec();
    bytes.extend_from_slice(&[128, 64, 32, 129, 16, 16, 16, 128, 1, 1, 1, 3]);
    let img = decode_hdr(&bytes, &Limits::small()).unwrap();
    assert_eq!(img.pixel(0, 0), [1.0, 0.5, 0.25]);
    for x in 1..5 {
        assert_eq!(img.pixel(x, 0), [0.0625; 3]);
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn round_trip_within_the_rgbe_bound(
        width in 1u32..40,
        height in 1u32..4,
        seed in any::<u64>(),
        runs in any::<bool>(),
    ) {
        // Runs of equal pixels exercise the RLE packets, random pixels the literals.
        let n = (3 * width * height) as usize;
        let data: Vec<f32> = (0..n)
            .map(|i| {
                let k = if runs { i / 3 / 5 } else { i } as u64;
                let h = (k ^ seed).wrapping_mul(0x9E3779B97F4A7C15) >> 40;
                (h as f32 / (1u64 << 24) as f32) * 10f32.powi((h % 13) as i32 - 6)
            })
            .collect();
        let image = RgbImage::new(width, height, data).unwrap();
        let back = decode_hdr(&encode_hdr(&image).unwrap(), &Limits::small()).unwrap();
        prop_assert_eq!((back.width, back.height), (width, height));
        for (px, qx) in image.data.chunks_exact(3).zip(back.data.chunks_exact(3)) {
            let bound = rgbe_error_bound(px[0].max(px[1]).max(px[2]));
            for c in 0..3 {
                prop_assert!((px[c] - qx[c]).abs() <= bound, "{:?} -> {:?}", px, qx);
            }
        }
    }
}
