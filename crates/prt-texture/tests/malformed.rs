//! Golden fixtures (valid files we write, committed under tests/data) and the malformed-input
//! corpus (tests/malformed): every malformed file fails with the typed error its name announces
//! (`<kind>-<description>.<ext>`), and every truncation of every fixture fails with an error.
//!
//! `PRT_REGENERATE_FIXTURES=1 cargo test -p prt-texture --test malformed` rewrites both folders.

use std::path::{Path, PathBuf};

use prt_texture::container::{
    ArrayLayout, CONTAINER_VERSION, Container, GridArray, LoadedContainer, MANIFEST_FILE, Manifest,
};
use prt_texture::exr_io::{ExrLayer, ExrSample, decode_exr, encode_exr};
use prt_texture::hdr::{RgbImage, decode_hdr, encode_hdr};
use prt_texture::{Encoding, Ktx2Texture, Limits, PixelFormat, Shape, TextureError};

fn dir(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests")
        .join(name)
}

fn ramp(n: usize, scale: f32) -> Vec<f32> {
    (0..n)
        .map(|i| ((i * 37) % 101) as f32 / 100.0 * scale)
        .collect()
}

fn ktx2(format: PixelFormat, shape: Shape, levels: usize) -> Vec<u8> {
    let data: Vec<Vec<f32>> = (0..levels as u32)
        .map(|l| {
            ramp(
                shape.level_texels(l).unwrap() as usize * format.channels(),
                1.0,
            )
        })
        .collect();
    Ktx2Texture::from_f32(format, shape, &data)
        .unwrap()
        .to_bytes()
        .unwrap()
}

fn small_container() -> Container {
    let mut c = Container::default();
    c.attributes.insert("rank".into(), 2.into());
    c.arrays.push((
        "coefficients".into(),
        GridArray::new([2, 2, 2], 2, ramp(16, 3.0)).unwrap(),
        Encoding::Unorm8,
        ArrayLayout::Volume,
    ));
    c
}

/// Valid files, deterministic: the same bytes on every run and platform.
fn fixtures() -> Vec<(&'static str, Vec<u8>)> {
    let (manifest, files) = small_container().encode().unwrap();
    vec![
        (
            "rgba16f-3d-mips.ktx2",
            ktx2(PixelFormat::R16G16B16A16Sfloat, Shape::d3(4, 4, 2), 3),
        ),
        (
            "rgb9e5-cube.ktx2",
            ktx2(PixelFormat::E5B9G9R9UfloatPack32, Shape::cube(2), 1),
        ),
        (
            "r8-array.ktx2",
            ktx2(PixelFormat::R8Unorm, Shape::d2_array(3, 2, 2), 2),
        ),
        (
            "rgba8snorm-2d.ktx2",
            ktx2(PixelFormat::R8G8B8A8Snorm, Shape::d2(5, 3), 1),
        ),
        ("coefficients.ktx2", files[0].1.clone()),
        ("manifest.json", manifest.to_json().unwrap()),
        (
            "rle.hdr",
            encode_hdr(&RgbImage::new(16, 3, ramp(144, 40.0)).unwrap()).unwrap(),
        ),
        (
            "flat.hdr",
            encode_hdr(&RgbImage::new(4, 2, ramp(24, 2.0)).unwrap()).unwrap(),
        ),
        (
            "rgb-f16.exr",
            encode_exr(
                &[ExrLayer {
                    name: None,
                    width: 4,
                    height: 3,
                    channels: 3,
                    data: ramp(36, 5.0),
                }],
                ExrSample::F16,
            )
            .unwrap(),
        ),
    ]
}

fn fixture(name: &str) -> Vec<u8> {
    fixtures().into_iter().find(|(n, _)| *n == name).unwrap().1
}

fn put_u32(bytes: &mut [u8], at: usize, v: u32) {
    bytes[at..at + 4].copy_from_slice(&v.to_le_bytes());
}

fn put_u64(bytes: &mut [u8], at: usize, v: u64) {
    bytes[at..at + 8].copy_from_slice(&v.to_le_bytes());
}

