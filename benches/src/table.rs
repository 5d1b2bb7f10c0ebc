//! Tables printed as GitHub markdown and written as CSV, and readable durations.

use std::path::Path;
use std::time::Duration;

/// Formats a duration in the most readable unit (ns, µs, ms or s) with three significant digits.
pub fn fmt_duration(d: Duration) -> String {
    let s = d.as_secs_f64();
    if s >= 1.0 {
        format!("{s:.3} s")
    } else if s >= 1e-3 {
        format!("{:.3} ms", s * 1e3)
    } else if s >= 1e-6 {
        format!("{:.3} µs", s * 1e6)
    } else {
        format!("{:.1} ns", s * 1e9)
    }
}

/// A table printed as GitHub markdown (so it can be pasted into `docs/results.md`) and
/// optionally written as CSV.
#[derive(Debug, Clone, Default)]
pub struct Table {
    header: Vec<String>,
    rows: Vec<Vec<String>>,
}

impl Table {
    /// A table with the given column names.
    pub fn new(header: &[&str]) -> Self {
        Self {
            header: header.iter().map(|s| s.to_string()).collect(),
            rows: Vec::new(),
        }
    }

    /// Appends a row (as many cells as columns).
    pub fn row(&mut self, cells: Vec<String>) {
        self.rows.push(cells);
    }

    /// The table as markdown.
    pub fn markdown(&self) -> String {
        let mut s = format!("| {} |\n", self.header.join(" | "));
        s += &format!("|{}\n", "---|".repeat(self.header.len()));
        for r in &self.rows {
            s += &format!("| {} |\n", r.join(" | "));
        }
        s
    }

    /// The table as CSV.
    pub fn csv(&self) -> String {
        let mut s = self.header.join(",") + "\n";
        for r in &self.rows {
            s += &(r.join(",") + "\n");
        }
        s
    }

    /// Writes the CSV to `dir/name.csv` when a folder is given (a binary's `--csv DIR`),
    /// creating the folder; the file is written under a temporary name and renamed, so that a
    /// reader never sees half a table.
    pub fn write_csv(&self, dir: Option<&Path>, name: &str) -> std::io::Result<()> {
        let Some(dir) = dir else {
            return Ok(());
        };
        std::fs::create_dir_all(dir)?;
        let path = dir.join(format!("{name}.csv"));
        let partial = dir.join(format!(".{name}.csv.partial"));
        std::fs::write(&partial, self.csv())?;
        std::fs::rename(&partial, &path)
    }

    /// [`Table::write_csv`] into the folder named by the environment variable `PRT_CSV_DIR`, if
    /// set: for the criterion benches, which take no flags of their own, and for binaries that
    /// do not take `--csv` yet.
    pub fn write_csv_if_requested(&self, name: &str) -> std::io::Result<()> {
        let dir = std::env::var_os("PRT_CSV_DIR").map(std::path::PathBuf::from);
        self.write_csv(dir.as_deref(), name)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn table_formats_markdown_and_csv() {
        let mut t = Table::new(&["knob", "time"]);
        t.row(vec!["1".into(), "2 ms".into()]);
        assert_eq!(t.markdown(), "| knob | time |\n|---|---|\n| 1 | 2 ms |\n");
        assert_eq!(t.csv(), "knob,time\n1,2 ms\n");
    }

    #[test]
    fn csv_lands_in_the_folder_only_when_asked() {
        let mut t = Table::new(&["a"]);
        t.row(vec!["1".into()]);
        let dir = std::env::temp_dir().join(format!("prt_benches_csv_{}", std::process::id()));
        t.write_csv(None, "nothing").expect("no-op");
        assert!(!dir.exists());
        t.write_csv(Some(&dir), "t").expect("written");
        let text = std::fs::read_to_string(dir.join("t.csv")).expect("readable");
        assert_eq!(text, "a\n1\n");
        assert!(!dir.join(".t.csv.partial").exists());
        std::fs::remove_dir_all(&dir).expect("cleaned up");
    }

    #[test]
    fn durations_pick_readable_units() {
        assert_eq!(fmt_duration(Duration::from_millis(1500)), "1.500 s");
        assert_eq!(fmt_duration(Duration::from_micros(2500)), "2.500 ms");
        assert_eq!(fmt_duration(Duration::from_nanos(2500)), "2.500 µs");
    }
}
