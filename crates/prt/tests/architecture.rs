//! The workspace's architectural invariants (docs/architecture.md, "Invariants"), checked on the
//! source text of every crate under `crates/`:
//!
//! * the crates depend only downwards through the layers of docs/architecture.md ("Dependency
//!   direction"), and every crate has a layer;
//! * no crate's top-level modules import each other in a cycle;
//! * only prt-cli prints (library code returns data and reports through `Progress`);
//! * files are written only through prt-texture's atomic writer (write to a temporary file in
//!   the same folder, then rename), so no reader ever sees a half-written file.
//!
//! Test modules (`#[cfg(test)]` blocks), comments and doc comments are not checked.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

fn crates_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// Every `.rs` file below `dir`.
fn rust_files(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let Ok(entries) = std::fs::read_dir(dir) else {
        return out;
    };
    for entry in entries.flatten() {
        let path = entry.path();
        if path.is_dir() {
            out.extend(rust_files(&path));
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
    out.sort();
    out
}

/// The library or binary source of each crate: (crate folder name, `src/` path).
fn crate_sources() -> Vec<(String, PathBuf)> {
    let mut crates: Vec<(String, PathBuf)> = std::fs::read_dir(crates_dir())
        .expect("crates/")
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.join("src").is_dir())
        .map(|p| {
            let name = p
                .file_name()
                .unwrap_or_default()
                .to_string_lossy()
                .into_owned();
            (name, p.join("src"))
        })
        .collect();
    crates.sort();
    assert!(crates.len() >= 10, "found only {} crates", crates.len());
    crates
}

/// The code of a file without comments and without its `#[cfg(test)]` items (a test module
/// runs to the end of the file by this workspace's convention; a `#[cfg(test)]` item elsewhere
/// is skipped up to its closing brace at the same indentation).
fn production_code(text: &str) -> String {
    let mut out = String::new();
    let mut lines = text.lines();
    while let Some(line) = lines.next() {
        let trimmed = line.trim_start();
        if trimmed.starts_with("#[cfg(test)]") {
            let indent = line.len() - trimmed.len();
            let closing = format!("{}}}", " ".repeat(indent));
            for skipped in lines.by_ref() {
                if skipped == closing || skipped.starts_with(&format!("{closing};")) {
                    break;
                }
            }
            continue;
        }
        let code = match trimmed.find("//") {
            Some(0) => continue,
            // A `//` inside a string literal (a URL) is rare here; cutting there only hides code.
            Some(i) => &trimmed[..i],
            None => trimmed,
        };
        out.push_str(code);
        out.push('\n');
    }
    out
}

/// The top-level module a file of `src/` belongs to (`None` for the crate root).
fn top_module(src: &Path, file: &Path) -> Option<String> {
    let rel = file.strip_prefix(src).ok()?;
    let first = rel
        .components()
        .next()?
        .as_os_str()
        .to_string_lossy()
        .into_owned();
    let name = first.trim_end_matches(".rs").to_string();
    (!matches!(name.as_str(), "lib" | "main")).then_some(name)
}

/// The `crate::module` paths `code` names, including inside `use crate::{a, b::c}` lists.
fn crate_references(code: &str) -> BTreeSet<String> {
    let mut out = BTreeSet::new();
    let mut rest = code;
    while let Some(at) = rest.find("crate::") {
        let after = &rest[at + "crate::".len()..];
        if let Some(list) = after.strip_prefix('{') {
            let end = list.find('}').unwrap_or(list.len());
            for item in list[..end].split(',') {
                let ident: String = item
                    .trim()
                    .chars()
                    .take_while(|c| c.is_alphanumeric() || *c == '_')
                    .collect();
                if !ident.is_empty() {
                    out.insert(ident);
                }
            }
        } else {
            let ident: String = after
                .chars()
                .take_while(|c| c.is_alphanumeric() || *c == '_')
                .collect();
            if !ident.is_empty() {
                out.insert(ident);
            }
        }
        rest = after;
    }
    out
}

/// A cycle in `graph`, if any, as the list of its nodes.
fn find_cycle(graph: &BTreeMap<String, BTreeSet<String>>) -> Option<Vec<String>> {
    fn visit(
        node: &str,
        graph: &BTreeMap<String, BTreeSet<String>>,
        state: &mut BTreeMap<String, u8>,
        stack: &mut Vec<String>,
    ) -> Option<Vec<String>> {
        state.insert(node.to_string(), 1);
        stack.push(node.to_string());
        for next in graph.get(node).into_iter().flatten() {
            match state.get(next.as_str()).copied().unwrap_or(0) {
                1 => {
                    let start = stack.iter().position(|n| n == next).unwrap_or(0);
                    let mut cycle = stack[start..].to_vec();
                    cycle.push(next.clone());
                    return Some(cycle);
                }
                0 => {
                    if let Some(cycle) = visit(next, graph, state, stack) {
                        return Some(cycle);
                    }
                }
                _ => {}
            }
        }
        stack.pop();
        state.insert(node.to_string(), 2);
        None
    }
    let mut state = BTreeMap::new();
    for node in graph.keys() {
        if state.get(node.as_str()).copied().unwrap_or(0) == 0 {
            let mut stack = Vec::new();
            if let Some(cycle) = visit(node, graph, &mut state, &mut stack) {
                return Some(cycle);
            }
        }
    }
    None
}

#[test]
fn no_crate_has_a_module_cycle() {
    let mut cycles = Vec::new();
    for (name, src) in crate_sources() {
        let mut graph: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
        for file in rust_files(&src) {
            let Some(module) = top_module(&src, &file) else {
                continue;
            };
            let code = production_code(&std::fs::read_to_string(&file).expect("read"));
            let entry = graph.entry(module.clone()).or_default();
            for target in crate_references(&code) {
                if target != module {
                    entry.insert(target);
                }
            }
        }
        // Only edges between the crate's own top-level modules count (re-exports at the root
        // are reached through `crate::Item`, which names no module).
        let modules: BTreeSet<String> = graph.keys().cloned().collect();
        for targets in graph.values_mut() {
            targets.retain(|t| modules.contains(t));
        }
        if let Some(cycle) = find_cycle(&graph) {
            cycles.push(format!("{name}: {}", cycle.join(" -> ")));
        }
    }
    assert!(cycles.is_empty(), "module cycles:\n{}", cycles.join("\n"));
}

#[test]
fn only_the_command_line_prints() {
    let mut offenders = Vec::new();
    for (name, src) in crate_sources() {
        if name == "prt-cli" {
            continue;
        }
        for file in rust_files(&src) {
            let code = production_code(&std::fs::read_to_string(&file).expect("read"));
            for macro_name in ["println!", "eprintln!", "print!", "eprint!", "dbg!"] {
                if code.contains(macro_name) {
                    offenders.push(format!("{}: {macro_name}", file.display()));
                }
            }
        }
    }
    assert!(
        offenders.is_empty(),
        "library code prints:\n{}",
        offenders.join("\n")
    );
}

#[test]
fn files_are_written_only_through_the_atomic_writer() {
    let atomic = crates_dir().join("prt-texture/src/atomic.rs");
    let mut offenders = Vec::new();
    for (_, src) in crate_sources() {
        for file in rust_files(&src) {
            if file.ends_with("prt-texture/src/atomic.rs") {
                continue;
            }
            let code = production_code(&std::fs::read_to_string(&file).expect("read"));
            for call in [
                "fs::write(",
                "File::create(",
                "OpenOptions::new(",
                "fs::rename(",
            ] {
                if code.contains(call) {
                    offenders.push(format!("{}: {call}", file.display()));
                }
            }
        }
    }
    assert!(
        atomic.is_file(),
        "the atomic writer moved from {}",
        atomic.display()
    );
    assert!(
        offenders.is_empty(),
        "files written outside prt-texture's atomic writer:\n{}",
        offenders.join("\n")
    );
}

/// The crates' layers, lowest first (docs/architecture.md, "Dependency direction"): a crate may
/// depend only on crates of lower layers.
const LAYERS: &[&[&str]] = &[
    &["prt-core", "prt-texture", "prt-shaders"],
    &["prt-linalg", "prt-kernels", "prt-sphere"],
    &["prt-mbd", "prt-plsq", "prt-wavelet", "prt-manylight"],
    &["prt-trace"],
    &["prt-bake", "prt-render", "prt-lightmap"],
    &["prt-export"],
    &["prt-cli", "prt"],
];

/// The `prt*` crates named in the `[dependencies]` table of a Cargo.toml.
fn prt_dependencies(manifest: &str) -> BTreeSet<String> {
    let mut out = BTreeSet::new();
    let mut in_dependencies = false;
    for line in manifest.lines().map(str::trim) {
        if line.starts_with('[') {
            in_dependencies = line == "[dependencies]";
            continue;
        }
        let name = line.split(['=', ' ', '.']).next().unwrap_or_default();
        if in_dependencies && (name == "prt" || name.starts_with("prt-")) {
            out.insert(name.to_string());
        }
    }
    out
}

/// Every dependency that does not run to a lower layer, and every crate without a layer.
fn layer_violations(dependencies: &BTreeMap<String, BTreeSet<String>>) -> Vec<String> {
    let layer = |name: &str| LAYERS.iter().position(|l| l.contains(&name));
    let mut out = Vec::new();
    for (krate, deps) in dependencies {
        let Some(own) = layer(krate) else {
            out.push(format!("{krate} has no layer in LAYERS"));
            continue;
        };
        for dep in deps {
            match layer(dep) {
                Some(l) if l < own => {}
                Some(l) => out.push(format!(
                    "{krate} (layer {own}) depends on {dep} (layer {l})"
                )),
                None => out.push(format!("{krate} depends on {dep}, which has no layer")),
            }
        }
    }
    out
}

#[test]
fn the_crates_depend_only_downwards() {
    let dependencies: BTreeMap<String, BTreeSet<String>> = crate_sources()
        .into_iter()
        .map(|(name, src)| {
            let manifest = std::fs::read_to_string(src.join("../Cargo.toml")).expect("Cargo.toml");
            (name, prt_dependencies(&manifest))
        })
        .collect();
    assert!(
        dependencies["prt-bake"].contains("prt-mbd"),
        "{dependencies:?}"
    );
    let violations = layer_violations(&dependencies);
    assert!(violations.is_empty(), "{violations:#?}");
}

/// The checks themselves: a cycle, a print, a write and an upward dependency are found where
/// they are, and test code is left out.
#[test]
fn the_checks_find_what_they_look_for() {
    let manifest = "[package]\nname = \"x\"\n[dependencies]\nprt-core = { workspace = true }\n\
                    prt-mbd.workspace = true\nserde = \"1\"\n[dev-dependencies]\nprt-cli = \"0\"\n";
    assert_eq!(
        prt_dependencies(manifest),
        BTreeSet::from(["prt-core".to_string(), "prt-mbd".to_string()])
    );
    let upward = BTreeMap::from([
        (
            "prt-mbd".to_string(),
            BTreeSet::from(["prt-bake".to_string()]),
        ),
        ("prt-new".to_string(), BTreeSet::new()),
    ]);
    assert_eq!(
        layer_violations(&upward).len(),
        2,
        "{:?}",
        layer_violations(&upward)
    );
    let mut graph = BTreeMap::new();
    graph.insert("a".to_string(), BTreeSet::from(["b".to_string()]));
    graph.insert("b".to_string(), BTreeSet::from(["a".to_string()]));
    assert!(find_cycle(&graph).is_some());
    graph.insert("b".to_string(), BTreeSet::new());
    assert!(find_cycle(&graph).is_none());
    let refs = crate_references("use crate::{alpha, beta::Gamma};\nlet x = crate::delta::f();");
    assert_eq!(
        refs,
        BTreeSet::from(["alpha".into(), "beta".into(), "delta".into()])
    );
    let code = production_code(
        "fn f() { println!(\"x\"); } // eprintln!\n#[cfg(test)]\nmod tests {\n    fn g() { dbg!(1); }\n}\n",
    );
    assert!(code.contains("println!") && !code.contains("eprintln!") && !code.contains("dbg!"));
}
