//! Never a stale tile (issue 40): a plan folder holding another plan is refused unless
//! `--replace`; a tile traced for another plan is traced again by `bake-tile` and refused by
//! `merge`, naming what differs; a tile whose floats were altered is refused naming it; a
//! damaged plan.json is a clean error; the tiles share the plan's surface cache, and a damaged
//! one is refused. Tiny bakes of the built-in Cornell box.

mod common;

use std::path::Path;
use std::process::Output;

use common::{assert_clean_failure, prt, scratch, stderr};

/// The knobs of every plan here: tiny and fast.
const KNOBS: [&str; 7] = [
    "--iterations",
    "4",
    "--rank",
    "4",
    "--basis-nodes",
    "3",
    "--no-baselines",
];

fn ok(out: &Output) {
    assert!(out.status.success(), "{}", stderr(out));
}

fn stdout(out: &Output) -> String {
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// `prt plan` of the Cornell box in two tiles into `dir`: 6 voxels along each axis, `rays` per
/// voxel, 4 cache rays, but where `extra` says otherwise.
fn plan(dir: &Path, rays: &str, extra: &[&str]) -> Output {
    let mut args = vec!["plan", "--tiles", "2,1,1", "--out", dir.to_str().unwrap()];
    args.extend(["--rays", rays]);
    for (flag, default) in [("--res", "6"), ("--cache-rays", "4")] {
        if !extra.contains(&flag) {
            args.extend([flag, default]);
        }
    }
    args.extend(KNOBS);
    args.extend(extra);
    prt(&args)
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for entry in std::fs::read_dir(from).unwrap() {
        let entry = entry.unwrap();
        std::fs::copy(entry.path(), to.join(entry.file_name())).unwrap();
    }
}

#[test]
fn a_stale_plan_is_refused_and_a_stale_tile_is_retraced_and_refused_by_the_merge() {
    let dir = scratch("stale");
    let old = dir.join("old");
    let old_s = old.to_str().unwrap();
    ok(&plan(&old, "12", &[]));
    ok(&prt(&["bake-tile", old_s, "--all", "--workers", "2"]));

    // The same plan again is a no-op that keeps the finished tiles.
    let same = plan(&old, "12", &[]);
    ok(&same);
    assert!(
        stdout(&same).contains("already holds this plan") && stdout(&same).contains("2 finished"),
        "{}",
        stdout(&same)
    );
    let skipped = prt(&["bake-tile", old_s, "--tile", "1"]);
    ok(&skipped);
    assert!(stdout(&skipped).contains("already done"));

    // Other rays, cache rays, margin or resolution into the same folder: refused, naming what
    // differs, and the tiles are left alone.
    for (rays, extra, differs) in [
        ("24", &[][..], "config.rays_per_voxel: 12 → 24"),
        ("12", &["--cache-rays", "8"][..], "config.cache_rays: 4 → 8"),
        ("12", &["--margin", "0.1"][..], "config.margin"),
        ("12", &["--res", "8"][..], "lattice_dims"),
    ] {
        assert_clean_failure(&plan(&old, rays, extra), "already holds a different plan");
        let out = plan(&old, rays, extra);
        assert!(
            stderr(&out).contains(differs),
            "{differs}: {}",
            stderr(&out)
        );
        assert!(stderr(&out).contains("--replace"), "{}", stderr(&out));
    }
    assert!(prt_bake::tiles::tile_is_done(&old, 0) && prt_bake::tiles::tile_is_done(&old, 1));

    // A tile of the old plan planted into a new plan's folder (another --rays): the merge
    // refuses it, naming the tile and what differs; bake-tile traces it again.
    let new = dir.join("new");
    let new_s = new.to_str().unwrap();
    ok(&plan(&new, "24", &[]));
    copy_dir(
        &prt_bake::tiles::tile_dir(&old, 0),
        &prt_bake::tiles::tile_dir(&new, 0),
    );
    let merged = prt(&["merge", new_s, "--out", dir.join("bake").to_str().unwrap()]);
    assert_clean_failure(&merged, "tile 0");
    assert!(
        stderr(&merged).contains("traced for another plan")
            && stderr(&merged).contains("rays_per_voxel: 12 → 24"),
        "{}",
        stderr(&merged)
    );
    let retraced = prt(&["bake-tile", new_s, "--tile", "0"]);
    ok(&retraced);
    assert!(
        stdout(&retraced).contains("traced for another plan")
            && stdout(&retraced).contains("rays_per_voxel: 12 → 24")
            && stdout(&retraced).contains("tracing it again"),
        "{}",
        stdout(&retraced)
    );
    let plan_new = prt_bake::tiles::TilePlan::read(&new, &prt_texture::Limits::default()).unwrap();
    assert_eq!(
        prt_bake::tiles::tile_status(&plan_new, &new, 0).unwrap(),
        prt_bake::tiles::TileStatus::Done
    );

    // A tile of another resolution is traced again by the --all runner too.
    let res8 = dir.join("res8");
    ok(&plan(&res8, "12", &["--res", "8"]));
    copy_dir(
        &prt_bake::tiles::tile_dir(&old, 1),
        &prt_bake::tiles::tile_dir(&res8, 1),
    );
    let all = prt(&["bake-tile", res8.to_str().unwrap(), "--all"]);
    ok(&all);
    assert!(
        stdout(&all).contains("2 of 2 tiles to bake (1 traced for another plan"),
        "{}",
        stdout(&all)
    );
    let plan8 = prt_bake::tiles::TilePlan::read(&res8, &prt_texture::Limits::default()).unwrap();
    assert_eq!(
        prt_bake::tiles::tile_status(&plan8, &res8, 1).unwrap(),
        prt_bake::tiles::TileStatus::Done
    );

    // --replace writes the new plan and removes the old tiles and their markers.
    let replaced = plan(&old, "24", &["--replace"]);
    ok(&replaced);
    assert!(
        stdout(&replaced).contains("removing its 2 tile folders"),
        "{}",
        stdout(&replaced)
    );
    assert!(
        !prt_bake::tiles::tile_dir(&old, 0).exists()
            && !prt_bake::tiles::tile_dir(&old, 1).exists()
    );
}

#[test]
fn a_tile_with_altered_floats_is_refused_by_the_merge_naming_it() {
    let dir = scratch("altered");
    let plan_dir = dir.join("plan");
    let plan_s = plan_dir.to_str().unwrap();
    ok(&plan(&plan_dir, "12", &[]));
    ok(&prt(&["bake-tile", plan_s, "--all", "--workers", "2"]));
    // One finite float changed in place, the file's size unchanged.
    let transfer = prt_bake::tiles::tile_dir(&plan_dir, 1).join("transfer.f32");
    let mut bytes = std::fs::read(&transfer).unwrap();
    let at = bytes.len() / 2 / 4 * 4;
    let x = f32::from_le_bytes(bytes[at..at + 4].try_into().unwrap());
    bytes[at..at + 4].copy_from_slice(&(x + 0.25).to_le_bytes());
    std::fs::write(&transfer, &bytes).unwrap();
    let bake = dir.join("bake");
    let bake_s = bake.to_str().unwrap();
    for stream in [&[][..], &["--stream"][..]] {
        let mut args = vec!["merge", plan_s, "--out", bake_s];
        args.extend(stream);
        let merged = prt(&args);
        assert_clean_failure(&merged, "tile 1");
        assert!(
            stderr(&merged).contains("transfer.f32 is damaged"),
            "{}",
            stderr(&merged)
        );
    }
    // Traced again (--force), it merges; the report counts the tiles' rays, their rate and
    // their surface-cache points.
    ok(&prt(&["bake-tile", plan_s, "--tile", "1", "--force"]));
    ok(&prt(&["merge", plan_s, "--out", bake_s]));
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(bake.join("report.json")).unwrap()).unwrap();
    assert!(report["bake"]["rays"].as_u64().unwrap() > 0, "{report}");
    assert!(
        report["bake"]["mrays_per_second"].as_f64().unwrap() > 0.0,
        "{report}"
    );
    let md = std::fs::read_to_string(bake.join("report.md")).unwrap();
    assert!(
        md.contains("surface-cache points") && !md.contains(" 0 surface-cache points"),
        "{md}"
    );
}

