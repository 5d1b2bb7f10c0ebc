//! The main job's speed/accuracy trade: each `prt bake` knob against the end-to-end error of
//! the container as written and the time of the bake.
//!
//! ```text
//! cargo run --release -p prt-benches --bin bake_knobs -- --scene cornell [--knobs res,rays,...] [--csv DIR]
//! cargo run --release -p prt-benches --bin bake_knobs -- --scene sponza --presets
//! ```
//!
//! One reference volume is traced at high quality (`--reference-res`, `--reference-rays`,
//! `--reference-cache-rays`, seed 1001) and cached in `target/bake_knobs/`. Then each knob in
//! turn takes every value of its list with every other knob at `prt bake`'s default; each bake
//! (`prt_bake::bake`, baselines off) writes its container into a temporary folder, which is read
//! back and scored against the reference (jittered samples over the reference's voxels; the
//! model clamps points outside its own voxel-centre box) and against the bake's own traced
//! volume (the compression alone). `--presets` runs the three named presets instead. The
//! reference's own Monte Carlo noise is measured against a second reference traced with another
//! seed (1002) and printed first: no bake can score below it.

use std::path::{Path, PathBuf};

use clap::{Parser, ValueEnum};
use glam::Vec3;
use prt_bake::container::read_container;
use prt_bake::{BakeConfig, Method, Quality, SceneInput, Stage, bake};
use prt_benches::mbd::{read_cached, write_cached};
use prt_benches::{
    RelativeError, Scratch, Stopwatch, Table, cache_dir, load_average, load_scene_input,
};
use prt_core::{FieldModel, GridField, NoProgress};
use prt_mbd::{EvalOptions, evaluate};
use prt_texture::{Encoding, Limits};
use prt_trace::{BakeOptions, TransferBaker};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;
use rayon::prelude::*;

/// Seeds of the two reference traces: never a bake's seed (0), whose ray directions they would
/// share.
const REFERENCE_SEEDS: [u64; 2] = [1001, 1002];

#[derive(Debug, Parser)]
#[command(about = "prt bake's knobs against end-to-end error and time, and the named presets")]
struct Cli {
    /// Scene: `cornell` (built in) or `sponza` (../shared/scenes/sponza).
    #[arg(long, default_value = "cornell")]
    scene: String,
    /// Knobs to sweep, each with every other knob at its default.
    #[arg(
        long,
        value_enum,
        value_delimiter = ',',
        default_value = "res,rays,cache_rays,rank,basis_nodes,iterations,encoding"
    )]
    knobs: Vec<Knob>,
    /// Run the presets (draft, default, high) through the same measurement instead of the knobs.
    #[arg(long)]
    presets: bool,
    /// Voxels along the longest axis of the values of `res` [default: 16,24,32,48; Sponza 32,48,64].
    #[arg(long, value_delimiter = ',')]
    res: Vec<usize>,
    /// Values of `rays` (directions per voxel).
    #[arg(long, value_delimiter = ',', default_value = "64,128,256,512")]
    rays: Vec<usize>,
    /// Values of `cache_rays` (surface-cache rays).
    #[arg(long, value_delimiter = ',', default_value = "16,32,64,128")]
    cache_rays: Vec<usize>,
    /// Values of `rank` (MBD rank L).
    #[arg(long, value_delimiter = ',', default_value = "2,4,8,12,16")]
    rank: Vec<usize>,
    /// Values of `basis_nodes` (MBD basis nodes per axis).
    #[arg(long, value_delimiter = ',', default_value = "3,4,5,7,9")]
    basis_nodes: Vec<usize>,
    /// Values of `iterations` (MBD iteration cap).
    #[arg(long, value_delimiter = ',', default_value = "16,32,64,128")]
    iterations: Vec<usize>,
    /// Values of `encoding` (f32, f16, unorm16, unorm8).
    #[arg(long, value_delimiter = ',', default_value = "f32,f16,unorm16,unorm8")]
    encoding: Vec<String>,
    /// Voxels along the longest axis of the reference volume.
    #[arg(long, default_value_t = 64)]
    reference_res: usize,
    /// Directions per voxel of the reference.
    #[arg(long, default_value_t = 2048)]
    reference_rays: usize,
    /// Surface-cache rays of the reference.
    #[arg(long, default_value_t = 256)]
    reference_cache_rays: usize,
    /// Also write each table as CSV into this folder (`bake_knobs_KNOB.csv`, `bake_knobs_presets.csv`).
    #[arg(long)]
    csv: Option<PathBuf>,
}

