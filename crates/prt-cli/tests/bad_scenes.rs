//! `prt bake` on every malformed scene of prt-trace's `tests/bad_scenes/`: a non-zero exit and an
//! `error:` line on stderr, never a panic or an abort.

use std::path::Path;
use std::process::Command;

#[test]
fn every_bad_scene_fails_cleanly() {
    let folder = Path::new(env!("CARGO_MANIFEST_DIR")).join("../prt-trace/tests/bad_scenes");
    let out = std::env::temp_dir().join(format!("prt-cli-bad-scenes-{}", std::process::id()));
    let mut files: Vec<_> = std::fs::read_dir(&folder)
        .expect("prt-trace/tests/bad_scenes exists")
        .map(|e| e.expect("entry").path())
        .collect();
    files.sort();
    assert!(files.len() >= 30, "only {} bad scenes", files.len());
    let mut wrong = Vec::new();
    for file in &files {
        let run = Command::new(env!("CARGO_BIN_EXE_prt"))
            .arg("bake")
            .arg(file)
            .args(["--res", "4", "--out"])
            .arg(&out)
            .output()
            .expect("the prt binary runs");
        let stderr = String::from_utf8_lossy(&run.stderr);
        let name = file.file_name().unwrap_or_default().to_string_lossy();
        // A panic exits with 101 and an abort is killed by a signal (no exit code).
        let clean_exit = matches!(run.status.code(), Some(c) if c != 0 && c != 101);
        let error_line = stderr.lines().any(|l| l.starts_with("error:"));
        if !clean_exit || !error_line || stderr.contains("panicked") {
            wrong.push(format!(
                "{name}: status {:?}, stderr {stderr:?}",
                run.status
            ));
        }
    }
    let _ = std::fs::remove_dir_all(&out);
    assert!(wrong.is_empty(), "{}", wrong.join("\n"));
}
