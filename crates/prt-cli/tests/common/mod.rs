//! Helpers shared by the `prt` binary's integration tests.
#![allow(dead_code)] // each test file uses its own subset

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// The knobs of the smallest bake the export and engine tests use: a Cornell box of 8 voxels
/// per axis, 48 rays, rank 4 on 3³ basis nodes, 8 iterations, no baselines.
pub const TINY_BAKE: &[&str] = &[
    "--res",
    "8",
    "--rays",
    "48",
    "--cache-rays",
    "16",
    "--rank",
    "4",
    "--basis-nodes",
    "3",
    "--iterations",
    "8",
    "--no-baselines",
];

/// The knobs of the tiny tiled plans of the scheduler tests (tiles, Slurm, Kubernetes): a Cornell
/// box of 8 voxels per axis, 48 rays, 8 surface-cache rays, 8 iterations, no baselines.
pub const TINY_PLAN: &[&str] = &[
    "--res",
    "8",
    "--rays",
    "48",
    "--cache-rays",
    "8",
    "--iterations",
    "8",
    "--no-baselines",
];

/// Runs `command`, requires success, and returns its stdout followed by its stderr.
pub fn run(command: &mut Command) -> String {
    let out = command.output().expect("the command runs");
    assert!(
        out.status.success(),
        "{command:?} failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr)
}

/// Debian's chromium: PRT_CHROMIUM, else `chromium` or `chromium-browser` on PATH.
pub fn chromium() -> PathBuf {
    if let Some(path) = std::env::var_os("PRT_CHROMIUM") {
        return path.into();
    }
    let path = std::env::var_os("PATH").unwrap_or_default();
    std::env::split_paths(&path)
        .flat_map(|dir| ["chromium", "chromium-browser"].map(|name| dir.join(name)))
        .find(|candidate| candidate.is_file())
        .expect("chromium on PATH (the test runs because PRT_REQUIRE_CHROMIUM=1 or because it was there when it was built)")
}

/// Runs the `prt` binary with `args`.
pub fn prt(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_prt"))
        .args(args)
        .output()
        .expect("the prt binary runs")
}

/// A fresh empty folder under the system's temp folder, unique to this process and `name`;
/// removed when dropped, unless the test is failing (its files are then left to read).
pub fn scratch(name: &str) -> Scratch {
    let dir = std::env::temp_dir().join(format!("prt-cli-test-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("temp dir");
    Scratch(dir)
}

/// A test's scratch folder (see [`scratch`]); dereferences to its path.
pub struct Scratch(PathBuf);

impl std::ops::Deref for Scratch {
    type Target = Path;

    fn deref(&self) -> &Path {
        &self.0
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        if std::thread::panicking() {
            eprintln!("the test's folder is kept: {}", self.0.display());
        } else {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }
}

/// Requires that a run of `prt` succeeded, showing its stderr if not.
pub fn ok(out: &Output) {
    assert!(out.status.success(), "{}", stderr(out));
}

/// Every file under `dir`, relative to it, sorted.
pub fn files(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for entry in std::fs::read_dir(&d).unwrap().flatten() {
            let path = entry.path();
            if path.is_dir() {
                stack.push(path);
            } else {
                out.push(path.strip_prefix(dir).unwrap().to_path_buf());
            }
        }
    }
    out.sort();
    out
}

/// A file of the repository's deploy/ folder, e.g. `slurm/submit.sh`.
pub fn deploy(path: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../deploy")
        .join(path)
}

/// Whether the environment variable `name` (a `PRT_REQUIRE_*` of .ci/run) is set to 1: a tool
/// the test needs must then be present, so that CI never passes by skipping.
pub fn required(name: &str) -> bool {
    std::env::var_os(name).is_some_and(|v| v == "1")
}

/// The documents of deploy/kubernetes/prt-bake-indexed-job.yaml as JSON, parsed by python3's
/// PyYAML (no YAML crate in the workspace), or `None` after saying so when either is missing
/// and `PRT_REQUIRE_YAML=1` does not require them.
pub fn kubernetes_manifest() -> Option<Vec<serde_json::Value>> {
    let dump = "import sys, json, yaml; \
                print(json.dumps([d for d in yaml.safe_load_all(open(sys.argv[1])) if d]))";
    let out = match Command::new("python3")
        .args(["-c", dump])
        .arg(deploy("kubernetes/prt-bake-indexed-job.yaml"))
        .output()
    {
        Ok(out) => out,
        Err(e) => {
            assert!(
                !required("PRT_REQUIRE_YAML"),
                "PRT_REQUIRE_YAML=1 but python3 cannot run: {e}"
            );
            eprintln!("skipped: python3 not available ({e})");
            return None;
        }
    };
    if stderr(&out).contains("No module named 'yaml'") {
        assert!(
            !required("PRT_REQUIRE_YAML"),
            "PRT_REQUIRE_YAML=1 but python3 has no PyYAML"
        );
        eprintln!("skipped: PyYAML not available");
        return None;
    }
    assert!(out.status.success(), "YAML: {}", stderr(&out));
    Some(serde_json::from_slice(&out.stdout).unwrap())
}

/// The process's stderr as text.
pub fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// The error is one line starting with `error:` and the exit code is non-zero.
pub fn assert_clean_failure(out: &Output, needle: &str) {
    assert!(!out.status.success(), "expected failure, got success");
    let err = stderr(out);
    let line = err
        .lines()
        .find(|l| l.starts_with("error:"))
        .unwrap_or_else(|| panic!("no error line in {err:?}"));
    assert!(
        line.contains(needle),
        "error line {line:?} does not mention {needle:?}"
    );
    assert!(!err.contains("panicked"), "panic in {err}");
}

/// A file of ../shared (beside the repository), e.g. `scenes/cornell_box/CornellBox-Original.gltf`.
/// Tests that read one are `#[cfg_attr(prt_skip_shared, ignore = ...)]`: build.rs sets the cfg
/// when ../shared is absent and PRT_REQUIRE_SHARED=1 does not require it.
pub fn shared(path: &str) -> PathBuf {
    let file = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared")
        .join(path);
    assert!(file.is_file(), "{} is missing", file.display());
    file
}

/// The Cornell box glTF of ../shared/scenes.
pub fn shared_cornell() -> PathBuf {
    shared("scenes/cornell_box/CornellBox-Original.gltf")
}