/// A knob of `prt bake`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
enum Knob {
    /// Voxels along the longest axis (`--res`).
    Res,
    /// Directions per voxel (`--rays`).
    Rays,
    /// Surface-cache rays (`--cache-rays`).
    #[value(name = "cache_rays")]
    CacheRays,
    /// MBD rank (`--rank`).
    Rank,
    /// MBD basis nodes per axis (`--basis-nodes`).
    #[value(name = "basis_nodes")]
    BasisNodes,
    /// MBD iteration cap (`--iterations`).
    Iterations,
    /// Storage encoding (`--encoding`).
    Encoding,
}

impl Knob {
    fn name(self) -> &'static str {
        match self {
            Knob::Res => "res",
            Knob::Rays => "rays",
            Knob::CacheRays => "cache_rays",
            Knob::Rank => "rank",
            Knob::BasisNodes => "basis_nodes",
            Knob::Iterations => "iterations",
            Knob::Encoding => "encoding",
        }
    }
}

/// One value of a knob.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Setting {
    Count(Knob, usize),
    Encoding(Encoding),
}

impl Setting {
    /// `base` with this setting applied.
    fn apply(self, base: &BakeConfig) -> BakeConfig {
        let mut config = base.clone();
        match self {
            Setting::Count(Knob::Res, v) => config.resolution = v,
            Setting::Count(Knob::Rays, v) => config.rays_per_voxel = v,
            Setting::Count(Knob::CacheRays, v) => config.cache_rays = v,
            Setting::Count(Knob::Rank, v) => config.rank = v,
            Setting::Count(Knob::BasisNodes, v) => config.basis_nodes = v,
            Setting::Count(Knob::Iterations, v) => config.max_iterations = v,
            Setting::Count(Knob::Encoding, _) => unreachable!("encodings are Setting::Encoding"),
            Setting::Encoding(e) => config.encoding = e,
        }
        config
    }

    fn label(self) -> String {
        match self {
            Setting::Count(_, v) => v.to_string(),
            Setting::Encoding(e) => format!("{e:?}").to_lowercase(),
        }
    }
}

fn parse_encoding(name: &str) -> Result<Encoding, String> {
    match name.trim().to_lowercase().as_str() {
        "f32" => Ok(Encoding::F32),
        "f16" => Ok(Encoding::F16),
        "unorm16" => Ok(Encoding::Unorm16),
        "unorm8" => Ok(Encoding::Unorm8),
        other => Err(format!(
            "unknown encoding {other} (f32, f16, unorm16, unorm8)"
        )),
    }
}

/// What one bake cost and how close its container comes.
#[derive(Debug, Clone)]
struct Row {
    label: String,
    trace_s: f64,
    mbd_s: f64,
    wall_s: f64,
    cpu_s: f64,
    bytes_per_voxel: f64,
    mse_own: f64,
    mse_reference: f64,
    mse_interior: f64,
}

const HEADER: [&str; 11] = [
    "value",
    "trace s",
    "MBD s",
    "total wall s",
    "total CPU s",
    "bytes/voxel",
    "rel. MSE vs own trace",
    "rel. MSE vs reference",
    "× default's",
    "vs reference, interior",
    "× default's",
];

/// The table of `rows`; the "× default's" columns divide by the errors of `default` (the row
/// with every knob at its default), when there is one.
fn table(rows: &[Row], default: Option<&Row>) -> Table {
    let mut table = Table::new(&HEADER);
    let ratio = |error: f64, default_error: Option<f64>| {
        default_error.map_or("–".into(), |d| format!("{:.2}", error / d))
    };
    for r in rows {
        table.row(vec![
            r.label.clone(),
            format!("{:.2}", r.trace_s),
            format!("{:.2}", r.mbd_s),
            format!("{:.2}", r.wall_s),
            format!("{:.2}", r.cpu_s),
            format!("{:.2}", r.bytes_per_voxel),
            format!("{:.3e}", r.mse_own),
            format!("{:.3e}", r.mse_reference),
            ratio(r.mse_reference, default.map(|d| d.mse_reference)),
            format!("{:.3e}", r.mse_interior),
            ratio(r.mse_interior, default.map(|d| d.mse_interior)),
        ]);
    }
    table
}

