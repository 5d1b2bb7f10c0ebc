//! Tells the tests whether `../shared/envmaps` is there. Without it the tests that read it
//! compile as `#[ignore]`d, so `cargo test` lists them as ignored with the reason instead of
//! passing unchecked; `PRT_REQUIRE_SHARED=1` makes them run (and fail) anyway.

use std::path::PathBuf;

fn main() {
    println!("cargo::rustc-check-cfg=cfg(prt_skip_shared_envmaps)");
    println!("cargo::rerun-if-changed=build.rs");
    println!("cargo::rerun-if-env-changed=PRT_REQUIRE_SHARED");
    let dir = PathBuf::from(std::env::var_os("CARGO_MANIFEST_DIR").expect("set by cargo"))
        .join("../../../shared/envmaps");
    if dir.is_dir() {
        // Only a present folder is watched: cargo reruns a script whose watched path is
        // missing, and rebuilds the crate after it, on every build.
        println!("cargo::rerun-if-changed={}", dir.display());
    } else if std::env::var_os("PRT_REQUIRE_SHARED").is_none_or(|v| v != "1") {
        println!("cargo::rustc-cfg=prt_skip_shared_envmaps");
    }
}
