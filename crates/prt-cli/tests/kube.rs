//! deploy/kubernetes/prt-bake-indexed-job.yaml: validated against the Kubernetes API's schemas
//! (kubernetes-validate, a PyPI package that bundles them), and its flow run here as a
//! Kubernetes controller would run it: the manifest's own container scripts as processes (the
//! shared volume's `/bake` a temp folder), the Indexed Job's indices `parallelism` at a time with
//! `$JOB_COMPLETION_INDEX`, a failed index retried alone up to `backoffLimitPerIndex` times, the
//! Job failing past `maxFailedIndexes`, and the merge's init container waiting for every tile.
//!
//! Both need python3 with PyYAML (the manifest is YAML; no YAML crate in the workspace), the
//! first also kubernetes-validate; without them they print why and return, unless
//! `PRT_REQUIRE_YAML=1` / `PRT_REQUIRE_KUBE_VALIDATE=1` (set by .ci/run, which installs both).

mod common;

use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use common::{TINY_PLAN, deploy, files, kubernetes_manifest, ok, prt, required, scratch, stderr};
use serde_json::Value;

/// Kubernetes versions the manifest is validated against: the first with
/// `backoffLimitPerIndex` generally available (1.33), and the newest the validator bundles.
const KUBERNETES_VERSIONS: [Option<&str>; 2] = [Some("1.33"), None];

/// How long the whole flow may take.
const TIMEOUT: Duration = Duration::from_secs(120);

#[test]
fn the_manifest_is_valid_against_the_kubernetes_api_schemas() {
    for version in KUBERNETES_VERSIONS {
        let mut command = Command::new("python3");
        command.args(["-m", "kubernetes_validate", "--strict", "--quiet"]);
        if let Some(version) = version {
            command.args(["-k", version]);
        }
        let out = match command
            .arg(deploy("kubernetes/prt-bake-indexed-job.yaml"))
            .output()
        {
            Ok(out) => out,
            Err(e) => {
                assert!(
                    !required("PRT_REQUIRE_KUBE_VALIDATE"),
                    "PRT_REQUIRE_KUBE_VALIDATE=1 but python3 cannot run: {e}"
                );
                eprintln!("skipped: python3 not available ({e})");
                return;
            }
        };
        if stderr(&out).contains("No module named kubernetes_validate") {
            assert!(
                !required("PRT_REQUIRE_KUBE_VALIDATE"),
                "PRT_REQUIRE_KUBE_VALIDATE=1 but python3 has no kubernetes_validate \
                 (pip install kubernetes-validate)"
            );
            eprintln!(
                "skipped: kubernetes-validate not available (pip install kubernetes-validate)"
            );
            return;
        }
        assert!(
            out.status.success(),
            "kubernetes-validate -k {version:?}: {}{}",
            String::from_utf8_lossy(&out.stdout),
            stderr(&out)
        );
    }
}

/// The shell script a container runs: `command: [sh, -c, SCRIPT]` or `command: [sh, -c]` with
/// `args: [SCRIPT]`.
fn script(container: &Value) -> String {
    let words: Vec<&str> = container["command"]
        .as_array()
        .into_iter()
        .chain(container["args"].as_array())
        .flatten()
        .map(|w| w.as_str().unwrap())
        .collect();
    assert_eq!(words[..2], ["sh", "-c"], "{container}");
    assert_eq!(words.len(), 3, "{container}");
    words[2].to_string()
}

/// A Job's pod: the scripts of its init containers and then of its one container, every volume
/// mounted at /bake.
struct PodTemplate {
    init: Vec<String>,
    main: String,
}

impl PodTemplate {
    fn of(job: &Value) -> PodTemplate {
        let spec = &job["spec"]["template"]["spec"];
        assert_eq!(spec["restartPolicy"], "Never");
        let containers = spec["containers"].as_array().unwrap();
        assert_eq!(containers.len(), 1);
        let init = spec["initContainers"]
            .as_array()
            .cloned()
            .unwrap_or_default();
        for container in init.iter().chain(containers) {
            let mounts = container["volumeMounts"].as_array().unwrap();
            assert!(
                mounts.iter().all(|m| m["mountPath"] == "/bake"),
                "{container}"
            );
        }
        PodTemplate {
            init: init.iter().map(script).collect(),
            main: script(&containers[0]),
        }
    }
}

