//! Does prt-trace's glTF loader survive the public glTF sample and conformance models? Every
//! `.gltf`/`.glb` under a folder is loaded with `Scene::load_gltf` (on a thread, panics caught,
//! a time limit per file) and, when it loads, baked into a tiny volume. Each row gives the
//! outcome (loaded, refused with a typed error, panic, hang), the triangles against the count
//! the document's accessors imply, whether the loaded bounds lie inside the bounds its POSITION
//! accessors' min/max imply, the warnings or the error, the glTF-Validator's error count where a
//! `*.report.json` sits beside the file, and the time. Prints the table, then totals.
//!
//! `cargo run --release -p prt-benches --bin gltf_conformance -- --dir ../conformance --res 6
//! --rays 24 --timeout 60 [--no-bake] [--csv DIR]` (the defaults; the folder is gathered by hand,
//! see docs/results.md § glTF conformance).
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::sync::mpsc;
use std::time::{Duration, Instant};

use clap::Parser;
use glam::{Mat4, Quat, Vec3};
use prt_benches::Table;
use prt_core::{Aabb, NoProgress};
use prt_trace::{BakeOptions, LoadOptions, Scene, TraceError, TransferBaker};
use serde_json::Value;

#[derive(Parser)]
#[command(
    about = "Load (and bake) every glTF/GLB under a folder; report panics, hangs, wrong geometry and errors"
)]
struct Args {
    /// Folder searched recursively for .gltf and .glb files.
    #[arg(long, default_value = "../conformance")]
    dir: PathBuf,
    /// Voxels per axis of the test bake.
    #[arg(long, default_value_t = 6)]
    res: usize,
    /// Directions per voxel of the test bake.
    #[arg(long, default_value_t = 24)]
    rays: usize,
    /// Seconds a file may take (load and bake) before it counts as a hang.
    #[arg(long, default_value_t = 60)]
    timeout: u64,
    /// Only load; do not bake.
    #[arg(long)]
    no_bake: bool,
    /// Also write the table as CSV in this folder.
    #[arg(long)]
    csv: Option<PathBuf>,
}

/// What happened to one file.
enum Outcome {
    Loaded {
        triangles: usize,
        dropped: usize,
        bounds: Option<Aabb>,
        warnings: Vec<String>,
        bake: String,
    },
    Refused(TraceError),
    Panic(String),
    Hang,
}

/// The last panic's message and place, recorded by the hook so that caught panics stay quiet.
static LAST_PANIC: Mutex<Option<String>> = Mutex::new(None);

fn run_one(path: &Path, args: &Args) -> Outcome {
    let (tx, rx) = mpsc::channel();
    let path = path.to_owned();
    let (res, rays, bake) = (args.res, args.rays, !args.no_bake);
    std::thread::spawn(move || {
        let result = std::panic::catch_unwind(|| load_and_bake(&path, res, rays, bake));
        let outcome = result.unwrap_or_else(|_| {
            Outcome::Panic(
                LAST_PANIC
                    .lock()
                    .map_or(None, |mut p| p.take())
                    .unwrap_or_default(),
            )
        });
        let _ = tx.send(outcome);
    });
    // A hung thread is left behind; the run goes on.
    rx.recv_timeout(Duration::from_secs(args.timeout))
        .unwrap_or(Outcome::Hang)
}

fn load_and_bake(path: &Path, res: usize, rays: usize, bake: bool) -> Outcome {
    let scene = match Scene::load_gltf(path, &LoadOptions::default()) {
        Ok(scene) => scene,
        Err(e) => return Outcome::Refused(e),
    };
    let bounds = scene.bounds();
    let bake = if !bake {
        "-".to_owned()
    } else if let Some(b) = bounds {
        let options = BakeOptions {
            resolution: [res; 3],
            rays_per_voxel: rays,
            probe_rays: rays.min(12),
            cache_rays: 8,
            // Closed models fill the box; a margin leaves open voxels around them.
            margin: 0.1 * b.size().length(),
            ..BakeOptions::default()
        };
        match TransferBaker::new(&scene, options).and_then(|baker| baker.bake(&NoProgress)) {
            Ok(volume) => format!(
                "{}/{} valid",
                volume.stats.valid_voxels(),
                volume.stats.voxels
            ),
            Err(e) => format!("error: {}", variant(&e)),
        }
    } else {
        "no triangles".to_owned()
    };
    Outcome::Loaded {
        triangles: scene.triangles().len(),
        dropped: scene.degenerate_dropped(),
        bounds,
        warnings: scene.warnings().to_vec(),
        bake,
    }
}

