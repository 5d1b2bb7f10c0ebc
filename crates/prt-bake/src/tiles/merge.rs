//! The merge's side of a tiled bake: the tiles' traces assembled into the global volume, and
//! the seam measures across tile borders.

use std::path::Path;

use ndarray::Array2;
use prt_core::{GridField, resample_to_grid};
use prt_mbd::{LocalBasis, SeamOptions};
use prt_trace::{BakeStats, TRANSFER_DIM, TransferVolume};

use prt_texture::Limits;

use super::cache::read_surface_cache_header;
use super::file::{TileData, read_tile, read_timing};
use super::plan::{TileError, TilePlan, flat, voxels};
use crate::seams::BLUR_SIGMA;
use crate::{Bake, BakeError};

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
    /// The transfer volume on the plan's lattice; its statistics are the tiles' sums (rays and
    /// the workers' times from their `timing.json`, so its rays per second are a worker's) plus
    /// the shared surface cache's points, rays and time, but the invalid voxels, counted over
    /// the assembled cores.
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

/// Reads every finished tile of `plan` from `plan_dir` and assembles the cores into the volume
/// on the plan's lattice. Errors, naming the tile, when a tile has not finished
/// ([`TileError::NotDone`]), was traced for another plan ([`TileError::StaleTile`]), has a file
/// whose checksum is not the recorded one ([`TileError::Damaged`]), is over `limits`
/// ([`TileError::TooLarge`]), or has a file of the wrong size or a non-finite value (named by
/// voxel; [`TileError::Malformed`]); and when the plan's shared surface cache, whose counts the
/// statistics take, is missing, stale or damaged.
pub fn assemble(
    plan: &TilePlan,
    plan_dir: &Path,
    limits: &Limits,
) -> Result<AssembledVolume, TileError> {
    let dims = plan.lattice_dims;
    let total: usize = dims.iter().product();
    let mut data = vec![0.0f32; total * TRANSFER_DIM];
    let mut valid = vec![false; total];
    let mut tile_of_voxel = vec![0u32; total];
    let mut stats = BakeStats::default();
    // (global voxel, the halo trace's vector): compared once every core is in place.
    let mut halo: Vec<(usize, Vec<f32>)> = Vec::new();
    for tile in &plan.tiles {
        let TileData {
            stats: info,
            transfer,
            valid: tile_valid,
        } = read_tile(plan, plan_dir, tile, limits)?;
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
        stats.voxel_rays += info.voxel_rays;
        stats.cache_rays += info.cache_rays;
        stats.cache_evaluated += info.cache_evaluated;
        stats.rays_per_voxel = info.rays_per_voxel;
        let [bvh, cache, voxel] = read_timing(plan_dir, tile.index);
        stats.bvh_time += bvh;
        stats.cache_time += cache;
        stats.voxel_time += voxel;
    }
    // The tiles share the plan's surface cache: its points, entries and rays once, its time as a
    // stage; the entries a tile evaluated itself (those the shared cache lacks) add up above.
    let (cache, cache_time) = read_surface_cache_header(plan, plan_dir, limits)?;
    stats.cache_points = cache.points;
    stats.cache_evaluated += cache.evaluated;
    stats.cache_rays += cache.rays;
    stats.cache_time += cache_time;
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
