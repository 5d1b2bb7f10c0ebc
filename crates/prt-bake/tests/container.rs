//! The MBD container's writer and reader: round trips within each encoding's bound, and typed
//! errors (never a panic) for missing or malformed containers.

mod common;

use common::{ENCODINGS, scratch};
use std::path::Path;

use ndarray::{Array2, Array3};
use proptest::prelude::*;
use prt_bake::container::ContainerContents;
use prt_bake::container::{ContainerError, MbdContainer, read_container, write_container};
use prt_core::{Aabb, FieldModel, glam::Vec3};
use prt_kernels::HatGrid;
use prt_mbd::MbdModel;
use prt_texture::container::{MANIFEST_FILE, Manifest};
use prt_texture::quant::rgb9e5_error_bound;
use prt_texture::{Encoding, Limits, TextureError};

const BOX: Aabb = Aabb {
    min: Vec3::new(-1.0, 0.0, -0.5),
    max: Vec3::new(1.0, 2.0, 0.5),
};

/// A model of rank `rank` and dimension `dim` with coefficients on a 4 × 3 × 2 grid and the
/// basis on a 2 × 2 × 2 grid, its values drawn from `values` (cycled).
fn model(rank: usize, dim: usize, values: &[f32]) -> MbdModel<HatGrid, HatGrid> {
    let coefficient_kernels = HatGrid::new([4, 3, 2], BOX).expect("kernels");
    let basis_kernels = HatGrid::new([2, 2, 2], BOX).expect("kernels");
    let mut next = values.iter().copied().cycle();
    let coefficients = Array2::from_shape_fn((24, rank), |_| next.next().unwrap_or(0.0));
    let basis = Array3::from_shape_fn((8, rank, dim), |_| next.next().unwrap_or(0.0));
    MbdModel::new(coefficient_kernels, basis_kernels, coefficients, basis).expect("model")
}

fn write(folder: &Path, model: &MbdModel<HatGrid, HatGrid>, encoding: Encoding) {
    let valid: Vec<bool> = (0..5 * 4 * 3).map(|v| v % 5 != 0).collect();
    let contents = ContainerContents {
        model,
        grid: [5, 4, 3],
        valid: &valid,
        scene: "test",
        lambda: 1e-4,
        encoding,
    };
    write_container(folder, &contents).expect("write");
}

fn read(folder: &Path) -> Result<MbdContainer, ContainerError> {
    read_container(folder, &Limits::small())
}

/// Largest error the encoding allows for one stored value `x`, given the largest magnitude
/// `max` of the values stored with it (its channel or its RGB9E5 texel).
fn bound(encoding: Encoding, x: f32, spread: f32, max: f32) -> f32 {
    let rounding = 4.0 * f32::EPSILON * max.max(x.abs());
    rounding
        + match encoding {
            Encoding::F32 => 0.0,
            Encoding::F16 => x.abs() * 2f32.powi(-11) + 2f32.powi(-25),
            Encoding::Unorm8 => spread / (2.0 * 255.0),
            Encoding::Unorm16 => spread / (2.0 * 65535.0),
            Encoding::Snorm8 => spread / (2.0 * 2.0 * 127.0),
            Encoding::Snorm16 => spread / (2.0 * 2.0 * 32767.0),
            Encoding::Rgb9e5 => rgb9e5_error_bound(max),
            _ => unreachable!("an encoding this test does not know"),
        }
}

