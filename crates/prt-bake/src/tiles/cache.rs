//! The plan's shared surface cache, `surface_cache.bin`: evaluated once (by `prt plan`, or by
//! the first worker that finds none) and read by every tile, so a tiled bake traces the cache's
//! rays about once, as a one-machine bake does. It holds the entries the first icosahedron of
//! each tile's voxels hits (a visibility pass over the tiles' own first rays), grown by three
//! lattice steps on their triangles; a tile evaluates any other entry its rays hit on first use,
//! with the plan's seed, so the values, and the tiles' bytes, do not depend on which entries
//! the file holds.
//!
//! The file: the magic `PRTSCACH`, a little-endian u32 version, a u32 length and that many bytes
//! of JSON ([`SurfaceCacheHeader`]: the fingerprint of everything that determines the values,
//! the lattice's spacing and layout hash, the counts, the payload's checksum), then the payload:
//! one bit per entry (`point * 2 + side`, least significant bit first) saying whether it is
//! evaluated, then each evaluated entry's nine little-endian f32 in entry order.

use std::path::{Path, PathBuf};
use std::time::Duration;

use prt_core::Progress;
use prt_texture::Limits;
use prt_trace::expert::SharedSurfaceCache;
use prt_trace::sh::SH9;
use prt_trace::{BakeOptions, TransferBaker};
use serde::{Deserialize, Serialize};

use super::checksum::Fnv1a64;
use super::plan::{TileError, TilePlan, as_json, json_differences};
use super::worker::{tile_options, tile_trace_box};
use crate::{BakeError, SceneInput, scene_hash};

/// File name of the shared surface cache inside a plan folder.
pub const SURFACE_CACHE_FILE: &str = "surface_cache.bin";
/// Wall time of the cache's evaluation (not reproducible, so kept apart).
const SURFACE_CACHE_TIMING_FILE: &str = "surface_cache_timing.json";
/// The file's first bytes.
pub const SURFACE_CACHE_MAGIC: &[u8; 8] = b"PRTSCACH";
/// Version of the file this crate writes and reads (2: the entries the tiles' first rays hit,
/// with the visibility pass's rays; 1 held every entry facing a voxel centre).
pub const SURFACE_CACHE_VERSION: u32 = 2;
/// Largest header read (a few hundred bytes).
const HEADER_MAX: usize = 1 << 16;

/// Everything that determines the cache's values and which entries it holds: the scene, the
/// lattice it is laid for, the bake's seed, the cache knobs and the tiles whose first rays chose
/// the entries. A file whose fingerprint is not its plan's is stale.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SurfaceCacheFingerprint {
    /// The plan's scene hash.
    pub scene_hash: String,
    /// The global lattice's voxels along x, y, z (the spacing is its mean voxel edge).
    pub lattice_dims: [usize; 3],
    /// The global lattice's box.
    pub lattice_min: [f32; 3],
    /// See `lattice_min`.
    pub lattice_max: [f32; 3],
    /// The bake's seed (a one-machine bake's cache has the same values).
    pub seed: u64,
    /// Hemisphere rays per entry.
    pub cache_rays: usize,
    /// `fnv1a64:HEX` of what decides the tiles' first rays: per tile its traced box (with the
    /// denoiser's margin), its seed and whether its directions come in replicate streams; the
    /// scene box's margin.
    pub tiles: String,
}

impl SurfaceCacheFingerprint {
    /// The fingerprint `plan`'s cache must carry.
    pub fn of(plan: &TilePlan) -> Result<Self, TileError> {
        let tiles = (0..plan.tiles.len())
            .map(|i| {
                let options = tile_options(plan, i)?;
                let replicated = options.adaptive.is_some() || options.denoise.is_some();
                Ok((tile_trace_box(plan, i)?, options.seed, replicated))
            })
            .collect::<Result<Vec<_>, TileError>>()?;
        let tiles = serde_json::to_vec(&(tiles, plan.config.margin)).unwrap_or_default();
        Ok(Self {
            scene_hash: plan.scene.hash.clone(),
            lattice_dims: plan.lattice_dims,
            lattice_min: plan.lattice_min,
            lattice_max: plan.lattice_max,
            seed: plan.config.seed,
            cache_rays: plan.config.cache_rays,
            tiles: Fnv1a64::of(&tiles),
        })
    }
}

