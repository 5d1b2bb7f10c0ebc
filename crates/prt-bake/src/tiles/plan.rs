//! The plan of a tiled bake: the global voxel lattice, the tiles, their seeds, the scene and
//! the bake's knobs, as a versioned JSON file.

use std::path::{Path, PathBuf};

use glam::Vec3;
use prt_core::Aabb;
use prt_texture::Limits;
use prt_trace::{BakeOptions, TransferBaker};
use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::{BakeConfig, BakeError, SceneInput, scene_hash};

/// File name of the plan inside a plan folder.
pub const PLAN_FILE: &str = "plan.json";
/// Value of the plan's `format` field.
pub const PLAN_FORMAT: &str = "prt tile plan";
/// Version of the plan format this crate writes and reads.
pub const PLAN_VERSION: u32 = 1;

/// Everything that can stop planning, baking a tile or merging.
#[derive(Debug, Error)]
#[non_exhaustive]
pub enum TileError {
    /// The tiling asked for cannot be laid on the lattice.
    #[error("invalid tiling: {0}")]
    InvalidTiling(String),
    /// A tile index outside the plan.
    #[error("tile {index} does not exist: the plan has {tiles} tiles (0..{tiles})")]
    NoSuchTile {
        /// The index asked for.
        index: usize,
        /// Tiles in the plan.
        tiles: usize,
    },
    /// The scene differs from the one planned.
    #[error(
        "the scene changed since the plan was written: its hash is {found}, the plan's {planned}"
    )]
    SceneChanged {
        /// The plan's hash.
        planned: String,
        /// The hash of the scene given.
        found: String,
    },
    /// A file could not be read or written.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// Why.
        #[source]
        source: std::io::Error,
    },
    /// A file is not what it should be (malformed, wrong version, wrong size, non-finite).
    #[error("{}: {why}", path.display())]
    Malformed {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        why: String,
    },
    /// A size a file announces (or the file itself) is over the reader's
    /// [`prt_texture::Limits`]; nothing was allocated for it.
    #[error("{}: {what} is {value}, over the limit of {limit}", path.display())]
    TooLarge {
        /// The file.
        path: PathBuf,
        /// What is too large.
        what: &'static str,
        /// Its value (`u64::MAX` when it overflows).
        value: u64,
        /// The limit.
        limit: u64,
    },
    /// A finished tile was traced for another plan: its fingerprint (everything that determines
    /// its bytes) differs from what the plan asks of it.
    #[error(
        "tile {index} ({}) was traced for another plan: {} (tile → plan); trace it again with \
         `prt bake-tile PLAN_DIR --tile {index}`",
        path.display(),
        differences.join("; ")
    )]
    StaleTile {
        /// The tile.
        index: usize,
        /// Its `tile.json`.
        path: PathBuf,
        /// What differs, as `field: tile's value → plan's value`.
        differences: Vec<String>,
    },
    /// A tile file's bytes are not those its worker wrote: their checksum differs from the one
    /// its `tile.json` records.
    #[error(
        "tile {index}: {} is damaged: its checksum is {found}, its tile.json records {recorded}; \
         trace it again with `prt bake-tile PLAN_DIR --tile {index} --force`",
        path.display()
    )]
    Damaged {
        /// The tile.
        index: usize,
        /// The damaged file.
        path: PathBuf,
        /// The checksum `tile.json` records.
        recorded: String,
        /// The checksum of the file's bytes.
        found: String,
    },
    /// The plan folder has no shared surface cache (`prt plan` writes it).
    #[error(
        "{} is missing: write it with `prt plan` (the same plan again keeps the finished tiles)",
        path.display()
    )]
    NoSurfaceCache {
        /// The missing file.
        path: PathBuf,
    },
    /// The plan folder's shared surface cache was evaluated for another plan.
    #[error(
        "{} was evaluated for another plan: {} (cache → plan); evaluate it again with `prt plan`",
        path.display(),
        differences.join("; ")
    )]
    StaleSurfaceCache {
        /// The file.
        path: PathBuf,
        /// What differs, as `field: cache's value → plan's value`.
        differences: Vec<String>,
    },
    /// The shared surface cache's bytes are not those written: their checksum differs from the
    /// one its header records.
    #[error(
        "{} is damaged: its checksum is {found}, its header records {recorded}; evaluate it \
         again with `prt plan`",
        path.display()
    )]
    DamagedSurfaceCache {
        /// The file.
        path: PathBuf,
        /// The checksum the header records.
        recorded: String,
        /// The checksum of the payload's bytes.
        found: String,
    },
    /// The plan folder already holds a different plan (see [`write_plan`]).
    #[error(
        "{} already holds a different plan ({}); replace it and remove its tiles with \
         `prt plan --replace`, or plan into another folder",
        folder.display(),
        differences.join("; ")
    )]
    PlanExists {
        /// The plan folder.
        folder: PathBuf,
        /// What differs, as `field: old value → new value`.
        differences: Vec<String>,
    },
    /// A tile the merge needs has not finished.
    #[error("tile {0} has not finished (no done marker); run `prt bake-tile` for it first")]
    NotDone(usize),
    /// Writing a file failed.
    #[error("cannot write {}", path.display())]
    Write {
        /// The file.
        path: PathBuf,
        /// Why.
        #[source]
        source: prt_texture::TextureError,
    },
    /// The bake itself (tracing, fitting, writing the container) failed.
    #[error(transparent)]
    Bake(#[from] BakeError),
    /// A file of the distributed merge is missing, stale or damaged.
    #[error(transparent)]
    Partial(#[from] super::partial::PartialError),
}

/// A box of voxels `min..max` (half-open) of the global lattice.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct VoxelRange {
    /// First voxel along x, y, z.
    pub min: [usize; 3],
    /// One past the last voxel along x, y, z.
    pub max: [usize; 3],
}

