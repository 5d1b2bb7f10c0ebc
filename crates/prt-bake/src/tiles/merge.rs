//! The merge's side of a tiled bake: the tiles' traces assembled into the global volume, and
//! the seam measures across tile borders.

use std::path::Path;

use ndarray::Array2;
use prt_core::{GridField, resample_to_grid};
use prt_mbd::{LocalBasis, SeamOptions};
use prt_trace::{BakeStats, TransferVolume};

use super::plan::{TileError, TilePlan, TileSpec, flat, voxels};
use super::worker::{TILE_FILE, TRANSFER_FILE, TileStats, VALID_FILE, tile_dir, tile_is_done};
use crate::{BLUR_SIGMA, Bake, BakeError, TRANSFER_DIM};

/// How well two tiles agree on the voxels both traced (a tile's halo lies in its neighbours'
/// cores): independent traces of the same voxels, so their difference is Monte Carlo noise.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HaloAgreement {
    /// Voxels compared (valid in both traces).
    pub voxels: usize,
    /// `sqrt(Σ‖a − b‖² / Σ‖b‖²)`, `a` the halo trace and `b` the owner's.
    pub relative_rms_difference: f64,
}

/// The global volume assembled from the tiles' cores.
#[derive(Debug, Clone)]
pub struct AssembledVolume {
    /// The transfer volume on the plan's lattice; its statistics are the tiles' sums (the
    /// timings are zero: each worker records its own).
    pub volume: TransferVolume,
    /// The tile owning each voxel (x fastest): the labels of the seam measures across tile
    /// borders.
    pub tile_of_voxel: Vec<u32>,
    /// The halo comparison, when the plan has a halo.
    pub halo: Option<HaloAgreement>,
}

/// Seam measures across tile borders, each the existing measure with the tiles as its clusters;
/// about 1 when the borders cannot be told from the inside of the tiles.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TileSeams {
    /// [`prt_mbd::error_seams`] of the traced volume against itself blurred by
    /// [`BLUR_SIGMA`]: a step in the *trace* at tile borders (e.g. from per-tile seeds of the
    /// surface cache) shows here.
    pub trace: f64,
    /// [`prt_mbd::error_seams`] of MBD's reconstruction on the denoised traced volume: a step of
    /// the fitted model at the borders.
    pub mbd: f64,
    /// [`prt_mbd::expert::residual_seam_ratio`] of MBD's moving basis: a jump of the basis.
    pub basis: f64,
}

fn malformed(path: &Path, why: impl Into<String>) -> TileError {
    TileError::Malformed {
        path: path.to_path_buf(),
        why: why.into(),
    }
}

fn read(path: &Path) -> Result<Vec<u8>, TileError> {
    std::fs::read(path).map_err(|source| TileError::Io {
        path: path.to_path_buf(),
        source,
    })
}

/// One finished tile's files, checked against the plan.
pub(crate) struct TileRead {
    /// What the worker recorded.
    pub info: TileStats,
    /// The traced vectors of the tile's voxels (core and halo, x fastest), 324 each.
    pub transfer: Vec<f32>,
    /// Whether each of those voxels is valid.
    pub valid: Vec<bool>,
}

/// Reads tile `tile` of `plan` from `plan_dir`. Errors when it has not finished, or its files do
/// not match the plan (size, seed, scene) or hold a non-finite value (named by voxel).
pub(crate) fn read_tile(
    plan: &TilePlan,
    plan_dir: &Path,
    tile: &TileSpec,
) -> Result<TileRead, TileError> {
    if !tile_is_done(plan_dir, tile.index) {
        return Err(TileError::NotDone(tile.index));
    }
    let dir = tile_dir(plan_dir, tile.index);
    let info_path = dir.join(TILE_FILE);
    let info: TileStats = serde_json::from_slice(&read(&info_path)?)
        .map_err(|e| malformed(&info_path, e.to_string()))?;
    let tdims = tile.traced.dims();
    if info.dims != tdims || info.seed != tile.seed || info.scene_hash != plan.scene.hash {
        return Err(malformed(
            &info_path,
            format!("tile {} was traced for another plan", tile.index),
        ));
    }
    let n = tile.traced.len();
    let transfer_path = dir.join(TRANSFER_FILE);
    let bytes = read(&transfer_path)?;
    if bytes.len() != n * TRANSFER_DIM * 4 {
        return Err(malformed(
            &transfer_path,
            format!(
                "{} bytes, the tile's {n} voxels need {}",
                bytes.len(),
                n * TRANSFER_DIM * 4
            ),
        ));
    }
    let valid_path = dir.join(VALID_FILE);
    let tile_valid = read(&valid_path)?;
    if tile_valid.len() != n || tile_valid.iter().any(|&b| b > 1) {
        return Err(malformed(&valid_path, format!("not {n} bytes of 0 or 1")));
    }
    let transfer: Vec<f32> = bytes
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect();
    if let Some(i) = transfer.iter().position(|x| !x.is_finite()) {
        let v = voxels(&tile.traced)
            .nth(i / TRANSFER_DIM)
            .unwrap_or_default();
        return Err(malformed(
            &transfer_path,
            format!("non-finite value at voxel {v:?} of the lattice"),
        ));
    }
    Ok(TileRead {
        info,
        transfer,
        valid: tile_valid.iter().map(|&b| b == 1).collect(),
    })
}