/// Malformed inputs: (file name announcing the expected error kind, bytes).
fn malformed() -> Vec<(String, Vec<u8>)> {
    let base = fixture("rgba16f-3d-mips.ktx2");
    let mut out: Vec<(String, Vec<u8>)> = Vec::new();
    let mut edit = |name: &str, f: &dyn Fn(&mut Vec<u8>)| {
        let mut b = base.clone();
        f(&mut b);
        out.push((name.to_owned(), b));
    };
    edit("truncated-header.ktx2", &|b| b.truncate(50));
    edit("truncated-last-level.ktx2", &|b| {
        let n = b.len() - 9;
        b.truncate(n)
    });
    edit("malformed-identifier.ktx2", &|b| b[5] = b'3');
    edit("too-large-width.ktx2", &|b| put_u32(b, 20, 1 << 30));
    edit("too-large-depth.ktx2", &|b| put_u32(b, 28, u32::MAX));
    edit("too-large-layers.ktx2", &|b| put_u32(b, 32, 1 << 31));
    edit("too-large-level-count.ktx2", &|b| put_u32(b, 40, 1000));
    edit("too-large-level-count-beyond-chain.ktx2", &|b| {
        put_u32(b, 40, 4)
    });
    edit("malformed-face-count.ktx2", &|b| put_u32(b, 36, 5));
    edit("malformed-type-size.ktx2", &|b| put_u32(b, 16, 4));
    edit("unsupported-format-bc7.ktx2", &|b| put_u32(b, 12, 145));
    edit("unsupported-supercompression-zstd.ktx2", &|b| {
        put_u32(b, 44, 2)
    });
    edit("truncated-dfd-offset-beyond-file.ktx2", &|b| {
        put_u32(b, 48, u32::MAX - 2)
    });
    edit("malformed-dfd-total-size.ktx2", &|b| {
        let at = u32::from_le_bytes(b[48..52].try_into().unwrap()) as usize;
        put_u32(b, at, 12)
    });
    edit("malformed-dfd-sample-bits.ktx2", &|b| {
        let at = u32::from_le_bytes(b[48..52].try_into().unwrap()) as usize;
        b[at + 4 + 24 + 2] = 7; // first sample: 8 bits instead of 16
    });
    edit("malformed-dfd-vendor.ktx2", &|b| {
        let at = u32::from_le_bytes(b[48..52].try_into().unwrap()) as usize;
        b[at + 4] = 1;
    });
    edit("malformed-dfd-bytes-plane.ktx2", &|b| {
        let at = u32::from_le_bytes(b[48..52].try_into().unwrap()) as usize;
        b[at + 4 + 8 + 8] = 16;
    });
    edit("malformed-level-length-lies.ktx2", &|b| {
        put_u64(b, 80 + 8, 1 << 40)
    });
    edit("truncated-level-offset-beyond-file.ktx2", &|b| {
        put_u64(b, 80, u64::MAX - 4)
    });
    edit("truncated-kvd-length-lies.ktx2", &|b| {
        put_u32(b, 60, 1 << 28)
    });
    edit("malformed-kvd-entry-without-nul.ktx2", &|b| {
        let at = u32::from_le_bytes(b[56..60].try_into().unwrap()) as usize;
        let len = u32::from_le_bytes(b[at..at + 4].try_into().unwrap()) as usize;
        b[at + 4..at + 4 + len].iter_mut().for_each(|x| *x = b'a');
    });
    edit("truncated-kvd-entry-length-lies.ktx2", &|b| {
        let at = u32::from_le_bytes(b[56..60].try_into().unwrap()) as usize;
        put_u32(b, at, u32::MAX);
    });

    let hdr = fixture("rle.hdr");
    let header_end = hdr.windows(2).position(|w| w == b"\n\n").unwrap() + 2;
    let mut push = |name: &str, b: Vec<u8>| out.push((name.to_owned(), b));
    push("malformed-no-signature.hdr", hdr[2..].to_vec());
    push(
        "too-large-dimensions.hdr",
        b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 100000 +X 100000\n".to_vec(),
    );
    push(
        "malformed-resolution-not-a-number.hdr",
        b"#?RADIANCE\n\n-Y ab +X 2\n".to_vec(),
    );
    push(
        "unsupported-orientation.hdr",
        b"#?RADIANCE\n\n+Y 2 +X 2\n\0\0\0\0".to_vec(),
    );
    push(
        "unsupported-xyze.hdr",
        b"#?RADIANCE\nFORMAT=32-bit_rle_xyze\n\n-Y 1 +X 1\n\0\0\0\0".to_vec(),
    );
    push(
        "malformed-header-never-ends.hdr",
        b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n".to_vec(),
    );
    push("truncated-pixels.hdr", hdr[..hdr.len() - 10].to_vec());
    let mut run = hdr.clone();
    run[header_end + "-Y 3 +X 16\n".len() + 4] = 128 + 100; // a run of 100 in a 16-pixel line
    push("malformed-run-overflows-scanline.hdr", run);
    let mut wide = hdr.clone();
    wide[header_end + "-Y 3 +X 16\n".len() + 3] = 17; // scanline announces 17 pixels
    push("malformed-scanline-width-lies.hdr", wide);
    push(
        "malformed-old-rle-first-pixel.hdr",
        b"#?RADIANCE\n\n-Y 1 +X 2\n\x01\x01\x01\x05\0\0\0\0".to_vec(),
    );

    push("json-manifest-not-json.json", b"{\"format\": ".to_vec());
    let manifest = String::from_utf8(fixture("manifest.json")).unwrap();
    push(
        "unsupported-manifest-version.json",
        manifest
            .replace(
                &format!("\"version\": {CONTAINER_VERSION}"),
                "\"version\": 99",
            )
            .into_bytes(),
    );
    push(
        "malformed-manifest-path-traversal.json",
        manifest
            .replace("\"coefficients.ktx2\"", "\"../etc/passwd\"")
            .into_bytes(),
    );
    push(
        "malformed-manifest-format.json",
        manifest.replace("prt-container", "other").into_bytes(),
    );
    push(
        "too-large-manifest-dims.json",
        manifest
            .replacen(
                "\"dims\": [\n        2,",
                "\"dims\": [\n        4000000000,",
                1,
            )
            .into_bytes(),
    );
    push(
        "json-manifest-unknown-field.json",
        manifest.replacen('{', "{\"extra\": 1,", 1).into_bytes(),
    );
    push(
        "malformed-manifest-atlas-without-tiles.json",
        manifest
            .replace("\"layout\": \"volume\"", "\"layout\": \"atlas\"")
            .into_bytes(),
    );
    push(
        "malformed-manifest-atlas-empty-tile-layer.json",
        manifest
            .replace(
                "\"layout\": \"volume\"",
                "\"layout\": \"atlas\", \"tiles\": [1, 1, 2]",
            )
            .into_bytes(),
    );
    push(
        "malformed-manifest-volume-with-tiles.json",
        manifest
            .replace(
                "\"layout\": \"volume\"",
                "\"layout\": \"volume\", \"tiles\": [1, 1, 1]",
            )
            .into_bytes(),
    );

    let exr = fixture("rgb-f16.exr");
    push(
        "exr-bad-magic.exr",
        [&[0u8, 1, 2, 3][..], &exr[4..]].concat(),
    );
    push("exr-truncated.exr", exr[..exr.len() / 2].to_vec());
    out
}

