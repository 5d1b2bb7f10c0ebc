//! Lighting a transfer by a sky: a voxel's incident-radiance SH and its irradiance toward a
//! normal, a constant sky, and the lit volume (incident radiance per voxel) that renders,
//! previews and engine exports sample. Use it to turn a traced or compressed transfer into light.

use glam::Vec3;
use prt_core::{Aabb, FieldModel, GridField, Progress, TrilinearWeights, resample_to_grid};
use prt_sphere::Sky;
use rayon::prelude::*;

use crate::TraceError;
pub use crate::bake::{constant_sky, incident_radiance, irradiance};
use crate::sh::{SH9, TRANSFER_DIM};

/// Incident radiance of one voxel: order-3 SH (prt's convention) per colour channel R, G, B.
pub type RadianceSh = [[f32; SH9]; 3];

/// A transfer volume lit by a sky: per voxel of a regular grid, the incident radiance as order-3
/// SH per colour channel, and whether the voxel was valid (outside geometry) in the bake. Built
/// from a traced volume ([`LitVolume::from_transfer`]) or a model of one
/// ([`LitVolume::from_model`]); prt-bake lights an MBD container or a bake folder's volume
/// (`MbdContainer::light`, `BakeFolder::lit_volume`).
///
/// Two lookups: [`LitVolume::irradiance_at`] interpolates every voxel, as an engine does after
/// invalid voxels were filled; [`LitVolume::incident`] and [`LitVolume::valid_irradiance_at`]
/// interpolate over the **valid** corners only, their weights renormalised to sum to one (an
/// engine does the same with hardware filtering by storing `valid · value` and `valid` and
/// dividing), and have no value where all eight corners are invalid.
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
    /// Lights a 324-D transfer volume (the baker's layout) with `sky`; `valid` is its validity
    /// mask. Reports one unit per z slice.
    ///
    /// Errors: a field that is not 324-D, a mask of the wrong length, a non-finite value,
    /// cancellation.
    pub fn from_transfer(
        transfer: &GridField,
        valid: &[bool],
        sky: &Sky,
        progress: &dyn Progress,
    ) -> Result<Self, TraceError> {
        if transfer.dim() != TRANSFER_DIM {
            return Err(TraceError::InvalidOption {
                what: "transfer volume",
                why: format!("{}-D vectors, not {TRANSFER_DIM}", transfer.dim()),
            });
        }
        if valid.len() != transfer.num_voxels() {
            return Err(TraceError::InvalidOption {
                what: "validity mask",
                why: format!(
                    "{} entries for {} voxels",
                    valid.len(),
                    transfer.num_voxels()
                ),
            });
        }
        let dims = transfer.dims();
        let per_slice = dims[0] * dims[1];
        progress.set_len(dims[2] as u64);
        let slices: Vec<Vec<RadianceSh>> = (0..dims[2])
            .into_par_iter()
            .map(|z| {
                progress.check()?;
                let slice = (z * per_slice..(z + 1) * per_slice)
                    .map(|v| incident_radiance(transfer.voxel(v), sky))
                    .collect();
                progress.inc(1);
                Ok(slice)
            })
            .collect::<Result<_, TraceError>>()?;
        let volume = LitVolume {
            dims,
            bounds: transfer.bounds(),
            valid: valid.to_vec(),
            radiance: slices.into_iter().flatten().collect(),
        };
        volume.check()?;
        Ok(volume)
    }

    /// Lights a model of the transfer (e.g. an MBD container read back) evaluated at the voxel
    /// centres of a `dims` grid over `bounds`: the volume an engine would sample.
    ///
    /// Errors: a model that is not 324-D, a mask of the wrong length, an evaluation error.
    pub fn from_model(
        model: &dyn FieldModel,
        dims: [usize; 3],
        bounds: Aabb,
        valid: &[bool],
        sky: &Sky,
        progress: &dyn Progress,
    ) -> Result<Self, TraceError> {
        if model.dim() != TRANSFER_DIM {
            return Err(TraceError::InvalidOption {
                what: "transfer model",
                why: format!("{}-D vectors, not {TRANSFER_DIM}", model.dim()),
            });
        }
        let transfer = resample_to_grid(model, dims, bounds)?;
        Self::from_transfer(&transfer, valid, sky, progress)
    }

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

    /// Incident-radiance SH per channel at `p`, interpolated trilinearly between voxel centres
    /// over the valid corners only; `None` when all eight are invalid (or `p` is not finite).
    pub fn incident(&self, p: Vec3) -> Option<RadianceSh> {
        let tw = TrilinearWeights::at(self.dims, self.bounds, p).ok()?;
        let mut sum = [[0.0f32; SH9]; 3];
        let mut total = 0.0f32;
        for (&v, &w) in tw.indices.iter().zip(&tw.weights) {
            if w == 0.0 || !self.valid[v] {
                continue;
            }
            total += w;
            for (s, l) in sum.iter_mut().zip(&self.radiance[v]) {
                for (s, &x) in s.iter_mut().zip(l) {
                    *s += w * x;
                }
            }
        }
        if total <= 0.0 {
            return None;
        }
        Some(sum.map(|s| s.map(|x| x / total)))
    }

    /// Diffuse irradiance (RGB) at `p` on a surface of unit normal `n`, from
    /// [`LitVolume::incident`] (valid voxels only); `None` where that has no value.
    pub fn valid_irradiance_at(&self, p: Vec3, n: Vec3) -> Option<Vec3> {
        let l = self.incident(p)?;
        Some(Vec3::from_array(l.map(|l| irradiance(&l, n))))
    }

    /// Checks that the arrays match the grid and every value is finite: what every writer of a
    /// lit volume checks first.
    pub fn check(&self) -> Result<(), TraceError> {
        if self.dims.contains(&0) {
            return Err(invalid("a dimension is zero"));
        }
        let n = self.voxels();
        if self.valid.len() != n || self.radiance.len() != n {
            return Err(invalid(format!(
                "{n} voxels but {} validity flags and {} radiance vectors",
                self.valid.len(),
                self.radiance.len()
            )));
        }
        if let Some(i) = self
            .radiance
            .iter()
            .flat_map(|l| l.as_flattened())
            .position(|v| !v.is_finite())
        {
            return Err(invalid(format!(
                "radiance value {i} (voxel {}) is not finite",
                i / 27
            )));
        }
        Ok(())
    }
}

fn invalid(why: impl Into<String>) -> TraceError {
    TraceError::InvalidOption {
        what: "lit volume",
        why: why.into(),
    }
}
