//! `prt export` end to end: a small Cornell bake exported for every target and sky kind, and
//! its one-line errors.

mod common;
use common::{TINY_BAKE, assert_clean_failure, prt, scratch, stderr};

#[test]
fn a_small_bake_exports_for_every_target_and_sky() {
    let dir = scratch("bake");
    let bake = dir.join("bake");
    let bake_s = bake.to_str().expect("utf-8");
    let args: Vec<&str> = std::iter::once("bake")
        .chain(TINY_BAKE.iter().copied())
        .chain(["--out", bake_s])
        .collect();
    let out = prt(&args);
    assert!(out.status.success(), "bake failed: {}", stderr(&out));
    let sky_json = dir.join("sky.json");
    std::fs::write(
        &sky_json,
        r#"{"sh": [[3,0,1,0,0,0,0,0,0],[3,0,1,0,0,0,0,0,0],[3,0,1,0,0,0,0,0,0]]}"#,
    )
    .expect("write sky");
    let cases: [(&str, &str, &[&str]); 4] = [
        (
            "bevy",
            "default",
            &[
                "irradiance_volume.ktx2",
                "irradiance_volume.json",
                "validity.ktx2",
            ],
        ),
        (
            "threejs",
            "sun:30,45",
            &[
                "light_probe_grid.ktx2",
                "light_probe_grid.json",
                "validity.ktx2",
            ],
        ),
        (
            "sh",
            sky_json.to_str().expect("utf-8"),
            &["sh_l1_r.ktx2", "sh_l2.ktx2", "sh.exr", "sh.json"],
        ),
        ("bevy", "sun", &["irradiance_volume.ktx2"]),
    ];
    for (k, (target, sky, files)) in cases.iter().enumerate() {
        let out_dir = dir.join(format!("out{k}"));
        let out = prt(&[
            "export",
            bake_s,
            "--target",
            target,
            "--sky",
            sky,
            "--rotate",
            "-30",
            "--format",
            "rgba16f",
            "--out",
            out_dir.to_str().expect("utf-8"),
        ]);
        assert!(
            out.status.success(),
            "export {target} {sky} failed: {}",
            stderr(&out)
        );
        for file in *files {
            assert!(out_dir.join(file).is_file(), "{target}: {file} missing");
        }
        let listing = String::from_utf8_lossy(&out.stdout);
        assert!(listing.contains("validity.ktx2"), "{listing}");
    }
    // The kept traced volume exports too (`--from`: the option's older name); an unknown
    // volume is a clean error.
    let out = prt(&[
        "export",
        bake_s,
        "--target",
        "sh",
        "--from",
        "reference",
        "--out",
        dir.join("ref").to_str().expect("utf-8"),
    ]);
    assert!(out.status.success(), "{}", stderr(&out));
    assert!(dir.join("ref/sh.json").is_file());
    assert_clean_failure(
        &prt(&["export", bake_s, "--target", "sh", "--method", "nothing"]),
        "nothing",
    );
    // The default output folder is BAKE_DIR/TARGET.
    let out = prt(&["export", bake_s, "--target", "sh", "--dilate", "none"]);
    assert!(out.status.success(), "{}", stderr(&out));
    assert!(bake.join("sh/sh.json").is_file());

    assert_clean_failure(
        &prt(&["export", bake_s, "--target", "bevy", "--sky", "sun:1"]),
        "sun:",
    );
    assert_clean_failure(
        &prt(&["export", bake_s, "--target", "bevy", "--sky", "nowhere.hdr"]),
        "nowhere.hdr",
    );
    assert_clean_failure(
        &prt(&["export", bake_s, "--target", "bevy", "--sky", "sky.txt"]),
        "--sky",
    );
    assert_clean_failure(
        &prt(&["export", bake_s, "--target", "bevy", "--dilate", "x"]),
        "--dilate",
    );
    let bad_json = dir.join("bad.json");
    std::fs::write(
        &bad_json,
        r#"{"sh": [[1e39,0,0,0,0,0,0,0,0],[0,0,0,0,0,0,0,0,0],[0,0,0,0,0,0,0,0,0]]}"#,
    )
    .expect("write");
    assert_clean_failure(
        &prt(&[
            "export",
            bake_s,
            "--target",
            "bevy",
            "--sky",
            bad_json.to_str().expect("utf-8"),
        ]),
        "bad.json",
    );
    assert_clean_failure(
        &prt(&["export", dir.to_str().expect("utf-8"), "--target", "sh"]),
        "no MBD container",
    );
}