impl VoxelRange {
    /// Voxels along x, y, z.
    pub fn dims(&self) -> [usize; 3] {
        [0, 1, 2].map(|k| self.max[k] - self.min[k])
    }

    /// Voxels in the box.
    pub fn len(&self) -> usize {
        self.dims().iter().product()
    }

    /// Whether the box holds no voxel.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Whether global voxel `[x, y, z]` lies in the box.
    pub fn contains(&self, voxel: [usize; 3]) -> bool {
        (0..3).all(|k| self.min[k] <= voxel[k] && voxel[k] < self.max[k])
    }
}

/// One tile of a plan.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct TileSpec {
    /// Its index (the scheduler's task index).
    pub index: usize,
    /// The voxels it owns: every voxel of the lattice belongs to exactly one tile's core.
    pub core: VoxelRange,
    /// The voxels it traces: the core grown by the halo, clipped to the lattice.
    pub traced: VoxelRange,
    /// Seed of its trace, derived from the bake's seed and the index.
    pub seed: u64,
}

/// The scene a plan was made for.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct PlannedScene {
    /// The glTF file (absolute); `None` for the built-in Cornell box.
    pub path: Option<PathBuf>,
    /// The name the container records.
    pub name: String,
    /// [`scene_hash`] of the loaded scene: workers refuse a scene that hashes differently.
    pub hash: String,
}

/// A tiled bake's plan: what every worker and the merge read.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TilePlan {
    /// [`PLAN_FORMAT`].
    pub format: String,
    /// [`PLAN_VERSION`].
    pub version: u32,
    /// The scene.
    pub scene: PlannedScene,
    /// Voxels of the global lattice along x, y, z (what `prt bake` would trace).
    pub lattice_dims: [usize; 3],
    /// The lattice's box: voxel `i` along axis k is centred at
    /// `min + (i + 0.5) (max − min) / lattice_dims`.
    pub lattice_min: [f32; 3],
    /// See `lattice_min`.
    pub lattice_max: [f32; 3],
    /// Tiles along x, y, z.
    pub counts: [usize; 3],
    /// Voxels each tile traces beyond its core on every side (clipped to the lattice).
    pub halo: usize,
    /// The tiles, x fastest.
    pub tiles: Vec<TileSpec>,
    /// The bake's knobs (without a memory budget or container folder).
    pub config: BakeConfig,
}

