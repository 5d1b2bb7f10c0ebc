//! Tells the tests whether `glslangValidator` (Debian's glslang-tools) is on PATH. Without it the
//! GLSL ES compile test builds as `#[ignore]`d, so `cargo test` lists it as ignored instead of
//! passing unchecked; `PRT_REQUIRE_GLSLANG=1` (set by .ci/run after installing it) makes it run
//! (and fail) anyway.

fn main() {
    println!("cargo::rustc-check-cfg=cfg(prt_skip_glslang)");
    println!("cargo::rerun-if-changed=build.rs");
    println!("cargo::rerun-if-env-changed=PRT_REQUIRE_GLSLANG");
    let on_path = std::env::var_os("PATH").and_then(|path| {
        std::env::split_paths(&path)
            .map(|dir| dir.join("glslangValidator"))
            .find(|candidate| candidate.is_file())
    });
    match on_path {
        // Watched so that removing it rebuilds the test as ignored.
        Some(binary) => println!("cargo::rerun-if-changed={}", binary.display()),
        None => {
            if std::env::var_os("PRT_REQUIRE_GLSLANG").is_none_or(|v| v != "1") {
                println!("cargo::rustc-cfg=prt_skip_glslang");
            }
        }
    }
}
