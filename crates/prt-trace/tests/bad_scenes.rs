//! Every malformed scene in `tests/bad_scenes/` fails to load with the expected typed error,
//! from a path and from memory, and never panics. Each is `tests/good_scenes/triangle.gltf` (or
//! `.glb`) with one thing broken, as its name says.

mod common;

use std::path::{Path, PathBuf};

use proptest::prelude::*;
use prt_trace::{LoadOptions, Scene, TraceError};

/// Each file of the folder and the error it must produce.
const CASES: &[(&str, &str)] = &[
    ("buffer_bad_base64_uri.gltf", "Buffer"),
    ("buffer_missing.gltf", "Buffer"),
    ("buffer_over_the_limit.gltf", "Limit"),
    ("buffer_shorter_than_declared.gltf", "Buffer"),
    ("buffer_unsupported_uri_scheme.gltf", "Buffer"),
    ("buffer_uri_percent_not_utf8.gltf", "Buffer"),
    ("buffer_without_uri_in_gltf.gltf", "Buffer"),
    ("draco_required.gltf", "UnsupportedExtension"),
    ("draco_used_without_fallback.gltf", "UnsupportedExtension"),
    ("empty_file.gltf", "Gltf"),
    // Found by the gltf_load fuzz target: the gltf crate unwraps the URI's percent-decoding.
    ("fuzz_buffer_uri_percent_not_utf8.gltf", "Buffer"),
    ("glb_header_length_4.glb", "Gltf"),
    ("glb_header_only.glb", "Gltf"),
    ("glb_missing_bin_chunk.glb", "Buffer"),
    ("glb_truncated_bin_chunk.glb", "Gltf"),
    ("glb_truncated_json_chunk.glb", "Gltf"),
    ("glb_version_1.glb", "Gltf"),
    ("index_accessor_float.gltf", "BadAccessor"),
    ("index_past_vertices.gltf", "BadAccessor"),
    ("indices_accessor_out_of_range.gltf", "Gltf"),
    ("indices_vec3.gltf", "BadAccessor"),
    ("light_out_of_range.gltf", "Gltf"),
    ("meshopt_required.gltf", "UnsupportedExtension"),
    ("morph_target_count_mismatch.gltf", "BadPrimitive"),
    ("node_cycle.gltf", "BadNode"),
    ("node_mesh_out_of_range.gltf", "Gltf"),
    ("node_own_child.gltf", "BadNode"),
    ("node_two_parents.gltf", "BadNode"),
    ("non_finite_position.gltf", "NonFinitePosition"),
    ("not_json.gltf", "Gltf"),
    ("position_accessor_missing.gltf", "BadPrimitive"),
    ("position_count_0.gltf", "BadAccessor"),
    ("position_count_past_view.gltf", "BadAccessor"),
    ("position_offset_overflow.gltf", "BadAccessor"),
    ("position_stride_4.gltf", "BadAccessor"),
    ("position_u16_without_quantization.gltf", "BadAccessor"),
    ("position_vec2.gltf", "BadAccessor"),
    ("sparse_index_past_count.gltf", "BadAccessor"),
    ("sparse_only_huge_count.gltf", "Limit"),
    ("truncated_json.gltf", "Gltf"),
    ("view_past_buffer.gltf", "BadAccessor"),
];

fn folder() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/bad_scenes")
}

/// The variant's name, looking through the warnings a failure may carry.
fn kind(error: &TraceError) -> &'static str {
    match error.without_warnings().0 {
        TraceError::Io { .. } => "Io",
        TraceError::Gltf { .. } => "Gltf",
        TraceError::Buffer { .. } => "Buffer",
        TraceError::Image { .. } => "Image",
        TraceError::BadPrimitive { .. } => "BadPrimitive",
        TraceError::BadAccessor { .. } => "BadAccessor",
        TraceError::BadNode { .. } => "BadNode",
        TraceError::UnsupportedExtension { .. } => "UnsupportedExtension",
        TraceError::NonFinitePosition { .. } => "NonFinitePosition",
        TraceError::Limit { .. } => "Limit",
        _ => "other",
    }
}

