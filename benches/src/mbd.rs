//! Helpers shared by the MBD experiments (`mbd_sweep`, `mbd_clustered`, `mbd_scale`): the
//! field a run works on (synthetic, or a traced scene cached on disk), the cost of a fit and
//! basis node counts.

use std::path::PathBuf;

use glam::Vec3;
use prt_core::{Aabb, GridField, NoProgress};
use prt_trace::{BakeOptions, TransferBaker};

use crate::Stopwatch;

/// The field an MBD experiment runs on.
#[derive(Debug, Clone, clap::Args)]
pub struct FieldArgs {
    /// `synthetic` (a smooth 324-D field on a curved manifold, n³ voxels), `cornell` (the
    /// built-in Cornell box) or `sponza` (../shared/scenes/sponza), the scenes traced at `prt
    /// bake`'s defaults (256 rays, 64 cache rays, seed 0) and cached in target/mbd_cache/.
    #[arg(long, default_value = "synthetic", global = true)]
    pub field: String,
    /// Voxels along the field's longest axis.
    #[arg(long, default_value_t = 32, global = true)]
    pub n: usize,
}

/// A field with its description and the voxels that count for the seam measures.
pub struct Input {
    /// The field.
    pub field: GridField,
    /// What it is, for table headings.
    pub name: String,
    /// The baker's validity mask (`None`: every voxel, for the synthetic field).
    pub valid: Option<Vec<bool>>,
    /// Blur of the reference for the error seams: one voxel for traced (noisy) volumes, none
    /// for the noise-free synthetic field, where the blur's own bias would be the largest
    /// error of an accurate method.
    pub seam_sigma: f64,
}

impl FieldArgs {
    /// The field, traced (and cached) on first use.
    pub fn load(&self) -> Input {
        let n = self.n;
        match self.field.as_str() {
            "synthetic" => Input {
                field: synthetic_field(n),
                name: format!("synthetic {n}³ × 324"),
                valid: None,
                seam_sigma: 0.0,
            },
            scene @ ("cornell" | "sponza") => {
                let field = traced_field(scene, n);
                let [x, y, z] = field.dims();
                let valid = prt_mbd::expert::nonzero_voxels(&field);
                let invalid = valid.iter().filter(|v| !**v).count();
                Input {
                    name: format!("traced {scene} {x}×{y}×{z} × 324, {invalid} invalid voxels"),
                    field,
                    valid: Some(valid),
                    seam_sigma: 1.0,
                }
            }
            other => {
                eprintln!("unknown --field {other} (synthetic, cornell or sponza)");
                std::process::exit(2);
            }
        }
    }
}

/// Wall and process CPU seconds of one fit.
#[derive(Debug, Clone, Copy)]
pub struct Cost {
    /// Wall seconds.
    pub wall: f64,
    /// User + system CPU seconds of the whole process (all threads).
    pub cpu: f64,
}

impl Cost {
    /// Runs `fit` and returns its value with what it cost.
    pub fn measure<T>(fit: impl FnOnce() -> T) -> (T, Cost) {
        let watch = Stopwatch::start();
        let value = fit();
        let cost = Cost {
            wall: watch.wall().as_secs_f64(),
            cpu: watch.cpu(),
        };
        (value, cost)
    }
}

/// Whether `methods` (empty: `default`) names `method`, case-insensitively.
pub fn method_enabled(methods: &[String], default: &[&str], method: &str) -> bool {
    if methods.is_empty() {
        default.iter().any(|m| m.eq_ignore_ascii_case(method))
    } else {
        methods
            .iter()
            .any(|m| m.trim().eq_ignore_ascii_case(method))
    }
}

/// The synthetic field of the experiments: `n`³ voxels of 324-D vectors on a curved manifold
/// (seed 1).
pub fn synthetic_field(n: usize) -> GridField {
    prt_mbd::SyntheticField {
        dims: [n; 3],
        dim: 324,
        harmonics: 4,
        seed: 1,
    }
    .build(Aabb::UNIT)
    .expect("synthetic field")
}