/// Where the pods run: the shared volume's folder, PATH with the test's prt, the pods' logs.
struct Node {
    volume: PathBuf,
    logs: PathBuf,
    path: std::ffi::OsString,
}

impl Node {
    /// `script` with the volume mounted at /bake here, and `sleep N` a tenth of a second (the
    /// simulation's clock runs faster; the scripts only sleep to poll).
    fn local(&self, script: &str) -> String {
        let script = script.replace("/bake", self.volume.to_str().unwrap());
        let mut out = String::new();
        let mut rest = script.as_str();
        while let Some(at) = rest.find("sleep ") {
            out += &rest[..at];
            let after = &rest[at + "sleep ".len()..];
            let digits = after.len() - after.trim_start_matches(|c: char| c.is_ascii_digit()).len();
            out += "sleep 0.1";
            rest = &after[digits..];
        }
        out + rest
    }

    /// Starts a pod: its init containers one after another, then its container, as one
    /// process group (so that evicting it kills every process in it).
    fn start(&self, name: &str, pod: &PodTemplate, index: Option<usize>) -> Pod {
        // sh -c 'sh -c "$1" && sh -c "$2" && exec sh -c "$3"' pod INIT... MAIN
        let scripts: Vec<String> = pod
            .init
            .iter()
            .chain(std::iter::once(&pod.main))
            .map(|s| self.local(s))
            .collect();
        let chain: Vec<String> = (1..=scripts.len())
            .map(|i| format!("sh -c \"${i}\""))
            .collect();
        let log = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(self.logs.join(format!("{name}.log")))
            .unwrap();
        let mut command = Command::new("sh");
        command
            .arg("-c")
            .arg(chain.join(" && "))
            .arg(name)
            .args(&scripts)
            .env("PATH", &self.path)
            .env_remove("JOB_COMPLETION_INDEX")
            .env_remove("SLURM_ARRAY_TASK_ID")
            .stdin(Stdio::null())
            .stdout(log.try_clone().unwrap())
            .stderr(log)
            .process_group(0);
        if let Some(index) = index {
            command.env("JOB_COMPLETION_INDEX", index.to_string());
        }
        Pod(command.spawn().unwrap())
    }
}

/// A running pod: a process group, killed when dropped (a failing test leaves no init
/// container polling forever).
struct Pod(Child);

impl Pod {
    /// Kills the pod's whole process group and reaps it.
    fn evict(&mut self) {
        if self.0.try_wait().is_ok_and(|s| s.is_none()) {
            let _ = Command::new("kill")
                .args(["-KILL", "--", &format!("-{}", self.0.id())])
                .output();
        }
        let _ = self.0.wait();
    }

    fn try_wait(&mut self) -> Option<std::process::ExitStatus> {
        self.0.try_wait().unwrap()
    }
}

impl Drop for Pod {
    fn drop(&mut self) {
        self.evict();
    }
}

/// What the Indexed Job controller did: attempts per index, the failed indexes, the outcome.
#[derive(Debug, Default)]
struct IndexedRun {
    attempts: BTreeMap<usize, usize>,
    failed_indexes: BTreeSet<usize>,
    complete: bool,
    most_at_once: usize,
}