/// The JSON header of `surface_cache.bin`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SurfaceCacheHeader {
    /// What determined the values.
    pub fingerprint: SurfaceCacheFingerprint,
    /// The lattice's spacing, in metres.
    pub spacing: f32,
    /// The lattice's layout hash (checked against the scene's lattice by the tracer).
    pub layout: u64,
    /// Lattice points (two entries each).
    pub points: usize,
    /// Entries evaluated.
    pub evaluated: usize,
    /// Rays traced to choose the entries and to evaluate them.
    pub rays: u64,
    /// Of `rays`, the visibility pass's.
    pub visibility_rays: u64,
    /// The payload's checksum, `fnv1a64:HEX`.
    pub checksum: String,
}

/// The tracer's options for `plan`'s shared cache: the global lattice, the bake's seed and
/// cache rays.
fn cache_options(plan: &TilePlan) -> BakeOptions {
    BakeOptions {
        resolution: plan.lattice_dims,
        margin: plan.config.margin,
        bounds: Some(plan.lattice_bounds()),
        rays_per_voxel: plan.config.rays_per_voxel,
        cache_rays: plan.config.cache_rays,
        seed: plan.config.seed,
        ..BakeOptions::default()
    }
}

/// Evaluates `plan`'s shared surface cache on `scene` (which must hash as the plan's): the
/// entries the first icosahedron of each tile's voxels hits (grown by three lattice steps),
/// with the values a one-machine bake computes.
pub fn evaluate_surface_cache(
    plan: &TilePlan,
    scene: &SceneInput,
    progress: &dyn Progress,
) -> Result<SharedSurfaceCache, TileError> {
    let found = scene_hash(&scene.scene);
    if found != plan.scene.hash {
        return Err(TileError::SceneChanged {
            planned: plan.scene.hash.clone(),
            found,
        });
    }
    let baker =
        TransferBaker::new(&scene.scene, cache_options(plan)).map_err(BakeError::TracerSetup)?;
    let tiles = (0..plan.tiles.len())
        .map(|i| tile_options(plan, i))
        .collect::<Result<Vec<_>, TileError>>()?;
    Ok(baker
        .evaluate_surface_cache(&tiles, progress)
        .map_err(BakeError::Trace)?)
}

/// `cache` as the bytes of `surface_cache.bin` for `plan`.
pub fn encode_surface_cache(
    plan: &TilePlan,
    cache: &SharedSurfaceCache,
) -> Result<Vec<u8>, TileError> {
    let mut payload = vec![0u8; cache.values.len().div_ceil(8)];
    for (entry, value) in cache.values.iter().enumerate() {
        if value.is_some() {
            payload[entry / 8] |= 1 << (entry % 8);
        }
    }
    for value in cache.values.iter().flatten() {
        for x in value {
            payload.extend_from_slice(&x.to_le_bytes());
        }
    }
    let header = SurfaceCacheHeader {
        fingerprint: SurfaceCacheFingerprint::of(plan)?,
        spacing: cache.spacing,
        layout: cache.layout,
        points: cache.points(),
        evaluated: cache.evaluated(),
        rays: cache.rays,
        visibility_rays: cache.visibility_rays,
        checksum: Fnv1a64::of(&payload),
    };
    let json = serde_json::to_vec(&header).unwrap_or_default();
    let mut bytes = Vec::with_capacity(16 + json.len() + payload.len());
    bytes.extend_from_slice(SURFACE_CACHE_MAGIC);
    bytes.extend_from_slice(&SURFACE_CACHE_VERSION.to_le_bytes());
    bytes.extend_from_slice(&(json.len() as u32).to_le_bytes());
    bytes.extend_from_slice(&json);
    bytes.extend_from_slice(&payload);
    Ok(bytes)
}

fn malformed(path: &Path, why: impl Into<String>) -> TileError {
    TileError::Malformed {
        path: path.to_path_buf(),
        why: why.into(),
    }
}

