//! `compare tiles`: tiled bakes measured: for each tile count, `prt plan`, every tile's worker
//! run one after another and the merge, each under `/usr/bin/time -v` (wall, user + system CPU,
//! peak RSS); and, with `--single`, two single-process bakes (seeds 0 and 1) against the last
//! tiled one: the per-voxel difference of the traced volumes and the MBD errors, to tell the
//! tiled bake's difference from Monte Carlo noise.
//!
//! `cargo run --release -p prt-benches --bin compare -- tiles --prt target/release/prt --scene ../shared/scenes/sponza/Sponza.gltf --res 48 --tiles 1,2,4,8,16 --single [--csv DIR]`
//!
//! Tile counts map to grids 1 = 1×1×1, 2 = 2×1×1, 4 = 2×2×1, 8 = 4×2×1, 16 = 4×4×1 (x, y, z;
//! y is up). The machine is shared: the load average is printed beside every row.
use std::error::Error;
use std::path::{Path, PathBuf};
use std::process::Command;

use prt_bake::BakeFolder;
use prt_bake::tiles::TilePlan;
use prt_bake::volumes::KeptVolumes;
use prt_benches::{RelativeError, Table, load_average};
use prt_texture::Limits;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// The prt binary (build it with `cargo build --release -p prt-cli`).
    #[arg(long, default_value = "target/release/prt")]
    prt: PathBuf,
    /// The scene (glTF).
    #[arg(long, default_value = "../shared/scenes/sponza/Sponza.gltf")]
    scene: PathBuf,
    /// Voxels along the longest axis.
    #[arg(long, default_value_t = 48)]
    res: usize,
    /// Tile counts (1, 2, 4, 8 or 16).
    #[arg(long, value_delimiter = ',', default_value = "1,2,4,8,16")]
    tiles: Vec<usize>,
    /// Halo of every plan, in voxels.
    #[arg(long, default_value_t = 1)]
    halo: usize,
    /// Also bake the scene single-process with seeds 0 and 1 and compare with the last tiled bake.
    #[arg(long)]
    single: bool,
    /// Working folder (plans and bake folders).
    #[arg(long, default_value = "target/tiles_scaling")]
    work: PathBuf,
    /// Folder for the tables as CSV (tiles_scaling.csv, tiles_vs_single.csv).
    #[arg(long)]
    csv: Option<PathBuf>,
}

/// What `/usr/bin/time -v` measured of one process.
#[derive(Debug, Clone, Copy, Default)]
struct Measured {
    wall: f64,
    cpu: f64,
    peak_rss_mib: f64,
}

/// Runs `prt args...` under `/usr/bin/time -v`; panics with its stderr when it fails.
fn timed(prt: &Path, args: &[&str], log: &Path) -> Measured {
    let out = Command::new("/usr/bin/time")
        .arg("-v")
        .arg("-o")
        .arg(log)
        .arg(prt)
        .args(args)
        .output()
        .expect("/usr/bin/time runs");
    assert!(
        out.status.success(),
        "prt {args:?} failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = std::fs::read_to_string(log).expect("time's log");
    let field = |key: &str| {
        text.lines()
            .find_map(|l| l.trim().strip_prefix(key))
            .map(|v| v.trim().to_string())
            .unwrap_or_else(|| panic!("no {key:?} in {text}"))
    };
    let seconds = |v: String| v.parse::<f64>().expect("seconds");
    // "h:mm:ss" or "m:ss.ss".
    let wall = field("Elapsed (wall clock) time (h:mm:ss or m:ss):")
        .split(':')
        .fold(0.0, |acc, part| {
            acc * 60.0 + part.parse::<f64>().expect("time")
        });
    Measured {
        wall,
        cpu: seconds(field("User time (seconds):")) + seconds(field("System time (seconds):")),
        peak_rss_mib: field("Maximum resident set size (kbytes):")
            .parse::<f64>()
            .expect("kbytes")
            / 1024.0,
    }
}

fn grid(tiles: usize) -> &'static str {
    match tiles {
        1 => "1,1,1",
        2 => "2,1,1",
        4 => "2,2,1",
        8 => "4,2,1",
        16 => "4,4,1",
        other => panic!("{other} tiles: use 1, 2, 4, 8 or 16"),
    }
}

