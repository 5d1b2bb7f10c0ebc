//! A tile's files: `tile.json` (what the worker traced, the fingerprint of everything that
//! determines the tile's bytes, the checksums of its payload files) and the payload
//! (`transfer.f32`, `valid.u8`), and their checked reading.

use std::io::Read;
use std::path::{Path, PathBuf};
use std::time::Duration;

use prt_texture::Limits;
use prt_trace::TRANSFER_DIM;
use serde::{Deserialize, Serialize};

use super::checksum::Fnv1a64;
use super::plan::{TileError, TilePlan, TileSpec, VoxelRange, as_json, json_differences, voxels};
use super::worker::{DONE_MARKER, tile_dir, tile_options};

/// The tile's traced transfer vectors: little-endian f32, traced voxels × 324, x fastest.
pub(crate) const TRANSFER_FILE: &str = "transfer.f32";
/// The tile's validity: one byte (0 or 1) per traced voxel.
pub(crate) const VALID_FILE: &str = "valid.u8";
/// The tile's description ([`TileStats`]): reproducible, no timings.
pub(crate) const TILE_FILE: &str = "tile.json";
/// Wall and stage times of the tile's last run (not reproducible, so kept apart).
pub(crate) const TIMING_FILE: &str = "timing.json";
/// Value of `tile.json`'s `format` field.
pub const TILE_FORMAT: &str = "prt tile";
/// Version of the tile files this crate writes and reads; a tile of another version reads as
/// stale and is traced again. Version 1: a `tile.json` without `format`, `version`, fingerprint
/// or checksums; version 2: tiles that each evaluated their own surface cache (3 reads the
/// plan's shared one).
pub const TILE_VERSION: u32 = 3;
/// Largest `tile.json` or `timing.json` read (they are a few hundred bytes).
const SMALL_FILE_MAX: u64 = 1 << 20;

/// Everything that determines a tile's bytes: the scene, the lattice, the tile's boxes and
/// seed, and every tracer knob of its trace. A finished tile whose fingerprint differs from the
/// one its plan asks for ([`TileFingerprint::of`]) is stale: `prt bake-tile` traces it again and
/// the merge refuses it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TileFingerprint {
    /// The plan's scene hash ([`crate::scene_hash`]).
    pub scene_hash: String,
    /// The bake's resolution knob (voxels along the longest axis of the scene box).
    pub resolution: usize,
    /// The global lattice's voxels along x, y, z.
    pub lattice_dims: [usize; 3],
    /// The global lattice's box.
    pub lattice_min: [f32; 3],
    /// See `lattice_min`.
    pub lattice_max: [f32; 3],
    /// The plan's halo.
    pub halo: usize,
    /// The voxels the tile owns.
    pub core: VoxelRange,
    /// The voxels it traces.
    pub traced: VoxelRange,
    /// The seed of its trace.
    pub seed: u64,
    /// Directions per voxel asked for (the tracer rounds up to a multiple of 12).
    pub rays_per_voxel: usize,
    /// Hemisphere rays per surface-cache point.
    pub cache_rays: usize,
    /// Margin around the scene bounds, in metres (voxels beyond it are not traced).
    pub margin: f32,
    /// Surface-cache spacing (`None`: the mean voxel edge).
    pub cache_spacing: Option<f32>,
    /// Directions that decide a voxel's validity.
    pub probe_rays: usize,
    /// Back-face fraction above which a voxel is invalid.
    pub max_backface_fraction: f32,
    /// How the one-bounce part is computed (`SurfaceCache`, `BruteForce`, `Off`).
    pub indirect: String,
    /// Adaptive sampling's target relative standard error and minimum directions (`None`:
    /// off).
    pub adaptive: Option<(f32, usize)>,
    /// The denoiser's strength and radius (`None`: off); with it the tile traces a margin of
    /// that radius around its traced box ([`super::tile_trace_box`]).
    pub denoise: Option<(f32, usize)>,
}

impl TileFingerprint {
    /// The fingerprint tile `index` of `plan` must carry.
    pub fn of(plan: &TilePlan, index: usize) -> Result<TileFingerprint, TileError> {
        let tile = plan.tile(index)?;
        let options = tile_options(plan, index)?;
        Ok(TileFingerprint {
            scene_hash: plan.scene.hash.clone(),
            resolution: plan.config.resolution,
            lattice_dims: plan.lattice_dims,
            lattice_min: plan.lattice_min,
            lattice_max: plan.lattice_max,
            halo: plan.halo,
            core: tile.core,
            traced: tile.traced,
            seed: options.seed,
            rays_per_voxel: options.rays_per_voxel,
            cache_rays: options.cache_rays,
            margin: options.margin,
            cache_spacing: options.cache_spacing,
            probe_rays: options.probe_rays,
            max_backface_fraction: options.max_backface_fraction,
            indirect: format!("{:?}", options.indirect),
            adaptive: options.adaptive.map(|a| (a.target_error, a.min_rays)),
            denoise: options.denoise.map(|d| (d.strength, d.radius)),
        })
    }
}