/// The error's variant name (looking through attached warnings).
fn variant(e: &TraceError) -> String {
    let debug = format!("{:?}", e.without_warnings().0);
    debug
        .split(|c: char| !c.is_alphanumeric())
        .next()
        .unwrap_or("")
        .to_owned()
}

/// What the document itself says of its default scene: triangles of its triangle primitives and
/// the box of their POSITION accessors' min/max under the node transforms. `None` where the
/// document does not say (a missing min/max, an unreadable field): no check then.
struct Expected {
    triangles: Option<usize>,
    bounds: Option<Aabb>,
}

fn json_of(bytes: &[u8]) -> Option<Value> {
    if bytes.starts_with(b"glTF") {
        let len = u32::from_le_bytes(bytes.get(12..16)?.try_into().ok()?) as usize;
        serde_json::from_slice(bytes.get(20..20 + len)?).ok()
    } else {
        serde_json::from_slice(bytes).ok()
    }
}

fn node_matrix(node: &Value) -> Option<Mat4> {
    if let Some(m) = node.get("matrix") {
        let m: Vec<f32> = serde_json::from_value(m.clone()).ok()?;
        return Some(Mat4::from_cols_slice(m.get(..16)?));
    }
    let vec = |key: &str, default: &[f32]| -> Option<Vec<f32>> {
        node.get(key).map_or(Some(default.to_vec()), |v| {
            serde_json::from_value(v.clone()).ok()
        })
    };
    let t = vec("translation", &[0.0; 3])?;
    let r = vec("rotation", &[0.0, 0.0, 0.0, 1.0])?;
    let s = vec("scale", &[1.0; 3])?;
    Some(Mat4::from_scale_rotation_translation(
        Vec3::from_slice(s.get(..3)?),
        Quat::from_slice(r.get(..4)?).normalize(),
        Vec3::from_slice(t.get(..3)?),
    ))
}

