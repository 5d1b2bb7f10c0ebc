//! The plan of a tiled bake: the global voxel lattice, the tiles, their seeds, the scene and
//! the bake's knobs, as a versioned JSON file.

use std::path::{Path, PathBuf};

use glam::Vec3;
use prt_core::Aabb;
use prt_trace::{BakeOptions, Scene, TransferBaker};
use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::{BakeConfig, BakeError, SceneInput};

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

    /// Writes the plan as `folder/plan.json` (atomically; the folder is created).
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

    /// Reads `folder/plan.json`, checking its format, version and consistency.
    pub fn read(folder: &Path) -> Result<TilePlan, TileError> {
        let path = folder.join(PLAN_FILE);
        let text = std::fs::read_to_string(&path).map_err(|source| TileError::Io {
            path: path.clone(),
            source,
        })?;
        let malformed = |why: String| TileError::Malformed {
            path: path.clone(),
            why,
        };
        let plan: TilePlan = serde_json::from_str(&text).map_err(|e| malformed(e.to_string()))?;
        if plan.format != PLAN_FORMAT || plan.version != PLAN_VERSION {
            return Err(malformed(format!(
                "format {:?} version {}, this prt reads {PLAN_FORMAT:?} version {PLAN_VERSION}",
                plan.format, plan.version
            )));
        }
        if !plan.lattice_bounds().is_valid()
            || (0..3).any(|k| plan.lattice_min[k] >= plan.lattice_max[k])
        {
            return Err(malformed(format!(
                "the lattice box {:?}..{:?} is not a finite box",
                plan.lattice_min, plan.lattice_max
            )));
        }
        // Every voxel in exactly one core, every core inside its traced box.
        let mut owners = vec![0u8; plan.lattice_dims.iter().product()];
        for (i, tile) in plan.tiles.iter().enumerate() {
            let inside = (0..3).all(|k| {
                tile.traced.min[k] <= tile.core.min[k]
                    && tile.core.min[k] < tile.core.max[k]
                    && tile.core.max[k] <= tile.traced.max[k]
                    && tile.traced.max[k] <= plan.lattice_dims[k]
            });
            if tile.index != i || !inside {
                return Err(malformed(format!("tile {i} is not a box of the lattice")));
            }
            for v in voxels(&tile.core) {
                let g = flat(plan.lattice_dims, v);
                owners[g] = owners[g].saturating_add(1);
            }
        }
        if owners.iter().any(|&n| n != 1) {
            return Err(malformed(
                "the tiles' cores do not cover the lattice exactly once".into(),
            ));
        }
        Ok(plan)
    }
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

/// A 64-bit FNV-1a hash of the loaded scene (triangles, materials, lights' count), as
/// `fnv1a64:HEX`: what a worker compares to refuse a scene edited since the plan.
pub fn scene_hash(scene: &Scene) -> String {
    let mut hash = 0xcbf2_9ce4_8422_2325u64;
    let mut eat = |bytes: &[u8]| {
        for &b in bytes {
            hash = (hash ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3);
        }
    };
    for triangle in scene.triangles() {
        for vertex in triangle {
            for c in vertex.to_array() {
                eat(&c.to_le_bytes());
            }
        }
    }
    for id in scene.material_ids() {
        eat(&id.to_le_bytes());
    }
    for material in scene.materials() {
        for c in material
            .albedo
            .to_array()
            .into_iter()
            .chain(material.emissive.to_array())
        {
            eat(&c.to_le_bytes());
        }
        eat(&[u8::from(material.double_sided)]);
    }
    eat(&(scene.lights().len() as u64).to_le_bytes());
    format!("fnv1a64:{hash:016x}")
}

/// SplitMix64: a tile's seed from the bake's seed and the tile index.
fn tile_seed(seed: u64, index: usize) -> u64 {
    let mut z = seed ^ (index as u64 + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
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
    let cut = |k: usize, i: usize| i * dims[k] / counts[k];
    let mut tiles = Vec::new();
    for tz in 0..counts[2] {
        for ty in 0..counts[1] {
            for tx in 0..counts[0] {
                let t = [tx, ty, tz];
                let core = VoxelRange {
                    min: [0, 1, 2].map(|k| cut(k, t[k])),
                    max: [0, 1, 2].map(|k| cut(k, t[k] + 1)),
                };
                let traced = VoxelRange {
                    min: core.min.map(|m| m.saturating_sub(halo)),
                    max: [0, 1, 2].map(|k| (core.max[k] + halo).min(dims[k])),
                };
                let index = tiles.len();
                tiles.push(TileSpec {
                    index,
                    core,
                    traced,
                    seed: tile_seed(config.seed, index),
                });
            }
        }
    }
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
