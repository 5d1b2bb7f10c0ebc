//! Helpers shared by the `prt` binary's integration tests.
#![allow(dead_code)] // each test file uses its own subset

use std::path::PathBuf;
use std::process::{Command, Output};

/// Runs the `prt` binary with `args`.
pub fn prt(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_prt"))
        .args(args)
        .output()
        .expect("the prt binary runs")
}

/// A fresh empty folder under the system's temp folder, unique to this process and `name`.
pub fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("prt-cli-test-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("temp dir");
    dir
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