fn read_any(name: &str, bytes: &[u8]) -> Result<(), TextureError> {
    let limits = Limits::small();
    match Path::new(name).extension().and_then(|e| e.to_str()) {
        Some("ktx2") => Ktx2Texture::from_bytes(bytes, &limits).map(|_| ()),
        Some("hdr") => decode_hdr(bytes, &limits).map(|_| ()),
        Some("exr") => decode_exr(bytes, &limits).map(|_| ()),
        Some("json") => Manifest::from_json(bytes, &limits).map(|_| ()),
        _ => panic!("unknown extension of {name}"),
    }
}

fn kind_matches(name: &str, err: &TextureError) -> bool {
    let kind = name.split('-').next().unwrap();
    matches!(
        (kind, err),
        ("truncated", TextureError::Truncated { .. })
            | ("too", TextureError::TooLarge { .. })
            | ("malformed", TextureError::Malformed { .. })
            | ("unsupported", TextureError::Unsupported { .. })
            | ("json", TextureError::Json(_))
            | ("exr", TextureError::Exr(_))
    )
}

fn regenerate() -> bool {
    std::env::var_os("PRT_REGENERATE_FIXTURES").is_some()
}

#[test]
fn golden_fixtures_are_stable_and_valid() {
    let data = dir("data");
    for (name, bytes) in fixtures() {
        let path = data.join(name);
        if regenerate() {
            std::fs::create_dir_all(&data).unwrap();
            std::fs::write(&path, &bytes).unwrap();
        }
        let committed = std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        assert_eq!(
            committed, bytes,
            "{name}: our writer's output changed; regenerate only if intended"
        );
        read_any(name, &bytes).unwrap_or_else(|e| panic!("{name}: {e}"));
    }
    // The committed container fixture loads as a container.
    let loaded = LoadedContainer::decode(&fixture("manifest.json"), &Limits::small(), |file| {
        assert_eq!(file, "coefficients.ktx2");
        Ok(std::fs::read(data.join(file)).unwrap())
    })
    .unwrap();
    assert_eq!(loaded.arrays.len(), 1);
    assert_eq!(MANIFEST_FILE, "manifest.json");
}

#[test]
fn every_malformed_input_fails_with_its_typed_error() {
    let folder = dir("malformed");
    if regenerate() {
        std::fs::create_dir_all(&folder).unwrap();
        for (name, bytes) in malformed() {
            std::fs::write(folder.join(&name), bytes).unwrap();
        }
    }
    let mut names: Vec<PathBuf> = std::fs::read_dir(&folder)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    names.sort();
    assert!(
        names.len() >= malformed().len(),
        "run with PRT_REGENERATE_FIXTURES=1 to create {}",
        folder.display()
    );
    for path in names {
        let name = path.file_name().unwrap().to_str().unwrap().to_owned();
        let bytes = std::fs::read(&path).unwrap();
        match read_any(&name, &bytes) {
            Ok(()) => panic!("{name} was accepted"),
            Err(e) => assert!(
                kind_matches(&name, &e),
                "{name}: unexpected error kind: {e:?}"
            ),
        }
    }
}

#[test]
fn every_truncation_of_every_fixture_is_an_error() {
    for (name, bytes) in fixtures() {
        // Sampled prefixes keep the test fast; small files are tried at every length.
        let step = (bytes.len() / 400).max(1);
        for len in (0..bytes.len()).step_by(step) {
            let result = read_any(name, &bytes[..len]);
            // A KTX2 or HDR prefix may only parse if it holds the whole payload (trailing
            // padding); EXR and JSON prefixes never parse.
            if let Ok(()) = result {
                assert!(
                    name.ends_with(".hdr") && len + 1 >= bytes.len(),
                    "{name} truncated to {len} bytes parsed"
                );
            }
        }
    }
}
