//! Shared helpers for prt's benchmark sweeps: timing and table printing.
//!
//! Sweeps (binaries in `src/bin`) print `(knob, time, error)` tables and can write CSV, so that
//! the speed/accuracy trade of every algorithm is measured as a curve and quoted in
//! `docs/results.md` together with the command that produced it.
#![deny(missing_docs)]

use std::time::{Duration, Instant};

pub mod manylight;
pub mod mbd;

/// User + system CPU seconds of this whole process so far, all threads (Linux `/proc/self/stat`,
/// 100 ticks per second); NaN where `/proc` is unavailable. On a shared machine the CPU time of
/// a run is what free cores would take, while the wall time also counts the waits for a core.
pub fn cpu_seconds() -> f64 {
    let Ok(stat) = std::fs::read_to_string("/proc/self/stat") else {
        return f64::NAN;
    };
    // Fields after the parenthesised command name (which may contain spaces); utime and stime
    // are fields 14 and 15 of the file, 11 and 12 after the name.
    let rest = stat.rsplit_once(')').map_or("", |(_, r)| r);
    let fields: Vec<&str> = rest.split_whitespace().collect();
    let ticks = |i: usize| fields.get(i).and_then(|v| v.parse::<f64>().ok());
    match (ticks(11), ticks(12)) {
        (Some(user), Some(system)) => (user + system) / 100.0,
        _ => f64::NAN,
    }
}

/// Nanoseconds the calling thread has spent on a CPU (Linux `/proc/thread-self/schedstat`), or
/// `None` elsewhere: single-thread timings that other processes on the machine do not inflate.
pub fn thread_cpu_ns() -> Option<u64> {
    std::fs::read_to_string("/proc/thread-self/schedstat")
        .ok()?
        .split_whitespace()
        .next()?
        .parse()
        .ok()
}

/// Runs `f` `reps` times after one warm-up call and returns the median wall time.
pub fn median_time<T>(reps: usize, mut f: impl FnMut() -> T) -> Duration {
    std::hint::black_box(f());
    let mut times: Vec<Duration> = (0..reps.max(1))
        .map(|_| {
            let t = Instant::now();
            std::hint::black_box(f());
            t.elapsed()
        })
        .collect();
    times.sort();
    times[times.len() / 2]
}

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

    /// Writes the CSV to `path` if the environment variable `PRT_CSV_DIR` names a folder.
    pub fn write_csv_if_requested(&self, name: &str) -> std::io::Result<()> {
        if let Ok(dir) = std::env::var("PRT_CSV_DIR") {
            std::fs::create_dir_all(&dir)?;
            std::fs::write(
                std::path::Path::new(&dir).join(format!("{name}.csv")),
                self.csv(),
            )?;
        }
        Ok(())
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
    fn durations_pick_readable_units() {
        assert_eq!(fmt_duration(Duration::from_millis(1500)), "1.500 s");
        assert_eq!(fmt_duration(Duration::from_micros(2500)), "2.500 ms");
        assert_eq!(fmt_duration(Duration::from_nanos(2500)), "2.500 µs");
    }
}
