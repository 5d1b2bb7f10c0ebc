//! A tiled bake of the built-in Cornell box at a tiny resolution: plan 2×2×1, four local worker
//! processes, merge; the result against single-process bakes, a retried tile's bytes, the
//! scheduler index variables, and the deploy files.

mod common;

use std::path::Path;
use std::process::Command;

use common::{
    TINY_PLAN, assert_clean_failure, deploy, kubernetes_manifest, ok, prt, scratch, stderr,
};
use prt_texture::Limits;

/// The plan's knobs, the denoiser on (the default): tiles trace with it (over a margin of its
/// radius), as the single bakes they are compared with do.
fn knobs() -> Vec<&'static str> {
    TINY_PLAN.to_vec()
}

/// `sqrt(Σ‖a − b‖² / Σ‖b‖²)` over voxels valid in both bakes' traced volumes.
fn difference(a: &Path, b: &Path) -> f64 {
    let read = |dir: &Path| {
        prt_bake::volumes::read_volumes(&dir.join("volumes"), &Limits::default()).unwrap()
    };
    let (a, b) = (read(a), read(b));
    assert_eq!(a.grid, b.grid, "the tiled lattice is the single bake's");
    let (fa, fb) = (a.get("reference").unwrap(), b.get("reference").unwrap());
    let (mut diff, mut norm) = (0.0f64, 0.0f64);
    for v in (0..fa.num_voxels()).filter(|&v| a.valid[v] && b.valid[v]) {
        for (&x, &y) in fa.voxel(v).iter().zip(fb.voxel(v)) {
            diff += (f64::from(x) - f64::from(y)).powi(2);
            norm += f64::from(y).powi(2);
        }
    }
    (diff / norm).sqrt()
}

