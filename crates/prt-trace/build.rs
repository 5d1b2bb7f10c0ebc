//! Tells the tests what they need is there, so that `cargo test` lists a test it cannot run as
//! ignored, with the reason, instead of passing it unchecked:
//! - `prt_skip_shared_scenes` when `../shared/scenes` is absent and `PRT_REQUIRE_SHARED=1` is
//!   not set;
//! - `prt_skip_x86_64_v3` when the CPU building (and so testing) lacks x86-64-v3 and
//!   `PRT_REQUIRE_CPU=1` is not set.
//!
//! With a `PRT_REQUIRE_*=1` variable the tests always run, and fail if what they need is missing.
//! Each rerun of this script rebuilds the crate, so only what can change the outcome is watched:
//! a present folder (cargo would rerun on every build for a missing path), or the variable when
//! the thing is absent (rerunning then also notices data added since).

use std::path::PathBuf;

fn main() {
    println!("cargo::rustc-check-cfg=cfg(prt_skip_shared_scenes, prt_skip_x86_64_v3)");
    println!("cargo::rerun-if-changed=build.rs");
    let dir = PathBuf::from(std::env::var_os("CARGO_MANIFEST_DIR").expect("set by cargo"))
        .join("../../../shared/scenes");
    if dir.is_dir() {
        println!("cargo::rerun-if-changed={}", dir.display());
    } else {
        skip_unless_required("prt_skip_shared_scenes", "PRT_REQUIRE_SHARED");
    }
    // The build machine's CPU says nothing about a cross-compiled target's.
    let native = std::env::var("HOST").ok() == std::env::var("TARGET").ok();
    if !(native && host_has_x86_64_v3()) {
        skip_unless_required("prt_skip_x86_64_v3", "PRT_REQUIRE_CPU");
    }
}

/// Sets `cfg` unless `var` is `1`, and reruns when `var` changes.
fn skip_unless_required(cfg: &str, var: &str) {
    println!("cargo::rerun-if-env-changed={var}");
    if std::env::var_os(var).is_none_or(|v| v != "1") {
        println!("cargo::rustc-cfg={cfg}");
    }
}

/// The features `bvh::x86_v3` is compiled with.
fn host_has_x86_64_v3() -> bool {
    #[cfg(target_arch = "x86_64")]
    return is_x86_feature_detected!("avx2")
        && is_x86_feature_detected!("fma")
        && is_x86_feature_detected!("bmi1")
        && is_x86_feature_detected!("bmi2")
        && is_x86_feature_detected!("lzcnt")
        && is_x86_feature_detected!("popcnt");
    #[cfg(not(target_arch = "x86_64"))]
    false
}
