//! `prt` — the command line of the prt toolkit.
//!
//! * `prt bake [SCENE.gltf]` traces a scene's 324-D light-transport volume (the built-in Cornell
//!   box by default), compresses it with Moving Basis Decomposition, compares it with blockwise
//!   and clustered PCA at equal basis count, writes the MBD container (KTX2 volumes + JSON
//!   manifest) and a report (`report.md`, images, loss plot) to an output folder.
//! * `prt encode ENVMAP` fits an environment map into a sphere basis and prints the coefficients.
//! * `prt export BAKE_DIR --target bevy|threejs|sh` lights a bake with a sky and writes probe
//!   volumes that Bevy, three.js or a custom engine load unchanged.
//! * `prt render BAKE_DIR --out IMG` renders the scene of a bake folder lit by one of its volumes
//!   (reference, MBD as written, BPCA, CPCA) under a sky, to PNG or EXR.
//! * `prt relight [SCENE] --envmap MAP --out DIR` bakes per-pixel wavelet transport for a fixed
//!   camera and renders a turning environment map frame by frame with NWA, BI and PBI lighting
//!   approximations against the exact product (frames, animated preview, table, error plot).
//! * `prt view BAKE_DIR` serves a bake folder on 127.0.0.1 with a WebGL2 page that draws its
//!   scene lit by the MBD container (decoded by prt-shaders' GLSL), lit anew as the sky turns.
//! * `prt plan SCENE --tiles X,Y,Z --out PLAN_DIR`, `prt bake-tile PLAN_DIR [--tile I | --all]`
//!   and `prt merge PLAN_DIR --out BAKE_DIR` split a bake into tiles traced by independent
//!   workers (a Kubernetes Indexed Job, a Slurm job array, or local processes) and merge them
//!   into the bake folder `prt bake` writes (deploy/ has the manifests).
//! * `prt manylight [SCENE] --out IMG` renders a scene lit by thousands of point lights (VPLs
//!   traced from its sky, sun and emitters, or a lights file) with row-column sampling,
//!   LightSlice, visibility clustering or tensor clustering over an animation, against brute
//!   force (time, speed-up, relative L2 and ꟻLIP); `--compare` renders every method side by side.
//! * `prt lightmap [SCENE] --out DIR` bakes a progressive lightmap: generated UV charts,
//!   path-traced texels encoded with (non-negative) progressive least squares into SG, SH,
//!   ambient dice or irradiance, previews every K samples, EXR + KTX2 + JSON manifest.
//! * `prt inspect FILE` prints what a KTX2 / EXR / HDR file or an MBD container holds (for a
//!   container, also the model read back: rank, dimension, kernels, validity).
//!
//! Errors are one line on stderr and a non-zero exit code; Ctrl-C cancels the running stage and
//! leaves no half-written file under a final name.

mod bake;
mod encode;
mod export;
mod inspect;
mod lightmap;
mod manylight;
mod merge;
mod plan;
mod progress;
mod relight;
mod render;
mod report;
mod sky;
mod tile;
mod view;

use std::process::ExitCode;

use clap::{Parser, Subcommand};

#[derive(Debug, Parser)]
#[command(
    name = "prt",
    version,
    about = "Precomputed light transport: bake, compress, export, encode, inspect"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Trace a scene's transfer volume, compress it with MBD, write textures and a report.
    Bake(bake::BakeArgs),
    /// Fit an environment map (.hdr / .exr) into a sphere basis.
    Encode(encode::EncodeArgs),
    /// Light a bake with a sky and write probe volumes for Bevy, three.js or custom engines.
    Export(export::ExportArgs),
    /// Print what a KTX2 / EXR / HDR file or an MBD manifest holds.
    Inspect(inspect::InspectArgs),
    /// Bake a progressive lightmap: UVs, path-traced texels encoded with (non-negative)
    /// progressive least squares, previews, EXR + KTX2 + manifest.
    Lightmap(lightmap::LightmapArgs),
    /// Relight a scene from a fixed camera under a turning environment map (per-pixel wavelet
    /// transport; NWA, BI, PBI against the exact product).
    Relight(relight::RelightArgs),
    /// Render a bake folder's scene lit by its reference, MBD, BPCA or CPCA volume (PNG / EXR).
    Render(render::RenderArgs),
    /// Serve a bake folder and a WebGL2 viewer that lights it by a turning sky in real time, on
    /// 127.0.0.1.
    View(view::ViewArgs),
    /// Cut a bake into tiles of its voxel lattice for independent workers (writes PLAN_DIR).
    Plan(plan::PlanArgs),
    /// Trace one tile of a plan (index from --tile, $JOB_COMPLETION_INDEX or
    /// $SLURM_ARRAY_TASK_ID), or every tile as local worker processes (--all).
    BakeTile(tile::TileArgs),
    /// Assemble a plan's finished tiles, solve MBD once and write the bake folder `prt bake`
    /// writes, with the seam measures across tile borders.
    Merge(merge::MergeArgs),
    /// Render a scene lit by thousands of point lights with many-light matrix sampling, against
    /// brute force.
    Manylight(manylight::ManyLightArgs),
}

