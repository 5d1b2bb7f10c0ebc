//! A bake lit by a sky: the one way `prt render`, `prt export` and the bake's report turn a
//! stored transfer into a [`LitVolume`].

use glam::Vec3;
use prt_core::{Aabb, KernelWeights, Progress, SpatialKernels};
use prt_sphere::Sky;
use prt_trace::lit::{RadianceSh, incident_radiance};
use prt_trace::{LitVolume, TRANSFER_DIM, TraceError};
use rayon::prelude::*;

use crate::container::MbdContainer;
use crate::folder::FolderVolume;

impl MbdContainer {
    /// The container lit by `sky` at the voxel centres of its baked grid: each basis vector is
    /// lit once (the transfer is linear in the sky), then every voxel sums the lit vectors with
    /// the model's coefficient and basis weights in f64. Equal to lighting the model's value at
    /// each voxel centre, at a fraction of the cost. Reports one unit per z slice.
    ///
    /// Errors: a model that is not 324-D, coefficient nodes that are not one per voxel (at
    /// least 2 per axis), a mask of the wrong length, cancellation.
    pub fn light(&self, sky: &Sky, progress: &dyn Progress) -> Result<LitVolume, TraceError> {
        let model = &self.model;
        let coefficient_kernels = model.coefficient_kernels();
        let basis_kernels = model.basis_kernels();
        let (_, rank, dim) = model.basis().dim();
        if dim != TRANSFER_DIM {
            return Err(invalid(
                "MBD model",
                format!("dimension {dim}, a transfer volume has {TRANSFER_DIM}"),
            ));
        }
        let grid = self.grid;
        if coefficient_kernels.nodes() != grid || grid.iter().any(|&n| n < 2) {
            return Err(invalid(
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
        let lit_basis: Vec<RadianceSh> = basis
            .chunks_exact(dim)
            .map(|b| incident_radiance(b, sky))
            .collect();
        let coefficients = model.coefficients();
        let mut volume = LitVolume {
            dims: grid,
            bounds,
            valid: self.valid.clone(),
            radiance: Vec::new(),
        };
        if volume.valid.len() != volume.voxels() {
            return Err(invalid(
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
                                    let r = &lit_basis[bi as usize * rank + l];
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
                    .collect::<Result<Vec<_>, TraceError>>()?;
                progress.inc(1);
                Ok(slice)
            })
            .collect::<Result<_, TraceError>>()?;
        volume.radiance = slices.into_iter().flatten().collect();
        volume.check()?;
        Ok(volume)
    }
}

impl FolderVolume {
    /// This volume lit by `sky`: the container by [`MbdContainer::light`], a kept volume voxel
    /// by voxel ([`LitVolume::from_transfer`]). Reports one unit per z slice.
    pub fn light(&self, sky: &Sky, progress: &dyn Progress) -> Result<LitVolume, TraceError> {
        match self {
            FolderVolume::Mbd(container) => container.light(sky, progress),
            FolderVolume::Kept { field, valid, .. } => {
                LitVolume::from_transfer(field, valid, sky, progress)
            }
        }
    }
}

fn invalid(what: &'static str, why: String) -> TraceError {
    TraceError::InvalidOption { what, why }
}
