//! deploy/slurm end to end on a real one-node Slurm cluster: Debian's munged, slurmctld and
//! slurmd started from a temp folder configured by deploy/slurm/local-cluster.sh (their own
//! munge key, slurm.conf, free ports, state and spool folders), stopped by PID when the test
//! ends however it ends. A 2×2×1 Cornell plan goes
//! through `submit.sh` with a merge flag and sbatch options, one tile fails (its folder is a
//! file), the merge runs after the array anyway and names the tile, `submit.sh --resume`
//! submits that tile and the merge again, and the bake folder is the bytes of a local
//! `bake-tile --all` + `merge`. Then `submit.sh --distributed-merge` on another plan: the
//! streamed merge as chained map arrays and reduces, to the bytes of `prt merge --stream`.
//!
//! Ignored when the programs or root are missing at build time (build.rs), unless
//! `PRT_REQUIRE_SLURM=1` (set by .ci/run, which installs slurm-wlm and munge).

mod common;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use common::{TINY_PLAN, deploy, files, ok, prt, scratch, stderr};

/// How long the cluster may take to start, and a submission to leave the queue.
const START_TIMEOUT: Duration = Duration::from_secs(60);
const QUEUE_TIMEOUT: Duration = Duration::from_secs(180);

/// A program of Slurm or munge: on PATH, else in sbin (which a user's PATH may lack).
fn program(name: &str) -> PathBuf {
    let path = std::env::var_os("PATH").unwrap_or_default();
    std::env::split_paths(&path)
        .chain(["/usr/sbin", "/usr/local/sbin"].map(PathBuf::from))
        .map(|dir| dir.join(name))
        .find(|candidate| candidate.is_file())
        .unwrap_or_else(|| {
            panic!(
                "{name} not found (apt-get install slurm-wlm munge; the test runs because \
                 PRT_REQUIRE_SLURM=1 or because it was there at build time)"
            )
        })
}

/// A one-node cluster whose daemons run in the foreground as this process's children; dropping
/// it cancels its jobs and stops them by PID (SIGTERM, then SIGKILL after 10 s).
struct Cluster {
    dir: PathBuf,
    conf: PathBuf,
    /// (name, daemon), stopped in reverse order.
    daemons: Vec<(&'static str, Child)>,
}

impl Cluster {
    /// Configures `dir` with deploy/slurm/local-cluster.sh (`conf`: slurm.conf on two free
    /// ports, a fresh munge key) and starts its three daemons as children (`run`, which execs
    /// each in the foreground, so a child's PID is the daemon's).
    fn start(dir: &Path) -> Cluster {
        let dir = dir.to_path_buf();
        let script = deploy("slurm/local-cluster.sh");
        let out = Command::new("bash")
            .arg(&script)
            .arg("conf")
            .arg(&dir)
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "local-cluster.sh conf: {}",
            stderr(&out)
        );
        let mut cluster = Cluster {
            dir: dir.clone(),
            conf: dir.join("slurm.conf"),
            daemons: Vec::new(),
        };
        let deadline = Instant::now() + START_TIMEOUT;
        for name in ["munged", "slurmctld", "slurmd"] {
            cluster.spawn(
                name,
                Command::new("bash")
                    .arg(&script)
                    .arg("run")
                    .arg(&dir)
                    .arg(name),
            );
            // slurmctld and slurmd authenticate through munged's socket.
            while name == "munged" && !dir.join("munge/munge.socket").exists() {
                assert!(Instant::now() < deadline, "munged did not start");
                cluster.check_alive();
                std::thread::sleep(Duration::from_millis(50));
            }
        }
        // Up once the node reports idle.
        loop {
            cluster.check_alive();
            let state = cluster
                .client("sinfo")
                .args(["-h", "-N", "-o", "%T"])
                .output();
            if state.is_ok_and(|o| String::from_utf8_lossy(&o.stdout).trim() == "idle") {
                break;
            }
            assert!(
                Instant::now() < deadline,
                "the node did not become idle\n{}",
                cluster.logs()
            );
            std::thread::sleep(Duration::from_millis(250));
        }
        cluster
    }

