//! Every KTX2 file we write parses with the `ktx2` crate (the test oracle) with identical
//! header, DFD, key/value data and level bytes, and reads back through our reader unchanged.

use proptest::prelude::*;
use prt_texture::ktx2::{KEY_ORIENTATION, KEY_WRITER, Ktx2Texture, Shape};
use prt_texture::{Limits, PixelFormat};

/// Values in the range every format accepts (RGB9E5 and unorm need [0, 1]).
fn sample_values(format: PixelFormat, texels: usize, seed: u32) -> Vec<f32> {
    let n = texels * format.channels();
    (0..n)
        .map(|i| {
            let h = (i as u32 ^ seed).wrapping_mul(2654435761) >> 8;
            h as f32 / (1u32 << 24) as f32
        })
        .collect()
}

fn build(format: PixelFormat, shape: Shape, levels: usize, seed: u32) -> Ktx2Texture {
    let data: Vec<Vec<f32>> = (0..levels as u32)
        .map(|l| sample_values(format, shape.level_texels(l).unwrap() as usize, seed + l))
        .collect();
    Ktx2Texture::from_f32(format, shape, &data).unwrap()
}

fn oracle_check(texture: &Ktx2Texture) {
    let bytes = texture.to_bytes().unwrap();
    let reader = ktx2::Reader::new(&bytes[..]).expect("ktx2 crate parses our file");
    let h = reader.header();
    let s = texture.shape();
    assert_eq!(
        h.format.map(|f| f.value()),
        Some(texture.format().vk_format())
    );
    assert_eq!(
        (
            h.pixel_width,
            h.pixel_height,
            h.pixel_depth,
            h.layer_count,
            h.face_count
        ),
        (s.width, s.height, s.depth, s.layers, s.faces)
    );
    assert_eq!(h.level_count as usize, texture.levels().len());
    assert_eq!(h.supercompression_scheme, None);
    let levels: Vec<_> = reader.levels().collect();
    for (ours, theirs) in texture.levels().iter().zip(&levels) {
        assert_eq!(ours.as_slice(), theirs.data);
        assert_eq!(theirs.uncompressed_byte_length, ours.len() as u64);
    }
    // The DFD equals the one the ktx2 crate generates for the format (after its length word).
    let vk = ktx2::Format::new(texture.format().vk_format()).unwrap();
    let (basic, type_size) = ktx2::dfd::Basic::from_format(vk).unwrap();
    assert_eq!(h.type_size, type_size);
    assert_eq!(reader.basic_dfd(), Some(&basic));
    let expected_block = ktx2::dfd::Block::Basic(basic).to_vec();
    assert_eq!(
        &texture.format().dfd_bytes()[4..],
        expected_block.as_slice()
    );
    let kv: Vec<(String, Vec<u8>)> = reader
        .key_value_data()
        .map(|(k, v)| (k.to_owned(), v.to_vec()))
        .collect();
    assert_eq!(kv, texture.key_values());
    // Every section is aligned as the specification requires.
    assert_eq!(h.index.dfd_byte_offset % 4, 0);
    assert_eq!(h.index.kvd_byte_offset % 4, 0);
    let ours = Ktx2Texture::from_bytes(&bytes, &Limits::default()).unwrap();
    assert_eq!(&ours, texture);
}

#[test]
fn every_format_and_kind_parses_with_the_oracle() {
    let shapes = [
        Shape::d2(7, 5),
        Shape::d3(4, 3, 5),
        Shape::d2_array(6, 2, 3),
        Shape::cube(4),
    ];
    for format in PixelFormat::ALL {
        for shape in shapes {
            for levels in [1, shape.max_levels() as usize] {
                oracle_check(&build(format, shape, levels, 17));
            }
        }
    }
}

#[test]
fn standard_keys_are_written() {
    let t = build(PixelFormat::R32Sfloat, Shape::d3(2, 2, 2), 1, 0);
    assert_eq!(t.key(KEY_ORIENTATION), Some(&b"rdi\0"[..]));
    assert!(
        t.key(KEY_WRITER)
            .is_some_and(|w| w.starts_with(b"prt-texture "))
    );
    let t = build(PixelFormat::R32Sfloat, Shape::cube(2), 1, 0);
    assert_eq!(t.key(KEY_ORIENTATION), Some(&b"rd\0"[..]));
}

#[test]
fn keys_stay_sorted_and_replace() {
    let mut t = build(PixelFormat::R8Unorm, Shape::d2(3, 3), 1, 0);
    t.set_key("zeta", b"1".to_vec());
    t.set_key("alpha", b"2".to_vec());
    t.set_key("zeta", b"3".to_vec());
    let keys: Vec<&str> = t.key_values().iter().map(|(k, _)| k.as_str()).collect();
    assert_eq!(keys, ["KTXorientation", "KTXwriter", "alpha", "zeta"]);
    assert_eq!(t.key("zeta"), Some(&b"3"[..]));
    oracle_check(&t);
}

#[test]
fn level_sizes_are_checked_on_construction() {
    let err =
        Ktx2Texture::new(PixelFormat::R8Unorm, Shape::d2(4, 4), vec![vec![0; 15]]).unwrap_err();
    assert!(matches!(
        err,
        prt_texture::TextureError::LengthMismatch {
            expected: 16,
            got: 15,
            ..
        }
    ));
    let too_many = vec![vec![0u8; 4]; 4]; // a 2x2 chain has 2 levels
    assert!(Ktx2Texture::new(PixelFormat::R8Unorm, Shape::d2(2, 2), too_many).is_err());
    assert!(Ktx2Texture::new(PixelFormat::R8Unorm, Shape::d2(0, 2), vec![vec![]]).is_err());
    let not_square = Shape {
        faces: 6,
        ..Shape::d2(2, 3)
    };
    assert!(Ktx2Texture::new(PixelFormat::R8Unorm, not_square, vec![vec![0; 36]]).is_err());
}

