//! Time and machine measurements: CPU time of the process and of a thread, wall-time medians,
//! the load average and resident memory (Linux `/proc`; NaN or `None` elsewhere).

use std::time::{Duration, Instant};

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

/// Wall time and process CPU time ([`cpu_seconds`]) since it was started: the two times every
/// experiment reports for a stage.
#[derive(Debug, Clone, Copy)]
pub struct Stopwatch {
    wall: Instant,
    cpu: f64,
}

impl Stopwatch {
    /// A stopwatch started now.
    pub fn start() -> Self {
        Self {
            wall: Instant::now(),
            cpu: cpu_seconds(),
        }
    }

    /// Wall time since the start.
    pub fn wall(&self) -> Duration {
        self.wall.elapsed()
    }

    /// CPU seconds of the whole process (all threads) since the start; NaN without `/proc`.
    pub fn cpu(&self) -> f64 {
        cpu_seconds() - self.cpu
    }
}

/// The 1, 5 and 15 minute load averages (`/proc/loadavg`), or `unknown`.
pub fn load_average() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .map(|s| s.split_whitespace().take(3).collect::<Vec<_>>().join(" "))
        .unwrap_or_else(|_| "unknown".into())
}

/// Bytes of a `/proc/self/status` memory line (given in kB there), NaN where unavailable.
fn status_bytes(key: &str) -> f64 {
    std::fs::read_to_string("/proc/self/status")
        .unwrap_or_default()
        .lines()
        .find_map(|l| l.strip_prefix(key))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<f64>().ok())
        .map_or(f64::NAN, |kb| kb * 1024.0)
}

/// Peak resident memory of this process so far in bytes (`VmHWM`), NaN where unavailable.
pub fn peak_resident_bytes() -> f64 {
    status_bytes("VmHWM:")
}

/// Resident memory of this process now in bytes (`VmRSS`), NaN where unavailable.
pub fn resident_bytes() -> f64 {
    status_bytes("VmRSS:")
}

/// Single-thread read bandwidth (bytes/s) of summing a 256 MiB buffer with 32 independent
/// accumulators (enough to keep the loads, not the adds, the bottleneck).
pub fn read_bandwidth() -> f64 {
    let data = vec![1.0f32; 64 << 20];
    // Median over repetitions of the thread's CPU time (the machine is shared: wall time
    // would count waiting), falling back to wall time where schedstat is unavailable.
    let mut times: Vec<Duration> = (0..6)
        .map(|_| {
            let (cpu, wall) = (thread_cpu_ns(), std::time::Instant::now());
            let mut acc = [0.0f32; 32];
            for c in data.chunks_exact(32) {
                for k in 0..32 {
                    acc[k] += c[k];
                }
            }
            std::hint::black_box(acc);
            let cpu = Duration::from_nanos(thread_cpu_ns().zip(cpu).map_or(0, |(b, a)| b - a));
            if cpu.is_zero() { wall.elapsed() } else { cpu }
        })
        .collect();
    times.sort();
    (data.len() * 4) as f64 / times[times.len() / 2].as_secs_f64()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stopwatch_counts_forward() {
        let watch = Stopwatch::start();
        std::thread::sleep(Duration::from_millis(2));
        assert!(watch.wall() >= Duration::from_millis(2));
        let cpu = watch.cpu();
        assert!(cpu.is_nan() || cpu >= 0.0);
    }

    #[test]
    fn memory_is_positive_where_proc_exists() {
        // Resident memory first: the peak read afterwards cannot be below it.
        let resident = resident_bytes();
        let peak = peak_resident_bytes();
        if !peak.is_nan() {
            assert!(resident > 0.0 && peak >= resident);
        }
    }
}
