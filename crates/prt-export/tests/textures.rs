//! Engine layouts: Bevy's irradiance volume texel placement (checked texel by texel against
//! bevy_pbr's shader) and L1 SH probe textures.

use proptest::prelude::*;
use prt_export::ExportError;
use prt_export::layout::{
    AmbientCubeVolume, ShL1Layout, ShL1Volume, bevy_irradiance_volume,
    bevy_irradiance_volume_decode, sh_l1_volume, sh_l1_volume_decode,
};
use prt_texture::quant::rgb9e5_error_bound;
use prt_texture::{Ktx2Texture, Limits, PixelFormat, TextureError};

/// A distinct, exactly representable RGB9E5 colour per (voxel, side): integers below 512 with
/// the largest channel dominating the exponent choice keep every channel exact.
fn colour(voxel: usize, side: usize) -> [f32; 3] {
    [
        256.0 + (voxel % 200) as f32,
        side as f32 * 8.0,
        1.0 + (voxel / 200) as f32,
    ]
}

#[test]
fn bevy_texels_sit_where_bevy_pbr_reads_them() {
    let dims = [3u32, 4, 2];
    let voxels = 24;
    let mut data = Vec::with_capacity(18 * voxels);
    for v in 0..voxels {
        for s in 0..6 {
            data.extend_from_slice(&colour(v, s));
        }
    }
    let volume = AmbientCubeVolume { dims, data };
    let texture = bevy_irradiance_volume(&volume).unwrap();
    assert_eq!(texture.format(), PixelFormat::E5B9G9R9UfloatPack32);
    let s = texture.shape();
    assert_eq!((s.width, s.height, s.depth), (3, 8, 6));
    let texels = texture.level_f32(0).unwrap();
    let (rx, ry, rz) = (3usize, 4usize, 2usize);
    // bevy_pbr's shader: s = x; t = y + (Ry if S in {-X,-Y,-Z}: it adds half the height for a
    // negative normal component); p = z + {0: ±X, Rz: ±Y, 2Rz: ±Z}.
    let sides = [
        ("+X", true, 0),
        ("-X", false, 0),
        ("+Y", true, 1),
        ("-Y", false, 1),
        ("+Z", true, 2),
        ("-Z", false, 2),
    ];
    for z in 0..rz {
        for y in 0..ry {
            for x in 0..rx {
                let v = x + rx * (y + ry * z);
                for (side, (_, positive, axis)) in sides.iter().enumerate() {
                    let t = y + if *positive { 0 } else { ry };
                    let p = z + axis * rz;
                    let texel = x + rx * (t + 2 * ry * p);
                    assert_eq!(
                        &texels[3 * texel..3 * texel + 3],
                        &colour(v, side),
                        "voxel {v} side {side}"
                    );
                }
            }
        }
    }
    // The file parses with the ktx2 crate as a 3D RGB9E5 texture, and decodes back exactly.
    let bytes = texture.to_bytes().unwrap();
    let reader = ktx2::Reader::new(&bytes[..]).unwrap();
    assert_eq!(
        reader.header().format,
        Some(ktx2::Format::E5B9G9R9_UFLOAT_PACK32)
    );
    let back =
        bevy_irradiance_volume_decode(&Ktx2Texture::from_bytes(&bytes, &Limits::small()).unwrap())
            .unwrap();
    assert_eq!(back, volume);
}