#[test]
fn extreme_float_values_survive_exactly_in_f32() {
    let values = vec![
        f32::MAX,
        f32::MIN_POSITIVE,
        -0.0,
        1e-45,
        -f32::MAX,
        1e-6,
        1e6,
        0.0,
    ];
    let t = Ktx2Texture::from_f32(
        PixelFormat::R32Sfloat,
        Shape::d2(8, 1),
        std::slice::from_ref(&values),
    )
    .unwrap();
    let back = Ktx2Texture::from_bytes(&t.to_bytes().unwrap(), &Limits::default()).unwrap();
    let got = back.level_f32(0).unwrap();
    assert_eq!(
        got.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
        values.iter().map(|v| v.to_bits()).collect::<Vec<_>>()
    );
    // NaN is rejected with its index.
    let err = Ktx2Texture::from_f32(
        PixelFormat::R32Sfloat,
        Shape::d2(2, 1),
        &[vec![0.0, f32::NAN]],
    )
    .unwrap_err();
    assert!(matches!(
        err,
        prt_texture::TextureError::NonFinite { index: 1, .. }
    ));
}

fn arb_shape() -> impl Strategy<Value = Shape> {
    prop_oneof![
        (1u32..9, 1u32..9).prop_map(|(w, h)| Shape::d2(w, h)),
        (1u32..6, 1u32..6, 1u32..6).prop_map(|(w, h, d)| Shape::d3(w, h, d)),
        (1u32..6, 1u32..6, 1u32..4).prop_map(|(w, h, l)| Shape::d2_array(w, h, l)),
        (1u32..6).prop_map(Shape::cube),
        (1u32..9).prop_map(|w| Shape {
            height: 0,
            ..Shape::d2(w, 1)
        }),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(96))]

    #[test]
    fn random_textures_round_trip_through_the_oracle(
        format_index in 0usize..PixelFormat::ALL.len(),
        shape in arb_shape(),
        level_fraction in 0.0f64..1.0,
        seed in any::<u32>(),
    ) {
        let format = PixelFormat::ALL[format_index];
        let levels = 1 + (level_fraction * shape.max_levels() as f64) as usize % shape.max_levels() as usize;
        oracle_check(&build(format, shape, levels, seed));
    }

    #[test]
    fn encode_then_decode_is_the_identity_on_decoded_values(
        format_index in 0usize..PixelFormat::ALL.len(),
        seed in any::<u32>(),
    ) {
        // decode(encode(decode(bytes))) == decode(bytes): stored values are fixed points.
        let format = PixelFormat::ALL[format_index];
        let values = sample_values(format, 16, seed);
        let once = format.decode(&format.encode(&values).unwrap()).unwrap();
        let twice = format.decode(&format.encode(&once).unwrap()).unwrap();
        prop_assert_eq!(once, twice);
    }
}

mod mips {
    use proptest::prelude::*;
    use prt_texture::ktx2::{Shape, box_mip_chain};
    use prt_texture::{Ktx2Texture, PixelFormat};

    fn mean(v: &[f32], channels: usize, c: usize) -> f64 {
        let n = v.len() / channels;
        v.iter()
            .skip(c)
            .step_by(channels)
            .map(|&x| f64::from(x))
            .sum::<f64>()
            / n as f64
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(48))]

        #[test]
        fn power_of_two_chains_keep_the_mean_and_constants_stay_constant(
            log in prop::array::uniform3(0u32..4),
            kind in 0usize..3,
            seed in any::<u32>(),
        ) {
            let [a, b, c] = log.map(|l| 1u32 << l);
            let shape = match kind { 0 => Shape::d2(a, b), 1 => Shape::d3(a, b, c), _ => Shape::cube(a) };
            let n = shape.level_texels(0).unwrap() as usize * 2;
            let values: Vec<f32> = (0..n).map(|i| ((i as u32 ^ seed).wrapping_mul(2654435761) >> 20) as f32).collect();
            let chain = box_mip_chain(shape, 2, &values, shape.max_levels()).unwrap();
            prop_assert_eq!(chain.len() as u32, shape.max_levels());
            for (l, level) in chain.iter().enumerate() {
                prop_assert_eq!(level.len(), shape.level_texels(l as u32).unwrap() as usize * 2);
                for ch in 0..2 {
                    let (m0, ml) = (mean(&values, 2, ch), mean(level, 2, ch));
                    prop_assert!((m0 - ml).abs() <= 1e-5 * m0.abs().max(1.0), "level {} ch {}: {} vs {}", l, ch, m0, ml);
                }
            }
            // The chain (first channel) is a valid KTX2 mip pyramid.
            let red: Vec<Vec<f32>> = chain.iter().map(|l| l.iter().step_by(2).copied().collect()).collect();
            Ktx2Texture::from_f32(PixelFormat::R32Sfloat, shape, &red).unwrap();
        }
    }

    #[test]
    fn odd_sizes_and_constants() {
        let shape = Shape::d2(5, 3);
        let chain = box_mip_chain(shape, 1, &[2.5; 15], 3).unwrap();
        assert_eq!(chain[1], vec![2.5; 2]);
        assert_eq!(chain[2], vec![2.5; 1]);
        assert!(box_mip_chain(shape, 1, &[0.0; 15], 4).is_err());
        assert!(box_mip_chain(shape, 1, &[0.0; 14], 1).is_err());
        let mut nan = vec![0.0; 15];
        nan[3] = f32::NAN;
        assert!(matches!(
            box_mip_chain(shape, 1, &nan, 2),
            Err(prt_texture::TextureError::NonFinite { index: 3, .. })
        ));
    }
}