    /// Starts a daemon in the foreground, its output in the log folder.
    fn spawn(&mut self, name: &'static str, command: &mut Command) {
        let log = |suffix: &str| {
            std::fs::File::create(self.dir.join("log").join(format!("{name}.{suffix}"))).unwrap()
        };
        let child = command
            .stdin(Stdio::null())
            .stdout(log("out"))
            .stderr(log("err"))
            .spawn()
            .unwrap_or_else(|e| panic!("cannot start {name}: {e}"));
        self.daemons.push((name, child));
    }

    /// A Slurm client command of this cluster.
    fn client(&self, name: &str) -> Command {
        let mut command = Command::new(program(name));
        self.environment(&mut command);
        command
    }

    /// Points `command` at this cluster, without any Slurm variable of an outer one.
    fn environment(&self, command: &mut Command) {
        for (key, _) in std::env::vars_os() {
            let key = key.to_string_lossy();
            if key.starts_with("SLURM_") || key.starts_with("SBATCH_") {
                command.env_remove(&*key);
            }
        }
        command.env("SLURM_CONF", &self.conf);
    }

    /// Panics, with the logs, when a daemon has exited.
    fn check_alive(&mut self) {
        for (name, child) in &mut self.daemons {
            if let Some(status) = child.try_wait().unwrap() {
                panic!("{name} exited ({status})\n{}", logs_of(&self.dir));
            }
        }
    }

    fn logs(&self) -> String {
        logs_of(&self.dir)
    }

    /// Waits until no job of the cluster is queued or running.
    fn wait_for_empty_queue(&mut self) {
        let deadline = Instant::now() + QUEUE_TIMEOUT;
        loop {
            self.check_alive();
            let out = self
                .client("squeue")
                .args(["-h", "-o", "%i %T %r"])
                .output();
            let out = out.unwrap();
            assert!(out.status.success(), "squeue: {}", stderr(&out));
            let queue = String::from_utf8_lossy(&out.stdout).into_owned();
            if queue.trim().is_empty() {
                return;
            }
            // What an `afterok` merge does after a failed tile: pend forever.
            assert!(
                !queue.contains("DependencyNeverSatisfied"),
                "a job waits on a dependency that can never be satisfied:\n{queue}"
            );
            assert!(
                Instant::now() < deadline,
                "jobs still queued after {QUEUE_TIMEOUT:?}:\n{queue}\n{}",
                self.logs()
            );
            std::thread::sleep(Duration::from_millis(500));
        }
    }

    /// `scontrol show job ID`'s fields, per job (an array job's tasks are one record each).
    fn jobs(&self, id: &str) -> Vec<BTreeMap<String, String>> {
        let out = self
            .client("scontrol")
            .args(["show", "job", id, "--oneliner"])
            .output()
            .unwrap();
        assert!(out.status.success(), "scontrol: {}", stderr(&out));
        String::from_utf8_lossy(&out.stdout)
            .lines()
            .filter(|l| !l.trim().is_empty())
            .map(|line| {
                line.split_whitespace()
                    .filter_map(|field| field.split_once('='))
                    .map(|(k, v)| (k.to_string(), v.to_string()))
                    .collect()
            })
            .collect()
    }
}

/// The daemons' logs, for a failure's message.
fn logs_of(dir: &Path) -> String {
    let mut text = String::new();
    for sub in ["log", "munge"] {
        let Ok(entries) = std::fs::read_dir(dir.join(sub)) else {
            continue;
        };
        for entry in entries.flatten() {
            let path = entry.path();
            if path.extension().is_some_and(|e| e == "log" || e == "err") {
                let content = std::fs::read_to_string(&path).unwrap_or_default();
                let tail: Vec<&str> = content.lines().rev().take(30).collect();
                text += &format!("--- {} (last lines)\n", path.display());
                for line in tail.iter().rev() {
                    text += line;
                    text.push('\n');
                }
            }
        }
    }
    text
}