impl TilePlan {
    /// The lattice's box.
    pub fn lattice_bounds(&self) -> Aabb {
        Aabb {
            min: Vec3::from_array(self.lattice_min),
            max: Vec3::from_array(self.lattice_max),
        }
    }

    /// The box covered by the voxels of `range` (its outer faces on the global lattice).
    pub fn range_bounds(&self, range: &VoxelRange) -> Aabb {
        let face = |k: usize, i: usize| {
            let (lo, hi) = (self.lattice_min[k] as f64, self.lattice_max[k] as f64);
            (lo + (hi - lo) * i as f64 / self.lattice_dims[k] as f64) as f32
        };
        Aabb {
            min: Vec3::from_array([0, 1, 2].map(|k| face(k, range.min[k]))),
            max: Vec3::from_array([0, 1, 2].map(|k| face(k, range.max[k]))),
        }
    }

    /// The tile `index`.
    pub fn tile(&self, index: usize) -> Result<&TileSpec, TileError> {
        self.tiles.get(index).ok_or(TileError::NoSuchTile {
            index,
            tiles: self.tiles.len(),
        })
    }

    /// Writes the plan as `folder/plan.json` (atomically; the folder is created), whatever the
    /// folder held; [`write_plan`] refuses to overwrite a different plan.
    pub fn write(&self, folder: &Path) -> Result<PathBuf, TileError> {
        std::fs::create_dir_all(folder).map_err(|source| TileError::Io {
            path: folder.to_path_buf(),
            source,
        })?;
        let path = folder.join(PLAN_FILE);
        let text = serde_json::to_string_pretty(self).map_err(|e| TileError::Malformed {
            path: path.clone(),
            why: e.to_string(),
        })?;
        prt_texture::write_atomic(&path, text.as_bytes()).map_err(|source| TileError::Write {
            path: path.clone(),
            source,
        })?;
        Ok(path)
    }

    /// Reads `folder/plan.json`, checking its format, version and consistency (see
    /// [`TilePlan::decode`]); a file over `limits.max_bytes` is refused before it is read.
    pub fn read(folder: &Path, limits: &Limits) -> Result<TilePlan, TileError> {
        let path = folder.join(PLAN_FILE);
        let io = |source| TileError::Io {
            path: path.clone(),
            source,
        };
        let size = std::fs::metadata(&path).map_err(io)?.len();
        if size > limits.max_bytes {
            return Err(too_large(
                &path,
                "the plan file's size",
                size,
                limits.max_bytes,
            ));
        }
        let bytes = std::fs::read(&path).map_err(io)?;
        decode_plan(&bytes, &path, limits)
    }

    /// A plan from the bytes of a `plan.json`, checked before anything is allocated for its
    /// lattice: the format and version; every lattice dimension from 1 to
    /// `limits.max_dimension` and the lattice's voxels at most `limits.max_bytes` (one byte
    /// each in the merge's validity mask), without overflow; a finite box; valid knobs; and the
    /// tiles exactly the cut of the lattice into `counts` tiles with `halo` that [`plan_tiles`]
    /// makes (so every voxel is in exactly one core), with their seeds. Errors are
    /// [`TileError::Malformed`] or [`TileError::TooLarge`], never a panic.
    pub fn decode(bytes: &[u8], limits: &Limits) -> Result<TilePlan, TileError> {
        decode_plan(bytes, Path::new(PLAN_FILE), limits)
    }