/// The built-in Cornell box (`"cornell"`) or Sponza (`"sponza"`) traced at `n` voxels along its
/// longest axis with `prt bake`'s defaults, read from the cache when an earlier run wrote it.
pub fn traced_field(scene_name: &str, n: usize) -> GridField {
    let path = cached_volume_path(scene_name, n);
    if let Some(field) = read_cached(&path) {
        eprintln!("{scene_name} {n}: read {}", path.display());
        return field;
    }
    let scene = crate::load_scene(scene_name).unwrap_or_else(|e| panic!("cannot load {e}"));
    let bounds = scene.bounds().expect("the scene has triangles");
    let size = bounds.size().to_array();
    let longest = size.iter().copied().fold(0.0f32, f32::max);
    let resolution = size.map(|s| ((s / longest * n as f32).round() as usize).clamp(2, n));
    let options = BakeOptions {
        resolution,
        ..BakeOptions::default()
    };
    let (volume, cost) = Cost::measure(|| {
        TransferBaker::new(&scene, options)
            .and_then(|baker| baker.bake(&NoProgress))
            .expect("bake")
    });
    eprintln!(
        "{scene_name} {n}: traced {resolution:?} in {:.2} s (CPU {:.2} s)",
        cost.wall, cost.cpu
    );
    if let Err(e) = write_cached(&path, &volume.field) {
        eprintln!("cannot cache {}: {e}", path.display());
    }
    volume.field
}

/// `b` basis nodes per axis, at least 2 and at most the field's voxels on that axis.
pub fn basis_nodes(field: &GridField, b: usize) -> [usize; 3] {
    let dims = field.dims();
    [0, 1, 2].map(|k| b.min(dims[k].max(2)))
}

/// Path of the cached traced volume of `scene` at `n` voxels along its longest axis (`prt
/// bake`'s defaults: 256 rays, 64 cache rays, seed 0).
pub fn cached_volume_path(scene: &str, n: usize) -> PathBuf {
    crate::cache_dir("mbd_cache").join(format!("{scene}_{n}_r256_c64_s0.f32"))
}

/// Cache layout, little endian: dims (3 × u64), bounds (6 × f32), dim (u64), data (f32).
pub fn write_cached(path: &std::path::Path, field: &GridField) -> std::io::Result<()> {
    std::fs::create_dir_all(path.parent().unwrap_or(std::path::Path::new(".")))?;
    let mut bytes = Vec::with_capacity(64 + 4 * field.data().len());
    for d in field.dims() {
        bytes.extend((d as u64).to_le_bytes());
    }
    let b = field.bounds();
    for v in b.min.to_array().into_iter().chain(b.max.to_array()) {
        bytes.extend(v.to_le_bytes());
    }
    bytes.extend((field.dim() as u64).to_le_bytes());
    for v in field.data().iter() {
        bytes.extend(v.to_le_bytes());
    }
    // Write, then rename: a run stopped midway leaves no truncated cache behind.
    let partial = path.with_extension("partial");
    std::fs::write(&partial, bytes)?;
    std::fs::rename(partial, path)
}

/// The cached field, or `None` when the file is missing or malformed.
pub fn read_cached(path: &std::path::Path) -> Option<GridField> {
    let bytes = std::fs::read(path).ok()?;
    let u64_at = |i: usize| -> Option<usize> {
        Some(u64::from_le_bytes(bytes.get(i..i + 8)?.try_into().ok()?) as usize)
    };
    let f32_at = |i: usize| -> Option<f32> {
        Some(f32::from_le_bytes(bytes.get(i..i + 4)?.try_into().ok()?))
    };
    let dims = [u64_at(0)?, u64_at(8)?, u64_at(16)?];
    let corner = |i: usize| Some(Vec3::new(f32_at(i)?, f32_at(i + 4)?, f32_at(i + 8)?));
    let bounds = Aabb::new(corner(24)?, corner(36)?);
    let dim = u64_at(48)?;
    let count = dims.iter().product::<usize>().checked_mul(dim)?;
    let payload = bytes.get(56..)?;
    if payload.len() != 4 * count {
        return None;
    }
    let data: Vec<f32> = payload
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect();
    let data = ndarray::Array2::from_shape_vec((count / dim.max(1), dim), data).ok()?;
    GridField::from_data(dims, bounds, data).ok()
}
