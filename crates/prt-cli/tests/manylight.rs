//! `prt manylight` on the Cornell box glTF of ../shared at a tiny size, and lights files it must
//! refuse with a one-line error.

mod common;
use std::path::Path;

use common::{assert_clean_failure, prt, scratch, shared_cornell, stderr};

/// 40 isotropic and downward lights in the Cornell box glTF (x in -1..1, y in 0..1.99, z in
/// -1.04..0.99), above its two blocks and below its ceiling.
fn write_lights(path: &Path) {
    let mut text = String::from("# x y z  nx ny nz  r g b\n");
    for k in 0..40 {
        let (x, y, z) = (
            -0.5 + 0.025 * k as f32,
            1.3 + 0.015 * k as f32,
            0.3 - 0.015 * k as f32,
        );
        let normal = if k % 2 == 0 { "0 0 0" } else { "0 -1 0" };
        text.push_str(&format!(
            "{x} {y} {z}  {normal}  0.5 0.4 {}\n",
            0.1 + 0.01 * k as f32
        ));
    }
    std::fs::write(path, text).expect("write the lights");
}

/// The relative L2 error (percent) and the ꟻLIP the `--compare` table prints for `method`.
fn table_errors(stdout: &str, method: &str) -> (f64, f64) {
    let row = stdout
        .lines()
        .find(|l| l.starts_with(&format!("| {method} |")))
        .unwrap_or_else(|| panic!("no row for {method} in {stdout}"));
    let cells: Vec<&str> = row.split('|').map(str::trim).collect();
    let number = |cell: &str| -> f64 {
        cell.trim_end_matches(" %")
            .parse()
            .unwrap_or_else(|_| panic!("no number in {row}"))
    };
    (number(cells[5]), number(cells[6]))
}

#[test]
#[cfg_attr(prt_skip_shared, ignore = "needs ../shared/scenes")]
fn compare_on_the_cornell_gltf_is_exact_with_a_column_per_light() {
    let scene = shared_cornell();
    let dir = scratch("manylight-compare");
    let lights = dir.join("lights.txt");
    write_lights(&lights);
    let out = dir.join("cornell.png");
    let run = prt(&[
        "manylight",
        scene.to_str().unwrap(),
        "--lights-file",
        lights.to_str().unwrap(),
        "--size",
        "24",
        "--rows",
        "32",
        "--columns",
        "40",
        "--compare",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(run.status.success(), "{}", stderr(&run));
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(
        stdout.contains("40 lights (40 VPLs from the lights file"),
        "{stdout}"
    );
    assert!(stdout.contains("(measured)"), "{stdout}");
    // One cluster per light: every method renders the brute-force image.
    for method in ["rowcol", "lightslice", "visibility", "mrcs"] {
        let (error, flip) = table_errors(&stdout, method);
        assert!(error < 0.01 && flip < 1e-3, "{method}: {stdout}");
    }
    let image = image::open(&out).expect("the PNG reads back");
    assert_eq!((image.width(), image.height()), (24, 24));
    let strip = image::open(dir.join("cornell_compare.png")).expect("the strip reads back");
    assert_eq!((strip.width(), strip.height()), (5 * 24, 2 * 24));
    // The lit box is not black.
    assert!(
        image
            .to_rgb8()
            .pixels()
            .any(|p| p.0.iter().any(|&c| c > 40))
    );
}

#[test]
#[cfg_attr(prt_skip_shared, ignore = "needs ../shared/scenes")]
fn traced_lights_on_a_light_path_with_estimated_brute_force_write_exr_frames() {
    let scene = shared_cornell();
    let dir = scratch("manylight-frames");
    let out = dir.join("frame.exr");
    let saved = dir.join("saved.txt");
    let run = prt(&[
        "manylight",
        scene.to_str().unwrap(),
        "--lights",
        "300",
        "--size",
        "16",
        "--rows",
        "16",
        "--columns",
        "32",
        "--frames",
        "3",
        "--path",
        "light",
        "--method",
        "mrcs",
        "--max-brute-elements",
        "0",
        "--sample-pixels",
        "8",
        "--save-lights",
        saved.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(run.status.success(), "{}", stderr(&run));
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(stdout.contains("traced, one bounce"), "{stdout}");
    assert!(
        stdout.contains("estimated from 8 sampled pixels per frame"),
        "{stdout}"
    );
    assert!(stdout.contains("time splits"), "{stdout}");
    for t in 0..3 {
        let frame = dir.join(format!("frame_{t:04}.exr"));
        assert!(frame.is_file(), "missing {}", frame.display());
    }
    // The saved lights read back as a lights file.
    let again = prt(&[
        "manylight",
        scene.to_str().unwrap(),
        "--lights-file",
        saved.to_str().unwrap(),
        "--size",
        "8",
        "--method",
        "brute",
        "--out",
        dir.join("again.png").to_str().unwrap(),
    ]);
    assert!(again.status.success(), "{}", stderr(&again));
}

#[test]
fn bad_lights_files_are_one_line_errors() {
    let dir = scratch("manylight-bad");
    let out = dir.join("out.png");
    let run_with = |name: &str, text: &str| {
        let path = dir.join(name);
        std::fs::write(&path, text).expect("write the lights");
        prt(&[
            "manylight",
            "--lights-file",
            path.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ])
    };
    let good = "0 1 0  0 -1 0  1 1 1\n";
    assert_clean_failure(
        &run_with("nan.txt", &format!("{good}0 1 0  0 -1 0  NaN 1 1\n")),
        "line 2: light 1: its power is not finite",
    );
    assert_clean_failure(
        &run_with("inf.txt", &format!("{good}{good}0 inf 0  0 -1 0  1 1 1\n")),
        "light 2: its position is not finite",
    );
    assert_clean_failure(&run_with("zero.txt", "0 1 0  0 -1 0  0 0 0\n"), "is zero");
    assert_clean_failure(
        &run_with("negative.txt", "0 1 0  0 -1 0  1 -0.5 1\n"),
        "is negative",
    );
    assert_clean_failure(&run_with("short.txt", "0 1 0 0 -1 0 1 1\n"), "line 1");
    assert_clean_failure(&run_with("empty.txt", "# no lights\n"), "no light");
    // Two million lights of 300 sampled rows each exceed the default 4 GiB: refused after
    // counting, before any is stored.
    let many = run_with("many.txt", &"0 1 0 0 -1 0 1 1 1\n".repeat(2_000_000));
    assert_clean_failure(&many, "2000000 lights need about");
    assert_clean_failure(
        &prt(&[
            "manylight",
            "--lights-file",
            dir.join("absent.txt").to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ]),
        "cannot read the lights file",
    );
    assert_clean_failure(
        &prt(&[
            "manylight",
            "--camera",
            "99",
            "--out",
            out.to_str().unwrap(),
        ]),
        "--camera 99 does not exist; the scene has 2 view(s): 0 = front, 1 = inside",
    );
    assert_clean_failure(
        &prt(&["manylight", "--size", "8", "--out", out.to_str().unwrap()]),
        "--rows 300 is more than the 64 pixels",
    );
    assert!(!out.exists());
}
