//! The scene mesh file: round trips, and damaged or hostile bytes as typed errors.

use glam::{Mat4, Vec3};
use proptest::prelude::*;
use prt_texture::Limits;
use prt_trace::Scene;
use prt_trace::mesh::{MeshError, decode_mesh, encode_mesh, read_mesh, write_mesh};
use prt_trace::scene::Camera;

fn cornell_with_cameras() -> Scene {
    Scene::cornell_box().with_cameras([
        Camera {
            name: Some("wide".into()),
            to_world: Mat4::from_translation(Vec3::new(0.0, 1.0, 3.5)),
            yfov: 0.7,
            aspect_ratio: Some(1.5),
            znear: 0.05,
        },
        Camera {
            name: None,
            to_world: Mat4::from_rotation_y(0.3),
            yfov: 1.2,
            aspect_ratio: None,
            znear: 0.0,
        },
    ])
}

fn assert_same_scene(a: &Scene, b: &Scene) {
    assert_eq!(a.triangles(), b.triangles());
    assert_eq!(a.material_ids(), b.material_ids());
    assert_eq!(a.materials(), b.materials());
    assert_eq!(a.cameras(), b.cameras());
}

#[test]
fn a_scene_survives_the_round_trip() {
    let scene = cornell_with_cameras();
    let bytes = encode_mesh(&scene).expect("encode");
    let back = decode_mesh(&bytes, &Limits::small()).expect("decode");
    assert_same_scene(&scene, &back);
    let single_sided = Scene::ground_plane(3.0, Vec3::new(0.1, 0.2, 0.3));
    let back = decode_mesh(
        &encode_mesh(&single_sided).expect("encode"),
        &Limits::small(),
    )
    .expect("decode");
    assert_same_scene(&single_sided, &back);
    assert!(!back.materials()[0].double_sided);
    let empty = decode_mesh(
        &encode_mesh(&Scene::empty()).expect("encode"),
        &Limits::small(),
    )
    .expect("decode");
    assert!(empty.triangles().is_empty());
}

