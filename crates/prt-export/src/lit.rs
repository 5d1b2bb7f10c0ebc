//! An MBD container lit by a sky, each basis vector relit once.

use glam::Vec3;
use prt_bake::container::MbdContainer;
use prt_core::{Aabb, KernelWeights, Progress, SpatialKernels};
use prt_sphere::Sky;
use prt_trace::LitVolume;
use prt_trace::TRANSFER_DIM;
use prt_trace::lit::{RadianceSh, incident_radiance};
use rayon::prelude::*;

use crate::ExportError;

/// Lights an MBD container with `sky`: each basis vector is relit once (the transfer is linear
/// in the sky), then every voxel centre of the baked grid combines the relit vectors with the
/// model's coefficient and basis weights. Reports one unit per z slice.
pub fn light_container(
    container: &MbdContainer,
    sky: &Sky,
    progress: &dyn Progress,
) -> Result<LitVolume, ExportError> {
    let model = &container.model;
    let coefficient_kernels = model.coefficient_kernels();
    let basis_kernels = model.basis_kernels();
    let (_, rank, dim) = model.basis().dim();
    if dim != TRANSFER_DIM {
        return Err(ExportError::invalid(
            "MBD model",
            format!("dimension {dim}, a transfer volume has {TRANSFER_DIM}"),
        ));
    }
    let grid = container.grid;
    if coefficient_kernels.nodes() != grid || grid.iter().any(|&n| n < 2) {
        return Err(ExportError::invalid(
            "MBD container",
            format!(
                "coefficient nodes {:?} are not one per voxel of the baked grid {grid:?} with at least 2 per axis",
                coefficient_kernels.nodes()
            ),
        ));
    }
    // The coefficient hats sit on the voxel centres: the baked box is half a voxel wider.
    let centres = coefficient_kernels.domain();
    let voxel = (centres.max - centres.min) / Vec3::from_array(grid.map(|n| (n - 1) as f32));
    let bounds = Aabb {
        min: centres.min - 0.5 * voxel,
        max: centres.max + 0.5 * voxel,
    };
    let basis = model.basis().as_standard_layout();
    let basis = basis
        .as_slice()
        .expect("a standard-layout array is contiguous");
    let relit: Vec<RadianceSh> = basis
        .chunks_exact(dim)
        .map(|b| incident_radiance(b, sky))
        .collect();
    let coefficients = model.coefficients();
    let mut volume = LitVolume {
        dims: grid,
        bounds,
        valid: container.valid.clone(),
        radiance: Vec::new(),
    };
    if volume.valid.len() != volume.voxels() {
        return Err(ExportError::invalid(
            "MBD container",
            format!(
                "{} validity flags for {} voxels",
                volume.valid.len(),
                volume.voxels()
            ),
        ));
    }
    progress.set_len(grid[2] as u64);
    let slices: Vec<Vec<RadianceSh>> = (0..grid[2])
        .into_par_iter()
        .map(|z| {
            progress.check()?;
            let mut wc = KernelWeights::with_capacity(coefficient_kernels.max_support());
            let mut wb = KernelWeights::with_capacity(basis_kernels.max_support());
            let slice = (0..grid[0] * grid[1])
                .map(|i| {
                    let x = volume.voxel_centre(i + z * grid[0] * grid[1]);
                    coefficient_kernels.eval(x, &mut wc)?;
                    basis_kernels.eval(x, &mut wb)?;
                    let mut acc = [[0.0f64; 9]; 3];
                    for (&ci, &cw) in wc.indices.iter().zip(&wc.weights) {
                        for l in 0..rank {
                            let c = f64::from(coefficients[[ci as usize, l]]) * f64::from(cw);
                            for (&bi, &bw) in wb.indices.iter().zip(&wb.weights) {
                                let r = &relit[bi as usize * rank + l];
                                let s = c * f64::from(bw);
                                for ch in 0..3 {
                                    for j in 0..9 {
                                        acc[ch][j] += s * f64::from(r[ch][j]);
                                    }
                                }
                            }
                        }
                    }
                    Ok(acc.map(|ch| ch.map(|v| v as f32)))
                })
                .collect::<Result<Vec<_>, ExportError>>()?;
            progress.inc(1);
            Ok(slice)
        })
        .collect::<Result<_, ExportError>>()?;
    volume.radiance = slices.into_iter().flatten().collect();
    volume.check()?;
    Ok(volume)
}
