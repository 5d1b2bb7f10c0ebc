//! Sets `prt_skip_avx2_fma` when the CPU building (and so testing) lacks AVX2 or FMA and
//! `PRT_REQUIRE_CPU=1` is not set: the test comparing the AVX2 path with the portable one is
//! then listed by `cargo test` as ignored, with the reason, instead of comparing the portable
//! path with itself. With `PRT_REQUIRE_CPU=1` it always runs, and fails without the features.

fn main() {
    println!("cargo::rustc-check-cfg=cfg(prt_skip_avx2_fma)");
    println!("cargo::rerun-if-changed=build.rs");
    // The build machine's CPU says nothing about a cross-compiled target's.
    let native = std::env::var("HOST").ok() == std::env::var("TARGET").ok();
    if !(native && host_has_avx2_fma()) {
        // Watched only here: each rerun rebuilds the crate, and with the features present the
        // variable changes nothing.
        println!("cargo::rerun-if-env-changed=PRT_REQUIRE_CPU");
        if std::env::var_os("PRT_REQUIRE_CPU").is_none_or(|v| v != "1") {
            println!("cargo::rustc-cfg=prt_skip_avx2_fma");
        }
    }
}

fn host_has_avx2_fma() -> bool {
    #[cfg(target_arch = "x86_64")]
    return is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma");
    #[cfg(not(target_arch = "x86_64"))]
    false
}
