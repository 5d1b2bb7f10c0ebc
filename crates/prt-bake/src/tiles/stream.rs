//! The merge in bounded memory: the tiles are read one at a time, never assembled. MBD's basis
//! is fitted to the volume halved until it is small (an eighth of it or less, summed tile by
//! tile), refined by
//! alternating least squares on the voxel centres whose basis step sums the tiles' normal
//! equations, and every voxel's coefficients are its own least-squares fit on that basis.

use std::path::Path;
use std::time::{Duration, Instant};

use ndarray::Array2;
use prt_core::{GridField, Progress};
use prt_kernels::HatGrid;
use prt_mbd::expert::{can_halve, halved_grid};
use prt_mbd::{
    Basis, BasisNormals, Mbd, MbdError, MbdModel, ProjectScratch, SolveReport, SolverOptions,
    StreamedMbd,
};
use prt_texture::Limits;
use prt_texture::container::WriteReport;
use rayon::prelude::*;

use super::file::{TileData, read_tile};
use super::plan::{TileError, TilePlan, TileSpec, flat, voxels};
use crate::container::{ContainerContents, write_container};
use crate::{BakeConfig, BakeError, TRANSFER_DIM};

/// Voxels per work unit of the passes over a tile (fixed, so that every sum is the same on any
/// number of threads).
const CHUNK: usize = 16384;

