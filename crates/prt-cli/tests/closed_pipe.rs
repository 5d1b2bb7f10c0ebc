//! A closed stdout (`prt inspect FILE | head`) ends any subcommand quietly with success: no
//! panic message, status 0 (issue 40).

mod common;

use std::path::Path;
use std::process::{Command, Output, Stdio};

use common::{scratch, stderr};

/// Runs `prt args` with its stdout a pipe whose reader is already closed, so that its first
/// write fails.
fn into_closed_pipe(args: &[&str]) -> Output {
    let (reader, writer) = std::io::pipe().unwrap();
    drop(reader);
    Command::new(env!("CARGO_BIN_EXE_prt"))
        .args(args)
        .stdin(Stdio::null())
        .stdout(writer)
        .stderr(Stdio::piped())
        .output()
        .unwrap()
}

#[test]
fn a_closed_stdout_ends_quietly() {
    let dir = scratch("pipe");
    let plan = dir.join("plan");
    let plan_s = plan.to_str().unwrap();
    let ktx2 = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../prt-texture/tests/data/rgba16f-3d-mips.ktx2");
    for args in [
        vec!["inspect", ktx2.to_str().unwrap()],
        vec![
            "plan", "--tiles", "2,1,1", "--res", "6", "--rays", "12", "--out", plan_s,
        ],
        vec!["bake-tile", plan_s, "--all"],
        vec!["plan", "--help"],
        vec!["--version"],
    ] {
        let out = into_closed_pipe(&args);
        assert!(
            out.status.success() && !stderr(&out).contains("panicked"),
            "{args:?}: {:?} {}",
            out.status,
            stderr(&out)
        );
    }
    // The plan was written before its report to the closed pipe.
    assert!(plan.join("plan.json").is_file());
}
