//! A worker: trace one tile of a plan and write it atomically into the plan folder.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use prt_core::Progress;
use prt_trace::{BakeOptions, TransferBaker, TransferVolume};
use serde::{Deserialize, Serialize};

use super::plan::{TileError, TilePlan, scene_hash};
use crate::{BakeError, SceneInput, TRANSFER_DIM};

/// Name of the file whose presence says a tile finished (written last).
pub const DONE_MARKER: &str = "done";
/// The tile's traced transfer vectors: little-endian f32, traced voxels × 324, x fastest.
pub(crate) const TRANSFER_FILE: &str = "transfer.f32";
/// The tile's validity: one byte (0 or 1) per traced voxel.
pub(crate) const VALID_FILE: &str = "valid.u8";
/// The tile's description ([`TileStats`]): reproducible, no timings.
pub(crate) const TILE_FILE: &str = "tile.json";
/// Wall and stage times of the tile's last run (not reproducible, so kept apart).
pub(crate) const TIMING_FILE: &str = "timing.json";

/// What a tile's `tile.json` records.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct TileStats {
    /// The tile index.
    pub index: usize,
    /// Voxels traced along x, y, z (the tile's traced box).
    pub dims: [usize; 3],
    /// The trace's seed.
    pub seed: u64,
    /// The scene's hash the tile was traced from.
    pub scene_hash: String,
    /// Voxels traced.
    pub voxels: usize,
    /// Voxels inside geometry.
    pub invalid_voxels: usize,
    /// Voxels outside the scene bounds (not traced).
    pub skipped_voxels: usize,
    /// Rays traced (voxel and surface-cache rays).
    pub rays: u64,
}

/// What [`bake_tile`] did.
#[derive(Debug, Clone, PartialEq)]
pub enum TileOutcome {
    /// The tile had finished before: nothing was done.
    Skipped,
    /// The tile was traced and written, in this wall time.
    Baked {
        /// Its description.
        stats: TileStats,
        /// Wall time of the trace (BVH, cache and voxels).
        trace: Duration,
        /// Wall time of writing the files.
        write: Duration,
    },
}

/// The folder of tile `index` in a plan folder: `PLAN_DIR/tiles/INDEX`.
pub fn tile_dir(plan_dir: &Path, index: usize) -> PathBuf {
    plan_dir.join("tiles").join(index.to_string())
}

/// Whether tile `index` finished (its done marker exists).
pub fn tile_is_done(plan_dir: &Path, index: usize) -> bool {
    tile_dir(plan_dir, index).join(DONE_MARKER).is_file()
}

/// The tracer's options for `tile` of `plan`: the tile's traced box of the global lattice
/// (as explicit bounds and resolution), the plan's knobs, the tile's seed.
pub fn tile_options(plan: &TilePlan, index: usize) -> Result<BakeOptions, TileError> {
    let tile = plan.tile(index)?;
    let config = &plan.config;
    Ok(BakeOptions {
        resolution: tile.traced.dims(),
        margin: config.margin,
        bounds: Some(plan.range_bounds(&tile.traced)),
        rays_per_voxel: config.rays_per_voxel,
        cache_rays: config.cache_rays,
        seed: tile.seed,
        ..BakeOptions::default()
    })
}

/// Traces tile `index` of `plan` (whose folder is `plan_dir`) from `scene`, which must hash as
/// the plan's, and writes `transfer.f32`, `valid.u8`, `tile.json`, `timing.json` and then the
/// done marker into [`tile_dir`], each file atomically. A finished tile is skipped unless
/// `force`. The files but `timing.json` are the same bytes on every run (the trace is
/// deterministic for its seed on any thread count).
pub fn bake_tile(
    plan: &TilePlan,
    plan_dir: &Path,
    scene: &SceneInput,
    index: usize,
    force: bool,
    progress: &dyn Progress,
) -> Result<TileOutcome, TileError> {
    let tile = plan.tile(index)?;
    if !force && tile_is_done(plan_dir, index) {
        return Ok(TileOutcome::Skipped);
    }
    let found = scene_hash(&scene.scene);
    if found != plan.scene.hash {
        return Err(TileError::SceneChanged {
            planned: plan.scene.hash.clone(),
            found,
        });
    }
    let dir = tile_dir(plan_dir, index);
    // A rerun first withdraws the marker, so a crash mid-write never leaves a "finished" tile
    // with mixed files.
    let marker = dir.join(DONE_MARKER);
    match std::fs::remove_file(&marker) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
            return Err(TileError::Io {
                path: marker,
                source: e,
            });
        }
        _ => {}
    }
    let start = Instant::now();
    let volume = TransferBaker::new(&scene.scene, tile_options(plan, index)?)
        .map_err(BakeError::TracerSetup)?
        .bake(progress)
        .map_err(BakeError::Trace)?;
    let trace = start.elapsed();
    let stats = TileStats {
        index,
        dims: tile.traced.dims(),
        seed: tile.seed,
        scene_hash: plan.scene.hash.clone(),
        voxels: volume.stats.voxels,
        invalid_voxels: volume.stats.invalid_voxels,
        skipped_voxels: volume.stats.skipped_voxels,
        rays: volume.stats.rays(),
    };
    let start = Instant::now();
    write_tile(&dir, &volume, &stats)?;
    let write = start.elapsed();
    let timing = serde_json::json!({
        "trace_seconds": trace.as_secs_f64(),
        "write_seconds": write.as_secs_f64(),
        "bvh_seconds": volume.stats.bvh_time.as_secs_f64(),
        "voxel_seconds": volume.stats.voxel_time.as_secs_f64(),
    });
    write_file(&dir.join(TIMING_FILE), timing.to_string().as_bytes())?;
    write_file(&marker, b"done\n")?;
    Ok(TileOutcome::Baked {
        stats,
        trace,
        write,
    })
}

fn write_file(path: &Path, bytes: &[u8]) -> Result<(), TileError> {
    prt_texture::write_atomic(path, bytes).map_err(|source| TileError::Write {
        path: path.to_path_buf(),
        source,
    })
}

fn write_tile(dir: &Path, volume: &TransferVolume, stats: &TileStats) -> Result<(), TileError> {
    std::fs::create_dir_all(dir).map_err(|source| TileError::Io {
        path: dir.to_path_buf(),
        source,
    })?;
    let path = dir.join(TRANSFER_FILE);
    prt_texture::write_atomic_with(&path, |file| {
        let mut out = std::io::BufWriter::new(file);
        for &x in volume.field.data() {
            out.write_all(&x.to_le_bytes())?;
        }
        out.flush()
    })
    .map_err(|source| TileError::Write { path, source })?;
    let valid: Vec<u8> = volume.valid.iter().map(|&v| u8::from(v)).collect();
    write_file(&dir.join(VALID_FILE), &valid)?;
    let text = serde_json::to_string_pretty(stats).map_err(|e| TileError::Malformed {
        path: dir.join(TILE_FILE),
        why: e.to_string(),
    })?;
    write_file(&dir.join(TILE_FILE), text.as_bytes())?;
    debug_assert_eq!(volume.field.dim(), TRANSFER_DIM);
    Ok(())
}
