//! Every scene in `tests/good_scenes/` loads, from a path and from memory, with the triangles
//! and the warning its table row gives. Each but the two originals is `triangle.gltf` (or
//! `.glb`) with something unusual but valid glTF 2.0, as its name says; several reproduce what
//! the public conformance models showed (docs/results.md § glTF conformance).

mod common;

use std::path::{Path, PathBuf};

use prt_trace::{LoadOptions, Scene};

/// Each file of the folder, its triangle count and a piece of the warning it must give (empty:
/// no warning).
const CASES: &[(&str, usize, &str)] = &[
    // Bytes past the length the GLB header declares are ignored, with a warning.
    (
        "glb_extra_bytes_after_length.glb",
        1,
        "after the GLB's declared length",
    ),
    // 80 million zero positions (no buffer view): no area, skipped without allocating them.
    (
        "huge_position_accessor_without_data.gltf",
        1,
        "1 primitive(s) skipped whose positions or indices have no data",
    ),
    // "count": 3.0 — JSON does not tell integers from integral floats; gltf-json does.
    ("integer_written_as_float.gltf", 1, ""),
    // An accessor with neither bufferView nor sparse values is zeros (glTF 2.0, "Accessors"):
    // here a morph target that moves nothing.
    ("morph_target_without_buffer_view.gltf", 1, ""),
    // A scene without "nodes" and an animation channel without a target node (both optional
    // in glTF 2.0; gltf-json requires them).
    ("optional_fields_omitted.gltf", 1, ""),
    // glTF 2.0 lets a primitive omit POSITION (it is not rendered).
    (
        "primitive_without_position.gltf",
        1,
        "1 primitive(s) without POSITION skipped",
    ),
    ("triangle.glb", 1, ""),
    ("triangle.gltf", 1, ""),
    // A buffer the loader does not read (no positions, indices or morph targets in it) is not
    // loaded, so a missing one does not matter.
    ("unused_buffer_missing.gltf", 1, ""),
];

fn folder() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/good_scenes")
}

#[test]
fn the_table_lists_every_file_of_the_folder() {
    let files = common::scene_folder_files("good_scenes");
    let listed: Vec<String> = CASES.iter().map(|(f, ..)| f.to_string()).collect();
    assert_eq!(files, listed);
}

#[test]
fn every_good_scene_loads_with_its_triangles_and_warnings() {
    let mut wrong = Vec::new();
    for &(file, triangles, warning) in CASES {
        let path = folder().join(file);
        let bytes = std::fs::read(&path).expect("read");
        let from_path = Scene::load_gltf(&path, &LoadOptions::default());
        let from_memory = Scene::load_gltf_slice(&bytes, Some(&folder()), &LoadOptions::default());
        for (how, result) in [("path", from_path), ("memory", from_memory)] {
            let scene = match result {
                Ok(scene) => scene,
                Err(e) => {
                    wrong.push(format!("{file} ({how}): {e}"));
                    continue;
                }
            };
            if scene.triangles().len() != triangles {
                wrong.push(format!(
                    "{file} ({how}): {} triangles, expected {triangles}",
                    scene.triangles().len()
                ));
            }
            let warnings = scene.warnings().join("; ");
            let expected = if warning.is_empty() {
                warnings.is_empty()
            } else {
                warnings.contains(warning)
            };
            if !expected {
                wrong.push(format!(
                    "{file} ({how}): warnings '{warnings}', expected '{warning}'"
                ));
            }
        }
    }
    assert!(wrong.is_empty(), "{}", wrong.join("\n"));
}

#[test]
fn a_zero_morph_target_leaves_the_triangle_in_place() {
    let scene = Scene::load_gltf(
        folder().join("morph_target_without_buffer_view.gltf"),
        &LoadOptions::default(),
    )
    .expect("loads");
    let original =
        Scene::load_gltf(folder().join("triangle.gltf"), &LoadOptions::default()).expect("loads");
    assert_eq!(scene.triangles(), original.triangles());
}
