//! A worker: trace one tile of a plan and write it atomically into the plan folder.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use prt_core::{GridField, Progress};
use prt_texture::Limits;
use prt_trace::{BakeOptions, BakeStats, TRANSFER_DIM, TransferBaker, TransferVolume};

use super::cache::ensure_surface_cache;
use super::checksum::Fnv1a64;
use super::file::{
    TILE_FILE, TILE_FORMAT, TILE_VERSION, TIMING_FILE, TRANSFER_FILE, TileChecksums,
    TileFingerprint, TileStats, TileStatus, VALID_FILE, tile_status,
};
use super::plan::{TileError, TilePlan, VoxelRange, flat, voxels};
use crate::scene_hash;
use crate::{BakeError, SceneInput};

/// Name of the file whose presence says a tile finished (written last).
pub const DONE_MARKER: &str = "done";

/// What [`bake_tile`] did.
#[derive(Debug, Clone, PartialEq)]
pub enum TileOutcome {
    /// The tile had finished before, for this plan: nothing was done.
    Skipped,
    /// The tile was traced and written, in this wall time.
    Baked {
        /// Its description.
        stats: Box<TileStats>,
        /// Wall time of the trace (BVH, cache and voxels).
        trace: Duration,
        /// Wall time of writing the files.
        write: Duration,
        /// When the tile had finished for another plan and was traced again: what differed
        /// ([`TileStatus::Stale`]); empty otherwise.
        stale: Vec<String>,
    },
}

/// The folder of tile `index` in a plan folder: `PLAN_DIR/tiles/INDEX`.
pub fn tile_dir(plan_dir: &Path, index: usize) -> PathBuf {
    plan_dir.join("tiles").join(index.to_string())
}

/// Whether tile `index` finished (its done marker exists), for whichever plan: see
/// [`tile_status`] for whether it finished for this one.
pub fn tile_is_done(plan_dir: &Path, index: usize) -> bool {
    tile_dir(plan_dir, index).join(DONE_MARKER).is_file()
}

/// The voxels tile `index` traces: its traced box, grown with the denoiser on by the
/// denoiser's radius (clipped to the lattice) so that every voxel it keeps is filtered with all
/// of its neighbours, as in a one-machine bake; the margin is dropped before the tile is written.
pub fn tile_trace_box(plan: &TilePlan, index: usize) -> Result<VoxelRange, TileError> {
    let traced = plan.tile(index)?.traced;
    let margin = plan
        .config
        .denoise
        .map_or(0, |_| plan.config.denoise_radius);
    Ok(VoxelRange {
        min: traced.min.map(|m| m.saturating_sub(margin)),
        max: [0, 1, 2].map(|k| {
            traced.max[k]
                .saturating_add(margin)
                .min(plan.lattice_dims[k])
        }),
    })
}

/// The tracer's options for `tile` of `plan`: the tile's [`tile_trace_box`] of the global
/// lattice (as explicit bounds and resolution), the plan's knobs (adaptive sampling and the
/// denoiser included), the tile's seed.
pub fn tile_options(plan: &TilePlan, index: usize) -> Result<BakeOptions, TileError> {
    let tile = plan.tile(index)?;
    let traced = tile_trace_box(plan, index)?;
    let config = &plan.config;
    Ok(BakeOptions {
        resolution: traced.dims(),
        margin: config.margin,
        bounds: Some(plan.range_bounds(&traced)),
        rays_per_voxel: config.rays_per_voxel,
        cache_rays: config.cache_rays,
        seed: tile.seed,
        adaptive: config.adaptive_sampling(),
        denoise: config.denoise_options(),
        ..BakeOptions::default()
    })
}

/// `volume`, traced over `from`, cut down to the voxels of `to` (inside `from`) on the lattice
/// of `plan`. The work done (rays, cache) stays the whole trace's; the voxel counts are the
/// cut's, a voxel outside the scene's box grown by the margin counting as skipped as the tracer
/// counts it.
fn crop(
    volume: TransferVolume,
    from: &VoxelRange,
    to: &VoxelRange,
    plan: &TilePlan,
    scene: &SceneInput,
) -> Result<TransferVolume, TileError> {
    if from == to {
        return Ok(volume);
    }
    let mut field = GridField::new(to.dims(), plan.range_bounds(to), TRANSFER_DIM)
        .map_err(|e| BakeError::Trace(e.into()))?;
    let mut valid = Vec::with_capacity(to.len());
    for (cut, v) in voxels(to).enumerate() {
        let local = flat(from.dims(), [0, 1, 2].map(|k| v[k] - from.min[k]));
        field
            .voxel_mut(cut)
            .copy_from_slice(volume.field.voxel(local));
        valid.push(volume.valid[local]);
    }
    let trace_box = scene.scene.bounds().map(|b| b.expand(plan.config.margin));
    let skipped = (0..to.len())
        .filter(|&v| trace_box.is_some_and(|b| !b.contains(field.centre_of(v))))
        .count();
    let stats = BakeStats {
        voxels: to.len(),
        invalid_voxels: valid.iter().filter(|&&ok| !ok).count() - skipped,
        skipped_voxels: skipped,
        ..volume.stats
    };
    Ok(TransferVolume {
        field,
        valid,
        stats,
    })
}