/// The checksums of a tile's payload files, as `fnv1a64:HEX` (64-bit FNV-1a of the file's
/// bytes).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct TileChecksums {
    /// Of `transfer.f32`.
    #[serde(rename = "transfer.f32")]
    pub transfer: String,
    /// Of `valid.u8`.
    #[serde(rename = "valid.u8")]
    pub valid: String,
}

/// What a tile's `tile.json` records: the same bytes on every run of the tile.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TileStats {
    /// [`TILE_FORMAT`].
    pub format: String,
    /// [`TILE_VERSION`].
    pub version: u32,
    /// The tile index.
    pub index: usize,
    /// Everything that determined the tile's bytes.
    pub fingerprint: TileFingerprint,
    /// The payload files' checksums.
    pub checksums: TileChecksums,
    /// Voxels traced.
    pub voxels: usize,
    /// Voxels inside geometry.
    pub invalid_voxels: usize,
    /// Voxels outside the scene bounds (not traced).
    pub skipped_voxels: usize,
    /// Directions per valid voxel as the tracer rounds them (the cap with adaptive sampling).
    pub rays_per_voxel: usize,
    /// Rays traced from voxels.
    pub voxel_rays: u64,
    /// Rays traced for the surface-cache entries the tile's rays hit that the plan's shared
    /// cache lacks.
    pub cache_rays: u64,
    /// Points of the surface cache the tile used (the plan's shared one).
    pub cache_points: usize,
    /// Its entries the tile evaluated (those the shared cache lacks).
    pub cache_evaluated: usize,
}

impl TileStats {
    /// All rays traced (voxel and surface-cache rays).
    pub fn rays(&self) -> u64 {
        self.voxel_rays + self.cache_rays
    }
}

/// Whether a tile of a plan is finished, see [`tile_status`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum TileStatus {
    /// No done marker.
    NotDone,
    /// Finished for this plan.
    Done,
    /// Finished, but for another plan (or its `tile.json` cannot be read): what differs, as
    /// `field: tile's value → plan's value`.
    Stale(Vec<String>),
}

/// One finished tile's files, checked against the plan.
#[derive(Debug, Clone, PartialEq)]
pub struct TileData {
    /// Its `tile.json`.
    pub stats: TileStats,
    /// The traced vectors of the tile's voxels (core and halo, x fastest), 324 each.
    pub transfer: Vec<f32>,
    /// Whether each of those voxels is valid.
    pub valid: Vec<bool>,
}