#[test]
fn a_tiled_bake_equals_the_single_bake_within_noise_and_retries_reproduce_bytes() {
    let dir = scratch("tiles");
    let plan = dir.join("plan");
    let plan_s = plan.to_str().unwrap();
    let mut args = vec!["plan", "--tiles", "2,2,1", "--halo", "1", "--out", plan_s];
    args.extend(knobs());
    ok(&prt(&args));

    // The merge refuses a plan whose tiles have not run.
    let early = prt(&[
        "merge",
        plan_s,
        "--out",
        dir.join("early").to_str().unwrap(),
    ]);
    assert_clean_failure(&early, "has not finished");

    ok(&prt(&["bake-tile", plan_s, "--all", "--workers", "4"]));
    for i in 0..4 {
        assert!(prt_bake::tiles::tile_is_done(&plan, i), "tile {i}");
    }
    let tiled = dir.join("tiled");
    let merged = prt(&["merge", plan_s, "--out", tiled.to_str().unwrap()]);
    ok(&merged);
    // The same bake folder as `prt bake`: a container that reads back, and the report.
    let container =
        prt_bake::container::read_container(&tiled.join("mbd"), &Limits::default()).unwrap();
    assert_eq!(container.grid, [8, 8, 8]);
    assert!(tiled.join("report.md").is_file());

    // Two single-process bakes with different seeds: the tiled trace differs from the first
    // no more than the second does (both are independent Monte Carlo samples of it).
    let single = |name: &str, seed: &str| {
        let out = dir.join(name);
        let mut args = vec!["bake", "--out", out.to_str().unwrap(), "--seed", seed];
        args.extend(knobs());
        ok(&prt(&args));
        out
    };
    let (s0, s1) = (single("single0", "0"), single("single1", "1"));
    let (tiled_vs_single, noise) = (difference(&tiled, &s0), difference(&s1, &s0));
    assert!(
        tiled_vs_single < 1.25 * noise && noise > 0.0,
        "tiled vs single {tiled_vs_single:.4}, single seed 1 vs 0 {noise:.4}"
    );

    // Seam ratios across tile borders are about 1.
    let report: prt_bake::tiles::TilesReport =
        serde_json::from_str(&std::fs::read_to_string(tiled.join("tiles.json")).unwrap()).unwrap();
    let seams = report.seam_ratio_across_tile_borders.unwrap();
    for (key, ratio) in [
        ("trace", seams.trace),
        ("mbd_error", seams.mbd_error),
        ("mbd_basis", seams.mbd_basis),
    ] {
        assert!((0.7..1.4).contains(&ratio), "{key}: {ratio}");
    }
    assert!(report.halo_agreement.unwrap().voxels > 0);

    // The streamed merge writes a container on the same lattice and validity (on 3 basis
    // nodes per axis: it fits the basis on the lattice halved, 4 voxels per axis).
    let plan3 = dir.join("plan3");
    let plan3_s = plan3.to_str().unwrap();
    let mut args = vec![
        "plan",
        "--tiles",
        "2,2,1",
        "--out",
        plan3_s,
        "--basis-nodes",
        "3",
    ];
    args.extend(knobs());
    ok(&prt(&args));
    ok(&prt(&["bake-tile", plan3_s, "--all", "--workers", "2"]));
    let streamed = dir.join("streamed");
    ok(&prt(&[
        "merge",
        plan3_s,
        "--out",
        streamed.to_str().unwrap(),
        "--stream",
        "--sweeps",
        "1",
    ]));
    let back =
        prt_bake::container::read_container(&streamed.join("mbd"), &Limits::default()).unwrap();
    assert_eq!((back.grid, &back.valid), (container.grid, &container.valid));
    let report: prt_bake::tiles::TilesReport =
        serde_json::from_str(&std::fs::read_to_string(streamed.join("tiles.json")).unwrap())
            .unwrap();
    let streamed_record = report.streamed.unwrap();
    assert_eq!(
        streamed_record.relative_error_at_valid_voxel_centres.len(),
        2
    );

    // A finished tile is skipped; a forced retry gives the same bytes.
    let files = ["transfer.f32", "valid.u8", "tile.json"];
    let tile2 = prt_bake::tiles::tile_dir(&plan, 2);
    let before: Vec<Vec<u8>> = files
        .iter()
        .map(|f| std::fs::read(tile2.join(f)).unwrap())
        .collect();
    let skipped = prt(&["bake-tile", plan_s, "--tile", "2"]);
    ok(&skipped);
    assert!(String::from_utf8_lossy(&skipped.stdout).contains("already done"));
    // The retry takes its index from the Slurm variable, as an array task would.
    let retried = Command::new(env!("CARGO_BIN_EXE_prt"))
        .args(["bake-tile", plan_s, "--force"])
        .env_remove("JOB_COMPLETION_INDEX")
        .env("SLURM_ARRAY_TASK_ID", "2")
        .output()
        .unwrap();
    ok(&retried);
    for (file, bytes) in files.iter().zip(&before) {
        assert!(
            &std::fs::read(tile2.join(file)).unwrap() == bytes,
            "{file} differs after a retry"
        );
    }

    // No index anywhere is a clear error; so is an index outside the plan.
    let none = Command::new(env!("CARGO_BIN_EXE_prt"))
        .args(["bake-tile", plan_s])
        .env_remove("JOB_COMPLETION_INDEX")
        .env_remove("SLURM_ARRAY_TASK_ID")
        .output()
        .unwrap();
    assert_clean_failure(&none, "no tile index");
    let outside = Command::new(env!("CARGO_BIN_EXE_prt"))
        .args(["bake-tile", plan_s])
        .env("JOB_COMPLETION_INDEX", "4")
        .output()
        .unwrap();
    assert_clean_failure(&outside, "tile 4 does not exist");
}

#[test]
fn the_deploy_files_parse() {
    for script in ["prt-bake.sbatch", "prt-merge.sbatch", "submit.sh"] {
        match Command::new("bash")
            .arg("-n")
            .arg(deploy(&format!("slurm/{script}")))
            .output()
        {
            Ok(out) => assert!(out.status.success(), "bash -n {script}: {}", stderr(&out)),
            Err(e) => eprintln!("skipped: bash not available ({e})"),
        }
    }
    let text = std::fs::read_to_string(deploy("kubernetes/prt-bake-indexed-job.yaml")).unwrap();
    for needle in [
        "completionMode: Indexed",
        "prt bake-tile",
        "prt merge",
        "JOB_COMPLETION_INDEX",
    ] {
        assert!(text.contains(needle), "the manifest lacks {needle:?}");
    }
    // A full YAML parse where python3 with PyYAML is at hand (PRT_REQUIRE_YAML=1 requires it).
    if let Some(documents) = kubernetes_manifest() {
        let jobs = documents.iter().filter(|d| d["kind"] == "Job").count();
        assert_eq!(jobs, 3, "{documents:?}");
    }
}
