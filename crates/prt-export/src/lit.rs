//! A bake lit by a sky: incident-radiance SH per voxel.

use glam::Vec3;
use prt_bake::{MbdContainer, TRANSFER_DIM};
use prt_core::{Aabb, GridField, KernelWeights, Progress, SpatialKernels};
use prt_sphere::Sky;
use prt_trace::{incident_radiance, irradiance};
use rayon::prelude::*;

use crate::ExportError;

/// Incident radiance of one voxel: order-3 SH (prt's convention) per colour channel R, G, B.
pub type RadianceSh = [[f32; 9]; 3];

/// A bake lit by a sky: per voxel of a regular grid, the incident radiance as order-3 SH per
/// colour channel, and whether the voxel was valid (outside geometry) in the bake.
///
/// Voxel `(x, y, z)` has flat index `x + nx (y + ny z)` and centre
/// `bounds.min + (x + ½, y + ½, z + ½) · voxel_size`.
#[derive(Debug, Clone, PartialEq)]
pub struct LitVolume {
    /// Voxels along x, y, z.
    pub dims: [usize; 3],
    /// The box the voxels tile (voxel centres sit half a voxel inside it).
    pub bounds: Aabb,
    /// Per voxel: valid in the bake (not inside geometry).
    pub valid: Vec<bool>,
    /// Per voxel: incident-radiance SH.
    pub radiance: Vec<RadianceSh>,
}

impl LitVolume {
    /// Number of voxels.
    pub fn voxels(&self) -> usize {
        self.dims.iter().product()
    }

    /// Edge lengths of one voxel.
    pub fn voxel_size(&self) -> Vec3 {
        self.bounds.size() / Vec3::from_array(self.dims.map(|d| d as f32))
    }

    /// Grid coordinates of flat voxel `v`.
    pub fn coords(&self, v: usize) -> [usize; 3] {
        let [nx, ny, _] = self.dims;
        [v % nx, v / nx % ny, v / (nx * ny)]
    }

    /// World-space centre of flat voxel `v`.
    pub fn voxel_centre(&self, v: usize) -> Vec3 {
        let c = self.coords(v).map(|i| i as f32 + 0.5);
        self.bounds.min + Vec3::from_array(c) * self.voxel_size()
    }

    /// The volume grown by `layers` voxels on every side, each new voxel a copy of the nearest
    /// voxel of `self` (value and validity): an engine that interpolates across the box then
    /// reads, anywhere inside `self.bounds`, exactly what clamping to `self` would give, while
    /// the surfaces on `self.bounds` lie `layers` voxels inside the box it is placed by.
    pub fn padded(&self, layers: usize) -> LitVolume {
        let dims = self.dims.map(|d| d + 2 * layers);
        let grow = layers as f32 * self.voxel_size();
        let n: usize = dims.iter().product();
        let (mut valid, mut radiance) = (Vec::with_capacity(n), Vec::with_capacity(n));
        for z in 0..dims[2] {
            for y in 0..dims[1] {
                for x in 0..dims[0] {
                    let source = [x, y, z]
                        .iter()
                        .zip(self.dims)
                        .map(|(&i, d)| i.saturating_sub(layers).min(d - 1))
                        .collect::<Vec<_>>();
                    let v = source[0] + self.dims[0] * (source[1] + self.dims[1] * source[2]);
                    valid.push(self.valid[v]);
                    radiance.push(self.radiance[v]);
                }
            }
        }
        LitVolume {
            dims,
            bounds: Aabb {
                min: self.bounds.min - grow,
                max: self.bounds.max + grow,
            },
            valid,
            radiance,
        }
    }

    /// The box spanned by the voxel centres.
    pub fn centre_box(&self) -> Aabb {
        let half = 0.5 * self.voxel_size();
        Aabb {
            min: self.bounds.min + half,
            max: self.bounds.max - half,
        }
    }

    /// Irradiance `E(n)` (RGB) at voxel `v` on a surface of unit normal `n`.
    pub fn irradiance(&self, v: usize, n: Vec3) -> Vec3 {
        let l = &self.radiance[v];
        Vec3::new(
            irradiance(&l[0], n),
            irradiance(&l[1], n),
            irradiance(&l[2], n),
        )
    }

