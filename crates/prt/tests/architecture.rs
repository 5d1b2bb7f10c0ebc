//! The workspace's architectural invariants (docs/architecture.md, "Invariants"), checked on the
//! source text of every crate under `crates/`:
//!
//! * the crates depend as docs/architecture.md's layer table draws ("Dependency direction"): the
//!   table is read from the page, every crate has one layer, every dependency runs to a lower
//!   layer the row's "may use" allows, so the page and the Cargo.toml files cannot disagree;
//! * no crate's top-level modules import each other in a cycle;
//! * only prt-cli prints (library code returns data and reports through `Progress`);
//! * files are written only through prt-texture's atomic writer (write to a temporary file in
//!   the same folder, then rename), so no reader ever sees a half-written file;
//! * prt-bake's and prt-trace's roots are front doors of 15–25 names, the rest in modules.
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

/// One row of docs/architecture.md's layer table ("Dependency direction").
#[derive(Debug, Clone, PartialEq)]
struct Layer {
    /// The layer's number (0 is the lowest).
    number: usize,
    /// The crates of the layer, as the table names them in backticks.
    crates: BTreeSet<String>,
    /// What the layer's crates may depend on.
    may_use: MayUse,
}

/// The table's "may use" column.
#[derive(Debug, Clone, PartialEq)]
enum MayUse {
    /// "nothing of ours".
    Nothing,
    /// "everything below".
    Below,
    /// "layers a–b" or "layer a".
    Layers(usize, usize),
    /// Crates named in backticks.
    Crates(BTreeSet<String>),
}

/// The names in backticks in a table cell.
fn backticked(cell: &str) -> BTreeSet<String> {
    cell.split('`')
        .skip(1)
        .step_by(2)
        .map(str::to_string)
        .collect()
}

/// The layer table of the section "## Dependency direction" of an architecture document: the
/// rows whose first cell is a number. Panics on a row it cannot read, so a reworded table fails
/// the test instead of checking nothing.
fn parse_layers(doc: &str) -> Vec<Layer> {
    let section = doc
        .split("\n## ")
        .find(|s| s.starts_with("Dependency direction"))
        .expect("a section '## Dependency direction'");
    let mut layers = Vec::new();
    for line in section.lines() {
        let cells: Vec<&str> = line
            .trim()
            .trim_matches('|')
            .split('|')
            .map(str::trim)
            .collect();
        let Ok(number) = cells[0].parse::<usize>() else {
            continue;
        };
        assert_eq!(
            cells.len(),
            3,
            "layer row '{line}': layer | crates | may use"
        );
        let may_use = match cells[2] {
            "nothing of ours" => MayUse::Nothing,
            "everything below" => MayUse::Below,
            cell if cell.starts_with("layer") => {
                let numbers: Vec<usize> = cell
                    .split(|c: char| !c.is_ascii_digit())
                    .filter_map(|n| n.parse().ok())
                    .collect();
                match numbers[..] {
                    [a] => MayUse::Layers(a, a),
                    [a, b] => MayUse::Layers(a, b),
                    _ => panic!("layer row '{line}': cannot read '{cell}'"),
                }
            }
            cell => {
                let crates = backticked(cell);
                assert!(
                    !crates.is_empty(),
                    "layer row '{line}': cannot read '{cell}'"
                );
                MayUse::Crates(crates)
            }
        };
        layers.push(Layer {
            number,
            crates: backticked(cells[1]),
            may_use,
        });
    }
    assert!(
        !layers.is_empty(),
        "no layer table under '## Dependency direction'"
    );
    layers
}

/// Where the documented layers and the crates' dependencies disagree: a crate without a layer
/// or with two, a documented crate that does not exist, a dependency on the same or a higher
/// layer, a dependency the layer's "may use" does not allow.
fn layer_violations(
    layers: &[Layer],
    dependencies: &BTreeMap<String, BTreeSet<String>>,
) -> Vec<String> {
    let mut out = Vec::new();
    let layer_of = |name: &str| layers.iter().find(|l| l.crates.contains(name));
    for layer in layers {
        for krate in &layer.crates {
            if !dependencies.contains_key(krate) {
                out.push(format!(
                    "layer {} names {krate}, which is not a crate",
                    layer.number
                ));
            }
        }
    }
    for (krate, deps) in dependencies {
        let owners = layers.iter().filter(|l| l.crates.contains(krate)).count();
        let Some(own) = layer_of(krate) else {
            out.push(format!("{krate} has no layer in docs/architecture.md"));
            continue;
        };
        if owners > 1 {
            out.push(format!("{krate} is in {owners} layers"));
        }
        for dep in deps {
            let Some(theirs) = layer_of(dep) else {
                out.push(format!("{krate} depends on {dep}, which has no layer"));
                continue;
            };
            if theirs.number >= own.number {
                out.push(format!(
                    "{krate} (layer {}) depends on {dep} (layer {})",
                    own.number, theirs.number
                ));
                continue;
            }
            let allowed = match &own.may_use {
                MayUse::Nothing => false,
                MayUse::Below => true,
                MayUse::Layers(a, b) => (*a..=*b).contains(&theirs.number),
                MayUse::Crates(names) => names.contains(dep),
            };
            if !allowed {
                out.push(format!(
                    "{krate} depends on {dep}, which its layer's 'may use' ({:?}) does not allow",
                    own.may_use
                ));
            }
        }
    }
    out
}

