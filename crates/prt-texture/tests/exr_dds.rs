//! OpenEXR round trips (f32 exact, f16 within its bound, named layers for cubemap faces) and
//! DDS output read back with `ddsfile`.

use ddsfile::{Dds, DxgiFormat};
use proptest::prelude::*;
use prt_texture::dds::encode_dds;
use prt_texture::exr_io::{CUBE_FACE_NAMES, ExrLayer, ExrSample, decode_exr, encode_exr};
use prt_texture::{Ktx2Texture, Limits, PixelFormat, Shape, TextureError};

fn layer(name: Option<&str>, w: u32, h: u32, channels: usize, seed: u32) -> ExrLayer {
    let data = (0..channels * (w * h) as usize)
        .map(|i| (((i as u32 ^ seed).wrapping_mul(2654435761) >> 12) as f32 / 1e5) - 10.0)
        .collect();
    ExrLayer {
        name: name.map(str::to_owned),
        width: w,
        height: h,
        channels,
        data,
    }
}

#[test]
fn cubemap_faces_as_named_layers_round_trip_exactly_in_f32() {
    let faces: Vec<ExrLayer> = CUBE_FACE_NAMES
        .iter()
        .enumerate()
        .map(|(i, n)| layer(Some(n), 8, 8, 4, i as u32))
        .collect();
    let back = decode_exr(
        &encode_exr(&faces, ExrSample::F32).unwrap(),
        &Limits::small(),
    )
    .unwrap();
    assert_eq!(back, faces);
}

#[test]
fn exr_limits_are_checked_from_the_header() {
    let bytes = encode_exr(&[layer(None, 64, 64, 3, 1)], ExrSample::F32).unwrap();
    let limits = Limits {
        max_dimension: 32,
        ..Limits::small()
    };
    assert!(matches!(
        decode_exr(&bytes, &limits),
        Err(TextureError::TooLarge {
            what: "EXR width",
            ..
        })
    ));
    let limits = Limits {
        max_bytes: 1000,
        ..Limits::small()
    };
    assert!(matches!(
        decode_exr(&bytes, &limits),
        Err(TextureError::TooLarge { .. })
    ));
}

#[test]
fn exr_rejects_bad_layers() {
    let mut l = layer(None, 2, 2, 3, 0);
    l.data[5] = f32::NAN;
    assert!(matches!(
        encode_exr(&[l], ExrSample::F32),
        Err(TextureError::NonFinite { index: 5, .. })
    ));
    let mut l = layer(None, 2, 2, 3, 0);
    l.data[2] = 1e6;
    assert!(matches!(
        encode_exr(&[l], ExrSample::F16),
        Err(TextureError::OutOfRange { index: 2, .. })
    ));
    assert!(encode_exr(&[layer(None, 2, 2, 2, 0)], ExrSample::F32).is_err());
    assert!(
        encode_exr(
            &[layer(Some("a"), 2, 2, 3, 0), layer(Some("b"), 3, 2, 3, 0)],
            ExrSample::F32
        )
        .is_err()
    );
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(24))]

    #[test]
    fn exr_round_trip(w in 1u32..20, h in 1u32..20, channels in 3usize..5, half in any::<bool>(), seed in any::<u32>()) {
        let l = layer(Some("slice0"), w, h, channels, seed);
        let sample = if half { ExrSample::F16 } else { ExrSample::F32 };
        let back = decode_exr(&encode_exr(std::slice::from_ref(&l), sample).unwrap(), &Limits::small()).unwrap();
        prop_assert_eq!(back.len(), 1);
        prop_assert_eq!((back[0].width, back[0].height, back[0].channels), (w, h, channels));
        prop_assert_eq!(back[0].name.as_deref(), Some("slice0"));
        for (&x, &y) in l.data.iter().zip(&back[0].data) {
            let bound = if half { (x.abs() * 2f32.powi(-11)).max(2f32.powi(-25)) } else { 0.0 };
            prop_assert!((x - y).abs() <= bound, "{} -> {}", x, y);
        }
    }
}

#[test]
fn dds_holds_the_same_texels_for_every_shape() {
    let cases = [
        (
            PixelFormat::R32G32B32A32Sfloat,
            Shape::d2(5, 3),
            2,
            DxgiFormat::R32G32B32A32_Float,
        ),
        (
            PixelFormat::R16G16B16A16Sfloat,
            Shape::cube(4),
            3,
            DxgiFormat::R16G16B16A16_Float,
        ),
        (
            PixelFormat::E5B9G9R9UfloatPack32,
            Shape::d3(4, 2, 3),
            2,
            DxgiFormat::R9G9B9E5_SharedExp,
        ),
        (
            PixelFormat::R16G16B16A16Sfloat,
            Shape::d2_array(3, 3, 4),
            1,
            DxgiFormat::R16G16B16A16_Float,
        ),
    ];
    for (format, shape, levels, dxgi) in cases {
        let data: Vec<Vec<f32>> = (0..levels)
            .map(|l| {
                (0..shape.level_texels(l).unwrap() as usize * format.channels())
                    .map(|i| (i % 17) as f32 / 16.0)
                    .collect()
            })
            .collect();
        let texture = Ktx2Texture::from_f32(format, shape, &data).unwrap();
        let dds = Dds::read(&encode_dds(&texture).unwrap()[..]).unwrap();
        assert_eq!(dds.get_dxgi_format(), Some(dxgi));
        assert_eq!(
            (dds.get_width(), dds.get_height()),
            (shape.width, shape.height)
        );
        assert_eq!(dds.get_num_mipmap_levels(), levels);
        assert_eq!(
            dds.get_num_array_layers(),
            shape.layers.max(1) * shape.faces
        );
        // DDS is layer-major: the first image's mip chain comes first.
        let images = (shape.layers.max(1) * shape.faces) as usize;
        let mut expected = Vec::new();
        for image in 0..images {
            for level in texture.levels() {
                let per = level.len() / images;
                expected.extend_from_slice(&level[image * per..(image + 1) * per]);
            }
        }
        assert_eq!(dds.data, expected, "{format:?} {shape:?}");
    }
}

#[test]
fn dds_refuses_formats_it_does_not_map() {
    let t = Ktx2Texture::from_f32(PixelFormat::R8Unorm, Shape::d2(2, 2), &[vec![0.0; 4]]).unwrap();
    assert!(matches!(
        encode_dds(&t),
        Err(TextureError::Unsupported { .. })
    ));
}