/// Traces tile `index` of `plan` (whose folder is `plan_dir`) from `scene`, which must hash as
/// the plan's, with the plan's shared surface cache (`surface_cache.bin`, evaluated and written
/// first when the folder has none; a stale or damaged one is an error), and writes `transfer.f32`, `valid.u8`, `tile.json` (with the tile's
/// [`TileFingerprint`] and the checksums of the two others), `timing.json` and then the done
/// marker into [`tile_dir`], each file atomically. A tile finished for this plan is skipped
/// unless `force`; one finished for another plan ([`TileStatus::Stale`]) is traced again. The
/// files but `timing.json` are the same bytes on every run (the trace is deterministic for its
/// seed on any thread count).
pub fn bake_tile(
    plan: &TilePlan,
    plan_dir: &Path,
    scene: &SceneInput,
    index: usize,
    force: bool,
    progress: &dyn Progress,
) -> Result<TileOutcome, TileError> {
    let stale = match tile_status(plan, plan_dir, index)? {
        TileStatus::Done if !force => return Ok(TileOutcome::Skipped),
        TileStatus::Stale(differences) => differences,
        _ => Vec::new(),
    };
    let fingerprint = TileFingerprint::of(plan, index)?;
    let found = scene_hash(&scene.scene);
    if found != plan.scene.hash {
        return Err(TileError::SceneChanged {
            planned: plan.scene.hash.clone(),
            found,
        });
    }
    let start = Instant::now();
    // Before the marker goes: a damaged or stale cache leaves a finished tile finished.
    let (cache, _) =
        ensure_surface_cache(plan, plan_dir, scene, false, &Limits::default(), progress)?;
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
    let volume = TransferBaker::new(&scene.scene, tile_options(plan, index)?)
        .and_then(|baker| baker.with_surface_cache(&cache))
        .map_err(BakeError::TracerSetup)?
        .bake(progress)
        .map_err(BakeError::Trace)?;
    let traced = plan.tile(index)?.traced;
    let volume = crop(volume, &tile_trace_box(plan, index)?, &traced, plan, scene)?;
    let trace = start.elapsed();
    let start = Instant::now();
    let stats = write_tile(&dir, index, fingerprint, &volume)?;
    let write = start.elapsed();
    let timing = serde_json::json!({
        "trace_seconds": trace.as_secs_f64(),
        "write_seconds": write.as_secs_f64(),
        "bvh_seconds": volume.stats.bvh_time.as_secs_f64(),
        "cache_seconds": volume.stats.cache_time.as_secs_f64(),
        "voxel_seconds": volume.stats.voxel_time.as_secs_f64(),
    });
    write_file(&dir.join(TIMING_FILE), timing.to_string().as_bytes())?;
    write_file(&marker, b"done\n")?;
    Ok(TileOutcome::Baked {
        stats: Box::new(stats),
        trace,
        write,
        stale,
    })
}

fn write_file(path: &Path, bytes: &[u8]) -> Result<(), TileError> {
    prt_texture::write_atomic(path, bytes).map_err(|source| TileError::Write {
        path: path.to_path_buf(),
        source,
    })
}

/// Writes the payload and then `tile.json` (with the payload's checksums) into `dir`.
fn write_tile(
    dir: &Path,
    index: usize,
    fingerprint: TileFingerprint,
    volume: &TransferVolume,
) -> Result<TileStats, TileError> {
    debug_assert_eq!(volume.field.dim(), TRANSFER_DIM);
    std::fs::create_dir_all(dir).map_err(|source| TileError::Io {
        path: dir.to_path_buf(),
        source,
    })?;
    let path = dir.join(TRANSFER_FILE);
    let mut transfer = Fnv1a64::default();
    prt_texture::write_atomic_with(&path, |file| {
        let mut out = std::io::BufWriter::new(file);
        for &x in volume.field.data() {
            let bytes = x.to_le_bytes();
            transfer.update(&bytes);
            out.write_all(&bytes)?;
        }
        out.flush()
    })
    .map_err(|source| TileError::Write { path, source })?;
    let valid: Vec<u8> = volume.valid.iter().map(|&v| u8::from(v)).collect();
    write_file(&dir.join(VALID_FILE), &valid)?;
    let s = &volume.stats;
    let stats = TileStats {
        format: TILE_FORMAT.into(),
        version: TILE_VERSION,
        index,
        fingerprint,
        checksums: TileChecksums {
            transfer: transfer.label(),
            valid: Fnv1a64::of(&valid),
        },
        voxels: s.voxels,
        invalid_voxels: s.invalid_voxels,
        skipped_voxels: s.skipped_voxels,
        rays_per_voxel: s.rays_per_voxel,
        voxel_rays: s.voxel_rays,
        cache_rays: s.cache_rays,
        cache_points: s.cache_points,
        cache_evaluated: s.cache_evaluated,
    };
    let text = serde_json::to_string_pretty(&stats).map_err(|e| TileError::Malformed {
        path: dir.join(TILE_FILE),
        why: e.to_string(),
    })?;
    write_file(&dir.join(TILE_FILE), text.as_bytes())?;
    Ok(stats)
}