/// The `prt*` dependencies of every crate under `crates/`.
fn workspace_dependencies() -> BTreeMap<String, BTreeSet<String>> {
    crate_sources()
        .into_iter()
        .map(|(name, src)| {
            let manifest = std::fs::read_to_string(src.join("../Cargo.toml")).expect("Cargo.toml");
            (name, prt_dependencies(&manifest))
        })
        .collect()
}

#[test]
fn the_crates_depend_as_the_architecture_page_draws() {
    let doc = std::fs::read_to_string(crates_dir().join("../docs/architecture.md"))
        .expect("docs/architecture.md");
    let layers = parse_layers(&doc);
    let dependencies = workspace_dependencies();
    assert!(
        dependencies["prt-bake"].contains("prt-mbd"),
        "{dependencies:?}"
    );
    let violations = layer_violations(&layers, &dependencies);
    assert!(
        violations.is_empty(),
        "docs/architecture.md's layer table and the Cargo.toml files disagree:\n{}",
        violations.join("\n")
    );
}

/// The names reachable at a crate root from its `lib.rs` (comments and test items removed): its
/// `pub mod`s, the names of its `pub use`s, and its other `pub` items; items behind
/// `#[cfg(doctest)]` (README doctests) do not count.
fn root_items(lib_rs: &str) -> BTreeSet<String> {
    let code = production_code(lib_rs);
    // Top-level statements: text up to a `;` or a closed `{ .. }` at brace depth 0.
    let mut statements = Vec::new();
    let (mut depth, mut current) = (0usize, String::new());
    for c in code.chars() {
        current.push(c);
        match c {
            '{' => depth += 1,
            '}' => {
                depth = depth.saturating_sub(1);
                if depth == 0 && !current.trim_start().starts_with("pub use") {
                    statements.push(std::mem::take(&mut current));
                }
            }
            ';' if depth == 0 => statements.push(std::mem::take(&mut current)),
            _ => {}
        }
    }
    let mut out = BTreeSet::new();
    for statement in statements {
        let mut rest = statement.trim();
        let mut doctest_only = false;
        while let Some(attribute) = rest.strip_prefix("#[") {
            let end = attribute.find(']').unwrap_or(attribute.len());
            doctest_only |= attribute[..end].contains("cfg(doctest)");
            rest = attribute[(end + 1).min(attribute.len())..].trim_start();
        }
        if doctest_only {
            continue;
        }
        if let Some(tree) = rest.strip_prefix("pub use ") {
            out.extend(use_tree_names(tree.trim_end_matches(';')));
            continue;
        }
        let Some(item) = rest.strip_prefix("pub ") else {
            continue;
        };
        let mut words = item.split(|c: char| !(c.is_alphanumeric() || c == '_'));
        let words: Vec<&str> = words.by_ref().filter(|w| !w.is_empty()).take(3).collect();
        let name = match words.as_slice() {
            ["unsafe" | "async" | "const", "fn" | "trait", name, ..] => name,
            [
                "mod" | "fn" | "struct" | "enum" | "const" | "static" | "type" | "trait" | "union"
                | "macro",
                name,
                ..,
            ] => name,
            _ => continue,
        };
        out.insert(name.to_string());
    }
    out
}