/// Every stored value of `back` lies within the encoding's bound of `original`'s (channels =
/// the last axis).
fn assert_within(original: &[f32], back: &[f32], channels: usize, encoding: Encoding) {
    assert_eq!(original.len(), back.len());
    for c in 0..channels {
        let column: Vec<f32> = original.iter().skip(c).step_by(channels).copied().collect();
        let lo = column.iter().copied().fold(f32::INFINITY, f32::min);
        let hi = column.iter().copied().fold(f32::NEG_INFINITY, f32::max);
        for (i, &x) in column.iter().enumerate() {
            let node = &original[i * channels..(i + 1) * channels];
            let max = node.iter().fold(0.0f32, |m, v| m.max(v.abs()));
            let y = back[i * channels + c];
            let allowed = bound(encoding, x, hi - lo, max);
            assert!(
                (x - y).abs() <= allowed,
                "{encoding:?} channel {c} node {i}: {x} vs {y} (bound {allowed})"
            );
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 24, ..ProptestConfig::default() })]

    #[test]
    fn a_model_round_trips_within_its_encodings_bound(
        rank in 1usize..5,
        dim in 1usize..7,
        values in prop::collection::vec(-100.0f32..100.0, 1..64),
        encoding in prop::sample::select(ENCODINGS.to_vec()),
    ) {
        let original = model(rank, dim, &values);
        let folder = scratch("container");
        write(&folder, &original, encoding);
        let back = read(&folder).expect("read");
        prop_assert_eq!(back.encoding, encoding);
        prop_assert_eq!(back.model.coefficient_kernels(), original.coefficient_kernels());
        prop_assert_eq!(back.model.basis_kernels(), original.basis_kernels());
        prop_assert_eq!(back.grid, [5, 4, 3]);
        prop_assert!(back.valid.iter().enumerate().all(|(v, &b)| b == (v % 5 != 0)));
        prop_assert_eq!(back.attribute_str("scene"), Some("test"));
        let flat = |a: &[f32]| a.to_vec();
        assert_within(
            &flat(original.coefficients().as_slice().expect("standard layout")),
            back.model.coefficients().as_slice().expect("standard layout"),
            rank,
            encoding,
        );
        assert_within(
            original.basis().as_slice().expect("standard layout"),
            back.model.basis().as_slice().expect("standard layout"),
            rank * dim,
            encoding,
        );
        if encoding == Encoding::F32 {
            prop_assert_eq!(&back.model, &original);
        }
        let _ = std::fs::remove_dir_all(folder);
    }
}

#[test]
fn rgb9e5_round_trips_non_negative_models_and_refuses_negative_ones() {
    let values: Vec<f32> = (0..50).map(|i| (i * 37 % 101) as f32 * 0.25).collect();
    let original = model(3, 3, &values);
    let folder = scratch("container");
    write(&folder, &original, Encoding::Rgb9e5);
    let back = read(&folder).expect("read");
    assert_within(
        original.coefficients().as_slice().expect("standard layout"),
        back.model
            .coefficients()
            .as_slice()
            .expect("standard layout"),
        3,
        Encoding::Rgb9e5,
    );
    let negative = model(3, 3, &[-1.0, 2.0]);
    let contents = ContainerContents {
        model: &negative,
        grid: [1, 1, 1],
        valid: &[true],
        scene: "test",
        lambda: 0.0,
        encoding: Encoding::Rgb9e5,
    };
    assert!(matches!(
        write_container(&scratch("container"), &contents),
        Err(ContainerError::Texture(TextureError::OutOfRange { .. }))
    ));
    let _ = std::fs::remove_dir_all(folder);
}

#[test]
fn the_read_back_model_evaluates_like_the_original() {
    let values: Vec<f32> = (0..97)
        .map(|i| ((i * 53) % 97) as f32 / 97.0 - 0.5)
        .collect();
    let original = model(3, 5, &values);
    let folder = scratch("container");
    write(&folder, &original, Encoding::F32);
    let back = read(&folder).expect("read");
    let (mut a, mut b) = (vec![0.0; 5], vec![0.0; 5]);
    for p in [
        Vec3::new(-1.0, 0.0, -0.5),
        Vec3::new(0.3, 1.1, 0.2),
        BOX.max,
    ] {
        original.eval(p, &mut a).expect("eval");
        back.model.eval(p, &mut b).expect("eval");
        assert_eq!(a, b, "at {p}");
    }
    let _ = std::fs::remove_dir_all(folder);
}

