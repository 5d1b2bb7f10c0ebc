//! docs/experiments.md's index against `src/bin`: every binary (and every subcommand of a
//! binary with a folder of its own, one module per subcommand) has a row, and every row names
//! one.

use std::collections::BTreeSet;
use std::path::Path;

/// The names `src/bin` defines: `NAME` for `NAME.rs`, `NAME SUB` for each `NAME/SUB.rs` beside
/// `NAME/main.rs` (the module's name in kebab case, as clap names the subcommand).
fn binaries(bin: &Path) -> BTreeSet<String> {
    let mut names = BTreeSet::new();
    for entry in std::fs::read_dir(bin).expect("src/bin is readable") {
        let path = entry.expect("a directory entry").path();
        let stem = path
            .file_stem()
            .and_then(|s| s.to_str())
            .expect("a UTF-8 name");
        if path.is_dir() {
            for module in std::fs::read_dir(&path).expect("a binary's folder is readable") {
                let module = module.expect("a directory entry").path();
                let sub = module
                    .file_stem()
                    .and_then(|s| s.to_str())
                    .expect("a UTF-8 name");
                if sub != "main" {
                    names.insert(format!("{stem} {}", sub.replace('_', "-")));
                }
            }
        } else if path.extension().is_some_and(|e| e == "rs") {
            names.insert(stem.to_string());
        }
    }
    names
}

/// The first cell of every row of the page's index table, but the criterion benches' row.
fn index_rows(page: &str) -> BTreeSet<String> {
    page.lines()
        .skip_while(|l| *l != "## Index")
        .skip(1)
        .take_while(|l| !l.starts_with("## "))
        .filter_map(|l| l.strip_prefix("| "))
        .filter_map(|l| l.split(" |").next())
        .filter(|cell| *cell != "binary" && *cell != "criterion benches")
        .map(str::to_string)
        .collect()
}

#[test]
fn every_binary_has_an_index_row_and_every_row_a_binary() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let page = std::fs::read_to_string(root.join("../docs/experiments.md"))
        .expect("docs/experiments.md is readable");
    let rows = index_rows(&page);
    let binaries = binaries(&root.join("src/bin"));
    assert!(binaries.contains("compare stream"), "{binaries:?}");
    let missing: Vec<_> = binaries.difference(&rows).collect();
    let stale: Vec<_> = rows.difference(&binaries).collect();
    assert!(
        missing.is_empty() && stale.is_empty(),
        "binaries without an index row in docs/experiments.md: {missing:?}; rows naming no \
         binary: {stale:?}"
    );
}