/// The header of `bytes` (a `surface_cache.bin` at `path`) and where its payload starts,
/// checked for `plan`: the magic and version, the fingerprint ([`TileError::StaleSurfaceCache`]),
/// the counts against `limits` ([`TileError::TooLarge`]) and the file's size, before anything is
/// allocated for the payload.
fn decode_header(
    plan: &TilePlan,
    bytes: &[u8],
    path: &Path,
    limits: &Limits,
) -> Result<(SurfaceCacheHeader, usize), TileError> {
    if bytes.len() < 16 || &bytes[..8] != SURFACE_CACHE_MAGIC {
        return Err(malformed(
            path,
            "not a prt surface cache (no PRTSCACH magic)",
        ));
    }
    let word =
        |at: usize| u32::from_le_bytes([bytes[at], bytes[at + 1], bytes[at + 2], bytes[at + 3]]);
    let version = word(8);
    if version != SURFACE_CACHE_VERSION {
        return Err(TileError::StaleSurfaceCache {
            path: path.to_path_buf(),
            differences: vec![format!("version: {version} → {SURFACE_CACHE_VERSION}")],
        });
    }
    let length = word(12) as usize;
    if length > HEADER_MAX || 16 + length > bytes.len() {
        return Err(malformed(
            path,
            format!("a header of {length} bytes does not fit the file"),
        ));
    }
    let header: SurfaceCacheHeader = serde_json::from_slice(&bytes[16..16 + length])
        .map_err(|e| malformed(path, format!("header: {e}")))?;
    let differences = json_differences(
        &as_json(&header.fingerprint),
        &as_json(&SurfaceCacheFingerprint::of(plan)?),
    );
    if !differences.is_empty() {
        return Err(TileError::StaleSurfaceCache {
            path: path.to_path_buf(),
            differences,
        });
    }
    let too_large = |what, value: u64, limit: u64| TileError::TooLarge {
        path: path.to_path_buf(),
        what,
        value,
        limit,
    };
    let entries = (header.points as u64).saturating_mul(2);
    let payload = entries
        .div_ceil(8)
        .saturating_add((header.evaluated as u64).saturating_mul(4 * SH9 as u64));
    if payload > limits.max_bytes {
        return Err(too_large("the payload's size", payload, limits.max_bytes));
    }
    if header.evaluated as u64 > entries {
        return Err(malformed(
            path,
            format!(
                "{} entries evaluated of {} points' {entries}",
                header.evaluated, header.points
            ),
        ));
    }
    let start = 16 + length;
    if (bytes.len() - start) as u64 != payload {
        return Err(malformed(
            path,
            format!(
                "the payload is {} bytes; {} points with {} entries evaluated make {payload}",
                bytes.len() - start,
                header.points,
                header.evaluated
            ),
        ));
    }
    Ok((header, start))
}

/// The shared surface cache of `plan` from the bytes of its `surface_cache.bin` (`path` names
/// it in errors): refused, never a panic, when it is not one ([`TileError::Malformed`]), is of
/// another plan or version ([`TileError::StaleSurfaceCache`]), is over `limits`
/// ([`TileError::TooLarge`], before allocating), has bytes whose checksum is not the recorded one
/// ([`TileError::DamagedSurfaceCache`]) or holds a non-finite value (named by entry). Its
/// `time` is zero ([`read_surface_cache`] reads the recorded one).
pub fn decode_surface_cache(
    plan: &TilePlan,
    bytes: &[u8],
    path: &Path,
    limits: &Limits,
) -> Result<SharedSurfaceCache, TileError> {
    let (header, start) = decode_header(plan, bytes, path, limits)?;
    let payload = &bytes[start..];
    check_payload(&header, payload, path)?;
    let entries = header.points * 2;
    let (mask, mut floats) = payload.split_at(entries.div_ceil(8));
    let marked: usize = mask.iter().map(|b| b.count_ones() as usize).sum();
    if marked != header.evaluated
        || (entries % 8 != 0 && mask[mask.len() - 1] >> (entries % 8) != 0)
    {
        return Err(malformed(
            path,
            format!(
                "the mask marks {marked} entries, the header {} evaluated",
                header.evaluated
            ),
        ));
    }
    let mut values = Vec::with_capacity(entries);
    for entry in 0..entries {
        if mask[entry / 8] >> (entry % 8) & 1 == 0 {
            values.push(None);
            continue;
        }
        let (value, rest) = floats.split_at(4 * SH9);
        floats = rest;
        let mut v = [0.0f32; SH9];
        for (k, x) in v.iter_mut().enumerate() {
            *x = f32::from_le_bytes([
                value[4 * k],
                value[4 * k + 1],
                value[4 * k + 2],
                value[4 * k + 3],
            ]);
            if !x.is_finite() {
                return Err(malformed(
                    path,
                    format!(
                        "entry {entry} (point {}, side {}) holds {x} at coefficient {k}",
                        entry / 2,
                        entry % 2
                    ),
                ));
            }
        }
        values.push(Some(v));
    }
    Ok(SharedSurfaceCache {
        spacing: header.spacing,
        layout: header.layout,
        seed: header.fingerprint.seed,
        cache_rays: header.fingerprint.cache_rays,
        rays: header.rays,
        visibility_rays: header.visibility_rays,
        time: Duration::ZERO,
        values,
    })
}