    /// What differs between this plan and `newer`, as `field: this value → newer value` (nested
    /// fields joined by dots, e.g. `config.rays_per_voxel: 48 → 96`); empty when they are equal.
    pub fn differences(&self, newer: &TilePlan) -> Vec<String> {
        json_differences(&as_json(self), &as_json(newer))
    }
}

fn too_large(path: &Path, what: &'static str, value: u64, limit: u64) -> TileError {
    TileError::TooLarge {
        path: path.to_path_buf(),
        what,
        value,
        limit,
    }
}

fn decode_plan(bytes: &[u8], path: &Path, limits: &Limits) -> Result<TilePlan, TileError> {
    let malformed = |why: String| TileError::Malformed {
        path: path.to_path_buf(),
        why,
    };
    if bytes.len() as u64 > limits.max_bytes {
        return Err(too_large(
            path,
            "the plan file's size",
            bytes.len() as u64,
            limits.max_bytes,
        ));
    }
    let plan: TilePlan = serde_json::from_slice(bytes).map_err(|e| malformed(e.to_string()))?;
    if plan.format != PLAN_FORMAT || plan.version != PLAN_VERSION {
        return Err(malformed(format!(
            "format {:?} version {}, this prt reads {PLAN_FORMAT:?} version {PLAN_VERSION}",
            plan.format, plan.version
        )));
    }
    let dims = plan.lattice_dims;
    if dims.contains(&0) {
        return Err(malformed(format!(
            "the lattice {dims:?} has no voxel along an axis"
        )));
    }
    for n in dims {
        if n as u64 > u64::from(limits.max_dimension) {
            return Err(too_large(
                path,
                "a lattice dimension",
                n as u64,
                u64::from(limits.max_dimension),
            ));
        }
    }
    let voxels = dims
        .iter()
        .try_fold(1u64, |a, &n| a.checked_mul(n as u64))
        .unwrap_or(u64::MAX);
    if voxels > limits.max_bytes {
        return Err(too_large(
            path,
            "the lattice's voxel count",
            voxels,
            limits.max_bytes,
        ));
    }
    if !plan.lattice_bounds().is_valid()
        || (0..3).any(|k| plan.lattice_min[k] >= plan.lattice_max[k])
    {
        return Err(malformed(format!(
            "the lattice box {:?}..{:?} is not a finite box",
            plan.lattice_min, plan.lattice_max
        )));
    }
    plan.config
        .validate()
        .map_err(|e| malformed(format!("config: {e}")))?;
    let counts = plan.counts;
    if (0..3).any(|k| counts[k] == 0 || counts[k] > dims[k]) {
        return Err(malformed(format!(
            "{counts:?} tiles do not fit the {dims:?} lattice (1 to its voxels along each axis)"
        )));
    }
    // At most the voxel count, checked above: no overflow.
    let tiles: usize = counts.iter().product();
    if plan.tiles.len() != tiles {
        return Err(malformed(format!(
            "{} tiles listed, {counts:?} tiles make {tiles}",
            plan.tiles.len()
        )));
    }
    // Every tile exactly the one `plan_tiles` lays there: the cores partition the lattice,
    // the traced boxes are the cores grown by the halo, the seeds derive from the bake's.
    for (i, tile) in plan.tiles.iter().enumerate() {
        if *tile != layout_tile(dims, counts, plan.halo, plan.config.seed, i) {
            return Err(malformed(format!(
                "tile {i} is not tile {i} of {counts:?} tiles with halo {} on the {dims:?} \
                 lattice (its index, core, traced box or seed differs)",
                plan.halo
            )));
        }
    }
    Ok(plan)
}

/// What [`write_plan`] did.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum PlanWritten {
    /// The folder held no plan: the plan was written.
    New,
    /// The folder held this same plan: nothing was written and its finished tiles are kept.
    Unchanged,
    /// The folder held another plan (or one that cannot be read): it was replaced, and its
    /// tiles (this many tile folders, done markers included) and worker logs were removed.
    Replaced {
        /// Tile folders removed.
        removed_tiles: usize,
    },
}