#[test]
fn the_table_lists_every_file_of_the_folder() {
    let files = common::scene_folder_files("bad_scenes");
    let listed: Vec<String> = CASES.iter().map(|(f, _)| f.to_string()).collect();
    assert_eq!(files, listed);
}

#[test]
fn every_bad_scene_is_the_expected_typed_error() {
    let mut wrong = Vec::new();
    for &(file, expected) in CASES {
        let path = folder().join(file);
        let from_path = Scene::load_gltf(&path, &LoadOptions::default());
        let bytes = std::fs::read(&path).expect("read");
        let from_memory = Scene::load_gltf_slice(&bytes, Some(&folder()), &LoadOptions::default());
        for (how, result) in [("path", from_path), ("memory", from_memory)] {
            match result {
                Err(e) if kind(&e) == expected => {
                    // The message names what is wrong; it never is a debug dump.
                    let message = e.to_string();
                    assert!(!message.contains("Path("), "{file}: {message}");
                }
                Err(e) => wrong.push(format!("{file} ({how}): expected {expected}, got {e:?}")),
                Ok(s) => wrong.push(format!(
                    "{file} ({how}): expected {expected}, loaded {} triangles",
                    s.triangles().len()
                )),
            }
        }
    }
    assert!(wrong.is_empty(), "{}", wrong.join("\n"));
}

#[test]
fn errors_name_what_is_wrong() {
    let load = |file: &str| {
        Scene::load_gltf(folder().join(file), &LoadOptions::default())
            .expect_err("malformed")
            .to_string()
    };
    let m = load("position_accessor_missing.gltf");
    assert!(m.contains("POSITION") && m.contains("accessor 5"), "{m}");
    let m = load("index_accessor_float.gltf");
    assert!(m.contains("accessor 1") && m.contains("F32"), "{m}");
    let m = load("position_stride_4.gltf");
    assert!(m.contains("byteStride 4"), "{m}");
    let m = load("draco_required.gltf");
    assert!(m.contains("KHR_draco_mesh_compression"), "{m}");
    let m = load("node_cycle.gltf");
    assert!(m.contains("node 0"), "{m}");
    let m = load("index_past_vertices.gltf");
    assert!(m.contains("index 7 past 3 vertices"), "{m}");
    // Draco used but not required, with no uncompressed data: the extension is named, not
    // the accessors' missing buffer views.
    let m = load("draco_used_without_fallback.gltf");
    assert!(m.contains("KHR_draco_mesh_compression"), "{m}");
    let m = load("buffer_without_uri_in_gltf.gltf");
    assert!(m.contains("no uri"), "{m}");
}

#[test]
fn the_undamaged_originals_load() {
    // Every bad scene is one of these with one thing broken.
    let good = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/good_scenes");
    for file in ["triangle.gltf", "triangle.glb"] {
        let scene = Scene::load_gltf(good.join(file), &LoadOptions::default()).expect(file);
        assert_eq!(scene.triangles().len(), 1, "{file}");
        let bytes = std::fs::read(good.join(file)).expect("read");
        let scene = Scene::load_gltf_slice(&bytes, None, &LoadOptions::default()).expect(file);
        assert_eq!(scene.triangles().len(), 1, "{file}");
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]
    /// The GLB original with any byte (JSON, chunk headers or binary buffer) replaced and the file
    /// cut anywhere: a scene of finite triangles or a typed error, never a panic.
    #[test]
    fn damaged_glb_loads_or_fails_cleanly(at in 0usize..600, byte in any::<u8>(), cut in 0usize..600) {
        let good = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/good_scenes/triangle.glb");
        let mut bytes = std::fs::read(good).expect("read");
        if at < bytes.len() {
            bytes[at] = byte;
        }
        bytes.truncate(cut.max(1));
        if let Ok(scene) = Scene::load_gltf_slice(&bytes, None, &LoadOptions::default()) {
            prop_assert!(scene.triangles().iter().flatten().all(|v| v.is_finite()));
        }
    }
}