fn malformed(path: &Path, why: impl Into<String>) -> TileError {
    TileError::Malformed {
        path: path.to_path_buf(),
        why: why.into(),
    }
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> TileError + '_ {
    move |source| TileError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// Reads `path`, refusing a file over `limit` bytes before reading it.
fn read_capped(path: &Path, what: &'static str, limit: u64) -> Result<Vec<u8>, TileError> {
    let size = std::fs::metadata(path).map_err(io(path))?.len();
    if size > limit {
        return Err(TileError::TooLarge {
            path: path.to_path_buf(),
            what,
            value: size,
            limit,
        });
    }
    std::fs::read(path).map_err(io(path))
}

/// How a `tile.json` compares with what the plan asks of its tile.
enum Record {
    /// It is this tile of this plan.
    Current(Box<TileStats>),
    /// It was written for another plan: what differs.
    Stale(Vec<String>),
}

/// Checks the bytes of tile `tile`'s `tile.json` against `plan`; `Err` says why they are
/// malformed.
fn check_record(plan: &TilePlan, tile: &TileSpec, bytes: &[u8]) -> Result<Record, String> {
    let value: serde_json::Value = serde_json::from_slice(bytes).map_err(|e| e.to_string())?;
    let Some(object) = value.as_object() else {
        return Err("not a JSON object".into());
    };
    match (object.get("format"), object.get("version")) {
        (None, None) => {
            return Ok(Record::Stale(vec![format!(
                "tile format version: 1 (no fingerprint, written by an older prt) → \
                 {TILE_VERSION}"
            )]));
        }
        (Some(f), _) if f.as_str() != Some(TILE_FORMAT) => {
            return Err(format!("format {f}, this prt reads {TILE_FORMAT:?}"));
        }
        (_, Some(v)) if v.as_u64() != Some(u64::from(TILE_VERSION)) => {
            return Ok(Record::Stale(vec![format!(
                "tile format version: {v} → {TILE_VERSION}"
            )]));
        }
        _ => {}
    }
    let expected = TileFingerprint::of(plan, tile.index).map_err(|e| e.to_string())?;
    let mut differences = Vec::new();
    let index = object.get("index").cloned().unwrap_or_default();
    if index.as_u64() != Some(tile.index as u64) {
        differences.push(format!("index: {index} → {}", tile.index));
    }
    match object.get("fingerprint") {
        Some(found) => differences.extend(json_differences(found, &as_json(&expected))),
        None => differences.push("fingerprint: (absent)".into()),
    }
    if !differences.is_empty() {
        return Ok(Record::Stale(differences));
    }
    let stats: TileStats = serde_json::from_value(value).map_err(|e| e.to_string())?;
    if stats.voxels != tile.traced.len() {
        return Err(format!(
            "{} voxels recorded, the tile traces {}",
            stats.voxels,
            tile.traced.len()
        ));
    }
    Ok(Record::Current(Box::new(stats)))
}

/// Whether tile `index` of `plan` is finished in `plan_dir`: no done marker; a marker and a
/// `tile.json` whose fingerprint is the plan's; or a marker with a `tile.json` written for
/// another plan (or unreadable), listing what differs. Reads `tile.json` only: a payload
/// damaged since is found when the tile is read ([`TileError::Damaged`]).
pub fn tile_status(
    plan: &TilePlan,
    plan_dir: &Path,
    index: usize,
) -> Result<TileStatus, TileError> {
    let tile = plan.tile(index)?;
    let dir = tile_dir(plan_dir, index);
    if !dir.join(DONE_MARKER).is_file() {
        return Ok(TileStatus::NotDone);
    }
    let path = dir.join(TILE_FILE);
    let record = read_capped(&path, "tile.json's size", SMALL_FILE_MAX)
        .map_err(|e| e.to_string())
        .and_then(|bytes| check_record(plan, tile, &bytes));
    Ok(match record {
        Ok(Record::Current(_)) => TileStatus::Done,
        Ok(Record::Stale(differences)) => TileStatus::Stale(differences),
        Err(why) => TileStatus::Stale(vec![format!("its tile.json cannot be read: {why}")]),
    })
}

/// `tile.json` checked: a [`TileError::Malformed`] or [`TileError::StaleTile`] error otherwise.
fn stats_of(
    plan: &TilePlan,
    tile: &TileSpec,
    path: &Path,
    bytes: &[u8],
) -> Result<TileStats, TileError> {
    match check_record(plan, tile, bytes) {
        Ok(Record::Current(stats)) => Ok(*stats),
        Ok(Record::Stale(differences)) => Err(TileError::StaleTile {
            index: tile.index,
            path: path.to_path_buf(),
            differences,
        }),
        Err(why) => Err(malformed(path, why)),
    }
}

/// The payload's size in bytes: `traced voxels × 324 × 4`, refused over `limits.max_bytes`.
fn payload_bytes(tile: &TileSpec, path: &Path, limits: &Limits) -> Result<u64, TileError> {
    let bytes = (tile.traced.len() as u64).saturating_mul(TRANSFER_DIM as u64 * 4);
    if bytes > limits.max_bytes {
        return Err(TileError::TooLarge {
            path: path.to_path_buf(),
            what: "the tile's transfer vectors' bytes",
            value: bytes,
            limit: limits.max_bytes,
        });
    }
    Ok(bytes)
}

/// `values` little-endian f32s read from `source` a chunk at a time, hashed as they pass, so
/// that the file's bytes are never held beside the decoded values; and the bytes' checksum.
fn decode_f32s(
    mut source: impl Read,
    values: usize,
    path: &Path,
) -> Result<(Vec<f32>, String), TileError> {
    let mut out = Vec::with_capacity(values);
    let mut hash = Fnv1a64::default();
    let mut chunk = vec![0u8; (values * 4).min(1 << 20)];
    let mut left = values * 4;
    while left > 0 {
        let bytes = &mut chunk[..left.min(1 << 20)];
        source.read_exact(bytes).map_err(io(path))?;
        hash.update(bytes);
        out.extend(
            bytes
                .chunks_exact(4)
                .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])),
        );
        left -= bytes.len();
    }
    Ok((out, hash.label()))
}