#[test]
fn the_file_is_written_and_read_back() {
    let dir = std::env::temp_dir().join(format!("prt-render-mesh-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("dir");
    let path = dir.join("scene.mesh");
    let scene = cornell_with_cameras();
    write_mesh(&path, &scene).expect("write");
    assert_same_scene(&scene, &read_mesh(&path, &Limits::default()).expect("read"));
    let tiny = Limits {
        max_bytes: 100,
        ..Limits::small()
    };
    assert!(matches!(
        read_mesh(&path, &tiny),
        Err(MeshError::TooLarge { .. })
    ));
    let _ = std::fs::remove_dir_all(dir);
}

#[test]
fn coplanar_triangles_of_one_material_share_vertices() {
    let scene = Scene::cornell_box();
    let bytes = encode_mesh(&scene).expect("encode");
    let vertices = u32::from_le_bytes(bytes[12..16].try_into().expect("4 bytes"));
    let triangles = u32::from_le_bytes(bytes[16..20].try_into().expect("4 bytes"));
    assert_eq!(triangles as usize, scene.triangles().len());
    // A quad whose two triangles have bit-identical normals is drawn from four vertices, not six
    // (the file's box sides are not all exactly planar, so not every quad shares).
    assert!(
        vertices < 3 * triangles,
        "{vertices} vertices for {triangles} triangles"
    );
    assert!(vertices >= 2 * triangles);
}

/// Offsets of the header's words and of the first position.
const VERTEX_COUNT: usize = 12;
const TRIANGLE_COUNT: usize = 16;
const FIRST_POSITION: usize = 32;

fn put_u32(bytes: &mut [u8], at: usize, value: u32) {
    bytes[at..at + 4].copy_from_slice(&value.to_le_bytes());
}

#[test]
fn damaged_files_are_typed_errors() {
    let good = encode_mesh(&cornell_with_cameras()).expect("encode");
    let limits = Limits::small();
    let decode = |edit: &dyn Fn(&mut Vec<u8>)| {
        let mut bytes = good.clone();
        edit(&mut bytes);
        decode_mesh(&bytes, &limits)
    };
    assert!(matches!(decode(&|b| b[0] = b'X'), Err(MeshError::BadMagic)));
    assert!(matches!(
        decode(&|b| put_u32(b, 8, 2)),
        Err(MeshError::UnsupportedVersion(2))
    ));
    assert!(matches!(
        decode(&|b| b.truncate(20)),
        Err(MeshError::Truncated { what: "header" })
    ));
    assert!(matches!(
        decode(&|b| b.truncate(b.len() - 1)),
        Err(MeshError::Truncated { .. })
    ));
    assert!(matches!(
        decode(&|b| b.push(0)),
        Err(MeshError::TrailingBytes(1))
    ));
    assert!(matches!(
        decode(&|b| put_u32(b, FIRST_POSITION + 4, f32::NAN.to_bits())),
        Err(MeshError::NonFinite {
            what: "position",
            index: 0
        })
    ));
    // Counts far beyond the bytes present fail before anything is allocated.
    for at in [VERTEX_COUNT, TRIANGLE_COUNT, 20, 24] {
        assert!(
            matches!(
                decode(&|b| put_u32(b, at, u32::MAX)),
                Err(MeshError::Truncated { .. })
            ),
            "count at {at}"
        );
    }
    let vertices = u32::from_le_bytes(good[12..16].try_into().expect("4 bytes")) as usize;
    let first_index = FIRST_POSITION + 28 * vertices;
    assert!(matches!(
        decode(&|b| put_u32(b, first_index, vertices as u32)),
        Err(MeshError::OutOfRange { .. })
    ));
    assert!(matches!(
        decode(&|b| put_u32(b, FIRST_POSITION + 24 * vertices, 99)),
        Err(MeshError::OutOfRange { .. })
    ));
    let oversized = Limits {
        max_bytes: good.len() as u64 - 1,
        ..limits
    };
    assert!(matches!(
        decode_mesh(&good, &oversized),
        Err(MeshError::TooLarge { .. })
    ));
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    /// Any truncation or corruption of a valid file is an error or a scene, never a panic, and
    /// a decoded scene re-encodes without error.
    #[test]
    fn damaged_bytes_never_panic(
        cut in 0usize..2000,
        flips in proptest::collection::vec((0usize..2000, any::<u8>()), 0..6),
    ) {
        let mut bytes = encode_mesh(&cornell_with_cameras()).expect("encode");
        for (at, value) in flips {
            let n = bytes.len();
            bytes[at % n] = value;
        }
        if cut < bytes.len() && cut % 3 == 0 {
            bytes.truncate(cut);
        }
        if let Ok(scene) = decode_mesh(&bytes, &Limits::small()) {
            // What the reader accepts, the writer writes back to the same scene (the fuzz
            // target mesh_read checks the same on arbitrary bytes).
            let again = decode_mesh(&encode_mesh(&scene).expect("encode"), &Limits::default());
            let again = again.expect("round trip");
            prop_assert_eq!(again.triangles(), scene.triangles());
            prop_assert_eq!(again.material_ids(), scene.material_ids());
        }
    }

    /// Random bytes after a valid header never panic either.
    #[test]
    fn random_bodies_never_panic(body in proptest::collection::vec(any::<u8>(), 0..400), counts in any::<[u8; 4]>()) {
        let mut bytes = b"PRTMESH\0".to_vec();
        bytes.extend_from_slice(&1u32.to_le_bytes());
        for c in counts {
            bytes.extend_from_slice(&u32::from(c % 8).to_le_bytes());
        }
        bytes.extend_from_slice(&0u32.to_le_bytes());
        bytes.extend_from_slice(&body);
        let _ = decode_mesh(&bytes, &Limits::small());
    }
}