/// Traces `scene` at `res` voxels along its longest axis (the grid `prt bake --res res` uses).
fn trace_reference(
    scene: &SceneInput,
    res: usize,
    rays: usize,
    cache_rays: usize,
    seed: u64,
) -> GridField {
    let bounds = scene.scene.bounds().expect("the scene has triangles");
    let grid = BakeConfig {
        resolution: res,
        ..BakeConfig::default()
    };
    let options = BakeOptions {
        resolution: grid.grid_resolution(bounds.size().to_array()),
        rays_per_voxel: rays,
        cache_rays,
        seed,
        ..BakeOptions::default()
    };
    TransferBaker::new(&scene.scene, options)
        .and_then(|baker| baker.bake(&NoProgress))
        .expect("reference trace")
        .field
}

/// [`trace_reference`], read from `target/bake_knobs/` when an earlier run wrote it.
fn cached_reference(
    scene_name: &str,
    scene: &SceneInput,
    (res, rays, cache_rays): (usize, usize, usize),
    seed: u64,
) -> GridField {
    let path = cache_dir("bake_knobs").join(format!(
        "{scene_name}_{res}_r{rays}_c{cache_rays}_s{seed}.f32"
    ));
    if let Some(field) = read_cached(&path) {
        eprintln!("reference: read {}", path.display());
        return field;
    }
    let watch = Stopwatch::start();
    let field = trace_reference(scene, res, rays, cache_rays, seed);
    eprintln!(
        "reference {:?}, {rays} rays, {cache_rays} cache rays, seed {seed}: traced in {:.1} s (CPU {:.1} s)",
        field.dims(),
        watch.wall().as_secs_f64(),
        watch.cpu()
    );
    if let Err(e) = write_cached(&path, &field) {
        eprintln!("cannot cache {}: {e}", path.display());
    }
    field
}

/// `Σ‖a − b‖² / Σ‖a‖²` over the voxels of two fields on the same grid.
fn voxel_relative_mse(a: &GridField, b: &GridField) -> f64 {
    assert_eq!(a.dims(), b.dims(), "the references share a grid");
    let mut sum = RelativeError::default();
    sum.add(
        b.data().as_slice().expect("standard layout"),
        a.data().as_slice().expect("standard layout"),
    );
    sum.relative_mse()
}

/// Bakes `scene` with `config` (baselines off, container into `folder`), reads the container
/// back and scores it against `reference`.
fn measure(
    scene: &SceneInput,
    config: &BakeConfig,
    reference: &Reference,
    folder: &Path,
    label: String,
) -> Row {
    let config = BakeConfig {
        baselines: false,
        container: Some(folder.to_path_buf()),
        ..config.clone()
    };
    let watch = Stopwatch::start();
    let baked = bake(scene, &config, &NoProgress).expect("bake");
    let (wall_s, cpu_s) = (watch.wall().as_secs_f64(), watch.cpu());
    let stage = |s: Stage| {
        baked
            .stage_times
            .iter()
            .find(|(stage, _)| *stage == s)
            .map_or(0.0, |(_, t)| t.as_secs_f64())
    };
    let written = baked
        .comparison
        .iter()
        .find(|row| matches!(row.method, Method::MbdAsWritten(_)))
        .expect("a container was written");
    let container = read_container(folder, &Limits::default()).expect("container reads back");
    let options = EvalOptions {
        seed: 0x5EED,
        ..EvalOptions::default()
    };
    let mse_reference = evaluate(&container.model, &reference.field, &options)
        .expect("the model evaluates over the reference's box")
        .relative_mse;
    let mse_interior = interior_relative_mse(&container.model, reference, options.seed);
    Row {
        label,
        trace_s: stage(Stage::Trace),
        mbd_s: stage(Stage::Mbd),
        wall_s,
        cpu_s,
        bytes_per_voxel: written.bytes_per_voxel.unwrap_or(f64::NAN),
        mse_own: written.relative_mse,
        mse_reference,
        mse_interior,
    }
}

/// The reference volume and its interior: the voxels that count for the interior error.
struct Reference {
    field: GridField,
    /// Per voxel: valid (non-zero transfer) and at least [`SHELL`] voxels from every face.
    interior: Vec<bool>,
}

/// Reference voxels next to the box's faces left out of the interior error. On Sponza the
/// outermost layer lies outside the walls under the open sky and holds 89 % of the reference's
/// energy, and the next one is mostly inside the walls: there the error measures how a coarse
/// grid meets the box's faces, not the transfer inside the building.
const SHELL: usize = 2;

