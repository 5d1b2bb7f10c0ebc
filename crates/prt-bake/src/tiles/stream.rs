//! The merge in bounded memory: the tiles are read one at a time, never assembled. MBD's basis
//! is fitted to the volume halved until it is small (an eighth of it or less, summed tile by
//! tile), refined by alternating least squares on the voxel centres whose basis step sums the
//! tiles' normal equations, and every voxel's coefficients are its own least-squares fit on that
//! basis.
//!
//! MBD's per-voxel loss weighting ([`BakeConfig::loss_weighting`]) is the in-memory fit's: each
//! voxel's vector is scaled by its weight as it is read and its coefficients are divided by it
//! after the fit. The weights' normalisation, the valid voxels' mean magnitude, is summed by the
//! coarse stage's maps, so every later stage knows it; the coarse fit weights the coarse volume
//! as [`Mbd`] weights any field.
//!
//! Every stage ([`MergeStage`]) is a map over tiles (a function of one tile and the current
//! basis giving a small [`Partial`]) and a reduce (the partials summed in tile order, then
//! solved). [`merge_streamed`] runs them all in one process; `prt merge --map` / `--reduce` run
//! the same functions as separate processes that pass the partials and bases as files
//! ([`map_tile`], [`reduce_stage`], [`merge_from_partials`]), so both give the same bytes.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use ndarray::{Array2, Array3};
use prt_core::{Aabb, GridField, Progress};
use prt_kernels::HatGrid;
use prt_mbd::expert::{can_halve, halved_grid};
use prt_mbd::{
    Basis, BasisNormals, BasisSolve, LossWeighting, Mbd, MbdError, MbdModel, ProjectScratch,
    SolverOptions, StreamedMbd,
};
use prt_texture::container::WriteReport;
use prt_texture::{Limits, RangeFit};
use prt_trace::TRANSFER_DIM;
use rayon::prelude::*;

use super::Fnv1a64;
use super::file::{TileData, read_tile};
use super::partial::{
    BASIS_FORMAT, BasisHeader, MERGE_FILE_VERSION, MergeStage, PARTIAL_FORMAT, PartialError,
    PartialHeader, basis_fingerprint, basis_path, frame, from_le, le_bytes, partial_fingerprint,
    partial_path, read_merge_file, unframe, write_merge_file,
};
use super::plan::{TileError, TilePlan, TileSpec, VoxelRange, flat, voxels};
use crate::container::{
    ContainerContents, ContainerParts, ContainerWriter, LayoutConfig, ValiditySummary,
    write_container,
};
use crate::{BakeConfig, BakeError};

/// Voxels per work unit of the passes over a tile (fixed, so that every sum is the same on any
/// number of threads).
const CHUNK: usize = 16384;

/// What [`merge_streamed`] did.
#[derive(Debug, Clone)]
pub struct StreamedMerge {
    /// The fitted model on the plan's lattice; `None` from [`merge_from_partials`], which
    /// writes the container a tile at a time and never holds every voxel's coefficients.
    pub model: Option<MbdModel<HatGrid, HatGrid>>,
    /// Per voxel of the lattice (x fastest): valid in its tile's trace; `None` from
    /// [`merge_from_partials`], which reads it a tile at a time.
    pub valid: Option<Vec<bool>>,
    /// The valid voxels of the lattice.
    pub valid_voxels: u64,
    /// The coarse grid the basis was first fitted on: the lattice halved
    /// [`BakeConfig::coarse_levels`] times (at least once, and no further than the basis grid
    /// allows).
    pub coarse_dims: [usize; 3],
    /// Iterations of that fit's solver.
    pub coarse_iterations: usize,
    /// Each sweep's basis solve.
    pub basis_solves: Vec<BasisSolve>,
    /// `Σ‖f − f̂‖² / Σ‖f‖²` over the valid voxel centres: after the coarse fit (the basis
    /// as fitted at half resolution) and after each alternating sweep.
    pub relative_errors: Vec<f64>,
    /// The same of the loss-weighted vectors `w f`: the loss the sweeps descend (equal to
    /// `relative_errors` without a loss weighting).
    pub weighted_errors: Vec<f64>,
    /// The valid voxels' mean magnitude `‖f‖`: the loss weighting's normalisation.
    pub mean_magnitude: f64,
    /// The container written, when the config names a folder.
    pub container: Option<WriteReport>,
    /// Wall time of each step this process ran: "coarse volume", "coarse fit", "sweep", ...,
    /// "coefficients", "write" ([`merge_from_partials`]: "coefficients" and "write").
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

/// A basis of the streamed merge: what a stage's reduce fitted, with the history so far.
#[derive(Debug, Clone, PartialEq)]
pub struct BasisState {
    /// The stage that fitted it.
    pub stage: MergeStage,
    /// `N × L × D`.
    pub basis: Array3<f32>,
    /// The relative error at the valid voxel centres of each basis before this one.
    pub relative_errors: Vec<f64>,
    /// The same of the loss-weighted vectors.
    pub weighted_errors: Vec<f64>,
    /// The valid voxels' mean magnitude (summed by the coarse stage): the loss weighting's
    /// normalisation, which every stage after the coarse one reads from its input basis.
    pub mean_magnitude: f64,
    /// The coarse grid and its fit's iterations.
    pub coarse_dims: [usize; 3],
    /// See `coarse_dims`.
    pub coarse_iterations: usize,
    /// Each sweep's basis solve so far.
    pub basis_solves: Vec<BasisSolve>,
    /// What the partials computed from it record.
    fingerprint: String,
}

impl BasisState {
    /// The relative errors and the weighted ones with those of `squares`, a stage's sums on
    /// this basis, appended.
    fn errors_with(&self, squares: Squares) -> (Vec<f64>, Vec<f64>) {
        let mut relative_errors = self.relative_errors.clone();
        relative_errors.push(relative(squares.residual, squares.energy));
        let mut weighted_errors = self.weighted_errors.clone();
        weighted_errors.push(relative(squares.weighted_residual, squares.weighted_energy));
        (relative_errors, weighted_errors)
    }
}

/// One tile's result of one stage: what the reduce sums.
#[derive(Debug, Clone, PartialEq)]
pub struct Partial {
    /// The stage.
    pub stage: MergeStage,
    /// The tile.
    pub tile: usize,
    /// `Σ‖f − f̂‖²` over the tile's valid core voxels on the stage's input basis (0 for the
    /// coarse stage).
    pub residual: f64,
    /// `Σ‖f‖²` over them (0 for the coarse stage).
    pub energy: f64,
    /// `residual` of the loss-weighted vectors `w f`.
    pub weighted_residual: f64,
    /// `energy` of the loss-weighted vectors.
    pub weighted_energy: f64,
    /// `Σ‖f‖` over the tile's valid core voxels (the coarse stage's; 0 for the others).
    pub magnitude: f64,
    payload: Payload,
}

#[derive(Debug, Clone, PartialEq)]
enum Payload {
    /// Over the tile's box of coarse voxels: valid voxels and their vectors' sums.
    Coarse { counts: Vec<u32>, sums: Vec<f64> },
    /// The tile's part of the basis step's normal equations.
    Sweep(BasisNormals),
    /// Over the tile's core: validity and coefficients (L each, zero when invalid).
    Coefficients {
        valid: Vec<bool>,
        coefficients: Vec<f32>,
    },
}

/// What every map and reduce of one streamed merge shares, derived from the plan: the grids,
/// the plan's hash, the sweeps.
#[derive(Debug, Clone)]
pub struct MergeContext<'a> {
    plan: &'a TilePlan,
    config: &'a BakeConfig,
    sweeps: usize,
    dims: [usize; 3],
    bounds: Aabb,
    nodes: [usize; 3],
    levels: usize,
    coarse_dims: [usize; 3],
    coarse_bounds: Aabb,
    plan_hash: String,
}