#[test]
fn a_damaged_plan_is_a_clean_error_for_bake_tile_and_merge() {
    let dir = scratch("damaged-plan");
    let plan_dir = dir.join("plan");
    let plan_s = plan_dir.to_str().unwrap();
    ok(&plan(&plan_dir, "12", &[]));
    let path = plan_dir.join("plan.json");
    let good: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    let out = dir.join("bake");
    for (dims, needle) in [
        (
            serde_json::json!([4294967296u64, 6, 6]),
            "a lattice dimension",
        ),
        (serde_json::json!([0, 6, 6]), "no voxel along an axis"),
        (serde_json::json!([16000, 16000, 16000]), "voxel count"),
        (serde_json::json!([9, 6, 6]), "is not tile 0"),
    ] {
        let mut damaged = good.clone();
        damaged["lattice_dims"] = dims;
        std::fs::write(&path, serde_json::to_string(&damaged).unwrap()).unwrap();
        for args in [
            vec!["bake-tile", plan_s, "--tile", "0"],
            vec!["bake-tile", plan_s, "--all"],
            vec!["merge", plan_s, "--out", out.to_str().unwrap()],
        ] {
            let result = prt(&args);
            assert_clean_failure(&result, "cannot read the plan");
            assert!(
                stderr(&result).contains(needle),
                "{args:?}: {}",
                stderr(&result)
            );
        }
    }
}