/// Writes `plan` into the plan folder `folder`, never next to another plan's tiles: a folder
/// holding the same plan is left as it is (its finished tiles stay valid); one holding a
/// different plan, or a `plan.json` that cannot be read with `limits`, is refused with
/// [`TileError::PlanExists`] unless `replace`, which first removes its `tiles/` and `logs/`.
pub fn write_plan(
    plan: &TilePlan,
    folder: &Path,
    replace: bool,
    limits: &Limits,
) -> Result<PlanWritten, TileError> {
    let path = folder.join(PLAN_FILE);
    let differences = match std::fs::symlink_metadata(&path) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => None,
        Err(source) => return Err(TileError::Io { path, source }),
        Ok(_) => match TilePlan::read(folder, limits) {
            Ok(old) if old == *plan => return Ok(PlanWritten::Unchanged),
            Ok(old) => Some(old.differences(plan)),
            Err(e) => Some(vec![format!("its plan.json cannot be read: {e}")]),
        },
    };
    let Some(differences) = differences else {
        plan.write(folder)?;
        return Ok(PlanWritten::New);
    };
    if !replace {
        return Err(TileError::PlanExists {
            folder: folder.to_path_buf(),
            differences,
        });
    }
    let tiles = folder.join("tiles");
    let removed_tiles = match std::fs::read_dir(&tiles) {
        Ok(entries) => entries.count(),
        Err(_) => 0,
    };
    for dir in [tiles, folder.join("logs")] {
        match std::fs::remove_dir_all(&dir) {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
                return Err(TileError::Io {
                    path: dir,
                    source: e,
                });
            }
            _ => {}
        }
    }
    plan.write(folder)?;
    Ok(PlanWritten::Replaced { removed_tiles })
}

/// `value` as JSON the way it reads back from its file (floats through their text form, so a
/// value serialised here equals the same value parsed from a file).
pub(crate) fn as_json<T: Serialize>(value: &T) -> serde_json::Value {
    serde_json::to_string(value)
        .ok()
        .and_then(|text| serde_json::from_str(&text).ok())
        .unwrap_or(serde_json::Value::Null)
}

/// The fields where `found` and `expected` differ, as `field: found → expected` (nested
/// objects walked, fields joined by dots; a long value shown as `differs`).
pub(crate) fn json_differences(
    found: &serde_json::Value,
    expected: &serde_json::Value,
) -> Vec<String> {
    fn walk(
        field: &str,
        a: Option<&serde_json::Value>,
        b: Option<&serde_json::Value>,
        out: &mut Vec<String>,
    ) {
        use serde_json::Value;
        if let (Some(Value::Object(x)), Some(Value::Object(y))) = (a, b) {
            let keys = x.keys().chain(y.keys().filter(|k| !x.contains_key(*k)));
            for key in keys {
                let name = if field.is_empty() {
                    key.clone()
                } else {
                    format!("{field}.{key}")
                };
                walk(&name, x.get(key), y.get(key), out);
            }
            return;
        }
        if a == b {
            return;
        }
        let show = |v: Option<&Value>| v.map_or_else(|| "(absent)".to_string(), Value::to_string);
        let (a, b) = (show(a), show(b));
        let name = if field.is_empty() {
            "(the whole)"
        } else {
            field
        };
        if a.len() + b.len() > 80 {
            out.push(format!("{name} differs"));
        } else {
            out.push(format!("{name}: {a} → {b}"));
        }
    }
    let mut out = Vec::new();
    walk("", Some(found), Some(expected), &mut out);
    out
}

/// The voxels of `range`, x fastest.
pub(crate) fn voxels(range: &VoxelRange) -> impl Iterator<Item = [usize; 3]> + '_ {
    (range.min[2]..range.max[2]).flat_map(move |z| {
        (range.min[1]..range.max[1])
            .flat_map(move |y| (range.min[0]..range.max[0]).map(move |x| [x, y, z]))
    })
}