/// Runs an Indexed Job: indices `0..completions`, `parallelism` pods at a time, each with
/// `$JOB_COMPLETION_INDEX`; a pod that fails is retried for its index alone until the index has
/// failed `backoffLimitPerIndex + 1` times, then the index is failed; more than
/// `maxFailedIndexes` failed indexes end the Job (its pods killed); otherwise every index runs
/// and the Job is complete when none failed. `evicted(index, attempt)` kills that pod as it
/// starts (a pod lost with its node).
fn run_indexed_job(node: &Node, job: &Value, evicted: impl Fn(usize, usize) -> bool) -> IndexedRun {
    let spec = &job["spec"];
    assert_eq!(spec["completionMode"], "Indexed");
    let count = |key: &str| spec[key].as_u64().unwrap() as usize;
    let (completions, parallelism) = (count("completions"), count("parallelism"));
    let (per_index, max_failed) = (count("backoffLimitPerIndex"), count("maxFailedIndexes"));
    let template = PodTemplate::of(job);
    let mut run = IndexedRun::default();
    let mut failures: BTreeMap<usize, usize> = BTreeMap::new();
    let mut pending: VecDeque<usize> = (0..completions).collect();
    let mut running: Vec<(usize, Pod)> = Vec::new();
    let deadline = Instant::now() + TIMEOUT;
    while !pending.is_empty() || !running.is_empty() {
        assert!(
            Instant::now() < deadline,
            "the Indexed Job did not end: {run:?}"
        );
        while running.len() < parallelism
            && let Some(index) = pending.pop_front()
        {
            let attempt = run.attempts.entry(index).or_default();
            *attempt += 1;
            let mut pod = node.start(&format!("tile-{index}"), &template, Some(index));
            if evicted(index, *attempt) {
                pod.evict();
            }
            running.push((index, pod));
        }
        run.most_at_once = run.most_at_once.max(running.len());
        let mut still = Vec::new();
        for (index, mut pod) in running.drain(..) {
            match pod.try_wait() {
                None => still.push((index, pod)),
                Some(status) if status.success() => {}
                Some(_) => {
                    let failed = failures.entry(index).or_default();
                    *failed += 1;
                    if *failed > per_index {
                        run.failed_indexes.insert(index);
                    } else {
                        pending.push_back(index);
                    }
                }
            }
        }
        running = still;
        if run.failed_indexes.len() > max_failed {
            // Dropping the running pods kills them.
            return run;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    run.complete = run.failed_indexes.is_empty();
    run
}

#[test]
fn the_indexed_job_flow_retries_per_index_and_the_merge_waits_for_every_tile() {
    let Some(documents) = kubernetes_manifest() else {
        return;
    };
    let job = |name: &str| {
        documents
            .iter()
            .find(|d| d["kind"] == "Job" && d["metadata"]["name"] == name)
            .unwrap_or_else(|| panic!("no Job {name}"))
            .clone()
    };
    let (plan_job, tiles_job, merge_job) = (
        job("prt-bake-plan"),
        job("prt-bake-tiles"),
        job("prt-bake-merge"),
    );

    // The plan Job's command: its --tiles must make as many tiles as the Indexed Job's
    // completions. The simulation plans the built-in Cornell box with that tiling and tiny knobs
    // (the manifest's scene and resolution are a real bake's).
    let plan_script = PodTemplate::of(&plan_job).main;
    let words: Vec<&str> = plan_script.split_whitespace().collect();
    assert_eq!(words[..2], ["prt", "plan"], "{plan_script}");
    let after = |flag: &str| {
        let at = words.iter().position(|w| *w == flag);
        words[at.unwrap_or_else(|| panic!("{flag} missing in {plan_script}")) + 1]
    };
    assert_eq!(after("--out"), "/bake/plan");
    let tiles = after("--tiles");
    let product: u64 = tiles
        .split(',')
        .map(|n| n.parse::<u64>().unwrap())
        .product();
    assert_eq!(
        tiles_job["spec"]["completions"].as_u64(),
        Some(product),
        "completions of prt-bake-tiles must be the plan's {tiles} tiles"
    );
    let plan_pod = PodTemplate {
        init: Vec::new(),
        main: format!(
            "prt plan --tiles {tiles} {} --out /bake/plan",
            TINY_PLAN.join(" ")
        ),
    };

    let dir = scratch("kube");
    let volume = dir.join("bake");
    let logs = dir.join("pods");
    std::fs::create_dir_all(volume.join("plan/tiles")).unwrap();
    std::fs::create_dir_all(&logs).unwrap();
    let prt_dir = Path::new(env!("CARGO_BIN_EXE_prt")).parent().unwrap();
    let path = std::env::var_os("PATH").unwrap_or_default();
    let node = Node {
        volume: volume.clone(),
        logs: logs.clone(),
        path: std::env::join_paths(
            std::iter::once(prt_dir.to_path_buf()).chain(std::env::split_paths(&path)),
        )
        .unwrap(),
    };
    let log = |name: &str| std::fs::read_to_string(logs.join(format!("{name}.log"))).unwrap();

    // Everything applied at once, as `kubectl apply -f` does; tile 2's folder is a file, so
    // its index fails on every try; index 1's first pod is evicted as it starts.
    let poisoned = volume.join("plan/tiles/2");
    std::fs::write(&poisoned, b"not a folder").unwrap();
    let mut merge = node.start("merge", &PodTemplate::of(&merge_job), None);
    let mut plan = node.start("plan", &plan_pod, None);
    let first = run_indexed_job(&node, &tiles_job, |index, attempt| {
        index == 1 && attempt == 1
    });
    let plan_status = loop {
        if let Some(status) = plan.try_wait() {
            break status;
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    assert!(plan_status.success(), "{}", log("plan"));
    let retries = tiles_job["spec"]["backoffLimitPerIndex"].as_u64().unwrap() as usize;
    assert_eq!(
        first.attempts,
        BTreeMap::from([(0, 1), (1, 2), (2, retries + 1), (3, 1)]),
        "{}",
        log("tile-2")
    );
    assert_eq!(first.failed_indexes, BTreeSet::from([2]));
    assert!(!first.complete, "a Job with a failed index is failed");
    let parallelism = tiles_job["spec"]["parallelism"].as_u64().unwrap() as usize;
    assert!(first.most_at_once <= parallelism);
    // The merge is still waiting for tile 2: it never merges a hole.
    std::thread::sleep(Duration::from_millis(500));
    assert!(merge.try_wait().is_none(), "{}", log("merge"));
    assert!(!volume.join("out").exists());

    // The recovery: the folder mended, prt-bake-tiles applied again; finished tiles skip.
    std::fs::remove_file(&poisoned).unwrap();
    let second = run_indexed_job(&node, &tiles_job, |_, _| false);
    assert!(second.complete, "{second:?}: {}", log("tile-2"));
    assert_eq!(log("tile-0").matches("already done").count(), 1);
    let deadline = Instant::now() + TIMEOUT;
    let status = loop {
        if let Some(status) = merge.try_wait() {
            break status;
        }
        assert!(
            Instant::now() < deadline,
            "the merge did not end: {}",
            log("merge")
        );
        std::thread::sleep(Duration::from_millis(50));
    };
    assert!(status.success(), "{}", log("merge"));

    // The same bytes as a local run of the same plan.
    let local_plan = dir.join("local-plan");
    let mut args = vec![
        "plan",
        "--tiles",
        tiles,
        "--out",
        local_plan.to_str().unwrap(),
    ];
    args.extend(TINY_PLAN);
    ok(&prt(&args));
    ok(&prt(&["bake-tile", local_plan.to_str().unwrap(), "--all"]));
    let local = dir.join("local");
    ok(&prt(&[
        "merge",
        local_plan.to_str().unwrap(),
        "--out",
        local.to_str().unwrap(),
    ]));
    let baked = volume.join("out");
    let listed = files(&local);
    assert_eq!(files(&baked), listed);
    // All but the reports, which hold timings.
    for file in listed
        .iter()
        .filter(|f| !f.to_str().unwrap().starts_with("report."))
    {
        assert!(
            std::fs::read(baked.join(file)).unwrap() == std::fs::read(local.join(file)).unwrap(),
            "{} differs",
            file.display()
        );
    }
}
