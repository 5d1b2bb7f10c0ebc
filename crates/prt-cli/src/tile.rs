//! `prt bake-tile`: one worker of a tiled bake (its tile from the argument or the scheduler's
//! index variable), or every unfinished tile as local worker processes (`--all`).

use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::thread::JoinHandle;

use anyhow::{Context, Result, bail};
use prt_bake::tiles::{TileOutcome, TileStatus};
use prt_core::Progress;

use crate::plan::{load_scene, read_plan};
use crate::progress::StageBar;

/// The scheduler variables a worker reads its tile index from, in order.
pub const INDEX_VARIABLES: [&str; 2] = ["JOB_COMPLETION_INDEX", "SLURM_ARRAY_TASK_ID"];

/// Options of `prt bake-tile`.
#[derive(Debug, clap::Args)]
pub struct TileArgs {
    /// Plan folder written by `prt plan` (shared by every worker; tiles go to PLAN_DIR/tiles/I).
    pub plan_dir: PathBuf,
    /// Tile index [default: $JOB_COMPLETION_INDEX (Kubernetes Indexed Job), else
    /// $SLURM_ARRAY_TASK_ID (Slurm job array)].
    #[arg(long, conflicts_with = "all")]
    pub tile: Option<usize>,
    /// Bake every unfinished tile here, as `--workers` processes of this same binary at a time
    /// (the local runner); each worker's output goes to PLAN_DIR/logs/tile-I.log.
    #[arg(long)]
    pub all: bool,
    /// Worker processes at a time with --all; each gets cores / workers threads.
    #[arg(long, default_value_t = 1, requires = "all")]
    pub workers: usize,
    /// Bake the tile again even if it finished (the same seed gives the same bytes).
    #[arg(long)]
    pub force: bool,
    /// Print the tiles not finished for this plan (no done marker, or traced for another plan)
    /// as a Slurm array list like `0-2,5`, an empty line when none, and bake nothing
    /// (deploy/slurm/submit.sh submits these).
    #[arg(long, conflicts_with_all = ["tile", "all", "force"])]
    pub unfinished: bool,
    /// The scene file, when it lives at another path on this machine than in the plan (its
    /// content must hash as the plan's).
    #[arg(long)]
    pub scene: Option<PathBuf>,
}

/// The tile index: the argument, else the first scheduler variable set.
fn tile_index(explicit: Option<usize>, var: impl Fn(&str) -> Option<String>) -> Result<usize> {
    if let Some(index) = explicit {
        return Ok(index);
    }
    for name in INDEX_VARIABLES {
        if let Some(value) = var(name) {
            return value.trim().parse().with_context(|| {
                format!("${name} is {value:?}, not a tile index (a non-negative integer)")
            });
        }
    }
    bail!(
        "no tile index: pass --tile I, or run under a Kubernetes Indexed Job \
         ($JOB_COMPLETION_INDEX) or a Slurm job array ($SLURM_ARRAY_TASK_ID), or use --all"
    )
}

pub fn run(args: &TileArgs) -> Result<()> {
    if args.unfinished {
        let plan = read_plan(&args.plan_dir)?;
        let mut unfinished = Vec::new();
        for i in 0..plan.tiles.len() {
            if prt_bake::tiles::tile_status(&plan, &args.plan_dir, i)? != TileStatus::Done {
                unfinished.push(i);
            }
        }
        println!("{}", index_ranges(&unfinished));
        return Ok(());
    }
    if args.all {
        return run_all(args);
    }
    let index = tile_index(args.tile, |name| std::env::var(name).ok())?;
    let plan = read_plan(&args.plan_dir)?;
    match prt_bake::tiles::tile_status(&plan, &args.plan_dir, index)? {
        TileStatus::Done if !args.force => {
            println!("tile {index}: already done (--force bakes it again)");
            return Ok(());
        }
        TileStatus::Stale(differences) => println!(
            "tile {index}: its files were traced for another plan ({}; tile → plan): tracing it \
             again",
            differences.join("; ")
        ),
        _ => {}
    }
    let scene = load_scene(&plan, args.scene.as_deref())?;
    let stage = StageBar::start("trace");
    let outcome =
        prt_bake::tiles::bake_tile(&plan, &args.plan_dir, &scene, index, args.force, &stage)?;
    stage.finish();
    match outcome {
        TileOutcome::Skipped => println!("tile {index}: already done"),
        TileOutcome::Baked {
            stats,
            trace,
            write,
            ..
        } => println!(
            "tile {index}: {} voxels ({} inside geometry), {:.2e} rays, traced in {:.2} s, \
             written in {:.2} s to {}",
            stats.voxels,
            stats.invalid_voxels,
            stats.rays() as f64,
            trace.as_secs_f64(),
            write.as_secs_f64(),
            prt_bake::tiles::tile_dir(&args.plan_dir, index).display()
        ),
    }
    Ok(())
}

/// Increasing indices as a Slurm `--array` list: runs of consecutive indices as `FIRST-LAST`,
/// joined by commas (`0-2,5`).
fn index_ranges(indices: &[usize]) -> String {
    let mut runs: Vec<(usize, usize)> = Vec::new();
    for &i in indices {
        match runs.last_mut() {
            Some((_, last)) if *last + 1 == i => *last = i,
            _ => runs.push((i, i)),
        }
    }
    let text: Vec<String> = runs
        .iter()
        .map(|&(first, last)| {
            if first == last {
                first.to_string()
            } else {
                format!("{first}-{last}")
            }
        })
        .collect();
    text.join(",")
}