    /// Irradiance at the world point `x`: the radiance SH interpolated trilinearly between voxel
    /// centres (constant beyond the outermost centres, as engines clamp), then convolved.
    pub fn irradiance_at(&self, x: Vec3, n: Vec3) -> Vec3 {
        let mut l = [[0.0f32; 9]; 3];
        for (v, w) in self.trilinear(x) {
            for c in 0..3 {
                for j in 0..9 {
                    l[c][j] += w * self.radiance[v][c][j];
                }
            }
        }
        Vec3::new(
            irradiance(&l[0], n),
            irradiance(&l[1], n),
            irradiance(&l[2], n),
        )
    }

    /// The eight voxels and weights of trilinear interpolation between voxel centres at `x`.
    pub fn trilinear(&self, x: Vec3) -> [(usize, f32); 8] {
        let g = (x - self.bounds.min) / self.voxel_size() - Vec3::splat(0.5);
        let mut lo = [0usize; 3];
        let mut t = [0f32; 3];
        for a in 0..3 {
            let top = (self.dims[a] - 1) as f32;
            let p = g[a].clamp(0.0, top);
            let i = (p.floor() as usize).min(self.dims[a].saturating_sub(2));
            lo[a] = i;
            t[a] = p - i as f32;
        }
        let mut out = [(0usize, 0f32); 8];
        for (corner, slot) in out.iter_mut().enumerate() {
            let mut idx = [0usize; 3];
            let mut w = 1.0;
            for a in 0..3 {
                let up = corner >> a & 1 == 1;
                idx[a] = (lo[a] + usize::from(up)).min(self.dims[a] - 1);
                w *= if up { t[a] } else { 1.0 - t[a] };
            }
            *slot = (idx[0] + self.dims[0] * (idx[1] + self.dims[1] * idx[2]), w);
        }
        out
    }

    /// Checks that the arrays match the grid and every value is finite.
    pub(crate) fn check(&self) -> Result<(), ExportError> {
        if self.dims.contains(&0) {
            return Err(ExportError::invalid("lit volume", "a dimension is zero"));
        }
        let n = self.voxels();
        if self.valid.len() != n || self.radiance.len() != n {
            return Err(ExportError::invalid(
                "lit volume",
                format!(
                    "{n} voxels but {} validity flags and {} radiance vectors",
                    self.valid.len(),
                    self.radiance.len()
                ),
            ));
        }
        if let Some(i) = self
            .radiance
            .iter()
            .flat_map(|l| l.as_flattened())
            .position(|v| !v.is_finite())
        {
            return Err(ExportError::invalid(
                "lit volume",
                format!("radiance value {i} (voxel {}) is not finite", i / 27),
            ));
        }
        Ok(())
    }
}

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

/// Lights a full transfer field (324 values per voxel, e.g. the traced volume a bake kept)
/// with `sky`; `valid` is its validity mask. Reports one unit per z slice.
pub fn light_field(
    field: &GridField,
    valid: &[bool],
    sky: &Sky,
    progress: &dyn Progress,
) -> Result<LitVolume, ExportError> {
    if field.dim() != TRANSFER_DIM {
        return Err(ExportError::invalid(
            "transfer field",
            format!("dimension {}, expected {TRANSFER_DIM}", field.dim()),
        ));
    }
    if valid.len() != field.num_voxels() {
        return Err(ExportError::invalid(
            "validity mask",
            format!("{} flags for {} voxels", valid.len(), field.num_voxels()),
        ));
    }
    let dims = field.dims();
    let per_slice = dims[0] * dims[1];
    progress.set_len(dims[2] as u64);
    let slices: Vec<Vec<RadianceSh>> = (0..dims[2])
        .into_par_iter()
        .map(|z| {
            progress.check()?;
            let slice = (z * per_slice..(z + 1) * per_slice)
                .map(|v| incident_radiance(field.voxel(v), sky))
                .collect();
            progress.inc(1);
            Ok(slice)
        })
        .collect::<Result<_, ExportError>>()?;
    let volume = LitVolume {
        dims,
        bounds: field.bounds(),
        valid: valid.to_vec(),
        radiance: slices.into_iter().flatten().collect(),
    };
    volume.check()?;
    Ok(volume)
}