/// Writes a valid f32 container of a rank-4 model, lets `damage` change it, and reads it.
fn damaged(damage: impl FnOnce(&Path)) -> ContainerError {
    let values: Vec<f32> = (0..31).map(|i| i as f32 - 15.0).collect();
    let folder = scratch("container");
    write(&folder, &model(4, 3, &values), Encoding::F32);
    damage(&folder);
    let error = read(&folder).expect_err("a damaged container must not read");
    let _ = std::fs::remove_dir_all(folder);
    error
}

/// Rewrites the manifest through `edit`.
fn edit_manifest(folder: &Path, edit: impl FnOnce(&mut Manifest)) {
    let path = folder.join(MANIFEST_FILE);
    let mut manifest =
        Manifest::from_json(&std::fs::read(&path).expect("manifest"), &Limits::default())
            .expect("valid manifest");
    edit(&mut manifest);
    std::fs::write(&path, manifest.to_json().expect("json")).expect("write manifest");
}

#[test]
fn a_missing_container_or_file_is_an_io_error() {
    let error = read(&scratch("container")).expect_err("nothing there");
    assert!(
        matches!(error, ContainerError::Texture(TextureError::Io { .. })),
        "{error:?}"
    );
    let error = damaged(|f| std::fs::remove_file(f.join("basis.ktx2")).expect("remove"));
    assert!(
        matches!(error, ContainerError::Texture(TextureError::Io { .. })),
        "{error:?}"
    );
}

#[test]
fn a_manifest_without_an_mbd_part_is_refused() {
    let error = damaged(|f| edit_manifest(f, |m| m.arrays.retain(|a| a.name != "validity")));
    assert!(
        matches!(
            error,
            ContainerError::Missing {
                name: "validity",
                ..
            }
        ),
        "{error:?}"
    );
    let error = damaged(|f| edit_manifest(f, |m| drop(m.kernels.remove("basis"))));
    assert!(
        matches!(
            error,
            ContainerError::Missing {
                kind: "kernels",
                name: "basis"
            }
        ),
        "{error:?}"
    );
    let error = damaged(|f| {
        edit_manifest(f, |m| {
            m.attributes.insert("model".into(), "clustered pca".into());
        })
    });
    assert!(
        matches!(error, ContainerError::Inconsistent(_)),
        "{error:?}"
    );
}

#[test]
fn a_manifest_naming_wrong_shapes_is_refused() {
    // Kernels that disagree with their array.
    let error = damaged(|f| {
        edit_manifest(f, |m| {
            m.kernels.get_mut("coefficients").expect("kernels").nodes = [4, 3, 3];
        })
    });
    assert!(
        matches!(error, ContainerError::Inconsistent(_)),
        "{error:?}"
    );
    // An array entry that disagrees with its texture.
    let error = damaged(|f| edit_manifest(f, |m| m.arrays[0].dims = [2, 3, 4]));
    assert!(
        matches!(
            error,
            ContainerError::Texture(TextureError::Malformed { .. })
        ),
        "{error:?}"
    );
    // A rank attribute that disagrees with the arrays.
    let error = damaged(|f| {
        edit_manifest(f, |m| {
            m.attributes.insert("rank".into(), 5.into());
        })
    });
    assert!(
        matches!(error, ContainerError::Inconsistent(_)),
        "{error:?}"
    );
    // A kernel domain whose corners are swapped.
    let error = damaged(|f| {
        edit_manifest(f, |m| {
            let k = m.kernels.get_mut("basis").expect("kernels");
            std::mem::swap(&mut k.domain_min, &mut k.domain_max);
        })
    });
    assert!(
        matches!(error, ContainerError::Kernels { which: "basis", .. }),
        "{error:?}"
    );
}