impl Reference {
    fn new(field: GridField) -> Reference {
        let [nx, ny, nz] = field.dims();
        let inside = |i: usize, n: usize| i >= SHELL && i + SHELL < n;
        let interior = (0..field.num_voxels())
            .map(|v| {
                let (x, y, z) = (v % nx, v / nx % ny, v / (nx * ny));
                inside(x, nx)
                    && inside(y, ny)
                    && inside(z, nz)
                    && field.voxel(v).iter().any(|&t| t != 0.0)
            })
            .collect();
        Reference { field, interior }
    }
}

/// `Σ‖f̂ − f‖² / Σ‖f‖²` over jittered samples (4 per voxel, as `prt_mbd::evaluate`) in the
/// reference's interior voxels.
fn interior_relative_mse(model: &dyn FieldModel, reference: &Reference, seed: u64) -> f64 {
    const SAMPLES: u64 = 4;
    let field = &reference.field;
    let size = field.voxel_size();
    let dim = field.dim();
    let sums: Vec<RelativeError> = (0..field.num_voxels())
        .into_par_iter()
        .filter(|&v| reference.interior[v])
        .map(|v| {
            let mut rng = Pcg64Mcg::seed_from_u64(seed ^ (v as u64).wrapping_mul(0x9E37_79B9));
            let (mut f, mut g) = (vec![0.0f32; dim], vec![0.0f32; dim]);
            let mut sum = RelativeError::default();
            for _ in 0..SAMPLES {
                let u = Vec3::new(rng.random(), rng.random(), rng.random());
                let x = field.centre_of(v) + (u - 0.5) * size;
                field.sample(x, &mut f).expect("inside the box");
                model.eval(x, &mut g).expect("the model clamps");
                sum.add(&g, &f);
            }
            sum
        })
        .collect();
    // Summed in voxel order, so the figure does not depend on the thread count.
    sums.into_iter()
        .fold(RelativeError::default(), RelativeError::merged)
        .relative_mse()
}

fn main() {
    let cli = Cli::parse();
    let scene = load_scene_input(&cli.scene).unwrap_or_else(|e| {
        eprintln!("cannot load the scene: {e}");
        std::process::exit(2)
    });
    let encodings = cli
        .encoding
        .iter()
        .map(|e| parse_encoding(e))
        .collect::<Result<Vec<_>, _>>()
        .unwrap_or_else(|e| {
            eprintln!("--encoding: {e}");
            std::process::exit(2);
        });
    let res_values = if cli.res.is_empty() {
        if cli.scene == "sponza" {
            vec![32, 48, 64]
        } else {
            vec![16, 24, 32, 48]
        }
    } else {
        cli.res.clone()
    };
    println!("load average before: {}\n", load_average());

    let reference_settings = (
        cli.reference_res,
        cli.reference_rays,
        cli.reference_cache_rays,
    );
    let [reference, second] =
        REFERENCE_SEEDS.map(|seed| cached_reference(&cli.scene, &scene, reference_settings, seed));
    let between = voxel_relative_mse(&reference, &second);
    let reference = Reference::new(reference);
    let interior = reference.interior.iter().filter(|&&i| i).count();
    println!(
        "Reference: {} {:?}, {} rays, {} cache rays, seed {}. Noise floor: relative MSE {between:.3e} \
         against a second reference with seed {} (independent noise: the reference's own noise is \
         about half, {:.3e}, and adds to every error below).\n",
        cli.scene,
        reference.field.dims(),
        cli.reference_rays,
        cli.reference_cache_rays,
        REFERENCE_SEEDS[0],
        REFERENCE_SEEDS[1],
        between / 2.0
    );
    println!(
        "\"vs reference\": jittered samples over the whole reference box; \"interior\": over its \
         {interior} valid voxels at least {SHELL} voxels from the box's faces.\n"
    );

    let scratch = Scratch::new("bake_knobs", &cli.scene);
    let base = BakeConfig::default();
    let run_start = Stopwatch::start();
    if cli.presets {
        let rows: Vec<Row> = [Quality::Draft, Quality::Default, Quality::High]
            .into_iter()
            .map(|quality| {
                let config = BakeConfig::preset(quality);
                let row = measure(
                    &scene,
                    &config,
                    &reference,
                    scratch.path(),
                    format!("{quality:?}").to_lowercase(),
                );
                eprintln!("preset {}: {row:?}", row.label);
                row
            })
            .collect();
        let table = table(&rows, Some(&rows[1]));
        println!("### {} — presets\n\n{}", cli.scene, table.markdown());
        table
            .write_csv(cli.csv.as_deref(), "bake_knobs_presets")
            .expect("CSV written");
    } else {
        for &knob in &cli.knobs {
            let settings: Vec<Setting> = match knob {
                Knob::Encoding => encodings.iter().map(|&e| Setting::Encoding(e)).collect(),
                _ => match knob {
                    Knob::Res => &res_values,
                    Knob::Rays => &cli.rays,
                    Knob::CacheRays => &cli.cache_rays,
                    Knob::Rank => &cli.rank,
                    Knob::BasisNodes => &cli.basis_nodes,
                    _ => &cli.iterations,
                }
                .iter()
                .map(|&v| Setting::Count(knob, v))
                .collect(),
            };
            let rows = sweep(&scene, &base, &settings, &reference, scratch.path());
            // The default's row, when the list holds it, scales the last column.
            let default = settings
                .iter()
                .position(|s| s.apply(&base) == base)
                .map(|i| &rows[i]);
            let table = table(&rows, default);
            println!(
                "### {} — {} (every other knob at its default)\n\n{}",
                cli.scene,
                knob.name(),
                table.markdown()
            );
            table
                .write_csv(cli.csv.as_deref(), &format!("bake_knobs_{}", knob.name()))
                .expect("CSV written");
        }
    }
    println!(
        "whole run: {:.1} s wall, {:.1} s CPU; load average after: {}",
        run_start.wall().as_secs_f64(),
        run_start.cpu(),
        load_average()
    );
}