/// A stage's sums of squares over valid voxels: of the vectors and of the loss-weighted vectors.
#[derive(Debug, Clone, Copy, Default)]
struct Squares {
    residual: f64,
    energy: f64,
    weighted_residual: f64,
    weighted_energy: f64,
}

impl Squares {
    fn add(&mut self, other: Squares) {
        self.residual += other.residual;
        self.energy += other.energy;
        self.weighted_residual += other.weighted_residual;
        self.weighted_energy += other.weighted_energy;
    }
}

impl<'a> MergeContext<'a> {
    /// The merge of `plan`'s tiles with `config`'s MBD and `sweeps` sweeps.
    ///
    /// # Errors
    /// An invalid config; a lattice too small to halve with its basis grid
    /// ([`TileError::InvalidTiling`]).
    pub fn new(
        plan: &'a TilePlan,
        config: &'a BakeConfig,
        sweeps: usize,
    ) -> Result<Self, TileError> {
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
        // The volume halved `levels` times (each coarse voxel the mean of the valid voxels of a
        // block of 2^levels per axis).
        let mut levels = config.coarse_levels(dims).max(1);
        let (mut coarse_dims, mut coarse_bounds) = (dims, bounds);
        for level in 0..levels {
            if !can_halve(coarse_dims, nodes) {
                levels = level;
                break;
            }
            (coarse_dims, coarse_bounds) = halved_grid(coarse_dims, coarse_bounds);
        }
        let plan_hash = Fnv1a64::of(&serde_json::to_vec(plan).unwrap_or_default());
        Ok(Self {
            plan,
            config,
            sweeps,
            dims,
            bounds,
            nodes,
            levels,
            coarse_dims,
            coarse_bounds,
            plan_hash,
        })
    }