#[test]
fn bevy_volume_rejects_negative_and_wrongly_sized_input() {
    let mut volume = AmbientCubeVolume {
        dims: [1, 1, 1],
        data: vec![1.0; 18],
    };
    volume.data[7] = -0.5;
    assert!(matches!(
        bevy_irradiance_volume(&volume),
        Err(ExportError::Texture(TextureError::OutOfRange { .. }))
    ));
    volume.data.pop();
    assert!(matches!(
        bevy_irradiance_volume(&volume),
        Err(ExportError::Invalid { .. })
    ));
    let empty = AmbientCubeVolume {
        dims: [0, 1, 1],
        data: vec![],
    };
    assert!(bevy_irradiance_volume(&empty).is_err());
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(24))]

    #[test]
    fn bevy_round_trip_within_rgb9e5_bound(dims in prop::array::uniform3(1u32..4), seed in any::<u32>()) {
        let voxels = dims.iter().product::<u32>() as usize;
        let data: Vec<f32> = (0..18 * voxels).map(|i| ((i as u32 ^ seed).wrapping_mul(2654435761) >> 16) as f32 / 100.0).collect();
        let volume = AmbientCubeVolume { dims, data };
        let back = bevy_irradiance_volume_decode(&bevy_irradiance_volume(&volume).unwrap()).unwrap();
        for (a, b) in volume.data.chunks(3).zip(back.data.chunks(3)) {
            let bound = rgb9e5_error_bound(a[0].max(a[1]).max(a[2]));
            for c in 0..3 {
                prop_assert!((a[c] - b[c]).abs() <= bound);
            }
        }
    }

    #[test]
    fn sh_l1_round_trip_in_both_layouts(dims in prop::array::uniform3(1u32..4), per_channel in any::<bool>(), half in any::<bool>(), seed in any::<u32>()) {
        let voxels = dims.iter().product::<u32>() as usize;
        let data: Vec<f32> = (0..12 * voxels)
            .map(|i| (((i as u32 ^ seed).wrapping_mul(2654435761) >> 16) as f32 / 1000.0) - 30.0)
            .collect();
        let volume = ShL1Volume { dims, data };
        let layout = if per_channel { ShL1Layout::PerChannel } else { ShL1Layout::PerCoefficient };
        let format = if half { PixelFormat::R16G16B16A16Sfloat } else { PixelFormat::R32G32B32A32Sfloat };
        let textures = sh_l1_volume(&volume, layout, format).unwrap();
        prop_assert_eq!(textures.len(), if per_channel { 3 } else { 4 });
        let back = sh_l1_volume_decode(&textures, layout).unwrap();
        prop_assert_eq!(back.dims, dims);
        for (&a, &b) in volume.data.iter().zip(&back.data) {
            let bound = if half { a.abs() * 2f32.powi(-11) } else { 0.0 };
            prop_assert!((a - b).abs() <= bound);
        }
    }
}

#[test]
fn sh_l1_texel_contents_follow_the_layout() {
    // One voxel: coefficient k of channel c = 10k + c.
    let data: Vec<f32> = (0..4)
        .flat_map(|k| (0..3).map(move |c| (10 * k + c) as f32))
        .collect();
    let volume = ShL1Volume {
        dims: [1, 1, 1],
        data,
    };
    let per_channel = sh_l1_volume(
        &volume,
        ShL1Layout::PerChannel,
        PixelFormat::R32G32B32A32Sfloat,
    )
    .unwrap();
    assert_eq!(
        per_channel[1].level_f32(0).unwrap(),
        [1.0, 11.0, 21.0, 31.0]
    );
    let per_coeff = sh_l1_volume(
        &volume,
        ShL1Layout::PerCoefficient,
        PixelFormat::R32G32B32A32Sfloat,
    )
    .unwrap();
    assert_eq!(per_coeff[2].level_f32(0).unwrap(), [20.0, 21.0, 22.0, 0.0]);
    assert!(sh_l1_volume(&volume, ShL1Layout::PerChannel, PixelFormat::R8Unorm).is_err());
}

#[test]
fn bevy_volume_in_rgba16f_keeps_the_layout_and_decodes_to_f16_rounding() {
    use prt_export::layout::bevy_irradiance_volume_as;
    let dims = [2u32, 3, 2];
    let data: Vec<f32> = (0..18 * 12).map(|i| 0.1 + i as f32 * 0.37).collect();
    let volume = AmbientCubeVolume { dims, data };
    let texture = bevy_irradiance_volume_as(&volume, PixelFormat::R16G16B16A16Sfloat).unwrap();
    let s = texture.shape();
    assert_eq!((s.width, s.height, s.depth), (2, 6, 6));
    let rgb9e5 = bevy_irradiance_volume(&volume).unwrap();
    let (a, b) = (
        bevy_irradiance_volume_decode(&texture).unwrap(),
        bevy_irradiance_volume_decode(&rgb9e5).unwrap(),
    );
    for (i, z) in volume.data.iter().enumerate() {
        let texel_max = volume.data[i / 3 * 3..i / 3 * 3 + 3]
            .iter()
            .fold(0f32, |m, &v| m.max(v));
        assert!((a.data[i] - z).abs() <= z.abs() * 2f32.powi(-11) + 1e-7);
        assert!((b.data[i] - z).abs() <= rgb9e5_error_bound(texel_max) + 1e-6);
    }
    assert!(bevy_irradiance_volume_as(&volume, PixelFormat::R8Unorm).is_err());
}
