//! The brick layout: written and read back, it equals the dense layout exactly on every node of
//! a stored brick (so on every live node), reads 0 elsewhere, and the reader refuses
//! indirection textures that point outside the atlas, share a slot or miscount.

use std::collections::BTreeMap;

use proptest::prelude::*;
use prt_texture::container::{
    ArrayLayout, BrickRequest, Container, GridArray, LoadedContainer, brick_grid, live_bricks,
};
use prt_texture::{Encoding, Limits, TextureError};

fn encodings() -> impl Strategy<Value = Encoding> {
    prop_oneof![
        Just(Encoding::F32),
        Just(Encoding::F16),
        Just(Encoding::Unorm8),
        Just(Encoding::Unorm16),
        Just(Encoding::Snorm8),
        Just(Encoding::Rgb9e5),
    ]
}

fn one(
    array: &GridArray,
    encoding: Encoding,
    layout: ArrayLayout,
    request: Option<BrickRequest>,
) -> Container {
    let mut c = Container::default();
    c.arrays
        .push(("coefficients".into(), array.clone(), encoding, layout));
    if let Some(request) = request {
        c.bricks.insert("coefficients".into(), request);
    }
    c
}

fn decode(c: &Container) -> Result<LoadedContainer, TextureError> {
    let (manifest, files) = c.encode()?;
    let files: BTreeMap<String, Vec<u8>> = files.into_iter().collect();
    LoadedContainer::decode(&manifest.to_json()?, &Limits::default(), |name| {
        files.get(name).cloned().ok_or(TextureError::Invalid {
            what: "test",
            why: name.to_string(),
        })
    })
}

/// Whether node `n` lies in a stored brick (the reader's rule: the brick owning it is live).
fn in_live_brick(dims: [u32; 3], size: u32, live_bricks: &[bool], n: usize) -> bool {
    let grid = brick_grid(dims, size);
    let node = [
        n % dims[0] as usize,
        n / dims[0] as usize % dims[1] as usize,
        n / (dims[0] * dims[1]) as usize,
    ];
    let b = [0, 1, 2].map(|a| (node[a] as u32 / size).min(grid[a] - 1) as usize);
    live_bricks[b[0] + grid[0] as usize * (b[1] + grid[1] as usize * b[2])]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]

    #[test]
    fn bricks_decode_to_the_dense_layout_on_stored_bricks(
        dims in prop::array::uniform3(1u32..11),
        channels in 1usize..7,
        size in 1u32..6,
        density in 0.0f64..1.0,
        encoding in encodings(),
        seed in any::<u64>(),
    ) {
        let nodes = dims.iter().product::<u32>() as usize;
        let mut state = seed | 1;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let data: Vec<f32> = (0..nodes * channels).map(|_| (4.0 * next() - 1.0) as f32).collect();
        // RGB9E5 stores no negatives.
        let data = if encoding == Encoding::Rgb9e5 { data.iter().map(|v| v.abs()).collect() } else { data };
        let live: Vec<bool> = (0..nodes).map(|_| next() < density * density).collect();
        let array = GridArray::new(dims, channels, data).unwrap();
        let dense = decode(&one(&array, encoding, ArrayLayout::Volume, None)).unwrap();
        let request = BrickRequest { size, live_nodes: live.clone() };
        let bricked = decode(&one(&array, encoding, ArrayLayout::Bricks, Some(request))).unwrap();
        let (dense, bricked) = (&dense.arrays[0].1, &bricked.arrays[0].1);
        prop_assert_eq!(bricked.dims, dims);
        let stored = live_bricks(dims, size, &live).unwrap();
        for n in 0..nodes {
            let values = n * channels..(n + 1) * channels;
            if in_live_brick(dims, size, &stored, n) {
                prop_assert_eq!(&bricked.data[values.clone()], &dense.data[values]);
            } else {
                prop_assert!(!live[n], "live node {n} is in an empty brick");
                prop_assert!(bricked.data[values].iter().all(|&v| v == 0.0));
            }
        }
    }
}

fn ramp(dims: [u32; 3], channels: usize) -> GridArray {
    let n = dims.iter().product::<u32>() as usize * channels;
    GridArray::new(dims, channels, (0..n).map(|i| i as f32 * 0.25).collect()).unwrap()
}