/// Reads `plan_dir/surface_cache.bin` for `plan` (see [`decode_surface_cache`]); a file over
/// `limits.max_bytes` is refused before it is read, a missing one is
/// [`TileError::NoSurfaceCache`].
pub fn read_surface_cache(
    plan: &TilePlan,
    plan_dir: &Path,
    limits: &Limits,
) -> Result<SharedSurfaceCache, TileError> {
    let path = plan_dir.join(SURFACE_CACHE_FILE);
    let bytes = read_file(&path, limits)?;
    Ok(SharedSurfaceCache {
        time: read_cache_time(plan_dir),
        ..decode_surface_cache(plan, &bytes, &path, limits)?
    })
}

/// The header of `plan_dir/surface_cache.bin` (its counts for the merge's report) and the
/// cache's evaluation time, checked as [`read_surface_cache`] checks the file (the payload's
/// checksum included) without decoding the values.
pub fn read_surface_cache_header(
    plan: &TilePlan,
    plan_dir: &Path,
    limits: &Limits,
) -> Result<(SurfaceCacheHeader, Duration), TileError> {
    let path = plan_dir.join(SURFACE_CACHE_FILE);
    let bytes = read_file(&path, limits)?;
    let (header, start) = decode_header(plan, &bytes, &path, limits)?;
    check_payload(&header, &bytes[start..], &path)?;
    Ok((header, read_cache_time(plan_dir)))
}

/// [`TileError::DamagedSurfaceCache`] when `payload`'s checksum is not the header's.
fn check_payload(
    header: &SurfaceCacheHeader,
    payload: &[u8],
    path: &Path,
) -> Result<(), TileError> {
    let found = Fnv1a64::of(payload);
    if found != header.checksum {
        return Err(TileError::DamagedSurfaceCache {
            path: path.to_path_buf(),
            recorded: header.checksum.clone(),
            found,
        });
    }
    Ok(())
}

fn read_file(path: &Path, limits: &Limits) -> Result<Vec<u8>, TileError> {
    let io = |source: std::io::Error| {
        if source.kind() == std::io::ErrorKind::NotFound {
            TileError::NoSurfaceCache {
                path: path.to_path_buf(),
            }
        } else {
            TileError::Io {
                path: path.to_path_buf(),
                source,
            }
        }
    };
    let size = std::fs::metadata(path).map_err(io)?.len();
    let limit = limits.max_bytes.saturating_add(HEADER_MAX as u64 + 16);
    if size > limit {
        return Err(TileError::TooLarge {
            path: path.to_path_buf(),
            what: "the surface cache file's size",
            value: size,
            limit,
        });
    }
    std::fs::read(path).map_err(io)
}

fn read_cache_time(plan_dir: &Path) -> Duration {
    std::fs::read(plan_dir.join(SURFACE_CACHE_TIMING_FILE))
        .ok()
        .filter(|bytes| bytes.len() < HEADER_MAX)
        .and_then(|bytes| serde_json::from_slice::<serde_json::Value>(&bytes).ok())
        .and_then(|v| v.get("seconds").and_then(serde_json::Value::as_f64))
        .and_then(|s| Duration::try_from_secs_f64(s).ok())
        .unwrap_or_default()
}

/// What [`ensure_surface_cache`] did.
#[derive(Debug, Clone, PartialEq)]
pub enum SurfaceCacheWritten {
    /// The plan folder held this plan's cache: it was read.
    Current,
    /// It was evaluated and written (none was there, or `rebuild` and it was stale or damaged:
    /// then why).
    Evaluated {
        /// Why the file there was not used (`None`: there was none).
        replaced: Option<String>,
    },
}