fn expected(path: &Path) -> Expected {
    let none = Expected {
        triangles: None,
        bounds: None,
    };
    let Some(doc) = std::fs::read(path).ok().and_then(|b| json_of(&b)) else {
        return none;
    };
    let array = |key: &str| doc.get(key).and_then(Value::as_array);
    let (Some(nodes), Some(meshes), Some(accessors)) =
        (array("nodes"), array("meshes"), array("accessors"))
    else {
        return none;
    };
    let scene_index = doc.get("scene").and_then(Value::as_u64).unwrap_or(0) as usize;
    let Some(roots) = array("scenes")
        .and_then(|s| s.get(scene_index))
        .and_then(|s| s.get("nodes"))
        .and_then(Value::as_array)
    else {
        return none;
    };
    let count_of = |a: &Value| -> Option<usize> {
        accessors
            .get(a.as_u64()? as usize)?
            .get("count")?
            .as_u64()
            .map(|c| c as usize)
    };
    let mut triangles = Some(0usize);
    let mut bounds: Option<Aabb> = None;
    let mut bounds_known = true;
    let mut visited = vec![false; nodes.len()];
    let mut stack: Vec<(usize, Mat4)> = roots
        .iter()
        .filter_map(|n| Some((n.as_u64()? as usize, Mat4::IDENTITY)))
        .collect();
    while let Some((n, parent)) = stack.pop() {
        let Some(node) = nodes.get(n) else {
            return none;
        };
        if std::mem::replace(&mut visited[n], true) {
            return none;
        }
        let Some(local) = node_matrix(node) else {
            return none;
        };
        let world = parent * local;
        if let Some(mesh) = node.get("mesh").and_then(Value::as_u64) {
            let Some(primitives) = meshes
                .get(mesh as usize)
                .and_then(|m| m.get("primitives"))
                .and_then(Value::as_array)
            else {
                return none;
            };
            for p in primitives {
                let mode = p.get("mode").and_then(Value::as_u64).unwrap_or(4);
                if !(4..=6).contains(&mode) {
                    continue;
                }
                let position = p.get("attributes").and_then(|a| a.get("POSITION"));
                // An accessor without data is zeros: the loader skips such a primitive, as it
                // has no area (unless morph targets move it).
                let zeros = |a: &Value| {
                    a.as_u64()
                        .and_then(|i| accessors.get(i as usize))
                        .is_some_and(|a| a.get("bufferView").is_none() && a.get("sparse").is_none())
                };
                let no_area = p.get("indices").is_some_and(zeros)
                    || position.is_some_and(zeros) && p.get("targets").is_none();
                let n = match p.get("indices") {
                    _ if no_area => Some(0),
                    Some(ix) => count_of(ix),
                    None => position.and_then(count_of),
                };
                triangles = match (triangles, n) {
                    (Some(t), Some(n)) if mode == 4 => Some(t + n / 3),
                    (Some(t), Some(n)) => Some(t + n.saturating_sub(2)),
                    _ => None,
                };
                // Morph targets move vertices past the base accessor's box.
                let accessor = position
                    .and_then(Value::as_u64)
                    .and_then(|a| accessors.get(a as usize));
                let corners = accessor
                    .filter(|_| p.get("targets").is_none())
                    .and_then(|a| {
                        let min: Vec<f32> = serde_json::from_value(a.get("min")?.clone()).ok()?;
                        let max: Vec<f32> = serde_json::from_value(a.get("max")?.clone()).ok()?;
                        let normalized = a.get("normalized").and_then(Value::as_bool) == Some(true);
                        let float = a.get("componentType").and_then(Value::as_u64) == Some(5126);
                        (float || !normalized).then_some(())?;
                        Some((
                            Vec3::from_slice(min.get(..3)?),
                            Vec3::from_slice(max.get(..3)?),
                        ))
                    });
                match corners {
                    Some((lo, hi)) => {
                        for k in 0..8 {
                            let c = Vec3::new(
                                if k & 1 == 0 { lo.x } else { hi.x },
                                if k & 2 == 0 { lo.y } else { hi.y },
                                if k & 4 == 0 { lo.z } else { hi.z },
                            );
                            let w = world.transform_point3(c);
                            bounds = Some(match bounds {
                                Some(b) => Aabb::new(b.min.min(w), b.max.max(w)),
                                None => Aabb::new(w, w),
                            });
                        }
                    }
                    None => bounds_known = false,
                }
            }
        }
        if let Some(children) = node.get("children").and_then(Value::as_array) {
            stack.extend(
                children
                    .iter()
                    .filter_map(|c| Some((c.as_u64()? as usize, world))),
            );
        }
    }
    Expected {
        triangles,
        bounds: bounds.filter(|_| bounds_known),
    }
}

/// Whether `inner` lies inside `outer` up to a relative tolerance.
fn inside(inner: Aabb, outer: Aabb) -> bool {
    let tol = 1e-3 * outer.size().length().max(1e-6);
    (inner.min - outer.min).min_element() >= -tol && (outer.max - inner.max).min_element() >= -tol
}

/// The glTF-Validator's expected number of errors, from a `FILE.report.json` beside the file.
fn validator_errors(path: &Path) -> Option<u64> {
    let mut report = path.as_os_str().to_owned();
    report.push(".report.json");
    let text = std::fs::read(PathBuf::from(report)).ok()?;
    let v: Value = serde_json::from_slice(&text).ok()?;
    v.get("issues")?.get("numErrors")?.as_u64()
}

fn gather(dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    let mut entries: Vec<_> = entries.filter_map(Result::ok).map(|e| e.path()).collect();
    entries.sort();
    for p in entries {
        if p.is_dir() {
            gather(&p, out);
        } else if p
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("gltf") || e.eq_ignore_ascii_case("glb"))
        {
            out.push(p);
        }
    }
}

/// One line of a message for a table cell.
fn cell(s: &str) -> String {
    let s: String = s.replace(['|', '\n'], " ");
    if s.chars().count() > 160 {
        s.chars().take(157).collect::<String>() + "..."
    } else {
        s
    }
}