/// What [`merge_streamed`] did.
#[derive(Debug, Clone)]
pub struct StreamedMerge {
    /// The fitted model on the plan's lattice.
    pub model: MbdModel<HatGrid, HatGrid>,
    /// Per voxel of the lattice (x fastest): valid in its tile's trace.
    pub valid: Vec<bool>,
    /// The coarse grid the basis was first fitted on: the lattice halved
    /// [`BakeConfig::coarse_levels`] times (at least once, and no further than the basis grid
    /// allows).
    pub coarse_dims: [usize; 3],
    /// That fit's solver report.
    pub coarse_solve: SolveReport,
    /// `Σ‖f − f̂‖² / Σ‖f‖²` over the valid voxel centres: after the coarse fit (the basis
    /// as fitted at half resolution) and after each alternating sweep.
    pub relative_errors: Vec<f64>,
    /// The container written, when the config names a folder.
    pub container: Option<WriteReport>,
    /// Wall time of each step: "coarse volume", "coarse fit", "sweep", ..., "coefficients",
    /// "write".
    pub stage_times: Vec<(&'static str, Duration)>,
}

fn mbd_error(source: MbdError) -> TileError {
    TileError::Bake(BakeError::Mbd(source))
}

/// The core voxels of `tile` that are valid, with their index into the tile's trace.
fn valid_core_voxels(tile: &TileSpec, read: &TileData) -> Vec<([usize; 3], usize)> {
    voxels(&tile.traced)
        .enumerate()
        .filter(|&(local, v)| tile.core.contains(v) && read.valid[local])
        .map(|(local, v)| (v, local))
        .collect()
}

/// Merges the finished tiles of `plan` in memory bounded by one tile, the coarse volume (at most
/// an eighth of the lattice) and the coefficients (L floats per voxel): MBD of `config`'s rank on its basis
/// grid, with `sweeps` alternating least-squares sweeps over the tiles after the coarse fit;
/// writes the container when `config.container` names a folder. Deterministic for the plan on
/// any number of threads.
///
/// # Errors
/// Those of reading the tiles, each checked against the plan and `limits` as
/// [`super::assemble`] does ([`TileError`]); a lattice too small to halve with its basis grid
/// ([`TileError::InvalidTiling`]); the fit's and the container's.
pub fn merge_streamed(
    plan: &TilePlan,
    plan_dir: &Path,
    scene_name: &str,
    config: &BakeConfig,
    sweeps: usize,
    limits: &Limits,
    progress: &dyn Progress,
) -> Result<StreamedMerge, TileError> {
    config.validate()?;
    let dims = plan.lattice_dims;
    let bounds = plan.lattice_bounds();
    let nodes = config.basis_grid(dims);
    if !can_halve(dims, nodes) {
        return Err(TileError::InvalidTiling(format!(
            "the lattice {dims:?} is too small to halve with {nodes:?} basis nodes; merge it \
             in memory"
        )));
    }
    let mut stage_times = Vec::new();
    let mut timed = |name: &'static str, start: Instant| stage_times.push((name, start.elapsed()));
    let d = TRANSFER_DIM;

    // The volume halved `levels` times (each coarse voxel the mean of the valid voxels of a
    // block of 2^levels per axis), summed tile by tile.
    let start = Instant::now();
    progress.message("coarse volume");
    let mut levels = config.coarse_levels(dims).max(1);
    let mut coarse_dims = dims;
    let mut coarse_bounds = bounds;
    for level in 0..levels {
        if !can_halve(coarse_dims, nodes) {
            levels = level;
            break;
        }
        (coarse_dims, coarse_bounds) = halved_grid(coarse_dims, coarse_bounds);
    }
    let coarse_voxels: usize = coarse_dims.iter().product();
    let mut sums = vec![0.0f32; coarse_voxels * d];
    let mut counts = vec![0u32; coarse_voxels];
    let mut valid = vec![false; dims.iter().product()];
    let coarse_of = |v: [usize; 3]| flat(coarse_dims, v.map(|i| i >> levels));
    for tile in &plan.tiles {
        progress
            .check()
            .map_err(|e| TileError::Bake(BakeError::Cancelled(e)))?;
        let read = read_tile(plan, plan_dir, tile, limits)?;
        for (v, local) in valid_core_voxels(tile, &read) {
            valid[flat(dims, v)] = true;
            let c = coarse_of(v);
            counts[c] += 1;
            let source = &read.transfer[local * d..(local + 1) * d];
            for (s, &x) in sums[c * d..(c + 1) * d].iter_mut().zip(source) {
                *s += x;
            }
        }
    }
    if !valid.contains(&true) {
        return Err(mbd_error(MbdError::InvalidOption {
            what: "validity mask",
            why: "no voxel is valid".into(),
        }));
    }
    let coarse_valid: Vec<bool> = counts.iter().map(|&n| n > 0).collect();
    for (row, &n) in sums.chunks_exact_mut(d).zip(&counts) {
        if n > 0 {
            let inverse = 1.0 / n as f32;
            row.iter_mut().for_each(|x| *x *= inverse);
        }
    }
    drop(counts);
    let coarse = GridField::from_data(
        coarse_dims,
        coarse_bounds,
        Array2::from_shape_vec((coarse_voxels, d), sums).map_err(|e| {
            mbd_error(MbdError::InvalidOption {
                what: "coarse volume",
                why: e.to_string(),
            })
        })?,
    )
    .map_err(|e| mbd_error(e.into()))?;
    timed("coarse volume", start);

    // MBD on it, from the paper's start.
    let start = Instant::now();
    progress.message("coarse fit");
    let mbd = Mbd {
        solver: SolverOptions {
            lambda: config.lambda,
            max_iterations: config.max_iterations,
            seed: config.seed ^ 0x4D42_4400,
            ..SolverOptions::default()
        },
        ..Mbd::new(config.rank, Basis::HatGrid { nodes })
    };
    let fit = mbd
        .fit_masked(&coarse, &coarse_valid, progress)
        .map_err(mbd_error)?;
    drop(coarse);
    let coarse_solve = fit.solve;
    let (_, _, _, basis) = fit.model.into_parts();
    let mut model =
        StreamedMbd::new(dims, bounds, nodes, basis, config.lambda).map_err(mbd_error)?;
    timed("coarse fit", start);

    // Alternating sweeps, then the coefficients on the last basis.
    let mut relative_errors = Vec::new();
    let l = model.rank();
    let mut coefficients = Array2::<f32>::zeros((valid.len(), l));
    for sweep in 0..=sweeps {
        let start = Instant::now();
        let last = sweep == sweeps;
        progress.message(if last { "coefficients" } else { "sweep" });
        let mut normals = (!last).then(|| model.normals());
        let (mut residual, mut energy) = (0.0f64, 0.0f64);
        for tile in &plan.tiles {
            progress
                .check()
                .map_err(|e| TileError::Bake(BakeError::Cancelled(e)))?;
            let read = read_tile(plan, plan_dir, tile, limits)?;
            let voxels = valid_core_voxels(tile, &read);
            let parts = voxels
                .par_chunks(CHUNK)
                .map(|chunk| project_chunk(&model, &read, chunk, !last))
                .collect::<Result<Vec<_>, MbdError>>()
                .map_err(mbd_error)?;
            for (chunk, part) in voxels.chunks(CHUNK).zip(parts) {
                residual += part.residual;
                energy += part.energy;
                if let (Some(total), Some(sums)) = (normals.as_mut(), part.normals.as_ref()) {
                    total.add(sums).map_err(mbd_error)?;
                }
                if last {
                    for (&(v, _), c) in chunk.iter().zip(part.coefficients.chunks_exact(l)) {
                        coefficients
                            .row_mut(flat(dims, v))
                            .iter_mut()
                            .zip(c)
                            .for_each(|(o, &x)| *o = x);
                    }
                }
            }
        }
        relative_errors.push(if energy > 0.0 {
            residual / energy
        } else {
            residual
        });
        if let Some(normals) = &normals {
            model.solve_basis(normals).map_err(mbd_error)?;
        }
        timed(if last { "coefficients" } else { "sweep" }, start);
    }
    let model = model.into_model(coefficients).map_err(mbd_error)?;

    let container = match &config.container {
        Some(folder) => {
            let start = Instant::now();
            progress.message("write");
            let contents = ContainerContents {
                model: &model,
                grid: dims,
                valid: &valid,
                scene: scene_name,
                lambda: config.lambda,
                encoding: config.encoding,
            };
            let report = write_container(folder, &contents)
                .map_err(|e| TileError::Bake(BakeError::Container(e)))?;
            timed("write", start);
            Some(report)
        }
        None => None,
    };
    Ok(StreamedMerge {
        model,
        valid,
        coarse_dims,
        coarse_solve,
        relative_errors,
        container,
        stage_times,
    })
}

/// One chunk's coefficients, residual and energy, and its part of the basis step's normal
/// equations when `accumulate` asks for them.
struct ChunkPart {
    coefficients: Vec<f32>,
    residual: f64,
    energy: f64,
    normals: Option<BasisNormals>,
}

fn project_chunk(
    model: &StreamedMbd,
    read: &TileData,
    chunk: &[([usize; 3], usize)],
    accumulate: bool,
) -> Result<ChunkPart, MbdError> {
    let (l, d) = (model.rank(), TRANSFER_DIM);
    let mut part = ChunkPart {
        coefficients: vec![0.0; chunk.len() * l],
        residual: 0.0,
        energy: 0.0,
        normals: accumulate.then(|| model.normals()),
    };
    let mut scratch = ProjectScratch::default();
    for (&(v, local), c) in chunk.iter().zip(part.coefficients.chunks_exact_mut(l)) {
        let f = &read.transfer[local * d..(local + 1) * d];
        part.residual += model.project(v, f, c, &mut scratch)?;
        part.energy += f.iter().map(|&x| f64::from(x).powi(2)).sum::<f64>();
        if let Some(normals) = part.normals.as_mut() {
            model.accumulate(v, f, c, normals, &mut scratch)?;
        }
    }
    Ok(part)
}
