//! Tells the tests whether `../shared/envmaps` is there. Without it the tests that read it
//! compile as `#[ignore]`d, so `cargo test` lists them as ignored with the reason instead of
//! passing unchecked; `PRT_REQUIRE_SHARED=1` makes them run (and fail) anyway.

use std::path::PathBuf;

fn main() {
    println!("cargo::rustc-check-cfg=cfg(prt_skip_shared_envmaps)");
    println!("cargo::rerun-if-changed=build.rs");
    let dir = PathBuf::from(std::env::var_os("CARGO_MANIFEST_DIR").expect("set by cargo"))
        .join("../../../shared/envmaps");
    // Each rerun rebuilds the crate, so only what can change the outcome is watched: a present
    // folder (cargo would rerun on every build for a missing path), or the variable when the
    // folder is absent (rerunning then also notices data added since).
    if dir.is_dir() {
        println!("cargo::rerun-if-changed={}", dir.display());
    } else {
        println!("cargo::rerun-if-env-changed=PRT_REQUIRE_SHARED");
        if std::env::var_os("PRT_REQUIRE_SHARED").is_none_or(|v| v != "1") {
            println!("cargo::rustc-cfg=prt_skip_shared_envmaps");
        }
    }
}