impl Drop for Cluster {
    fn drop(&mut self) {
        // Jobs first, so that no job step outlives slurmd.
        let _ = self.client("scancel").arg("--user=root").output();
        for (name, child) in self.daemons.iter_mut().rev() {
            if child.try_wait().is_ok_and(|s| s.is_some()) {
                continue;
            }
            let _ = Command::new("kill")
                .args(["-TERM", &child.id().to_string()])
                .output();
            let deadline = Instant::now() + Duration::from_secs(10);
            while child.try_wait().is_ok_and(|s| s.is_none()) && Instant::now() < deadline {
                std::thread::sleep(Duration::from_millis(50));
            }
            if child.try_wait().is_ok_and(|s| s.is_none()) {
                eprintln!("{name} ignored SIGTERM: killed");
                let _ = child.kill();
                let _ = child.wait();
            }
        }
        if std::thread::panicking() {
            eprintln!("the cluster's folder is kept: {}", self.dir.display());
        } else {
            let _ = std::fs::remove_dir_all(&self.dir);
        }
    }
}

/// Runs deploy/slurm/submit.sh with `args` against `cluster`, with the test's prt first on
/// PATH (the jobs inherit it), and returns its stdout; requires success.
fn submit(cluster: &Cluster, args: &[&str]) -> String {
    let out = submit_command(cluster, args).output().unwrap();
    assert!(
        out.status.success(),
        "submit.sh {args:?}: {}{}",
        String::from_utf8_lossy(&out.stdout),
        stderr(&out)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

fn submit_command(cluster: &Cluster, args: &[&str]) -> Command {
    let script = deploy("slurm/submit.sh");
    let prt_dir = Path::new(env!("CARGO_BIN_EXE_prt")).parent().unwrap();
    let path = std::env::var_os("PATH").unwrap_or_default();
    let path = std::env::join_paths(
        std::iter::once(prt_dir.to_path_buf()).chain(std::env::split_paths(&path)),
    )
    .unwrap();
    let mut command = Command::new("bash");
    command
        .arg(script)
        .args(args)
        .env("PATH", path)
        // A tile's index must come from the array, never from an outer Indexed Job.
        .env_remove("JOB_COMPLETION_INDEX");
    cluster.environment(&mut command);
    command
}

/// The job id a submit.sh output line `WHAT...: job ID` names.
fn job_id(output: &str, what: &str) -> String {
    output
        .lines()
        .find(|l| l.starts_with(what))
        .and_then(|l| l.split("job ").nth(1))
        .and_then(|rest| rest.split_whitespace().next())
        .unwrap_or_else(|| panic!("no {what:?} job in {output}"))
        .to_string()
}

/// The state of each task of array job `id`, by task index.
fn task_states(cluster: &Cluster, id: &str) -> BTreeMap<usize, String> {
    cluster
        .jobs(id)
        .into_iter()
        .map(|job| (job["ArrayTaskId"].parse().unwrap(), job["JobState"].clone()))
        .collect()
}

#[test]
#[cfg_attr(
    prt_skip_slurm,
    ignore = "needs munged, slurmctld, slurmd and Slurm's clients (apt-get install slurm-wlm \
              munge) and root, absent at build time (PRT_REQUIRE_SLURM=1 requires them)"
)]
fn deploy_slurm_bakes_resumes_a_failed_tile_and_matches_a_local_bake_byte_for_byte() {
    let dir = scratch("slurm");
    let mut cluster = Cluster::start(&dir.join("cluster"));
    let plan_for = |name: &str| {
        let plan = dir.join(name);
        let mut args = vec!["plan", "--tiles", "2,2,1", "--halo", "1", "--out"];
        args.push(plan.to_str().unwrap());
        args.extend(TINY_PLAN);
        ok(&prt(&args));
        plan
    };

    // The local run: every tile as worker processes here, then the merge.
    let local_plan = plan_for("local-plan");
    let local = dir.join("local");
    ok(&prt(&[
        "bake-tile",
        local_plan.to_str().unwrap(),
        "--all",
        "--workers",
        "2",
    ]));
    ok(&prt(&[
        "merge",
        local_plan.to_str().unwrap(),
        "--out",
        local.to_str().unwrap(),
        "--keep-volumes",
        "never",
    ]));

    // The same plan through Slurm, with tile 1's folder a file: its task fails writing.
    let plan = plan_for("slurm-plan");
    let (plan_s, baked) = (plan.to_str().unwrap(), dir.join("slurm-bake"));
    std::fs::create_dir_all(plan.join("tiles")).unwrap();
    std::fs::write(prt_bake::tiles::tile_dir(&plan, 1), b"not a folder").unwrap();
    let first = submit(
        &cluster,
        &[
            plan_s,
            baked.to_str().unwrap(),
            "--keep-volumes",
            "never",
            "--",
            "--time=5",
            "--merge",
            "--time=7",
        ],
    );
    let (tiles, merge) = (job_id(&first, "tiles 0-3"), job_id(&first, "merge"));
    // A second submission while the first is queued is refused (the merge waits for four tiles
    // traced one after another: it cannot have ended yet).
    let again = submit_command(&cluster, &["--resume", plan_s])
        .output()
        .unwrap();
    assert!(
        !again.status.success(),
        "a resume while jobs run was accepted"
    );
    assert!(
        stderr(&again).contains("still queued or running"),
        "{}",
        stderr(&again)
    );
    cluster.wait_for_empty_queue();

    let logs = |name: &str| std::fs::read_to_string(plan.join("logs").join(name)).unwrap();
    let states = task_states(&cluster, &tiles);
    let expected: BTreeMap<usize, String> = [
        (0, "COMPLETED"),
        (1, "FAILED"),
        (2, "COMPLETED"),
        (3, "COMPLETED"),
    ]
    .map(|(i, s)| (i, s.to_string()))
    .into();
    assert_eq!(states, expected, "{}", logs("slurm-tile-1.log"));
    // The options went through: the time limits; the CPUs: the node's, at most 8.
    let cpus = std::thread::available_parallelism().unwrap().get();
    let node_cpus: usize = cluster.jobs(&tiles)[0]["NumCPUs"].parse().unwrap();
    for job in cluster.jobs(&tiles) {
        assert_eq!(job["TimeLimit"], "00:05:00");
        assert_eq!(
            job["CPUs/Task"],
            node_cpus.min(8).to_string(),
            "{cpus} CPUs here"
        );
    }
    // The merge ran after the failed array (afterany) instead of pending forever, and failed
    // naming the tile.
    let merge_job = &cluster.jobs(&merge)[0];
    assert_eq!(merge_job["TimeLimit"], "00:07:00");
    assert_eq!(merge_job["JobState"], "FAILED");
    assert!(
        logs("slurm-merge.log").contains("tile 1 has not finished"),
        "{}",
        logs("slurm-merge.log")
    );
    assert!(!baked.join("mbd").exists());

    // The recovery: the tile's folder mended, --resume submits tile 1 and the merge.
    std::fs::remove_file(prt_bake::tiles::tile_dir(&plan, 1)).unwrap();
    let second = submit(&cluster, &["--resume", plan_s]);
    let (tiles, merge) = (job_id(&second, "tiles 1"), job_id(&second, "merge"));
    cluster.wait_for_empty_queue();
    assert_eq!(
        task_states(&cluster, &tiles),
        BTreeMap::from([(1, "COMPLETED".to_string())])
    );
    let merge_job = &cluster.jobs(&merge)[0];
    assert_eq!(
        merge_job["JobState"],
        "COMPLETED",
        "{}",
        logs("slurm-merge.log")
    );
    // The saved options came back with --resume.
    assert_eq!(merge_job["TimeLimit"], "00:07:00");
    // Logs are appended, one header per attempt.
    assert_eq!(
        logs("slurm-tile-1.log").matches("=== prt-tile 1:").count(),
        2
    );
    assert_eq!(
        logs("slurm-tile-0.log").matches("=== prt-tile 0:").count(),
        1
    );
    assert_eq!(logs("slurm-merge.log").matches("=== prt-merge:").count(), 2);

    // Every tile and every file of the bake folder is the local run's bytes, but the reports
    // (they hold timings).
    for i in 0..4 {
        for file in ["transfer.f32", "valid.u8", "tile.json"] {
            let read =
                |p: &Path| std::fs::read(prt_bake::tiles::tile_dir(p, i).join(file)).unwrap();
            assert!(read(&plan) == read(&local_plan), "tile {i}: {file} differs");
        }
    }
    let listed = files(&local);
    // The merge flag went through: no kept volumes.
    assert_eq!(files(&baked), listed);
    assert!(!listed.iter().any(|f| f.starts_with("volumes")));
    let mut compared = 0;
    for file in &listed {
        if ["report.md", "report.json"].contains(&file.to_str().unwrap()) {
            continue;
        }
        assert!(
            std::fs::read(baked.join(file)).unwrap() == std::fs::read(local.join(file)).unwrap(),
            "{} differs",
            file.display()
        );
        compared += 1;
    }
    assert!(compared >= 5 && listed.iter().any(|f| f.starts_with("mbd")));

    distributed_merge(&mut cluster, &dir);

    drop(cluster);
}

