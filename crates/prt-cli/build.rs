//! Tells the tests whether a `chromium` binary is there (on PATH, or named by PRT_CHROMIUM).
//! Without one the viewer's screenshot test compiles as `#[ignore]`d, so `cargo test` lists it
//! as ignored with the reason instead of passing unchecked; `PRT_REQUIRE_CHROMIUM=1` (set by
//! .ci/run after installing Debian's chromium) makes it run (and fail) anyway.

use std::path::PathBuf;

fn main() {
    println!("cargo::rustc-check-cfg=cfg(prt_skip_chromium)");
    println!("cargo::rerun-if-changed=build.rs");
    println!("cargo::rerun-if-env-changed=PRT_REQUIRE_CHROMIUM");
    println!("cargo::rerun-if-env-changed=PRT_CHROMIUM");
    let named = std::env::var_os("PRT_CHROMIUM")
        .map(PathBuf::from)
        .filter(|p| p.is_file());
    let on_path = std::env::var_os("PATH").and_then(|path| {
        std::env::split_paths(&path)
            .flat_map(|dir| ["chromium", "chromium-browser"].map(|name| dir.join(name)))
            .find(|candidate| candidate.is_file())
    });
    match named.or(on_path) {
        // Watched so that removing it rebuilds the test as ignored.
        Some(binary) => println!("cargo::rerun-if-changed={}", binary.display()),
        None => {
            if std::env::var_os("PRT_REQUIRE_CHROMIUM").is_none_or(|v| v != "1") {
                println!("cargo::rustc-cfg=prt_skip_chromium");
            }
        }
    }
}
