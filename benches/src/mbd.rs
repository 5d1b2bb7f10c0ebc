//! Helpers shared by the MBD sweeps (`mbd_sweep`, `mbd_walls`, `mbd_clustered`): the
//! traced-volume cache, environment knobs, the load average and the error by distance to the
//! nearest wall.

use std::path::PathBuf;

use glam::Vec3;
use prt_core::{Aabb, FieldModel, GridField, resample_to_grid};

/// Whether the comma-separated `MBD_METHODS` list (case-insensitive; `default` when unset)
/// names `method`.
pub fn method_enabled(method: &str, default: &str) -> bool {
    let list = std::env::var("MBD_METHODS").unwrap_or_else(|_| default.into());
    list.split(',')
        .any(|m| m.trim().eq_ignore_ascii_case(method))
}

/// Runs `fit`; returns its value with the wall and the process CPU seconds it took.
pub fn measure<T>(fit: impl FnOnce() -> T) -> (T, f64, f64) {
    let (start, cpu) = (std::time::Instant::now(), crate::cpu_seconds());
    let value = fit();
    (
        value,
        start.elapsed().as_secs_f64(),
        crate::cpu_seconds() - cpu,
    )
}

/// The sweeps' synthetic field: `n`³ voxels of 324-D vectors on a curved manifold (seed 1).
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

/// The traced `scene` volume at resolution `n` from the cache; without it, `bin` says how to
/// trace it and the process exits.
pub fn cached_volume_or_exit(bin: &str, scene: &str, n: usize) -> GridField {
    let path = cached_volume_path(scene, n);
    read_cached(&path).unwrap_or_else(|| {
        eprintln!(
            "{bin}: no cached volume at {} (run `MBD_FIELD={scene} MBD_N={n} mbd_sweep walls` once to trace it)",
            path.display()
        );
        std::process::exit(1);
    })
}

/// `b` basis nodes per axis, at least 2 and at most the field's voxels on that axis.
pub fn basis_nodes(field: &GridField, b: usize) -> [usize; 3] {
    let dims = field.dims();
    [0, 1, 2].map(|k| b.min(dims[k].max(2)))
}

/// The 1, 5 and 15 minute load averages.
pub fn load_average() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .map(|s| s.split_whitespace().take(3).collect::<Vec<_>>().join(" "))
        .unwrap_or_else(|_| "unknown".into())
}

/// The environment variable `name` parsed, or `default` when it is unset or does not parse.
pub fn env_or<T: std::str::FromStr>(name: &str, default: T) -> T {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

/// The polish's acceleration from `MBD_ACCEL`: `none`, `extrapolation` or `cg` (default:
/// `PolishOptions`' own, `cg` since MBD session 11). Earlier sessions' switch `MBD_EXTRAP`
/// (before session 11 the extrapolation was the default): 0 means `none`, 1 `extrapolation`.
pub fn polish_acceleration() -> prt_mbd::PolishAcceleration {
    use prt_mbd::PolishAcceleration as A;
    match (
        std::env::var("MBD_ACCEL").as_deref(),
        std::env::var("MBD_EXTRAP").as_deref(),
    ) {
        (Ok("none"), _) | (Err(_), Ok("0")) => A::None,
        (Ok("extrapolation"), _) | (Err(_), Ok("1")) => A::Extrapolation,
        (Ok("cg"), _) => A::ConjugateGradients,
        _ => prt_mbd::PolishOptions::default().acceleration,
    }
}

/// [`env_or`] for counts and switches.
pub fn env_usize(name: &str, default: usize) -> usize {
    env_or(name, default)
}

/// Folder for cached traced volumes: `$CARGO_TARGET_DIR` or the workspace's `target/`.
pub fn cache_dir() -> PathBuf {
    std::env::var_os("CARGO_TARGET_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../target")))
        .join("mbd_cache")
}

/// Path of the cached traced volume of `scene` at `n` voxels along its longest axis (`prt
/// bake`'s defaults: 256 rays, 64 cache rays, seed 0).
pub fn cached_volume_path(scene: &str, n: usize) -> PathBuf {
    cache_dir().join(format!("{scene}_{n}_r256_c64_s0.f32"))
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
    std::fs::write(path, bytes)
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

/// Cap of [`wall_distance`].
pub const CAP: usize = 4;

/// Chebyshev distance (in voxels) of every voxel to the nearest invalid voxel: 0 = invalid,
/// 1 = touching an invalid voxel, ..., capped at [`CAP`].
pub fn wall_distance(f: &GridField, valid: &[bool]) -> Vec<usize> {
    let dims = f.dims();
    (0..f.num_voxels())
        .map(|v| {
            if !valid[v] {
                return 0;
            }
            let (x, y, z) = (
                v % dims[0],
                (v / dims[0]) % dims[1],
                v / (dims[0] * dims[1]),
            );
            (1..CAP)
                .find(|&r| {
                    let lo = |c: usize| c.saturating_sub(r);
                    let hi = |c: usize, n: usize| (c + r).min(n - 1);
                    (lo(z)..=hi(z, dims[2])).any(|k| {
                        (lo(y)..=hi(y, dims[1])).any(|j| {
                            (lo(x)..=hi(x, dims[0]))
                                .any(|i| !valid[i + dims[0] * (j + dims[1] * k)])
                        })
                    })
                })
                .unwrap_or(CAP)
        })
        .collect()
}

/// Squared error of `model` at the voxel centres, summed per [`wall_distance`] bin.
pub fn wall_bins(f: &GridField, model: &dyn FieldModel, distance: &[usize]) -> [f64; CAP + 1] {
    let recon = resample_to_grid(model, f.dims(), f.bounds()).expect("resample");
    wall_bins_of_grid(f, &recon, distance)
}

/// [`wall_bins`] of a reconstruction already resampled to `f`'s voxel centres.
pub fn wall_bins_of_grid(f: &GridField, recon: &GridField, distance: &[usize]) -> [f64; CAP + 1] {
    let mut bins = [0.0f64; CAP + 1];
    for v in 0..f.num_voxels() {
        let err: f64 = f
            .voxel(v)
            .iter()
            .zip(recon.voxel(v))
            .map(|(&a, &b)| (f64::from(a) - f64::from(b)).powi(2))
            .sum();
        bins[distance[v]] += err;
    }
    bins
}

/// `Σ ‖f(v)‖²` over the voxels `keep` accepts.
pub fn voxel_energy(f: &GridField, keep: &dyn Fn(usize) -> bool) -> f64 {
    (0..f.num_voxels())
        .filter(|&v| keep(v))
        .map(|v| {
            f.voxel(v)
                .iter()
                .map(|&x| f64::from(x).powi(2))
                .sum::<f64>()
        })
        .sum()
}

/// A [`wall_distance`] bin's name in table headers: `3`, or `≥ 4` for the last.
pub fn distance_name(d: usize) -> String {
    if d == CAP {
        format!("≥ {CAP}")
    } else {
        d.to_string()
    }
}