#[test]
fn a_sparse_grid_takes_fewer_bytes_in_bricks() {
    let dims = [24, 24, 24];
    let array = ramp(dims, 8);
    // A slab of live nodes: one layer of bricks of six.
    let live: Vec<bool> = (0..24 * 24 * 24).map(|n| n / (24 * 24) < 2).collect();
    let size = |c: &Container| {
        c.encode()
            .unwrap()
            .1
            .iter()
            .map(|f| f.1.len())
            .sum::<usize>()
    };
    let dense = size(&one(&array, Encoding::F16, ArrayLayout::Volume, None));
    let request = BrickRequest::new(live);
    let bricks = size(&one(
        &array,
        Encoding::F16,
        ArrayLayout::Bricks,
        Some(request),
    ));
    assert!(3 * bricks < dense, "bricks {bricks} B, dense {dense} B");
}

#[test]
fn the_manifest_names_the_bricks_and_the_reader_checks_the_indirection() {
    let dims = [9, 5, 3];
    let array = ramp(dims, 5);
    let live: Vec<bool> = (0..135).map(|n| n % 9 < 3).collect();
    let c = one(
        &array,
        Encoding::F16,
        ArrayLayout::Bricks,
        Some(BrickRequest::new(live)),
    );
    let (manifest, files) = c.encode().unwrap();
    let entry = &manifest.arrays[0];
    let bricks = entry.bricks.as_ref().unwrap();
    assert_eq!(bricks.grid, [2, 1, 1]);
    assert_eq!(bricks.live, 1);
    assert_eq!(bricks.indirection, "coefficients.bricks.ktx2");
    let json = manifest.to_json().unwrap();
    let files: BTreeMap<String, Vec<u8>> = files.into_iter().collect();
    let indirection = &files["coefficients.bricks.ktx2"];
    // Corrupt the last byte of the level (brick 1's alpha: 0 → 7, neither empty nor live).
    let tampered = |edit: &dyn Fn(&mut Vec<u8>)| {
        let mut bytes = indirection.clone();
        edit(&mut bytes);
        LoadedContainer::decode(&json, &Limits::default(), |name| {
            Ok(if name.ends_with(".bricks.ktx2") {
                bytes.clone()
            } else {
                files[name].clone()
            })
        })
    };
    assert!(tampered(&|_| ()).is_ok());
    let n = indirection.len();
    for edit in [
        &(|b: &mut Vec<u8>| b[n - 1] = 7) as &dyn Fn(&mut Vec<u8>),
        // brick 1 live at the same slot as brick 0: two bricks in one slot, and a miscount
        &|b: &mut Vec<u8>| b[n - 1] = 255,
        // brick 0 outside the atlas
        &|b: &mut Vec<u8>| b[n - 8] = 9,
    ] {
        let error = tampered(edit).unwrap_err();
        assert!(matches!(error, TextureError::Malformed { .. }), "{error:?}");
    }
}

#[test]
fn a_bricks_layout_without_a_request_is_refused() {
    let c = one(
        &ramp([3, 3, 3], 2),
        Encoding::F16,
        ArrayLayout::Bricks,
        None,
    );
    assert!(matches!(c.encode(), Err(TextureError::Invalid { .. })));
}

#[test]
fn version_4_containers_still_read() {
    let data = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data");
    let manifest = std::fs::read_to_string(data.join("manifest.json")).unwrap();
    assert!(manifest.contains("\"version\": 5"));
    let old = manifest.replace("\"version\": 5", "\"version\": 4");
    let loaded = LoadedContainer::decode(old.as_bytes(), &Limits::small(), |file| {
        Ok(std::fs::read(data.join(file)).unwrap())
    })
    .unwrap();
    assert_eq!(loaded.manifest.version, 4);
}

#[test]
fn a_huge_grid_behind_a_small_atlas_is_refused_before_decoding() {
    let c = one(
        &ramp([9, 5, 3], 5),
        Encoding::F16,
        ArrayLayout::Bricks,
        Some(BrickRequest::new(vec![true; 135])),
    );
    let (manifest, _) = c.encode().unwrap();
    let json = String::from_utf8(manifest.to_json().unwrap()).unwrap();
    // The same entry claiming 2000 × 2000 × 1000 nodes (its brick grid to match).
    let huge = json
        .replacen(
            "\"dims\": [\n        9,\n        5,\n        3\n      ]",
            "\"dims\": [2000, 2000, 1000]",
            1,
        )
        .replacen(
            "\"grid\": [\n          2,\n          1,\n          1\n        ]",
            "\"grid\": [500, 500, 250]",
            1,
        );
    assert_ne!(huge, json);
    let error =
        prt_texture::container::Manifest::from_json(huge.as_bytes(), &Limits::small()).unwrap_err();
    assert!(
        matches!(
            error,
            TextureError::TooLarge {
                what: "decoded brick array bytes",
                ..
            }
        ),
        "{error:?}"
    );
}