/// The payload checked against `stats`: `transfer` holds the tile's voxels × 324 f32s (its size
/// checked by the caller); checksums, the size of `valid`, 0 / 1 validity, finite values.
fn decode_payload(
    tile: &TileSpec,
    stats: TileStats,
    dir: &Path,
    transfer: impl Read,
    valid: &[u8],
) -> Result<TileData, TileError> {
    let n = tile.traced.len();
    let (transfer_path, valid_path) = (dir.join(TRANSFER_FILE), dir.join(VALID_FILE));
    if valid.len() != n {
        return Err(malformed(
            &valid_path,
            format!("{} bytes, the tile's {n} voxels need {n}", valid.len()),
        ));
    }
    let (transfer, transfer_checksum) = decode_f32s(transfer, n * TRANSFER_DIM, &transfer_path)?;
    for (path, found, recorded) in [
        (&transfer_path, transfer_checksum, &stats.checksums.transfer),
        (&valid_path, Fnv1a64::of(valid), &stats.checksums.valid),
    ] {
        if &found != recorded {
            return Err(TileError::Damaged {
                index: tile.index,
                path: path.clone(),
                recorded: recorded.clone(),
                found,
            });
        }
    }
    if valid.iter().any(|&b| b > 1) {
        return Err(malformed(&valid_path, format!("not {n} bytes of 0 or 1")));
    }
    if let Some(i) = transfer.iter().position(|x| !x.is_finite()) {
        let v = voxels(&tile.traced)
            .nth(i / TRANSFER_DIM)
            .unwrap_or_default();
        return Err(malformed(
            &transfer_path,
            format!("non-finite value at voxel {v:?} of the lattice"),
        ));
    }
    Ok(TileData {
        stats,
        transfer,
        valid: valid.iter().map(|&b| b == 1).collect(),
    })
}

/// Tile `index` of `plan` from the bytes of its `tile.json`, `transfer.f32` and `valid.u8`:
/// the record's format, version and fingerprint against the plan ([`TileError::StaleTile`]
/// naming what differs), the payload's size against `limits.max_bytes` before anything is
/// allocated ([`TileError::TooLarge`]), its checksums ([`TileError::Damaged`]), 0 / 1
/// validity and finite values ([`TileError::Malformed`]). Never panics.
pub fn decode_tile(
    plan: &TilePlan,
    index: usize,
    tile_json: &[u8],
    transfer: &[u8],
    valid: &[u8],
    limits: &Limits,
) -> Result<TileData, TileError> {
    let tile = plan.tile(index)?;
    let dir = Path::new("tiles").join(index.to_string());
    let stats = stats_of(plan, tile, &dir.join(TILE_FILE), tile_json)?;
    let transfer_path = dir.join(TRANSFER_FILE);
    let expected = payload_bytes(tile, &transfer_path, limits)?;
    if transfer.len() as u64 != expected {
        return Err(malformed(
            &transfer_path,
            format!(
                "{} bytes, the tile's {} voxels need {expected}",
                transfer.len(),
                tile.traced.len()
            ),
        ));
    }
    decode_payload(tile, stats, &dir, transfer, valid)
}

/// Reads tile `tile` of `plan` from `plan_dir`, checked as [`decode_tile`] does; the record is
/// checked before the payload is read, and the payload's size against the plan and `limits`
/// before it is read.
pub(crate) fn read_tile(
    plan: &TilePlan,
    plan_dir: &Path,
    tile: &TileSpec,
    limits: &Limits,
) -> Result<TileData, TileError> {
    let dir = tile_dir(plan_dir, tile.index);
    if !dir.join(DONE_MARKER).is_file() {
        return Err(TileError::NotDone(tile.index));
    }
    let info_path = dir.join(TILE_FILE);
    let info = read_capped(&info_path, "tile.json's size", SMALL_FILE_MAX)?;
    let stats = stats_of(plan, tile, &info_path, &info)?;
    let transfer_path = dir.join(TRANSFER_FILE);
    let expected = payload_bytes(tile, &transfer_path, limits)?;
    let valid_path = dir.join(VALID_FILE);
    for (path, want) in [
        (&transfer_path, expected),
        (&valid_path, tile.traced.len() as u64),
    ] {
        let size = std::fs::metadata(path).map_err(io(path))?.len();
        if size != want {
            return Err(malformed(
                path,
                format!(
                    "{size} bytes, the tile's {} voxels need {want}",
                    tile.traced.len()
                ),
            ));
        }
    }
    let transfer = std::fs::File::open(&transfer_path).map_err(io(&transfer_path))?;
    let valid = std::fs::read(&valid_path).map_err(io(&valid_path))?;
    decode_payload(tile, stats, &dir, transfer, &valid)
}

/// A worker's times from its `timing.json` (zero when absent or unreadable): BVH, surface
/// cache, voxels.
pub(crate) fn read_timing(plan_dir: &Path, index: usize) -> [Duration; 3] {
    let path: PathBuf = tile_dir(plan_dir, index).join(TIMING_FILE);
    let value: serde_json::Value = read_capped(&path, "timing.json's size", SMALL_FILE_MAX)
        .ok()
        .and_then(|bytes| serde_json::from_slice(&bytes).ok())
        .unwrap_or_default();
    ["bvh_seconds", "cache_seconds", "voxel_seconds"].map(|key| {
        value
            .get(key)
            .and_then(serde_json::Value::as_f64)
            .and_then(|s| Duration::try_from_secs_f64(s).ok())
            .unwrap_or_default()
    })
}