    fn tile(&self, index: usize) -> Result<&'a TileSpec, TileError> {
        self.plan.tiles.get(index).ok_or(TileError::NoSuchTile {
            index,
            tiles: self.plan.tiles.len(),
        })
    }

    /// The coarse voxels the core of `tile` falls in.
    fn coarse_box(&self, tile: &TileSpec) -> VoxelRange {
        VoxelRange {
            min: tile.core.min.map(|i| i >> self.levels),
            max: tile.core.max.map(|i| ((i - 1) >> self.levels) + 1),
        }
    }

    /// The streamed model of `state`'s basis.
    pub fn model(&self, state: &BasisState) -> Result<StreamedMbd, TileError> {
        StreamedMbd::new(
            self.dims,
            self.bounds,
            self.nodes,
            state.basis.clone(),
            self.config.lambda,
        )
        .map_err(mbd_error)
    }

    /// The loss weights of the stages that start from `basis`: the config's weighting
    /// normalised by the mean magnitude the coarse stage summed.
    fn voxel_weights(&self, basis: &BasisState) -> VoxelWeights {
        VoxelWeights {
            weighting: self.config.loss_weighting,
            mean_magnitude: basis.mean_magnitude,
        }
    }

    /// The checked stage and the basis its maps start from.
    fn input<'s>(
        &self,
        stage: MergeStage,
        basis: Option<&'s BasisState>,
    ) -> Result<Option<&'s BasisState>, TileError> {
        stage.check(self.sweeps)?;
        match (stage.input(self.sweeps), basis) {
            (None, _) => Ok(None),
            (Some(want), Some(state)) if state.stage == want => Ok(Some(state)),
            (Some(want), _) => Err(PartialError::NoSuchStage {
                stage: format!("{stage} (its input is the basis of {want})"),
                sweeps: self.sweeps,
            }
            .into()),
        }
    }

    /// Stage `stage`'s partial of tile `index`, read from `plan_dir`; `basis` is the basis the
    /// stage starts from (`None` for the coarse stage). Reads one tile; holds its partial.
    ///
    /// # Errors
    /// Those of reading the tile (checked against the plan and `limits`); a stage that does not
    /// exist or a basis of another stage; the projection's.
    pub fn map(
        &self,
        stage: MergeStage,
        index: usize,
        plan_dir: &Path,
        basis: Option<&BasisState>,
        limits: &Limits,
    ) -> Result<Partial, TileError> {
        let basis = self.input(stage, basis)?;
        let tile = self.tile(index)?;
        let read = read_tile(self.plan, plan_dir, tile, limits)?;
        let voxels = valid_core_voxels(tile, &read);
        let d = TRANSFER_DIM;
        let Some(basis) = basis else {
            let coarse = self.coarse_box(tile);
            let mut counts = vec![0u32; coarse.len()];
            let mut sums = vec![0.0f64; coarse.len() * d];
            let mut magnitude = 0.0f64;
            for (v, local) in voxels {
                let c = flat(
                    coarse.dims(),
                    [0, 1, 2].map(|k| (v[k] >> self.levels) - coarse.min[k]),
                );
                counts[c] += 1;
                let source = &read.transfer[local * d..(local + 1) * d];
                magnitude += LossWeighting::magnitude(source);
                for (s, &x) in sums[c * d..(c + 1) * d].iter_mut().zip(source) {
                    *s += f64::from(x);
                }
            }
            return Ok(Partial {
                stage,
                tile: index,
                residual: 0.0,
                energy: 0.0,
                weighted_residual: 0.0,
                weighted_energy: 0.0,
                magnitude,
                payload: Payload::Coarse { counts, sums },
            });
        };
        let model = self.model(basis)?;
        let weights = self.voxel_weights(basis);
        let l = model.rank();
        let coefficients_stage = stage == MergeStage::Coefficients;
        let mut normals = if coefficients_stage {
            None
        } else {
            Some(
                model
                    .normals_for_voxels(tile.core.min, tile.core.max)
                    .map_err(mbd_error)?,
            )
        };
        let core_dims = tile.core.dims();
        let mut coefficients = if coefficients_stage {
            vec![0.0f32; tile.core.len() * l]
        } else {
            Vec::new()
        };
        let mut valid = vec![
            false;
            if coefficients_stage {
                tile.core.len()
            } else {
                0
            }
        ];
        let mut squares = Squares::default();
        // Chunks in groups as wide as the pool: the sums are over the same chunks in the same
        // order on any number of threads, and at most one group's parts are held.
        let chunks: Vec<&[([usize; 3], usize)]> = voxels.chunks(CHUNK).collect();
        let group = 2 * rayon::current_num_threads().max(1);
        for chunks in chunks.chunks(group) {
            let parts = chunks
                .par_iter()
                .map(|chunk| {
                    project_chunk(&model, &weights, &read, chunk, tile, !coefficients_stage)
                })
                .collect::<Result<Vec<_>, MbdError>>()
                .map_err(mbd_error)?;
            for (chunk, part) in chunks.iter().zip(parts) {
                squares.add(part.squares);
                if let (Some(total), Some(sums)) = (normals.as_mut(), part.normals.as_ref()) {
                    total.add(sums).map_err(mbd_error)?;
                }
                if coefficients_stage {
                    for (&(v, _), c) in chunk.iter().zip(part.coefficients.chunks_exact(l)) {
                        let local = flat(core_dims, [0, 1, 2].map(|k| v[k] - tile.core.min[k]));
                        valid[local] = true;
                        coefficients[local * l..(local + 1) * l].copy_from_slice(c);
                    }
                }
            }
        }
        Ok(Partial {
            stage,
            tile: index,
            residual: squares.residual,
            energy: squares.energy,
            weighted_residual: squares.weighted_residual,
            weighted_energy: squares.weighted_energy,
            magnitude: 0.0,
            payload: match normals {
                Some(normals) => Payload::Sweep(normals),
                None => Payload::Coefficients {
                    valid,
                    coefficients,
                },
            },
        })
    }

    /// The payload bytes of `stage`'s partial of `tile` (`model`: the stage's input).
    fn payload_bytes(
        &self,
        stage: MergeStage,
        tile: &TileSpec,
        model: Option<&StreamedMbd>,
    ) -> Result<u64, TileError> {
        let d = TRANSFER_DIM as u64;
        let l = self.config.rank as u64;
        Ok(match (stage, model) {
            (MergeStage::Coarse, _) | (_, None) => self.coarse_box(tile).len() as u64 * (4 + 8 * d),
            (MergeStage::Sweep(_), Some(model)) => {
                let normals = model
                    .normals_for_voxels(tile.core.min, tile.core.max)
                    .map_err(mbd_error)?;
                88 + BasisNormals::bytes_for(normals.nodes(), model.rank(), model.dim())
            }
            (MergeStage::Coefficients, Some(_)) => tile.core.len() as u64 * (1 + 4 * l),
        })
    }

    /// `partial` as a file's bytes, recording that it was computed from `basis`.
    pub fn encode_partial(&self, partial: &Partial, basis: Option<&BasisState>) -> Vec<u8> {
        let payload = match &partial.payload {
            Payload::Coarse { counts, sums } => {
                let mut out = le_bytes(counts, u32::to_le_bytes);
                out.extend(le_bytes(sums, f64::to_le_bytes));
                out
            }
            Payload::Sweep(normals) => normals.to_bytes(),
            Payload::Coefficients {
                valid,
                coefficients,
            } => {
                let mut out: Vec<u8> = valid.iter().map(|&v| u8::from(v)).collect();
                out.extend(le_bytes(coefficients, f32::to_le_bytes));
                out
            }
        };
        let header = PartialHeader {
            format: PARTIAL_FORMAT.into(),
            version: MERGE_FILE_VERSION,
            stage: partial.stage.to_string(),
            tile: partial.tile,
            fingerprint: self.partial_fingerprint(partial.stage, partial.tile, basis),
            residual: partial.residual,
            energy: partial.energy,
            weighted_residual: partial.weighted_residual,
            weighted_energy: partial.weighted_energy,
            magnitude: partial.magnitude,
            payload_bytes: payload.len() as u64,
            checksum: Fnv1a64::of(&payload),
        };
        frame(&header, &payload)
    }

    /// The fingerprint that stage `stage`'s partial of tile `tile`, mapped from `basis`,
    /// records: of the plan, the stage, the tile and the basis.
    pub fn partial_fingerprint(
        &self,
        stage: MergeStage,
        tile: usize,
        basis: Option<&BasisState>,
    ) -> String {
        partial_fingerprint(
            &self.plan_hash,
            stage,
            tile,
            basis.map_or("", |b| &b.fingerprint),
        )
    }

    /// Reads `stage`'s partial of tile `index` from `bytes` (the file at `path`), which must
    /// have been computed from this plan and `basis`: every size is the plan's, checked against
    /// `limits` before anything is allocated.
    ///
    /// # Errors
    /// [`PartialError::Malformed`] (bad framing, size, checksum, a non-finite or impossible
    /// value), [`PartialError::Stale`] (another plan, stage, tile or basis),
    /// [`PartialError::TooLarge`]; as [`MergeContext::map`] for the stage and tile.
    pub fn decode_partial(
        &self,
        stage: MergeStage,
        index: usize,
        basis: Option<&BasisState>,
        path: &Path,
        bytes: &[u8],
        limits: &Limits,
    ) -> Result<Partial, TileError> {
        let basis = self.input(stage, basis)?;
        let model = basis.map(|b| self.model(b)).transpose()?;
        self.decode_partial_on(stage, index, basis.zip(model.as_ref()), path, bytes, limits)
    }

    /// [`MergeContext::decode_partial`] given the input basis with its model (one copy of the
    /// basis fewer per partial read).
    fn decode_partial_on(
        &self,
        stage: MergeStage,
        index: usize,
        input: Option<(&BasisState, &StreamedMbd)>,
        path: &Path,
        bytes: &[u8],
        limits: &Limits,
    ) -> Result<Partial, TileError> {
        let basis = self.input(stage, input.map(|(basis, _)| basis))?;
        let model = input.map(|(_, model)| model);
        let tile = self.tile(index)?;
        let expected = self.payload_bytes(stage, tile, model)?;
        let (header, payload) = unframe::<PartialHeader>(
            path,
            bytes,
            PARTIAL_FORMAT,
            |h| (&h.format, h.version, h.payload_bytes, &h.checksum),
            expected,
            limits,
        )?;
        let malformed = |why: String| PartialError::Malformed {
            path: path.to_path_buf(),
            why,
        };
        let fingerprint = self.partial_fingerprint(stage, index, basis);
        if header.fingerprint != fingerprint
            || header.stage != stage.to_string()
            || header.tile != index
        {
            return Err(PartialError::Stale {
                path: path.to_path_buf(),
                found: format!(
                    "stage {}, tile {}, {}",
                    header.stage, header.tile, header.fingerprint
                ),
                expected: format!("stage {stage}, tile {index}, {fingerprint}"),
            }
            .into());
        }
        for (what, v) in [
            ("residual", header.residual),
            ("energy", header.energy),
            ("weighted residual", header.weighted_residual),
            ("weighted energy", header.weighted_energy),
            ("magnitude", header.magnitude),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(malformed(format!("{what} {v} is not a finite sum of norms")).into());
            }
        }
        let payload = match (stage, model) {
            (MergeStage::Coarse, _) | (_, None) => {
                let n = self.coarse_box(tile).len();
                let (counts, sums) = payload.split_at(4 * n);
                let counts: Vec<u32> = from_le(counts, u32::from_le_bytes);
                let block = 1u64 << (3 * self.levels);
                if let Some(i) = counts.iter().position(|&c| u64::from(c) > block) {
                    return Err(malformed(format!(
                        "coarse voxel {i} counts {} voxels, more than its {block}",
                        counts[i]
                    ))
                    .into());
                }
                let sums: Vec<f64> = from_le(sums, f64::from_le_bytes);
                if let Some(i) = sums.iter().position(|v| !v.is_finite()) {
                    return Err(malformed(format!("non-finite sum at value {i}")).into());
                }
                Payload::Coarse { counts, sums }
            }
            (MergeStage::Sweep(_), Some(model)) => {
                let normals = BasisNormals::from_bytes(
                    payload,
                    model.basis_grid(),
                    model.rank(),
                    model.dim(),
                )
                .map_err(|e| malformed(e.to_string()))?;
                let want = model
                    .normals_for_voxels(tile.core.min, tile.core.max)
                    .map_err(mbd_error)?;
                if normals.node_box() != want.node_box() {
                    return Err(malformed(format!(
                        "normal equations over nodes {:?}, the tile reaches {:?}",
                        normals.node_box(),
                        want.node_box()
                    ))
                    .into());
                }
                Payload::Sweep(normals)
            }
            (MergeStage::Coefficients, Some(model)) => {
                let (n, l) = (tile.core.len(), model.rank());
                let (valid, coefficients) = payload.split_at(n);
                if let Some(i) = valid.iter().position(|&v| v > 1) {
                    return Err(
                        malformed(format!("validity {} at core voxel {i}", valid[i])).into(),
                    );
                }
                let valid: Vec<bool> = valid.iter().map(|&v| v == 1).collect();
                let coefficients: Vec<f32> = from_le(coefficients, f32::from_le_bytes);
                for (i, c) in coefficients.chunks_exact(l).enumerate() {
                    if c.iter().any(|x| !x.is_finite())
                        || (!valid[i] && c.iter().any(|&x| x != 0.0))
                    {
                        return Err(malformed(format!(
                            "coefficients of core voxel {i} are non-finite, or non-zero for an \
                             invalid voxel"
                        ))
                        .into());
                    }
                }
                Payload::Coefficients {
                    valid,
                    coefficients,
                }
            }
        };
        Ok(Partial {
            stage,
            tile: index,
            residual: header.residual,
            energy: header.energy,
            weighted_residual: header.weighted_residual,
            weighted_energy: header.weighted_energy,
            magnitude: header.magnitude,
            payload,
        })
    }

    /// Empty sums of `stage` (its input basis `basis`), to which the tiles' partials are added
    /// in tile order.
    ///
    /// # Errors
    /// A stage that does not exist or a basis of another stage.
    pub fn sums(
        &self,
        stage: MergeStage,
        basis: Option<&BasisState>,
    ) -> Result<StageSums, TileError> {
        let basis = self.input(stage, basis)?;
        let sums = match (stage, basis) {
            (MergeStage::Coarse, _) | (_, None) => {
                let n: usize = self.coarse_dims.iter().product();
                Sums::Coarse {
                    counts: vec![0; n],
                    sums: vec![0.0; n * TRANSFER_DIM],
                }
            }
            (MergeStage::Sweep(_), Some(basis)) => Sums::Sweep(self.model(basis)?.normals()),
            (MergeStage::Coefficients, Some(_)) => {
                let n: usize = self.dims.iter().product();
                Sums::Coefficients {
                    valid: vec![false; n],
                    coefficients: Array2::zeros((n, self.config.rank)),
                }
            }
        };
        Ok(StageSums {
            stage,
            next_tile: 0,
            squares: Squares::default(),
            magnitude: 0.0,
            sums,
        })
    }

    /// Adds tile `partial.tile`'s partial to `sums`; the tiles must come in order.
    ///
    /// # Errors
    /// A partial of another stage or out of order ([`PartialError::Stale`] naming the tiles).
    pub fn add(&self, sums: &mut StageSums, partial: &Partial) -> Result<(), TileError> {
        if partial.stage != sums.stage || partial.tile != sums.next_tile {
            return Err(TileError::InvalidTiling(format!(
                "partial of {} tile {} added to the sums of {} where tile {} comes next",
                partial.stage, partial.tile, sums.stage, sums.next_tile
            )));
        }
        let tile = self.tile(partial.tile)?;
        sums.squares.add(Squares {
            residual: partial.residual,
            energy: partial.energy,
            weighted_residual: partial.weighted_residual,
            weighted_energy: partial.weighted_energy,
        });
        sums.magnitude += partial.magnitude;
        let d = TRANSFER_DIM;
        match (&mut sums.sums, &partial.payload) {
            (Sums::Coarse { counts, sums }, Payload::Coarse { counts: c, sums: s }) => {
                let coarse = self.coarse_box(tile);
                for (local, v) in voxels(&coarse).enumerate() {
                    let g = flat(self.coarse_dims, v);
                    counts[g] += c[local];
                    for (total, &x) in sums[g * d..(g + 1) * d].iter_mut().zip(&s[local * d..]) {
                        *total += x as f32;
                    }
                }
            }
            (Sums::Sweep(total), Payload::Sweep(part)) => total.add(part).map_err(mbd_error)?,
            (
                Sums::Coefficients {
                    valid,
                    coefficients,
                },
                Payload::Coefficients {
                    valid: v,
                    coefficients: c,
                },
            ) => {
                let l = coefficients.ncols();
                for (local, voxel) in voxels(&tile.core).enumerate() {
                    let g = flat(self.dims, voxel);
                    valid[g] = v[local];
                    coefficients
                        .row_mut(g)
                        .iter_mut()
                        .zip(&c[local * l..(local + 1) * l])
                        .for_each(|(o, &x)| *o = x);
                }
            }
            _ => {
                return Err(TileError::InvalidTiling(format!(
                    "partial of tile {} does not match the sums of {}",
                    partial.tile, sums.stage
                )));
            }
        }
        sums.next_tile += 1;
        Ok(())
    }

    /// The basis a coarse or sweep stage's reduce fits to its sums (all tiles added); `basis`
    /// is the stage's input.
    ///
    /// # Errors
    /// Sums missing tiles; no valid voxel; the fit's.
    pub fn reduce(
        &self,
        sums: StageSums,
        basis: Option<&BasisState>,
        progress: &dyn Progress,
    ) -> Result<BasisState, TileError> {
        let basis = self.input(sums.stage, basis)?;
        self.check_complete(&sums)?;
        let (stage, squares, magnitude) = (sums.stage, sums.squares, sums.magnitude);
        match (sums.sums, basis) {
            (Sums::Coarse { counts, mut sums }, _) => {
                let valid_voxels: u64 = counts.iter().map(|&n| u64::from(n)).sum();
                if valid_voxels == 0 {
                    return Err(mbd_error(MbdError::InvalidOption {
                        what: "validity mask",
                        why: "no voxel is valid".into(),
                    }));
                }
                let coarse_valid: Vec<bool> = counts.iter().map(|&n| n > 0).collect();
                for (row, &n) in sums.chunks_exact_mut(TRANSFER_DIM).zip(&counts) {
                    if n > 0 {
                        let inverse = 1.0 / n as f32;
                        row.iter_mut().for_each(|x| *x *= inverse);
                    }
                }
                drop(counts);
                let voxels = coarse_valid.len();
                let coarse = GridField::from_data(
                    self.coarse_dims,
                    self.coarse_bounds,
                    Array2::from_shape_vec((voxels, TRANSFER_DIM), sums).map_err(|e| {
                        mbd_error(MbdError::InvalidOption {
                            what: "coarse volume",
                            why: e.to_string(),
                        })
                    })?,
                )
                .map_err(|e| mbd_error(e.into()))?;
                // MBD on it, from the paper's start, under the config's loss weighting (of the
                // coarse voxels: the start of the sweeps, which weight every voxel).
                let mbd = Mbd {
                    solver: SolverOptions {
                        lambda: self.config.lambda,
                        max_iterations: self.config.max_iterations,
                        seed: self.config.seed ^ 0x4D42_4400,
                        ..SolverOptions::default()
                    },
                    loss_weighting: self.config.loss_weighting,
                    ..Mbd::new(self.config.rank, Basis::HatGrid { nodes: self.nodes })
                };
                let fit = mbd
                    .fit_masked(&coarse, &coarse_valid, progress)
                    .map_err(mbd_error)?;
                let coarse_iterations = fit.solve.history.len();
                let (_, _, _, basis) = fit.model.into_parts();
                Ok(self.state(BasisState {
                    stage,
                    basis,
                    relative_errors: Vec::new(),
                    weighted_errors: Vec::new(),
                    mean_magnitude: magnitude / valid_voxels as f64,
                    coarse_dims: self.coarse_dims,
                    coarse_iterations,
                    basis_solves: Vec::new(),
                    fingerprint: String::new(),
                }))
            }
            (Sums::Sweep(normals), Some(input)) => {
                let mut model = self.model(input)?;
                let solve = model.solve_basis(&normals).map_err(mbd_error)?;
                let (relative_errors, weighted_errors) = input.errors_with(squares);
                let mut basis_solves = input.basis_solves.clone();
                basis_solves.push(solve);
                Ok(self.state(BasisState {
                    stage,
                    basis: model.basis().clone(),
                    relative_errors,
                    weighted_errors,
                    basis_solves,
                    fingerprint: String::new(),
                    ..input.clone()
                }))
            }
            _ => Err(PartialError::NoSuchStage {
                stage: format!("{stage} (its reduce writes the bake folder: merge_from_partials)"),
                sweeps: self.sweeps,
            }
            .into()),
        }
    }

    fn check_complete(&self, sums: &StageSums) -> Result<(), TileError> {
        if sums.next_tile != self.plan.tiles.len() {
            return Err(TileError::InvalidTiling(format!(
                "the sums of {} hold {} of {} tiles",
                sums.stage,
                sums.next_tile,
                self.plan.tiles.len()
            )));
        }
        Ok(())
    }

    /// `state` with its fingerprint: of the plan, the stage, the basis and the weights'
    /// normalisation.
    fn state(&self, state: BasisState) -> BasisState {
        let mut payload = le_bytes(state.basis.as_slice().unwrap_or(&[]), f32::to_le_bytes);
        payload.extend(state.mean_magnitude.to_le_bytes());
        let fingerprint = basis_fingerprint(&self.plan_hash, state.stage, &Fnv1a64::of(&payload));
        BasisState {
            fingerprint,
            ..state
        }
    }

    /// The model, validity and relative errors of the coefficient stage's sums (all tiles
    /// added) on `basis`, the last basis.
    fn finish(&self, sums: StageSums, basis: &BasisState) -> Result<Finished, TileError> {
        self.check_complete(&sums)?;
        let Sums::Coefficients {
            valid,
            coefficients,
        } = sums.sums
        else {
            return Err(TileError::InvalidTiling(format!(
                "the sums of {} are not the coefficients'",
                sums.stage
            )));
        };
        let errors = basis.errors_with(sums.squares);
        let model = self
            .model(basis)?
            .into_model(coefficients)
            .map_err(mbd_error)?;
        Ok((model, valid, errors))
    }

    /// `basis` (`N × L × D`, the plan's basis grid and rank) as the basis `stage`'s reduce
    /// fitted, without history, with `mean_magnitude` as the loss weights' normalisation: to map
    /// from a basis made elsewhere.
    ///
    /// # Errors
    /// A basis of another shape.
    pub fn basis_state(
        &self,
        stage: MergeStage,
        basis: Array3<f32>,
        mean_magnitude: f64,
    ) -> Result<BasisState, TileError> {
        let want = (self.nodes.iter().product(), self.config.rank, TRANSFER_DIM);
        if basis.dim() != want {
            return Err(mbd_error(MbdError::ShapeMismatch {
                what: "basis",
                expected: vec![want.0, want.1, want.2],
                got: basis.shape().to_vec(),
            }));
        }
        Ok(self.state(BasisState {
            stage,
            basis,
            relative_errors: Vec::new(),
            weighted_errors: Vec::new(),
            mean_magnitude,
            coarse_dims: self.coarse_dims,
            coarse_iterations: 0,
            basis_solves: Vec::new(),
            fingerprint: String::new(),
        }))
    }

    /// Writes `state` to `plan_dir`'s merge folder (atomically); returns the file and its size.
    ///
    /// # Errors
    /// Writing.
    pub fn write_basis(
        &self,
        plan_dir: &Path,
        state: &BasisState,
    ) -> Result<(PathBuf, u64), TileError> {
        let payload = le_bytes(state.basis.as_slice().unwrap_or(&[]), f32::to_le_bytes);
        let (_, rank, dim) = state.basis.dim();
        let header = BasisHeader {
            format: BASIS_FORMAT.into(),
            version: MERGE_FILE_VERSION,
            stage: state.stage.to_string(),
            plan: self.plan_hash.clone(),
            nodes: self.nodes,
            rank,
            dim,
            coarse_grid: state.coarse_dims,
            coarse_iterations: state.coarse_iterations,
            relative_errors: state.relative_errors.clone(),
            weighted_errors: state.weighted_errors.clone(),
            mean_magnitude: state.mean_magnitude,
            basis_solves: state
                .basis_solves
                .iter()
                .map(|s| (s.iterations, s.relative_residual))
                .collect(),
            payload_bytes: payload.len() as u64,
            checksum: Fnv1a64::of(&payload),
        };
        let bytes = frame(&header, &payload);
        let path = basis_path(plan_dir, state.stage);
        write_merge_file(&path, &bytes)?;
        Ok((path, bytes.len() as u64))
    }

    /// Reads the basis `stage`'s reduce wrote into `plan_dir`, checked against the plan.
    ///
    /// # Errors
    /// [`PartialError::Missing`] before the reduce; [`PartialError::Stale`] for another plan's;
    /// [`PartialError::Malformed`], [`PartialError::TooLarge`].
    pub fn read_basis(
        &self,
        plan_dir: &Path,
        stage: MergeStage,
        limits: &Limits,
    ) -> Result<BasisState, TileError> {
        let path = basis_path(plan_dir, stage);
        let (n, l, d) = (
            self.nodes.iter().product::<usize>(),
            self.config.rank,
            TRANSFER_DIM,
        );
        let expected = (n * l * d * 4) as u64;
        let bytes = read_merge_file(&path, expected, limits, stage, None)?;
        let (header, payload) = unframe::<BasisHeader>(
            &path,
            &bytes,
            BASIS_FORMAT,
            |h| (&h.format, h.version, h.payload_bytes, &h.checksum),
            expected,
            limits,
        )?;
        let malformed = |why: String| PartialError::Malformed {
            path: path.clone(),
            why,
        };
        if header.plan != self.plan_hash || header.stage != stage.to_string() {
            return Err(PartialError::Stale {
                path: path.clone(),
                found: format!("plan {}, stage {}", header.plan, header.stage),
                expected: format!("plan {}, stage {stage}", self.plan_hash),
            }
            .into());
        }
        let sweeps_before = match stage {
            MergeStage::Sweep(k) => k,
            _ => 0,
        };
        if header.nodes != self.nodes
            || header.rank != l
            || header.dim != d
            || header.relative_errors.len() != sweeps_before
            || header.weighted_errors.len() != sweeps_before
            || header.basis_solves.len() != sweeps_before
            || (header.relative_errors.iter())
                .chain(&header.weighted_errors)
                .any(|e| !e.is_finite())
            || !(header.mean_magnitude.is_finite() && header.mean_magnitude >= 0.0)
        {
            return Err(malformed(format!(
                "basis of {:?} nodes, rank {}, dimension {}, {} and {} errors and {} solves, \
                 mean magnitude {}; expected {:?}, {l}, {d}, {sweeps_before} each, a finite \
                 magnitude",
                header.nodes,
                header.rank,
                header.dim,
                header.relative_errors.len(),
                header.weighted_errors.len(),
                header.basis_solves.len(),
                header.mean_magnitude,
                self.nodes
            ))
            .into());
        }
        let values: Vec<f32> = from_le(payload, f32::from_le_bytes);
        if let Some(i) = values.iter().position(|v| !v.is_finite()) {
            return Err(malformed(format!("non-finite basis value {i}")).into());
        }
        let basis =
            Array3::from_shape_vec((n, l, d), values).map_err(|e| malformed(e.to_string()))?;
        Ok(self.state(BasisState {
            stage,
            basis,
            relative_errors: header.relative_errors,
            weighted_errors: header.weighted_errors,
            mean_magnitude: header.mean_magnitude,
            coarse_dims: header.coarse_grid,
            coarse_iterations: header.coarse_iterations,
            basis_solves: header
                .basis_solves
                .into_iter()
                .map(|(iterations, relative_residual)| BasisSolve {
                    iterations,
                    relative_residual,
                })
                .collect(),
            fingerprint: String::new(),
        }))
    }

    /// The sums of `stage` over every tile's partial file in `plan_dir`, read and added in tile
    /// order (one partial held at a time).
    fn sum_partials(
        &self,
        stage: MergeStage,
        basis: Option<&BasisState>,
        plan_dir: &Path,
        limits: &Limits,
        progress: &dyn Progress,
    ) -> Result<StageSums, TileError> {
        let mut sums = self.sums(stage, basis)?;
        let model = basis.map(|b| self.model(b)).transpose()?;
        for tile in &self.plan.tiles {
            progress
                .check()
                .map_err(|e| TileError::Bake(BakeError::Cancelled(e)))?;
            let partial =
                self.read_partial(stage, tile, basis, model.as_ref(), plan_dir, limits)?;
            self.add(&mut sums, &partial)?;
        }
        Ok(sums)
    }

    /// Tile `tile`'s partial of `stage` (input basis `basis`, its model `model`), read from
    /// `plan_dir` and checked.
    fn read_partial(
        &self,
        stage: MergeStage,
        tile: &TileSpec,
        basis: Option<&BasisState>,
        model: Option<&StreamedMbd>,
        plan_dir: &Path,
        limits: &Limits,
    ) -> Result<Partial, TileError> {
        let path = partial_path(plan_dir, stage, tile.index);
        let expected = self.payload_bytes(stage, tile, model)?;
        let bytes = read_merge_file(&path, expected, limits, stage, Some(tile.index))?;
        self.decode_partial_on(stage, tile.index, basis.zip(model), &path, &bytes, limits)
    }

    /// The container of `model` and the [`StreamedMerge`].
    fn write(
        &self,
        scene_name: &str,
        (model, valid, (relative_errors, weighted_errors)): Finished,
        basis: &BasisState,
        mut stage_times: Vec<(&'static str, Duration)>,
        progress: &dyn Progress,
    ) -> Result<StreamedMerge, TileError> {
        let container = match &self.config.container {
            Some(folder) => {
                let start = Instant::now();
                progress.message("write");
                let contents = ContainerContents {
                    model: &model,
                    grid: self.dims,
                    valid: &valid,
                    scene: scene_name,
                    lambda: self.config.lambda,
                    encoding: self.config.encoding,
                };
                let report = write_container(folder, &contents)
                    .map_err(|e| TileError::Bake(BakeError::Container(e)))?;
                stage_times.push(("write", start.elapsed()));
                Some(report)
            }
            None => None,
        };
        Ok(StreamedMerge {
            model: Some(model),
            valid_voxels: valid.iter().filter(|&&v| v).count() as u64,
            valid: Some(valid),
            coarse_dims: basis.coarse_dims,
            coarse_iterations: basis.coarse_iterations,
            basis_solves: basis.basis_solves.clone(),
            relative_errors,
            weighted_errors,
            mean_magnitude: basis.mean_magnitude,
            container,
            stage_times,
        })
    }
}