/// Reads every finished tile of `plan` from `plan_dir` and assembles the cores into the volume
/// on the plan's lattice. Errors when a tile has not finished, or a tile's files do not match
/// the plan (size, seed, scene) or hold a non-finite value (named by tile and voxel).
pub fn assemble(plan: &TilePlan, plan_dir: &Path) -> Result<AssembledVolume, TileError> {
    let dims = plan.lattice_dims;
    let total: usize = dims.iter().product();
    let mut data = vec![0.0f32; total * TRANSFER_DIM];
    let mut valid = vec![false; total];
    let mut tile_of_voxel = vec![0u32; total];
    let mut stats = BakeStats::default();
    // (global voxel, the halo trace's vector): compared once every core is in place.
    let mut halo: Vec<(usize, Vec<f32>)> = Vec::new();
    for tile in &plan.tiles {
        let TileRead {
            info,
            transfer,
            valid: tile_valid,
        } = read_tile(plan, plan_dir, tile)?;
        for (local, v) in voxels(&tile.traced).enumerate() {
            let vector = &transfer[local * TRANSFER_DIM..(local + 1) * TRANSFER_DIM];
            let g = flat(dims, v);
            if tile.core.contains(v) {
                data[g * TRANSFER_DIM..(g + 1) * TRANSFER_DIM].copy_from_slice(vector);
                valid[g] = tile_valid[local];
                tile_of_voxel[g] = tile.index as u32;
            } else if tile_valid[local] {
                halo.push((g, vector.to_vec()));
            }
        }
        stats.voxels += tile.core.len();
        stats.invalid_voxels += info.invalid_voxels;
        stats.skipped_voxels += info.skipped_voxels;
        stats.voxel_rays += info.rays;
        stats.rays_per_voxel = plan.config.rays_per_voxel.div_ceil(12) * 12;
    }
    // The tiles counted their halos too; recount over the assembled cores.
    stats.invalid_voxels = valid.iter().filter(|&&v| !v).count();
    stats.skipped_voxels = 0;
    let halo = (!halo.is_empty()).then(|| {
        let (mut diff, mut norm, mut count) = (0.0f64, 0.0f64, 0usize);
        for (g, a) in &halo {
            if !valid[*g] {
                continue;
            }
            let b = &data[g * TRANSFER_DIM..(g + 1) * TRANSFER_DIM];
            for (&x, &y) in a.iter().zip(b) {
                diff += (f64::from(x) - f64::from(y)).powi(2);
                norm += f64::from(y).powi(2);
            }
            count += 1;
        }
        HaloAgreement {
            voxels: count,
            relative_rms_difference: if norm > 0.0 {
                (diff / norm).sqrt()
            } else {
                0.0
            },
        }
    });
    let data = Array2::from_shape_vec((total, TRANSFER_DIM), data)
        .map_err(|e| malformed(plan_dir, e.to_string()))?;
    let field = GridField::from_data(dims, plan.lattice_bounds(), data)
        .map_err(|e| malformed(plan_dir, e.to_string()))?;
    Ok(AssembledVolume {
        volume: TransferVolume {
            field,
            valid,
            stats,
        },
        tile_of_voxel,
        halo,
    })
}

/// The [`TileSeams`] of a bake of an assembled volume, with its
/// [`AssembledVolume::tile_of_voxel`] as `labels` (the volume itself moved into the bake).
pub fn tile_seams(labels: &[u32], bake: &Bake) -> Result<TileSeams, TileError> {
    let field = &bake.volume.field;
    let valid = &bake.volume.valid;
    let score = |source| {
        TileError::Bake(BakeError::Score {
            method: "tile seams".into(),
            source,
        })
    };
    let options = SeamOptions {
        denoise_sigma: BLUR_SIGMA,
        valid: Some(valid),
    };
    let trace = prt_mbd::error_seams(field, field, labels, &options).map_err(score)?;
    let reconstruction = resample_to_grid(&bake.mbd.model, field.dims(), field.bounds())
        .map_err(|e| score(e.into()))?;
    let mbd = prt_mbd::error_seams(field, &reconstruction, labels, &options).map_err(score)?;
    let smoothed = prt_mbd::expert::blur_valid(field, valid, BLUR_SIGMA).map_err(score)?;
    let basis = LocalBasis::Moving {
        kernels: bake.mbd.model.basis_kernels(),
        basis: bake.mbd.model.basis(),
    };
    let residuals =
        prt_mbd::expert::projection_residuals(&smoothed, valid, &basis).map_err(score)?;
    let basis = prt_mbd::expert::residual_seam_ratio(&smoothed, valid, labels, &residuals)
        .map_err(score)?;
    Ok(TileSeams {
        trace: trace.ratio(),
        mbd: mbd.ratio(),
        basis,
    })
}