#[test]
fn nan_in_the_data_is_a_typed_error() {
    // The coefficient texture's last 4 bytes are the last value of its single mip level.
    let error = damaged(|f| {
        let path = f.join("coefficients.ktx2");
        let mut bytes = std::fs::read(&path).expect("texture");
        let n = bytes.len();
        bytes[n - 4..].copy_from_slice(&f32::NAN.to_le_bytes());
        std::fs::write(&path, bytes).expect("write");
    });
    assert!(
        matches!(
            error,
            ContainerError::Texture(TextureError::NonFinite { .. })
        ),
        "{error:?}"
    );
}

#[test]
fn a_container_over_the_limits_is_refused_before_it_is_decoded() {
    let values: Vec<f32> = (0..31).map(|i| i as f32).collect();
    let folder = scratch("container");
    write(&folder, &model(4, 3, &values), Encoding::F16);
    let tiny = Limits {
        max_dimension: 2,
        ..Limits::small()
    };
    let error = read_container(&folder, &tiny).expect_err("over the limits");
    assert!(
        matches!(
            error,
            ContainerError::Texture(TextureError::TooLarge { .. })
        ),
        "{error:?}"
    );
    let _ = std::fs::remove_dir_all(folder);
}

#[test]
fn garbage_files_never_panic() {
    for garbage in [&b""[..], b"{}", b"not json", &[0xff; 64]] {
        let error = damaged(|f| std::fs::write(f.join(MANIFEST_FILE), garbage).expect("write"));
        assert!(matches!(error, ContainerError::Texture(_)), "{error:?}");
        let error = damaged(|f| std::fs::write(f.join("basis.ktx2"), garbage).expect("write"));
        assert!(matches!(error, ContainerError::Texture(_)), "{error:?}");
    }
}

#[test]
fn the_basis_is_written_as_a_filterable_atlas_and_a_rows_basis_still_reads() {
    use prt_texture::container::{ArrayLayout, Container, GridArray, LoadedContainer};
    let values: Vec<f32> = (0..97).map(|i| (i as f32 * 0.37).sin()).collect();
    let original = model(3, 324, &values);
    let folder = scratch("container");
    write(&folder, &original, Encoding::F32);
    let back = read(&folder).expect("read");
    let layout = |name: &str| {
        let entry = back.manifest.arrays.iter().find(|a| a.name == name);
        entry.map(|a| (a.layout, a.tiles))
    };
    let (basis_layout, tiles) = layout("basis").expect("basis");
    assert_eq!(basis_layout, ArrayLayout::Atlas);
    let [tx, ty, tz] = tiles.expect("an atlas names its tiles");
    assert!(tx * ty * tz >= 3 * 81);
    assert_eq!(layout("coefficients"), Some((ArrayLayout::Volume, None)));
    assert_eq!(back.model, original);

    // The same arrays re-stored with the basis as rows (the layout before the atlas) read
    // back to the same model.
    let loaded = LoadedContainer::read(&folder, &Limits::small()).expect("load");
    let mut rows = Container {
        attributes: loaded.manifest.attributes.clone(),
        kernels: loaded.manifest.kernels.clone(),
        arrays: Vec::new(),
        ..Container::default()
    };
    for (entry, (name, array)) in loaded.manifest.arrays.iter().zip(&loaded.arrays) {
        let layout = if name == "basis" {
            ArrayLayout::Rows
        } else {
            entry.layout
        };
        let array = GridArray::new(array.dims, array.channels, array.data.clone()).expect("array");
        rows.arrays
            .push((name.clone(), array, entry.encoding, layout));
    }
    let other = scratch("container");
    rows.write(&other).expect("write rows");
    assert_eq!(read(&other).expect("read rows").model, original);

    // An atlas whose tiles do not hold every group is refused.
    edit_manifest(&folder, |m| {
        for a in &mut m.arrays {
            if a.name == "basis" {
                a.tiles = Some([1, 1, 1]);
            }
        }
    });
    assert!(matches!(
        read(&folder),
        Err(ContainerError::Texture(TextureError::Malformed { .. }))
    ));
    let _ = std::fs::remove_dir_all(folder);
    let _ = std::fs::remove_dir_all(other);
}