/// A stage's running sums over the tiles' partials (see [`MergeContext::sums`]).
#[derive(Debug, Clone)]
pub struct StageSums {
    stage: MergeStage,
    next_tile: usize,
    squares: Squares,
    /// `Σ‖f‖` over the valid voxels (the coarse stage's).
    magnitude: f64,
    sums: Sums,
}

#[derive(Debug, Clone)]
enum Sums {
    /// Over the coarse grid (f32, as the coarse volume is stored).
    Coarse {
        counts: Vec<u32>,
        sums: Vec<f32>,
    },
    Sweep(BasisNormals),
    /// Over the lattice: the container writer takes the model whole.
    Coefficients {
        valid: Vec<bool>,
        coefficients: Array2<f32>,
    },
}

/// The coefficient stage's result: the model, the validity per voxel, the relative errors and
/// those of the weighted vectors.
type Finished = (MbdModel<HatGrid, HatGrid>, Vec<bool>, (Vec<f64>, Vec<f64>));

fn relative(residual: f64, energy: f64) -> f64 {
    if energy > 0.0 {
        residual / energy
    } else {
        residual
    }
}

/// Merges the finished tiles of `plan` in memory bounded by one tile, the coarse volume (at most
/// an eighth of the lattice), the basis step's block-sparse normal equations and the
/// coefficients (L floats per voxel): MBD of `config`'s rank on its basis grid, with `sweeps`
/// alternating least-squares sweeps over the tiles after the coarse fit; writes the container
/// when `config.container` names a folder. Runs every stage's map and reduce in this process
/// (the same functions as [`map_tile`] and [`reduce_stage`]); deterministic for the plan on any
/// number of threads.
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
    let context = MergeContext::new(plan, config, sweeps)?;
    let mut stage_times = Vec::new();
    let mut basis: Option<BasisState> = None;
    // Each stage: its map over the tiles, its partials summed in tile order, its reduce.
    let sum_tiles = |stage: MergeStage, basis: Option<&BasisState>| {
        let mut sums = context.sums(stage, basis)?;
        for tile in &plan.tiles {
            progress
                .check()
                .map_err(|e| TileError::Bake(BakeError::Cancelled(e)))?;
            let partial = context.map(stage, tile.index, plan_dir, basis, limits)?;
            context.add(&mut sums, &partial)?;
        }
        Ok::<_, TileError>(sums)
    };
    for stage in MergeStage::all(sweeps) {
        let start = Instant::now();
        match stage {
            MergeStage::Coarse => {
                progress.message("coarse volume");
                let sums = sum_tiles(stage, None)?;
                stage_times.push(("coarse volume", start.elapsed()));
                let start = Instant::now();
                progress.message("coarse fit");
                basis = Some(context.reduce(sums, None, progress)?);
                stage_times.push(("coarse fit", start.elapsed()));
            }
            MergeStage::Sweep(_) => {
                progress.message("sweep");
                let sums = sum_tiles(stage, basis.as_ref())?;
                basis = Some(context.reduce(sums, basis.as_ref(), progress)?);
                stage_times.push(("sweep", start.elapsed()));
            }
            MergeStage::Coefficients => {
                let last = basis.as_ref().ok_or_else(|| {
                    TileError::InvalidTiling("the coefficients need a basis".into())
                })?;
                progress.message("coefficients");
                let sums = sum_tiles(stage, Some(last))?;
                let finished = context.finish(sums, last)?;
                stage_times.push(("coefficients", start.elapsed()));
                return context.write(scene_name, finished, last, stage_times, progress);
            }
        }
    }
    Err(TileError::InvalidTiling(
        "the stages end with the coefficients".into(),
    ))
}