/// Bakes `base` with each of `settings` and measures it.
fn sweep(
    scene: &SceneInput,
    base: &BakeConfig,
    settings: &[Setting],
    reference: &Reference,
    folder: &Path,
) -> Vec<Row> {
    settings
        .iter()
        .map(|&setting| {
            let row = measure(
                scene,
                &setting.apply(base),
                reference,
                folder,
                setting.label(),
            );
            eprintln!("{setting:?}: {row:?}");
            row
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn more_rays_bring_the_container_closer_to_the_reference() {
        let scene = SceneInput::cornell_box();
        let reference = Reference::new(trace_reference(&scene, 8, 48, 16, REFERENCE_SEEDS[0]));
        // The undenoised trace: denoised, both bakes sit at the 48-ray reference's own noise
        // (and 12 rays round up to 48, whole rounds of the variance's streams).
        let base = BakeConfig {
            resolution: 8,
            rays_per_voxel: 24,
            cache_rays: 8,
            basis_nodes: 3,
            max_iterations: 16,
            denoise: None,
            ..BakeConfig::default()
        };
        let scratch = Scratch::new("bake_knobs", "test");
        let rows = sweep(
            &scene,
            &base,
            &[
                Setting::Count(Knob::Rays, 12),
                Setting::Count(Knob::Rays, 96),
            ],
            &reference,
            scratch.path(),
        );
        let (few, many) = (&rows[0], &rows[1]);
        assert!(
            many.mse_reference < 0.8 * few.mse_reference
                && many.mse_interior < 0.8 * few.mse_interior,
            "12 rays: {few:?}, 96 rays: {many:?}"
        );
        assert!(few.bytes_per_voxel > 0.0 && few.mse_own > 0.0);
    }

    #[test]
    fn a_coarse_model_evaluates_over_a_finer_grid_by_clamping() {
        // The model's coefficient grid spans its voxel centres; the reference's jittered samples
        // reach past them to the box's faces, where the model must clamp, not fail.
        let scene = SceneInput::cornell_box();
        let reference = Reference::new(trace_reference(&scene, 8, 12, 4, REFERENCE_SEEDS[0]));
        let config = BakeConfig {
            resolution: 4,
            rays_per_voxel: 12,
            cache_rays: 4,
            rank: 2,
            basis_nodes: 2,
            max_iterations: 4,
            ..BakeConfig::default()
        };
        let scratch = Scratch::new("bake_knobs", "clamp");
        let row = measure(&scene, &config, &reference, scratch.path(), "4".into());
        assert!(row.mse_reference.is_finite() && row.mse_reference > 0.0);
        assert!(row.mse_interior.is_finite() && row.mse_interior > 0.0);
    }
}