/// `OUT/report.json`'s `bake` object.
fn bake_counters(out: &Path) -> serde_json::Value {
    let text = std::fs::read_to_string(out.join("report.json")).unwrap();
    serde_json::from_str::<serde_json::Value>(&text).unwrap()["bake"].clone()
}

/// The tiles share the plan's surface cache: a 2×2×1 tiling without halo or denoiser margin
/// traces at most 1.1× the rays of one bake with the same knobs; the merged report counts the
/// tiles' rays plus the cache's once, its points once, at a positive rate; a damaged cache is
/// refused by the workers and the merge and evaluated again by `prt plan`.
#[test]
fn tiles_share_one_surface_cache_and_the_report_counts_it_once() {
    let dir = scratch("shared-cache");
    // Enough rays per voxel that the plan's visibility pass (12 per voxel) is a small share.
    let knobs = [
        "--res",
        "8",
        "--rays",
        "240",
        "--cache-rays",
        "8",
        "--denoise",
        "off",
    ];
    let one = dir.join("one");
    let mut args = vec!["bake", "--out", one.to_str().unwrap()];
    args.extend(knobs);
    args.extend(KNOBS);
    ok(&prt(&args));
    let plan_dir = dir.join("plan");
    let plan_s = plan_dir.to_str().unwrap();
    let mut args = vec!["plan", "--tiles", "2,2,1", "--out", plan_s];
    args.extend(knobs);
    args.extend(KNOBS);
    let planned = prt(&args);
    ok(&planned);
    assert!(stdout(&planned).contains("the surface cache every tile shares"));
    ok(&prt(&["bake-tile", plan_s, "--all", "--workers", "2"]));
    let merged = dir.join("merged");
    ok(&prt(&["merge", plan_s, "--out", merged.to_str().unwrap()]));

    let limits = prt_texture::Limits::default();
    let plan = prt_bake::tiles::TilePlan::read(&plan_dir, &limits).unwrap();
    let (cache, _) = prt_bake::tiles::read_surface_cache_header(&plan, &plan_dir, &limits).unwrap();
    let (mut tile_rays, mut tile_evaluated) = (0, 0);
    for i in 0..plan.tiles.len() {
        let text =
            std::fs::read_to_string(prt_bake::tiles::tile_dir(&plan_dir, i).join("tile.json"))
                .unwrap();
        let stats: prt_bake::tiles::TileStats = serde_json::from_str(&text).unwrap();
        // A tile traces cache rays only for the entries the shared cache lacks.
        assert_eq!(
            stats.cache_rays,
            8 * stats.cache_evaluated as u64,
            "tile {i}"
        );
        tile_rays += stats.rays();
        tile_evaluated += stats.cache_evaluated as u64;
    }
    let (single, tiled) = (bake_counters(&one), bake_counters(&merged));
    let rays = |c: &serde_json::Value| c["rays"].as_u64().unwrap();
    assert_eq!(rays(&tiled), tile_rays + cache.rays);
    // Entries evaluated: the shared cache's and those each tile evaluated itself.
    assert_eq!(
        tiled["cache_evaluated"].as_u64(),
        Some(cache.evaluated as u64 + tile_evaluated)
    );
    let ratio = rays(&tiled) as f64 / rays(&single) as f64;
    assert!(ratio <= 1.1, "tiled / one bake's rays: {ratio:.3}");
    assert!(tiled["mrays_per_second"].as_f64().unwrap() > 0.0);
    let report = std::fs::read_to_string(merged.join("report.md")).unwrap();
    assert!(
        report.contains(&format!("{} surface-cache points", cache.points)) && cache.points > 0,
        "{report}"
    );

    // A damaged cache: refused by a worker and by the merge, evaluated again by `prt plan`.
    let file = plan_dir.join(prt_bake::tiles::SURFACE_CACHE_FILE);
    let mut bytes = std::fs::read(&file).unwrap();
    let last = bytes.len() - 2;
    bytes[last] ^= 0x10;
    std::fs::write(&file, &bytes).unwrap();
    let worker = prt(&["bake-tile", plan_s, "--tile", "0", "--force"]);
    assert_clean_failure(&worker, "is damaged");
    let merge = prt(&["merge", plan_s, "--out", dir.join("m2").to_str().unwrap()]);
    assert_clean_failure(&merge, "is damaged");
    let again = prt(&args);
    ok(&again);
    assert!(
        stdout(&again).contains("replacing one"),
        "{}",
        stdout(&again)
    );
    ok(&prt(&[
        "merge",
        plan_s,
        "--out",
        dir.join("m3").to_str().unwrap(),
    ]));
}