/// Runs one worker process (this binary) for tile `index` on a thread, and writes its output
/// to `log` (atomically) when it ends; the thread returns whether it succeeded.
fn launch(
    args: &TileArgs,
    index: usize,
    threads: usize,
    log: PathBuf,
) -> Result<JoinHandle<Result<bool>>> {
    let exe = std::env::current_exe().context("cannot locate the prt binary")?;
    let mut command = Command::new(exe);
    command
        .arg("bake-tile")
        .arg(&args.plan_dir)
        .args(["--tile", &index.to_string()])
        .env("RAYON_NUM_THREADS", threads.to_string())
        // The worker's index comes from --tile, never from a scheduler variable of this shell.
        .env_remove(INDEX_VARIABLES[0])
        .env_remove(INDEX_VARIABLES[1])
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    if args.force {
        command.arg("--force");
    }
    if let Some(scene) = &args.scene {
        command.arg("--scene").arg(scene);
    }
    let child = command
        .spawn()
        .with_context(|| format!("cannot launch the worker of tile {index}"))?;
    Ok(std::thread::spawn(move || {
        let out = child.wait_with_output().context("waiting for a worker")?;
        let text = [out.stdout, out.stderr].concat();
        prt_texture::write_atomic(&log, &text)
            .with_context(|| format!("cannot write the worker log {}", log.display()))?;
        Ok(out.status.success())
    }))
}

/// The local runner: every unfinished tile (all with --force) as worker processes, `workers`
/// at a time.
fn run_all(args: &TileArgs) -> Result<()> {
    if args.workers == 0 {
        bail!("--workers must be at least 1");
    }
    let plan = read_plan(&args.plan_dir)?;
    let mut stale = 0;
    let mut todo = Vec::new();
    for i in 0..plan.tiles.len() {
        match prt_bake::tiles::tile_status(&plan, &args.plan_dir, i)? {
            TileStatus::Done if !args.force => {}
            TileStatus::Stale(_) => {
                stale += 1;
                todo.push(i);
            }
            _ => todo.push(i),
        }
    }
    let logs = args.plan_dir.join("logs");
    std::fs::create_dir_all(&logs).with_context(|| format!("cannot create {}", logs.display()))?;
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let threads = (cores / args.workers).max(1);
    println!(
        "{} of {} tiles to bake{}, {} workers of {threads} threads",
        todo.len(),
        plan.tiles.len(),
        if stale > 0 {
            format!(" ({stale} traced for another plan: traced again)")
        } else {
            String::new()
        },
        args.workers
    );
    let stage = StageBar::start("tiles");
    stage.set_len(todo.len() as u64);
    let mut pending = todo.into_iter();
    let mut running: Vec<(usize, JoinHandle<Result<bool>>)> = Vec::new();
    let mut failed = Vec::new();
    loop {
        while running.len() < args.workers
            && let Some(index) = pending.next()
        {
            let log = logs.join(format!("tile-{index}.log"));
            running.push((index, launch(args, index, threads, log)?));
        }
        if running.is_empty() {
            break;
        }
        let (done, still): (Vec<_>, Vec<_>) =
            running.into_iter().partition(|(_, w)| w.is_finished());
        running = still;
        for (index, worker) in done {
            let ok = worker
                .join()
                .map_err(|_| anyhow::anyhow!("the thread watching tile {index} panicked"))??;
            if !ok {
                failed.push(index);
            }
            stage.inc(1);
        }
        // Ctrl-C reaches the workers too (one process group): they cancel, and end.
        if stage.is_cancelled() && running.is_empty() {
            bail!("cancelled; finished tiles are kept, rerun to bake the others");
        }
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
    stage.finish();
    if !failed.is_empty() {
        bail!(
            "the workers of tiles {failed:?} failed; see {}/tile-I.log",
            logs.display()
        );
    }
    println!(
        "all {} tiles done; next: prt merge {} --out BAKE_DIR",
        plan.tiles.len(),
        args.plan_dir.display()
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn from(vars: &[(&str, &str)]) -> impl Fn(&str) -> Option<String> {
        let vars: Vec<(String, String)> = vars
            .iter()
            .map(|(k, v)| (k.to_string(), v.to_string()))
            .collect();
        move |name| vars.iter().find(|(k, _)| k == name).map(|(_, v)| v.clone())
    }

    #[test]
    fn unfinished_tiles_print_as_a_slurm_array_list() {
        assert_eq!(index_ranges(&[]), "");
        assert_eq!(index_ranges(&[4]), "4");
        assert_eq!(index_ranges(&[0, 1, 2, 5, 7, 8]), "0-2,5,7-8");
    }

    #[test]
    fn the_index_comes_from_the_argument_then_kubernetes_then_slurm() {
        let both = from(&[("JOB_COMPLETION_INDEX", "3"), ("SLURM_ARRAY_TASK_ID", "5")]);
        assert_eq!(tile_index(Some(1), &both).unwrap(), 1);
        assert_eq!(tile_index(None, &both).unwrap(), 3);
        assert_eq!(
            tile_index(None, from(&[("SLURM_ARRAY_TASK_ID", "5")])).unwrap(),
            5
        );
        let none = tile_index(None, from(&[])).unwrap_err().to_string();
        assert!(none.contains("--tile"), "{none}");
        let bad = tile_index(None, from(&[("SLURM_ARRAY_TASK_ID", "x")]))
            .unwrap_err()
            .to_string();
        assert!(bad.contains("SLURM_ARRAY_TASK_ID"), "{bad}");
    }
}