/// The names a `use` tree brings in: `a::b` gives `b`, `a::{b, c::{d, e as f}}` gives `b`, `d`,
/// `f`, and `a::{self, b}` gives `a` and `b`.
fn use_tree_names(tree: &str) -> Vec<String> {
    let tree = tree.trim();
    if let Some(open) = tree.find('{') {
        let prefix = tree[..open].trim_end_matches("::");
        let inner = &tree[open + 1..tree.rfind('}').unwrap_or(tree.len())];
        let (mut depth, mut start, mut parts) = (0usize, 0, Vec::new());
        for (i, c) in inner.char_indices() {
            match c {
                '{' => depth += 1,
                '}' => depth -= 1,
                ',' if depth == 0 => {
                    parts.push(&inner[start..i]);
                    start = i + 1;
                }
                _ => {}
            }
        }
        parts.push(&inner[start..]);
        return parts
            .into_iter()
            .filter(|part| !part.trim().is_empty())
            .flat_map(|part| match part.trim() {
                "self" => vec![prefix.rsplit("::").next().unwrap_or(prefix).to_string()],
                part => use_tree_names(part),
            })
            .collect();
    }
    let name = match tree.split_once(" as ") {
        Some((_, alias)) => alias,
        None => tree.rsplit("::").next().unwrap_or(tree),
    };
    vec![name.trim().to_string()]
}

/// prt-bake's and prt-trace's roots are front doors: what a newcomer needs first (about 15–25
/// names), the rest in a module per concern (docs/architecture.md, "API boundaries").
#[test]
fn the_front_door_crates_have_small_roots() {
    let mut offenders = Vec::new();
    for name in ["prt-bake", "prt-trace"] {
        let lib =
            std::fs::read_to_string(crates_dir().join(name).join("src/lib.rs")).expect("lib.rs");
        let items = root_items(&lib);
        if !(15..=25).contains(&items.len()) {
            offenders.push(format!("{name}: {} root items {items:?}", items.len()));
        }
    }
    assert!(
        offenders.is_empty(),
        "crate roots outside 15..=25 items (move the rest into a module by concern):\n{}",
        offenders.join("\n")
    );
}

/// The checks themselves: a cycle, a print, a write and an upward dependency are found where
/// they are, test code is left out, and a crate root's names are counted.
#[test]
fn the_checks_find_what_they_look_for() {
    let manifest = "[package]\nname = \"x\"\n[dependencies]\nprt-core = { workspace = true }\n\
                    prt-mbd.workspace = true\nserde = \"1\"\n[dev-dependencies]\nprt-cli = \"0\"\n";
    assert_eq!(
        prt_dependencies(manifest),
        BTreeSet::from(["prt-core".to_string(), "prt-mbd".to_string()])
    );
    let doc = "# x\n\n## Dependency direction\n\n| layer | crates | may use |\n|---|---|---|\n\
               | 2 | `prt-cli` (the binary) | everything below |\n\
               | 1 | `prt-mbd`, `prt-bake` | `prt-core` |\n\
               | 0 | `prt-core` | nothing of ours |\n\n## Next\n\n| 9 | `prt-x` | layer 0 |\n";
    let layers = parse_layers(doc);
    assert_eq!(layers.len(), 3, "{layers:?}");
    assert_eq!(layers[1].crates.len(), 2);
    assert_eq!(
        parse_layers("\n## Dependency direction\n| 4 | `a` | layers 0–3 |\n")[0].may_use,
        MayUse::Layers(0, 3)
    );
    let deps = |pairs: &[(&str, &[&str])]| -> BTreeMap<String, BTreeSet<String>> {
        pairs
            .iter()
            .map(|(k, v)| (k.to_string(), v.iter().map(|d| d.to_string()).collect()))
            .collect()
    };
    let agreeing = deps(&[
        ("prt-cli", &["prt-mbd", "prt-core"]),
        ("prt-mbd", &["prt-core"]),
        ("prt-bake", &[]),
        ("prt-core", &[]),
    ]);
    assert!(layer_violations(&layers, &agreeing).is_empty());
    // Upward, sideways and not-allowed dependencies; an undocumented and a missing crate.
    let disagreeing = deps(&[
        ("prt-cli", &[]),
        ("prt-mbd", &["prt-cli", "prt-bake"]),
        ("prt-core", &["prt-mbd"]),
        ("prt-new", &[]),
    ]);
    let found = layer_violations(&layers, &disagreeing);
    assert_eq!(found.len(), 5, "{found:#?}");
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
    let lib = "//! docs: pub use hidden::Nope;\nmod private;\npub mod front;\n\
               pub use a::{B, c::{D, E as F}, g::{self, H}};\npub use i::J;\n\
               /// doc\n#[derive(Debug)]\npub struct K {\n    pub field: u8,\n}\n\
               pub mod inline {\n    pub use crate::private::L;\n}\npub const fn m() {}\n\
               #[doc = include_str!(\"../README.md\")]\n#[cfg(doctest)]\npub struct Readme;\n";
    let names: Vec<String> = root_items(lib).into_iter().collect();
    assert_eq!(
        names,
        ["B", "D", "F", "H", "J", "K", "front", "g", "inline", "m"]
    );
}