/// What [`map_tile`] did.
#[derive(Debug, Clone, PartialEq)]
pub enum MapOutcome {
    /// The partial was computed and written.
    Written {
        /// The partial file.
        path: PathBuf,
        /// Its size.
        bytes: u64,
    },
    /// A current partial was already there (a requeued task).
    AlreadyDone {
        /// The partial file.
        path: PathBuf,
    },
}

/// `prt merge --map`: stage `stage`'s partial of tile `tile`, from the tile and the basis of the
/// stage before (read from `plan_dir`), written atomically to
/// `plan_dir/merge/STAGE/tile-INDEX.part`; a current partial already there is kept.
///
/// # Errors
/// Those of [`MergeContext::map`]; the input basis missing or stale; writing.
pub fn map_tile(
    plan: &TilePlan,
    plan_dir: &Path,
    config: &BakeConfig,
    sweeps: usize,
    stage: MergeStage,
    tile: usize,
    limits: &Limits,
) -> Result<MapOutcome, TileError> {
    let context = MergeContext::new(plan, config, sweeps)?;
    stage.check(sweeps)?;
    let basis = stage
        .input(sweeps)
        .map(|input| context.read_basis(plan_dir, input, limits))
        .transpose()?;
    let path = partial_path(plan_dir, stage, tile);
    let model = basis.as_ref().map(|b| context.model(b)).transpose()?;
    let expected = context.payload_bytes(stage, context.tile(tile)?, model.as_ref())?;
    if let Ok(bytes) = read_merge_file(&path, expected, limits, stage, Some(tile))
        && context
            .decode_partial_on(
                stage,
                tile,
                basis.as_ref().zip(model.as_ref()),
                &path,
                &bytes,
                limits,
            )
            .is_ok()
    {
        return Ok(MapOutcome::AlreadyDone { path });
    }
    let partial = context.map(stage, tile, plan_dir, basis.as_ref(), limits)?;
    let bytes = context.encode_partial(&partial, basis.as_ref());
    write_merge_file(&path, &bytes)?;
    Ok(MapOutcome::Written {
        path,
        bytes: bytes.len() as u64,
    })
}

