//! Tells the tests whether `../shared/scenes` is there, so that `cargo test` lists a test it
//! cannot run as ignored, with the reason, instead of passing it unchecked: sets
//! `prt_skip_shared_scenes` when the folder is absent and `PRT_REQUIRE_SHARED=1` is not set
//! (with it, the tests run and fail loudly). Reruns only when what can change the outcome does.

use std::path::PathBuf;

fn main() {
    println!("cargo::rustc-check-cfg=cfg(prt_skip_shared_scenes)");
    println!("cargo::rerun-if-changed=build.rs");
    let dir = PathBuf::from(std::env::var_os("CARGO_MANIFEST_DIR").expect("set by cargo"))
        .join("../../../shared/scenes");
    if dir.is_dir() {
        println!("cargo::rerun-if-changed={}", dir.display());
    } else {
        println!("cargo::rerun-if-env-changed=PRT_REQUIRE_SHARED");
        if std::env::var_os("PRT_REQUIRE_SHARED").is_none_or(|v| v != "1") {
            println!("cargo::rustc-cfg=prt_skip_shared_scenes");
        }
    }
}