fn main() {
    let args = Args::parse();
    std::panic::set_hook(Box::new(|info| {
        if let Ok(mut last) = LAST_PANIC.lock() {
            *last = Some(info.to_string());
        }
    }));
    let mut files = Vec::new();
    gather(&args.dir, &mut files);
    if files.is_empty() {
        eprintln!("no .gltf or .glb file under {}", args.dir.display());
        std::process::exit(2);
    }
    let mut table = Table::new(&[
        "model",
        "outcome",
        "triangles (expected)",
        "bounds",
        "bake",
        "validator errors",
        "warnings / error",
        "ms",
    ]);
    let (mut loaded, mut refused, mut panicked, mut hung, mut wrong) = (0, 0, 0, 0, 0);
    let mut refusals = std::collections::BTreeMap::<String, usize>::new();
    let prefix = format!("{}/", args.dir.display());
    for (i, path) in files.iter().enumerate() {
        let name = path
            .strip_prefix(&args.dir)
            .unwrap_or(path)
            .display()
            .to_string();
        eprintln!("[{}/{}] {name}", i + 1, files.len());
        let expect = expected(path);
        let validator = validator_errors(path).map_or("-".to_owned(), |n| n.to_string());
        let t = Instant::now();
        let outcome = run_one(path, &args);
        let ms = format!("{:.1}", t.elapsed().as_secs_f64() * 1e3);
        let row = match outcome {
            Outcome::Loaded {
                triangles,
                dropped,
                bounds,
                warnings,
                bake,
            } => {
                loaded += 1;
                let count_ok = expect.triangles.is_none_or(|n| n == triangles + dropped);
                let bounds_ok = match (bounds, expect.bounds) {
                    (Some(b), Some(e)) => inside(b, e),
                    _ => true,
                };
                let check = if bounds.is_none() || expect.bounds.is_none() {
                    "-"
                } else if bounds_ok {
                    "ok"
                } else {
                    "OUTSIDE"
                };
                if !(count_ok && bounds_ok) || bake.starts_with("error") && bounds.is_some() {
                    wrong += 1;
                }
                let expected = expect.triangles.map_or("?".to_owned(), |n| n.to_string());
                let mark = if count_ok { "" } else { " MISMATCH" };
                vec![
                    name,
                    "loaded".to_owned(),
                    format!("{triangles}+{dropped} degenerate ({expected}){mark}"),
                    check.to_owned(),
                    bake,
                    validator,
                    cell(&warnings.join("; ")),
                    ms,
                ]
            }
            Outcome::Refused(e) => {
                refused += 1;
                *refusals.entry(variant(&e)).or_default() += 1;
                vec![
                    name,
                    format!("refused: {}", variant(&e)),
                    "-".to_owned(),
                    "-".to_owned(),
                    "-".to_owned(),
                    validator,
                    // Paths are relative to the folder, as in the first column.
                    cell(&e.to_string().replace(&prefix, "")),
                    ms,
                ]
            }
            Outcome::Panic(message) => {
                panicked += 1;
                vec![
                    name,
                    "PANIC".to_owned(),
                    "-".to_owned(),
                    "-".to_owned(),
                    "-".to_owned(),
                    validator,
                    cell(&message),
                    ms,
                ]
            }
            Outcome::Hang => {
                hung += 1;
                vec![
                    name,
                    "HANG".to_owned(),
                    "-".to_owned(),
                    "-".to_owned(),
                    "-".to_owned(),
                    validator,
                    format!("no answer within {} s", args.timeout),
                    ms,
                ]
            }
        };
        table.row(row);
    }
    print!("{}", table.markdown());
    println!(
        "\n{} files: {loaded} loaded ({wrong} with a wrong count, bounds or a failed bake), \
         {refused} refused with a typed error, {panicked} panicked, {hung} hung",
        files.len()
    );
    let by_kind: Vec<String> = refusals.iter().map(|(k, n)| format!("{k} {n}")).collect();
    println!("refusals by error: {}", by_kind.join(", "));
    if let Err(e) = table.write_csv(args.csv.as_deref(), "gltf_conformance") {
        eprintln!("cannot write the CSV: {e}");
    }
    if panicked + hung > 0 {
        std::process::exit(1);
    }
}