/// What [`reduce_stage`] did.
#[derive(Debug, Clone, PartialEq)]
pub struct ReduceOutcome {
    /// The basis file written.
    pub path: PathBuf,
    /// Its size.
    pub bytes: u64,
    /// The basis.
    pub basis: BasisState,
}

/// `prt merge --reduce` of the coarse stage or a sweep: every tile's partial read from
/// `plan_dir` and summed in tile order, the basis fitted to the sums, written atomically to
/// `plan_dir/merge/STAGE.basis`. The coefficients' reduce is [`merge_from_partials`].
///
/// # Errors
/// A partial missing, stale or malformed, naming the tile; the fit's; writing.
pub fn reduce_stage(
    plan: &TilePlan,
    plan_dir: &Path,
    config: &BakeConfig,
    sweeps: usize,
    stage: MergeStage,
    limits: &Limits,
    progress: &dyn Progress,
) -> Result<ReduceOutcome, TileError> {
    let context = MergeContext::new(plan, config, sweeps)?;
    stage.check(sweeps)?;
    let input = stage
        .input(sweeps)
        .map(|input| context.read_basis(plan_dir, input, limits))
        .transpose()?;
    let sums = context.sum_partials(stage, input.as_ref(), plan_dir, limits, progress)?;
    let basis = context.reduce(sums, input.as_ref(), progress)?;
    let (path, bytes) = context.write_basis(plan_dir, &basis)?;
    Ok(ReduceOutcome { path, bytes, basis })
}

