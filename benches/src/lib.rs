//! Shared helpers for prt's experiment binaries (`src/bin`) and criterion benches: time and
//! machine measurements, markdown/CSV tables, the shared scenes and maps, and command-line
//! pieces used by several binaries.
//!
//! Binaries print `(knob, time, error)` tables and can write CSV (`--csv DIR`), so that the
//! speed/accuracy trade of every algorithm is measured as a curve and quoted in
//! `docs/results.md` together with the command that produced it; `docs/experiments.md` lists
//! every binary with its command.
#![deny(missing_docs)]

mod cli;
mod data;
mod error;
#[cfg(test)]
mod experiments_index;
mod measure;
mod plot;
mod table;

pub mod manylight;
pub mod mbd;

pub use cli::BvhQuality;
pub use data::{
    Scratch, cache_dir, envmap_names, large_file_limits, load_envmap, load_scene, load_scene_input,
    save_png, shared_dir,
};
pub use error::{RelativeError, model_error_at_centres, relative_mse_at_centres, relative_rms};
pub use measure::{
    Stopwatch, cpu_seconds, load_average, median_time, peak_resident_bytes, read_bandwidth,
    resident_bytes, thread_cpu_ns,
};
pub use plot::{PlotLabels, PlotPoint, plot_lines};
pub use table::{Table, fmt_duration};