fn main() -> ExitCode {
    end_quietly_on_closed_stdout();
    let cli = Cli::parse();
    progress::install_ctrlc_handler();
    let result = match cli.command {
        Command::Bake(args) => bake::run(&args),
        Command::Encode(args) => encode::run(&args),
        Command::Export(args) => export::run(&args),
        Command::Inspect(args) => inspect::run(&args),
        Command::Lightmap(args) => lightmap::run(&args),
        Command::Relight(args) => relight::run(&args),
        Command::Render(args) => render::run(&args),
        Command::View(args) => view::run(&args),
        Command::Plan(args) => plan::run(&args),
        Command::BakeTile(args) => tile::run(&args),
        Command::Merge(args) => merge::run(&args),
        Command::Manylight(args) => manylight::run(&args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        // The reader of our output went away (`prt inspect FILE | head`): nothing to report.
        Err(e) if is_closed_stdout(&e) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {}", error_text(&e));
            ExitCode::FAILURE
        }
    }
}

/// `error` and its causes joined by ": ", each cause once: many library errors already end
/// their message with their source's (`"{path}: {source}"`), and anyhow's `{:#}` would repeat it.
fn error_text(error: &anyhow::Error) -> String {
    let mut text = String::new();
    for cause in error.chain() {
        let message = cause.to_string();
        if text.ends_with(&message) {
            continue;
        }
        if !text.is_empty() {
            text.push_str(": ");
        }
        text.push_str(&message);
    }
    text
}

/// Whether `error` is a write into a pipe whose reader has gone.
fn is_closed_stdout(error: &anyhow::Error) -> bool {
    error.chain().any(|cause| {
        cause
            .downcast_ref::<std::io::Error>()
            .is_some_and(|e| e.kind() == std::io::ErrorKind::BrokenPipe)
    })
}

/// A closed stdout (`prt inspect FILE | head`) ends any subcommand quietly with success, as a
/// pipe's reader that stopped reading asks: `println!` panics on a write error ("failed printing
/// to stdout: Broken pipe"), and this hook ends the process with status 0 instead for that panic
/// only (every other panic is reported as before). Rust ignores SIGPIPE, so such a write
/// returns an error rather than killing the process.
fn end_quietly_on_closed_stdout() {
    let report = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        let payload = info.payload();
        let message = payload
            .downcast_ref::<String>()
            .map(String::as_str)
            .or_else(|| payload.downcast_ref::<&str>().copied())
            .unwrap_or_default();
        if is_closed_stdout_panic(message) {
            std::process::exit(0);
        }
        report(info)
    }));
}

/// Whether `message` is std's panic of a `print!` into a pipe without a reader.
fn is_closed_stdout_panic(message: &str) -> bool {
    let Some(error) = message.strip_prefix("failed printing to stdout: ") else {
        return false;
    };
    // EPIPE on Linux, macOS and the BSDs; ERROR_BROKEN_PIPE and ERROR_NO_DATA on Windows.
    let codes: &[i32] = if cfg!(windows) { &[109, 232] } else { &[32] };
    codes.iter().any(|&code| {
        let broken = std::io::Error::from_raw_os_error(code);
        broken.kind() == std::io::ErrorKind::BrokenPipe && error == broken.to_string()
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_a_print_into_a_closed_pipe_is_quiet() {
        let broken = std::io::Error::from(std::io::ErrorKind::BrokenPipe);
        assert!(is_closed_stdout(
            &anyhow::Error::new(broken).context("writing")
        ));
        assert!(!is_closed_stdout(&anyhow::anyhow!("Broken pipe")));
        let code = if cfg!(windows) { 232 } else { 32 };
        let epipe = std::io::Error::from_raw_os_error(code);
        assert!(is_closed_stdout_panic(&format!(
            "failed printing to stdout: {epipe}"
        )));
        let full = std::io::Error::from(std::io::ErrorKind::StorageFull);
        assert!(!is_closed_stdout_panic(&format!(
            "failed printing to stdout: {full}"
        )));
        assert!(!is_closed_stdout_panic(&format!(
            "failed printing to stderr: {epipe}"
        )));
    }

    #[test]
    fn an_error_prints_each_cause_once() {
        #[derive(Debug)]
        struct EmbedsItsSource {
            source: std::io::Error,
        }
        impl std::fmt::Display for EmbedsItsSource {
            fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                write!(f, "plan.json: {}", self.source)
            }
        }
        impl std::error::Error for EmbedsItsSource {
            fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
                Some(&self.source)
            }
        }
        let missing = || std::io::Error::from(std::io::ErrorKind::NotFound);
        let embedded = anyhow::Error::new(EmbedsItsSource { source: missing() })
            .context("cannot read the plan");
        assert_eq!(
            error_text(&embedded),
            format!("cannot read the plan: plan.json: {}", missing())
        );
        let chained = anyhow::Error::new(missing()).context("cannot read the plan");
        assert_eq!(
            error_text(&chained),
            format!("cannot read the plan: {}", missing())
        );
    }
}
