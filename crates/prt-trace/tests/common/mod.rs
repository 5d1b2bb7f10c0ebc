//! Helpers shared by the integration tests.
#![allow(dead_code)]

use std::path::PathBuf;

/// `../shared/scenes/<rel>`, which must exist. Tests that call this carry
/// `#[cfg_attr(prt_skip_shared_scenes, ignore = "...")]`: build.rs sets that cfg when the
/// folder is absent (unless `PRT_REQUIRE_SHARED=1`), so a test that runs never skips.
pub fn shared_scene(rel: &str) -> PathBuf {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/scenes")
        .join(rel);
    assert!(
        p.exists(),
        "{} is missing; the test runs because PRT_REQUIRE_SHARED=1 or because ../shared/scenes \
         was there when it was built",
        p.display()
    );
    p
}

/// A fresh empty folder under the system temp dir.
pub fn temp_dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("prt-trace-test-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).expect("temp dir");
    d
}

/// The names of the files in `tests/<folder>`, sorted: what a scene folder's table must list.
pub fn scene_folder_files(folder: &str) -> Vec<String> {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests")
        .join(folder);
    let mut files: Vec<String> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|e| e.expect("entry").file_name().to_string_lossy().into_owned())
        .collect();
    files.sort();
    files
}