/// The plan's shared surface cache from `plan_dir`, evaluated on `scene` and written atomically
/// (with its timing) when there is none; a stale or damaged one is an error unless `rebuild`
/// (what `prt plan`, the folder's owner, asks), which evaluates it again. Workers that find
/// none evaluate it themselves (the same bytes, so concurrent writers agree).
pub fn ensure_surface_cache(
    plan: &TilePlan,
    plan_dir: &Path,
    scene: &SceneInput,
    rebuild: bool,
    limits: &Limits,
    progress: &dyn Progress,
) -> Result<(SharedSurfaceCache, SurfaceCacheWritten), TileError> {
    let replaced = match read_surface_cache(plan, plan_dir, limits) {
        Ok(cache) => return Ok((cache, SurfaceCacheWritten::Current)),
        Err(TileError::NoSurfaceCache { .. }) => None,
        Err(
            e @ (TileError::StaleSurfaceCache { .. }
            | TileError::DamagedSurfaceCache { .. }
            | TileError::Malformed { .. }),
        ) if rebuild => Some(e.to_string()),
        Err(e) => return Err(e),
    };
    let cache = evaluate_surface_cache(plan, scene, progress)?;
    let write = |path: PathBuf, bytes: &[u8]| {
        prt_texture::write_atomic(&path, bytes).map_err(|source| TileError::Write { path, source })
    };
    std::fs::create_dir_all(plan_dir).map_err(|source| TileError::Io {
        path: plan_dir.to_path_buf(),
        source,
    })?;
    write(
        plan_dir.join(SURFACE_CACHE_FILE),
        &encode_surface_cache(plan, &cache)?,
    )?;
    let timing = serde_json::json!({ "seconds": cache.time.as_secs_f64() });
    write(
        plan_dir.join(SURFACE_CACHE_TIMING_FILE),
        timing.to_string().as_bytes(),
    )?;
    Ok((cache, SurfaceCacheWritten::Evaluated { replaced }))
}

#[cfg(test)]
mod tests {
    use prt_core::NoProgress;

    use super::*;
    use crate::BakeConfig;
    use crate::tiles::plan_tiles;

    fn plan(seed: u64) -> TilePlan {
        let config = BakeConfig {
            resolution: 6,
            rays_per_voxel: 12,
            cache_rays: 4,
            seed,
            ..BakeConfig::default()
        };
        plan_tiles(&SceneInput::cornell_box(), None, &config, [2, 1, 1], 0).unwrap()
    }

    #[test]
    fn the_cache_reads_back_and_a_stale_damaged_or_oversized_one_is_refused() {
        let plan = plan(0);
        let scene = SceneInput::cornell_box();
        let cache = evaluate_surface_cache(&plan, &scene, &NoProgress).unwrap();
        let bytes = encode_surface_cache(&plan, &cache).unwrap();
        let path = Path::new(SURFACE_CACHE_FILE);
        let limits = Limits::default();
        let read = decode_surface_cache(&plan, &bytes, path, &limits).unwrap();
        assert_eq!(read.values, cache.values);
        assert_eq!((read.layout, read.spacing), (cache.layout, cache.spacing));
        // Another seed: stale, naming it and the tiles (seeded from it) whose rays chose the
        // entries.
        let error =
            decode_surface_cache(&super::tests::plan(1), &bytes, path, &limits).unwrap_err();
        assert!(
            matches!(&error, TileError::StaleSurfaceCache { differences, .. }
                if differences.len() == 2
                    && differences[0] == "seed: 0 → 1"
                    && differences[1].starts_with("tiles: ")),
            "{error}"
        );
        // A flipped payload bit: damaged.
        let mut damaged = bytes.clone();
        let last = damaged.len() - 3;
        damaged[last] ^= 4;
        let error = decode_surface_cache(&plan, &damaged, path, &limits).unwrap_err();
        assert!(
            matches!(error, TileError::DamagedSurfaceCache { .. }),
            "{error}"
        );
        // Over the limits: refused before the payload is read.
        let small = Limits {
            max_bytes: 64,
            ..limits
        };
        let error = decode_surface_cache(&plan, &bytes, path, &small).unwrap_err();
        assert!(matches!(error, TileError::TooLarge { .. }), "{error}");
        // Cut short, or every prefix: an error, never a panic.
        for cut in (0..bytes.len()).step_by(97) {
            assert!(decode_surface_cache(&plan, &bytes[..cut], path, &limits).is_err());
        }
    }
}