/// `prt merge --reduce --stage coefficients`: the last basis and every tile's coefficient
/// partial read from `plan_dir`, the container written as [`merge_streamed`] writes it (the
/// same bytes) a tile at a time, in memory bounded by a partial, the basis, a flag per brick
/// of coefficient nodes and the write buffers ([`ContainerWriter`]): the partials are read
/// twice, first for the summary of the validity, the errors and the coefficients' ranges, then
/// to write the validity and the coefficients. The result holds neither model nor validity.
///
/// # Errors
/// As [`reduce_stage`]; the container's.
pub fn merge_from_partials(
    plan: &TilePlan,
    plan_dir: &Path,
    scene_name: &str,
    config: &BakeConfig,
    sweeps: usize,
    limits: &Limits,
    progress: &dyn Progress,
) -> Result<StreamedMerge, TileError> {
    let context = MergeContext::new(plan, config, sweeps)?;
    let stage = MergeStage::Coefficients;
    let start = Instant::now();
    progress.message("coefficients");
    let last = stage.input(sweeps).unwrap_or(MergeStage::Coarse);
    let basis = context.read_basis(plan_dir, last, limits)?;
    let model = context.model(&basis)?;
    // Each tile's partial in tile order: its squares, validity and coefficients.
    type Visit<'v> = dyn FnMut(&TileSpec, &Partial, &[bool], &[f32]) -> Result<(), TileError> + 'v;
    let each_partial = |visit: &mut Visit<'_>| {
        for tile in &plan.tiles {
            progress
                .check()
                .map_err(|e| TileError::Bake(BakeError::Cancelled(e)))?;
            let partial =
                context.read_partial(stage, tile, Some(&basis), Some(&model), plan_dir, limits)?;
            let Payload::Coefficients {
                valid,
                coefficients,
            } = &partial.payload
            else {
                return Err(TileError::InvalidTiling(format!(
                    "tile {}'s partial is not the coefficients'",
                    tile.index
                )));
            };
            visit(tile, &partial, valid, coefficients)?;
        }
        Ok::<_, TileError>(())
    };
    // First pass: the validity's summary, the sums of squares (in tile order, as the streamed
    // merge adds them) and the ranges of the coefficients the container stores.
    let coefficient_kernels = model.coefficient_kernels().map_err(mbd_error)?;
    let layout = LayoutConfig::default();
    let container_error = |e| TileError::Bake(BakeError::Container(e));
    let summary_bytes =
        ValiditySummary::bytes_for(context.dims, coefficient_kernels.nodes(), layout.brick_size);
    if summary_bytes > limits.max_bytes {
        return Err(TileError::TooLarge {
            path: plan_dir.to_path_buf(),
            what: "the validity's summary (a flag per coefficient brick)",
            value: summary_bytes,
            limit: limits.max_bytes,
        });
    }
    let mut validity = ValiditySummary::new(&coefficient_kernels, context.dims, layout.brick_size)
        .map_err(container_error)?;
    let mut squares = Squares::default();
    let mut ranges = RangeFit::new(config.rank);
    each_partial(&mut |tile, partial, tile_valid, coefficients| {
        validity
            .add(tile.core.min, tile.core.dims(), tile_valid)
            .map_err(container_error)?;
        squares.add(Squares {
            residual: partial.residual,
            energy: partial.energy,
            weighted_residual: partial.weighted_residual,
            weighted_energy: partial.weighted_energy,
        });
        ranges.add(coefficients);
        Ok(())
    })?;
    let mut stage_times = vec![("coefficients", start.elapsed())];
    let container = match &config.container {
        Some(folder) => {
            let start = Instant::now();
            progress.message("write");
            let parts = ContainerParts {
                coefficient_kernels: &coefficient_kernels,
                basis_kernels: model.basis_kernels(),
                basis: model.basis(),
                grid: context.dims,
                scene: scene_name,
                lambda: config.lambda,
                encoding: config.encoding,
            };
            let mut writer =
                ContainerWriter::create(folder, &parts, &ranges, &validity, layout.layout)
                    .map_err(container_error)?;
            each_partial(&mut |tile, _, tile_valid, coefficients| {
                let (min, size) = (tile.core.min, tile.core.dims());
                writer
                    .write_validity(min, size, tile_valid)
                    .and_then(|()| writer.write_coefficients(min, size, coefficients))
                    .map_err(container_error)
            })?;
            let report = writer.finish().map_err(container_error)?;
            stage_times.push(("write", start.elapsed()));
            Some(report)
        }
        None => None,
    };
    let (relative_errors, weighted_errors) = basis.errors_with(squares);
    Ok(StreamedMerge {
        model: None,
        valid: None,
        valid_voxels: validity.valid_voxels(),
        coarse_dims: basis.coarse_dims,
        coarse_iterations: basis.coarse_iterations,
        basis_solves: basis.basis_solves.clone(),
        relative_errors,
        weighted_errors,
        mean_magnitude: basis.mean_magnitude,
        container,
        stage_times,
    })
}