/// Knobs of every bake here.
fn knobs(res: &str) -> Vec<&str> {
    vec!["--res", res, "--no-baselines", "--keep-volumes", "always"]
}

/// `sqrt(Σ‖a − b‖² / Σ‖b‖²)` of two bakes' traced volumes over voxels valid in both.
fn difference(a: &KeptVolumes, b: &KeptVolumes) -> Result<f64, Box<dyn Error>> {
    if a.grid != b.grid {
        return Err(format!("grids differ: {:?} vs {:?}", a.grid, b.grid).into());
    }
    let (fa, fb) = (super::traced(a)?, super::traced(b)?);
    let mut sum = RelativeError::default();
    for v in (0..fa.num_voxels()).filter(|&v| a.valid[v] && b.valid[v]) {
        sum.add(fa.voxel(v), fb.voxel(v));
    }
    Ok(sum.relative_rms())
}

/// The tile of every voxel of the plan's lattice (x fastest).
fn tile_labels(plan: &TilePlan) -> Vec<u32> {
    let [nx, ny, nz] = plan.lattice_dims;
    let mut labels = vec![0u32; nx * ny * nz];
    for tile in &plan.tiles {
        for z in tile.core.min[2]..tile.core.max[2] {
            for y in tile.core.min[1]..tile.core.max[1] {
                for x in tile.core.min[0]..tile.core.max[0] {
                    labels[x + nx * (y + ny * z)] = tile.index as u32;
                }
            }
        }
    }
    labels
}

/// The seam ratios across the plan's tile borders of a bake folder (tiled or not): of its
/// traced volume against itself blurred, and of its MBD container's error, as `prt merge`
/// measures them.
fn border_seams(
    dir: &Path,
    kept: &KeptVolumes,
    labels: &[u32],
) -> Result<(f64, f64), Box<dyn Error>> {
    let field = super::traced(kept)?;
    let options = prt_mbd::SeamOptions {
        denoise_sigma: prt_bake::seams::BLUR_SIGMA,
        valid: Some(&kept.valid),
    };
    let trace = prt_mbd::error_seams(field, field, labels, &options)?;
    let model = super::container(dir)?.model;
    let recon = prt_core::resample_to_grid(&model, field.dims(), field.bounds())?;
    let mbd = prt_mbd::error_seams(field, &recon, labels, &options)?;
    Ok((trace.ratio(), mbd.ratio()))
}

/// MBD's relative MSE (as written) from a bake folder's report.json.
fn mbd_error(dir: &Path) -> Result<f64, Box<dyn Error>> {
    let text = std::fs::read_to_string(BakeFolder::new(dir).report_json())?;
    let report: serde_json::Value = serde_json::from_str(&text)?;
    let rows = report["methods"]
        .as_array()
        .ok_or("report.json has no method rows")?;
    let error = rows
        .iter()
        .find(|r| {
            r["method"]
                .as_str()
                .is_some_and(|m| m.contains("as written"))
        })
        .or(rows.first())
        .and_then(|r| r["relative_mse"].as_f64())
        .ok_or("report.json has no relative_mse")?;
    Ok(error)
}

