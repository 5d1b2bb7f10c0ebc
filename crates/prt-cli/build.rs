//! Tells the tests whether a `chromium` binary is there (on PATH, or named by PRT_CHROMIUM).
//! Without one the viewer's screenshot test compiles as `#[ignore]`d, so `cargo test` lists it
//! as ignored with the reason instead of passing unchecked; `PRT_REQUIRE_CHROMIUM=1` (set by
//! .ci/run after installing Debian's chromium) makes it run (and fail) anyway.
//!
//! The three.js test (tests/threejs.rs) also needs examples/threejs/node_modules (`npm ci`).
//!
//! Likewise for the Bevy test (tests/bevy.rs): it needs the built examples/bevy binary, named
//! by PRT_BEVY_EXAMPLE, and ../shared/scenes; without either it compiles as ignored, unless
//! PRT_REQUIRE_BEVY=1 (set by .ci/run after building the example) and PRT_REQUIRE_SHARED=1.
//!
//! Tests that read ../shared (scenes, environment maps: the manylight, lightmap and relight
//! tests) compile as ignored when it is absent, unless PRT_REQUIRE_SHARED=1 (set by .ci/run).
//!
//! And for the Slurm test (tests/slurm.rs): it starts munged, slurmctld and slurmd (Debian's
//! munge and slurm-wlm) as root; without them, or not as root, it compiles as ignored, unless
//! PRT_REQUIRE_SLURM=1 (set by .ci/run after installing them).

use std::path::PathBuf;

fn main() {
    println!("cargo::rustc-check-cfg=cfg(prt_skip_chromium)");
    println!("cargo::rustc-check-cfg=cfg(prt_skip_bevy)");
    println!("cargo::rustc-check-cfg=cfg(prt_skip_threejs)");
    println!("cargo::rustc-check-cfg=cfg(prt_skip_slurm)");
    println!("cargo::rustc-check-cfg=cfg(prt_skip_shared)");
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
    if skip_bevy() {
        println!("cargo::rustc-cfg=prt_skip_bevy");
    }
    if skip_threejs() {
        println!("cargo::rustc-cfg=prt_skip_threejs");
    }
    if skip_slurm() {
        println!("cargo::rustc-cfg=prt_skip_slurm");
    }
    if skip_shared() {
        println!("cargo::rustc-cfg=prt_skip_shared");
    }
}

/// Whether ../shared (beside the repository) is absent and may be skipped.
fn skip_shared() -> bool {
    println!("cargo::rerun-if-env-changed=PRT_REQUIRE_SHARED");
    let shared = PathBuf::from(std::env::var_os("CARGO_MANIFEST_DIR").expect("set by cargo"))
        .join("../../../shared");
    if shared.is_dir() {
        println!("cargo::rerun-if-changed={}", shared.display());
        return false;
    }
    std::env::var_os("PRT_REQUIRE_SHARED").is_none_or(|v| v != "1")
}

/// Whether tests/slurm.rs lacks Slurm's and munge's programs, or root, and may skip.
fn skip_slurm() -> bool {
    use std::os::unix::fs::MetadataExt;
    println!("cargo::rerun-if-env-changed=PRT_REQUIRE_SLURM");
    if std::env::var_os("PRT_REQUIRE_SLURM").is_some_and(|v| v == "1") {
        return false;
    }
    // The daemons live in sbin, which a user's PATH may lack.
    let path = std::env::var_os("PATH").unwrap_or_default();
    let dirs: Vec<PathBuf> = std::env::split_paths(&path)
        .chain(["/usr/sbin", "/usr/local/sbin"].map(PathBuf::from))
        .collect();
    let mut missing = false;
    for name in [
        "munged",
        "slurmctld",
        "slurmd",
        "sbatch",
        "squeue",
        "sinfo",
        "scontrol",
    ] {
        match dirs.iter().map(|d| d.join(name)).find(|c| c.is_file()) {
            Some(binary) => println!("cargo::rerun-if-changed={}", binary.display()),
            None => missing = true,
        }
    }
    let root = std::fs::metadata("/proc/self").is_ok_and(|m| m.uid() == 0);
    missing || !root
}

/// Whether tests/threejs.rs lacks three.js (`npm ci` in examples/threejs installs the pinned
/// version) and may skip; PRT_REQUIRE_CHROMIUM=1 requires it too.
fn skip_threejs() -> bool {
    let example = PathBuf::from(std::env::var_os("CARGO_MANIFEST_DIR").expect("set by cargo"))
        .join("../../examples/threejs");
    // The folder's time changes when `npm ci` creates or removes node_modules in it.
    println!("cargo::rerun-if-changed={}", example.display());
    !example.join("node_modules/three/package.json").is_file()
        && std::env::var_os("PRT_REQUIRE_CHROMIUM").is_none_or(|v| v != "1")
}

/// Whether tests/bevy.rs lacks the example binary or the shared scenes (and may skip them).
fn skip_bevy() -> bool {
    println!("cargo::rerun-if-env-changed=PRT_BEVY_EXAMPLE");
    println!("cargo::rerun-if-env-changed=PRT_REQUIRE_BEVY");
    println!("cargo::rerun-if-env-changed=PRT_REQUIRE_SHARED");
    let required = |name: &str| std::env::var_os(name).is_some_and(|v| v == "1");
    let example = std::env::var_os("PRT_BEVY_EXAMPLE")
        .map(PathBuf::from)
        .filter(|p| p.is_file());
    if let Some(binary) = &example {
        println!("cargo::rerun-if-changed={}", binary.display());
    }
    let scenes = PathBuf::from(std::env::var_os("CARGO_MANIFEST_DIR").expect("set by cargo"))
        .join("../../../shared/scenes");
    if scenes.is_dir() {
        println!("cargo::rerun-if-changed={}", scenes.display());
    }
    (example.is_none() && !required("PRT_REQUIRE_BEVY"))
        || (!scenes.is_dir() && !required("PRT_REQUIRE_SHARED"))
}