/// One chunk's coefficients, sums of squares, and its part of the basis step's normal
/// equations (over the tile's nodes) when `accumulate` asks for them.
struct ChunkPart {
    coefficients: Vec<f32>,
    squares: Squares,
    normals: Option<BasisNormals>,
}

/// The loss weight of each voxel in the stages after the coarse one: the config's
/// [`LossWeighting`] of the voxel's magnitude against the valid voxels' mean, as the in-memory
/// fit weighs it; 1 without a weighting.
#[derive(Debug, Clone, Copy)]
struct VoxelWeights {
    weighting: Option<LossWeighting>,
    mean_magnitude: f64,
}

impl VoxelWeights {
    fn of(&self, f: &[f32]) -> f32 {
        self.weighting.map_or(1.0, |weighting| {
            weighting.weight(LossWeighting::magnitude(f), self.mean_magnitude)
        })
    }
}

fn project_chunk(
    model: &StreamedMbd,
    weights: &VoxelWeights,
    read: &TileData,
    chunk: &[([usize; 3], usize)],
    tile: &TileSpec,
    accumulate: bool,
) -> Result<ChunkPart, MbdError> {
    let (l, d) = (model.rank(), TRANSFER_DIM);
    let mut part = ChunkPart {
        coefficients: vec![0.0; chunk.len() * l],
        squares: Squares::default(),
        normals: if accumulate {
            Some(model.normals_for_voxels(tile.core.min, tile.core.max)?)
        } else {
            None
        },
    };
    let mut scratch = VoxelScratch::default();
    for (&(v, local), c) in chunk.iter().zip(part.coefficients.chunks_exact_mut(l)) {
        let f = &read.transfer[local * d..(local + 1) * d];
        let squares = fit_voxel(
            model,
            weights.of(f),
            v,
            f,
            c,
            part.normals.as_mut(),
            &mut scratch,
        )?;
        part.squares.add(squares);
    }
    Ok(part)
}

/// Reused buffers of [`fit_voxel`].
#[derive(Default)]
struct VoxelScratch {
    project: ProjectScratch,
    /// The weighted vector.
    weighted: Vec<f32>,
}

/// Voxel `v`'s coefficients `c` and sums of squares, its vector `f` fitted as `w f`: the fit of
/// `w f`, added to `normals` when given, then `c` divided by `w`. Exact to
/// undo: the transfer is linear in the light and the voxel's coefficients are its own, so `c`
/// is the fit of `f` itself, ridge included (`argmin ‖w f − bᵀc'‖² + λ‖c'‖²` is `w` times
/// `argmin ‖f − bᵀc‖² + λ‖c‖²`); the weight decides how much the voxel pulls on the basis.
fn fit_voxel(
    model: &StreamedMbd,
    w: f32,
    v: [usize; 3],
    f: &[f32],
    c: &mut [f32],
    normals: Option<&mut BasisNormals>,
    scratch: &mut VoxelScratch,
) -> Result<Squares, MbdError> {
    let VoxelScratch { project, weighted } = scratch;
    weighted.clear();
    weighted.extend(f.iter().map(|&x| w * x));
    let weighted_residual = model.project(v, weighted, c, project)?;
    if let Some(normals) = normals {
        model.accumulate(v, weighted, c, normals, project)?;
    }
    c.iter_mut().for_each(|x| *x /= w);
    let energy = |g: &[f32]| g.iter().map(|&x| f64::from(x).powi(2)).sum::<f64>();
    Ok(Squares {
        residual: weighted_residual / f64::from(w).powi(2),
        energy: energy(f),
        weighted_residual,
        weighted_energy: energy(weighted),
    })
}

#[cfg(test)]
mod tests {
    use proptest::prelude::*;

    use super::*;

    /// The f64 values of normal equations (after their 11-word header): `G`, then `R`.
    fn normal_values(normals: &BasisNormals) -> Vec<f64> {
        from_le(&normals.to_bytes()[88..], f64::from_le_bytes)
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(48))]
        /// Scaling a voxel's vector by its weight and dividing its coefficients by it after the
        /// fit is exact: at every rank (full rank included) and ridge, the coefficients, and so
        /// the reconstruction, are the unweighted fit's; the voxel's sums of squares and its
        /// part of the basis step's normal equations scale by w², which is the weighting.
        #[test]
        fn a_weighted_voxel_fits_as_the_unweighted_one_and_pulls_w_squared_on_the_basis(
            rank in 1usize..=6,
            w in 0.02f32..50.0,
            lambda in prop_oneof![Just(0.0f32), Just(1e-4), Just(0.1)],
            noise in prop::collection::vec(-0.1f32..0.1, 8 * 6 * 6),
            f in prop::collection::vec(-2.0f32..2.0, 6),
        ) {
            let (d, dims) = (6, [3, 2, 2]);
            // Well conditioned at every point (each node's basis within 0.6 of the identity's
            // rows in norm), so that f32 rounding stays far below the tolerances.
            let basis = Array3::from_shape_fn((8, rank, d), |(n, l, k)| {
                f32::from(u8::from(l == k)) + noise[(n * 6 + l) * 6 + k]
            });
            let model = StreamedMbd::new(dims, Aabb::UNIT, [2, 2, 2], basis, lambda).unwrap();
            let mut scratch = VoxelScratch::default();
            let energy: f64 = f.iter().map(|&x| f64::from(x).powi(2)).sum();
            let w2 = f64::from(w).powi(2);
            for v in voxels(&VoxelRange { min: [0; 3], max: dims }) {
                let (mut plain, mut weighted) = (vec![0.0f32; rank], vec![0.0f32; rank]);
                let (mut plain_normals, mut weighted_normals) = (model.normals(), model.normals());
                let one = fit_voxel(&model, 1.0, v, &f, &mut plain, Some(&mut plain_normals),
                    &mut scratch).unwrap();
                let scaled = fit_voxel(&model, w, v, &f, &mut weighted,
                    Some(&mut weighted_normals), &mut scratch).unwrap();
                let largest = plain.iter().fold(1.0f32, |m, c| m.max(c.abs()));
                for (a, b) in plain.iter().zip(&weighted) {
                    prop_assert!((a - b).abs() <= 1e-3 * largest, "{plain:?} vs {weighted:?}");
                }
                if rank == d && lambda == 0.0 {
                    // Full rank: both reproduce the vector.
                    prop_assert!(one.residual <= 1e-6 * energy, "{one:?}");
                }
                prop_assert!((one.residual - scaled.residual).abs() <= 1e-5 * energy);
                prop_assert_eq!(one.energy, scaled.energy);
                prop_assert!((scaled.weighted_residual - w2 * one.residual).abs()
                    <= 1e-5 * w2 * energy);
                prop_assert!((scaled.weighted_energy - w2 * energy).abs() <= 1e-6 * w2 * energy);
                let (a, b) = (normal_values(&plain_normals), normal_values(&weighted_normals));
                let largest = a.iter().fold(1e-30f64, |m, x| m.max(x.abs()));
                for (a, b) in a.iter().zip(&b) {
                    prop_assert!((w2 * a - b).abs() <= 1e-4 * w2 * largest, "{a} {b}");
                }
            }
        }
    }
}