/// Flat index of voxel `v` on a grid of `dims` (x fastest).
pub(crate) fn flat(dims: [usize; 3], v: [usize; 3]) -> usize {
    v[0] + dims[0] * (v[1] + dims[1] * v[2])
}

/// SplitMix64: a tile's seed from the bake's seed and the tile index.
fn tile_seed(seed: u64, index: usize) -> u64 {
    let mut z = seed ^ (index as u64 + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Tile `index` (x fastest) of the `dims` lattice cut into `counts` tiles per axis (as equal
/// as the voxel counts allow), traced with `halo` extra voxels on every side, seeded from
/// `seed`. `counts` must be at least 1 and at most `dims` along every axis.
fn layout_tile(
    dims: [usize; 3],
    counts: [usize; 3],
    halo: usize,
    seed: u64,
    index: usize,
) -> TileSpec {
    let t = [
        index % counts[0],
        index / counts[0] % counts[1],
        index / (counts[0] * counts[1]),
    ];
    let cut = |k: usize, i: usize| (i as u128 * dims[k] as u128 / counts[k] as u128) as usize;
    let core = VoxelRange {
        min: [0, 1, 2].map(|k| cut(k, t[k])),
        max: [0, 1, 2].map(|k| cut(k, t[k] + 1)),
    };
    let traced = VoxelRange {
        min: core.min.map(|m| m.saturating_sub(halo)),
        max: [0, 1, 2].map(|k| core.max[k].saturating_add(halo).min(dims[k])),
    };
    TileSpec {
        index,
        core,
        traced,
        seed: tile_seed(seed, index),
    }
}

/// Plans a tiled bake of `scene` (loaded from `scene_path`, `None` for the built-in Cornell
/// box) with `config`: the lattice `prt bake` would trace, cut into `counts` tiles per axis
/// (as equal as the voxel counts allow), each traced with `halo` extra voxels on every side.
pub fn plan_tiles(
    scene: &SceneInput,
    scene_path: Option<&Path>,
    config: &BakeConfig,
    counts: [usize; 3],
    halo: usize,
) -> Result<TilePlan, TileError> {
    config.validate()?;
    let bounds = scene.scene.bounds().ok_or_else(|| BakeError::EmptyScene {
        scene: scene.name.clone(),
    })?;
    let dims = config.grid_resolution(bounds.size().to_array());
    if let Some(k) = (0..3).find(|&k| counts[k] == 0 || counts[k] > dims[k]) {
        return Err(TileError::InvalidTiling(format!(
            "{} tiles along axis {k}, which has {} voxels (1 to {} tiles)",
            counts[k], dims[k], dims[k]
        )));
    }
    // The lattice exactly as `prt bake` lays it (the tracer owns the rule for flat axes).
    let options = BakeOptions {
        resolution: dims,
        margin: config.margin,
        ..BakeOptions::default()
    };
    let lattice = TransferBaker::new(&scene.scene, options)
        .map_err(BakeError::TracerSetup)?
        .grid_bounds();
    let tiles = (0..counts.iter().product())
        .map(|index| layout_tile(dims, counts, halo, config.seed, index))
        .collect();
    let path = match scene_path {
        Some(p) => Some(std::fs::canonicalize(p).map_err(|source| TileError::Io {
            path: p.to_path_buf(),
            source,
        })?),
        None => None,
    };
    Ok(TilePlan {
        format: PLAN_FORMAT.into(),
        version: PLAN_VERSION,
        scene: PlannedScene {
            path,
            name: scene.name.clone(),
            hash: scene_hash(&scene.scene),
        },
        lattice_dims: dims,
        lattice_min: lattice.min.to_array(),
        lattice_max: lattice.max.to_array(),
        counts,
        halo,
        tiles,
        config: BakeConfig {
            max_memory: None,
            container: None,
            ..config.clone()
        },
    })
}