/// `submit.sh --distributed-merge` on finished tiles: per stage an array of map tasks and a
/// reduce, chained; every job completes and the bake folder is the bytes of
/// `prt merge --stream` run here (tiles.json aside: it holds timings).
fn distributed_merge(cluster: &mut Cluster, dir: &Path) {
    let plan = dir.join("stream-plan");
    let plan_s = plan.to_str().unwrap();
    let mut args = vec![
        "plan",
        "--tiles",
        "2,2,1",
        "--halo",
        "1",
        "--basis-nodes",
        "3",
        "--out",
        plan_s,
    ];
    args.extend(TINY_PLAN);
    ok(&prt(&args));
    ok(&prt(&["bake-tile", plan_s, "--all", "--workers", "2"]));
    let local = dir.join("stream-local");
    let local_s = local.to_str().unwrap();
    ok(&prt(&[
        "merge", plan_s, "--out", local_s, "--stream", "--sweeps", "1",
    ]));

    let baked = dir.join("stream-slurm");
    let out = submit(
        cluster,
        &[
            plan_s,
            baked.to_str().unwrap(),
            "--distributed-merge",
            "--sweeps",
            "1",
            "--",
            "--time=5",
        ],
    );
    assert!(out.contains("every tile is finished"), "{out}");
    // coarse, sweep-1, coefficients: "STAGE: maps job M, reduce job R".
    let jobs: Vec<(String, String)> = out
        .lines()
        .filter_map(|line| {
            let (_, ids) = line.split_once(": maps job ")?;
            let (maps, reduce) = ids.split_once(", reduce job ")?;
            Some((maps.to_string(), reduce.to_string()))
        })
        .collect();
    assert_eq!(jobs.len(), 3, "{out}");
    assert_eq!(job_id(&out, "merge"), jobs[2].1);
    cluster.wait_for_empty_queue();
    let log =
        |name: &str| std::fs::read_to_string(plan.join("logs").join(name)).unwrap_or_default();
    for (stage, (maps, reduce)) in ["coarse", "sweep-1", "coefficients"].iter().zip(&jobs) {
        let states = task_states(cluster, maps);
        assert_eq!(states.len(), 4);
        assert!(
            states.values().all(|s| s == "COMPLETED"),
            "{stage} maps: {states:?}\n{}",
            log(&format!("slurm-map-{stage}-0.log"))
        );
        assert_eq!(
            cluster.jobs(reduce)[0]["JobState"],
            "COMPLETED",
            "{}",
            log(&format!("slurm-reduce-{stage}.log"))
        );
        assert!(prt_bake::tiles::partial_path(&plan, stage.parse().unwrap(), 3).is_file());
    }
    let listed = files(&local);
    assert_eq!(files(&baked), listed);
    assert!(listed.iter().any(|f| f.starts_with("mbd")));
    for file in &listed {
        let (a, b) = (
            std::fs::read(local.join(file)).unwrap(),
            std::fs::read(baked.join(file)).unwrap(),
        );
        if file.to_str() == Some("tiles.json") {
            let errors = |bytes: &[u8]| {
                let report: prt_bake::tiles::TilesReport = serde_json::from_slice(bytes).unwrap();
                report
                    .streamed
                    .unwrap()
                    .relative_error_at_valid_voxel_centres
            };
            assert_eq!(errors(&a), errors(&b));
            continue;
        }
        assert!(a == b, "{} differs", file.display());
    }
}