pub fn run(cli: &Args) -> Result<(), Box<dyn Error>> {
    std::fs::create_dir_all(&cli.work)?;
    let res = cli.res.to_string();
    let scene = cli.scene.to_str().ok_or("--scene: not UTF-8")?;
    let mut table = Table::new(&[
        "tiles",
        "largest tile (voxels traced)",
        "tile wall s (mean / max)",
        "tile CPU s (sum)",
        "tile peak RSS MiB (max)",
        "merge wall s",
        "merge CPU s",
        "merge peak RSS MiB",
        "load avg (1/5/15 min)",
    ]);
    let mut last = None;
    for &tiles in &cli.tiles {
        let plan = cli.work.join(format!("plan-{tiles}"));
        let out = cli.work.join(format!("bake-{tiles}"));
        let _ = std::fs::remove_dir_all(&plan);
        let (plan_s, out_s) = (utf8(&plan)?, utf8(&out)?);
        let halo = cli.halo.to_string();
        let mut args = vec!["plan", scene, "--tiles", grid(tiles), "--halo", &halo];
        args.extend(["--out", plan_s]);
        args.extend(
            knobs(&res)
                .into_iter()
                .filter(|&k| k != "--keep-volumes" && k != "always"),
        );
        let log = cli.work.join("time.log");
        timed(&cli.prt, &args, &log);
        let load = load_average();
        let plan_data = TilePlan::read(&plan, &Limits::default())?;
        let runs: Vec<Measured> = (0..tiles)
            .map(|i| {
                let index = i.to_string();
                timed(&cli.prt, &["bake-tile", plan_s, "--tile", &index], &log)
            })
            .collect();
        let merge = timed(
            &cli.prt,
            &["merge", plan_s, "--out", out_s, "--keep-volumes", "always"],
            &log,
        );
        let largest = plan_data
            .tiles
            .iter()
            .map(|t| t.traced.len())
            .max()
            .unwrap();
        let mean = runs.iter().map(|m| m.wall).sum::<f64>() / tiles as f64;
        let max = runs.iter().map(|m| m.wall).fold(0.0, f64::max);
        table.row(vec![
            format!("{tiles} ({})", grid(tiles).replace(',', "×")),
            largest.to_string(),
            format!("{mean:.1} / {max:.1}"),
            format!("{:.1}", runs.iter().map(|m| m.cpu).sum::<f64>()),
            format!(
                "{:.0}",
                runs.iter().map(|m| m.peak_rss_mib).fold(0.0, f64::max)
            ),
            format!("{:.1}", merge.wall),
            format!("{:.1}", merge.cpu),
            format!("{:.0}", merge.peak_rss_mib),
            load,
        ]);
        println!("{}", table.markdown());
        last = Some(out);
    }
    table.write_csv(cli.csv.as_deref(), "tiles_scaling")?;
    if let (true, Some(tiled)) = (cli.single, last) {
        let mut single = Table::new(&[
            "bake",
            "wall s",
            "CPU s",
            "peak RSS MiB",
            "traced volume vs single seed 0 (relative RMS)",
            "MBD relative MSE (as written)",
            "seam ratio at the tile borders: trace / MBD error",
        ]);
        let mut dirs = Vec::new();
        for seed in ["0", "1"] {
            let out = cli.work.join(format!("single-{seed}"));
            let mut args = vec!["bake", scene, "--out", utf8(&out)?, "--seed", seed];
            args.extend(knobs(&res));
            let m = timed(&cli.prt, &args, &cli.work.join("time.log"));
            dirs.push((format!("single process, seed {seed}"), out, Some(m)));
        }
        let plan = cli.work.join(format!("plan-{}", cli.tiles.last().unwrap()));
        let labels = tile_labels(&TilePlan::read(&plan, &Limits::default())?);
        dirs.push(("tiled (last row above)".into(), tiled, None));
        let reference = super::kept_volumes(&dirs[0].1)?;
        for (name, dir, m) in &dirs {
            let m = m.unwrap_or_default();
            let kept = super::kept_volumes(dir)?;
            let (trace_seam, mbd_seam) = border_seams(dir, &kept, &labels)?;
            single.row(vec![
                name.clone(),
                format!("{:.1}", m.wall),
                format!("{:.1}", m.cpu),
                format!("{:.0}", m.peak_rss_mib),
                format!("{:.4}", difference(&kept, &reference)?),
                format!("{:.4e}", mbd_error(dir)?),
                format!("{trace_seam:.3} / {mbd_seam:.3}"),
            ]);
        }
        println!("{}", single.markdown());
        single.write_csv(cli.csv.as_deref(), "tiles_vs_single")?;
    }
    Ok(())
}

/// A path as the UTF-8 argument `prt` takes.
fn utf8(path: &Path) -> Result<&str, Box<dyn Error>> {
    Ok(path
        .to_str()
        .ok_or_else(|| format!("{}: not UTF-8", path.display()))?)
}
