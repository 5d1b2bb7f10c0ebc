//! A transfer volume lit by a sky: incident-radiance SH9 RGB per voxel, sampled trilinearly over
//! the valid voxels.

use glam::Vec3;
use prt_core::{Aabb, FieldModel, GridField, resample_to_grid};
use prt_sphere::Sky;
use prt_trace::{SH9, TRANSFER_DIM, incident_radiance, irradiance};
use rayon::prelude::*;

use crate::RenderError;

/// Values per voxel of a [`RelitVolume`]: SH9 of incident radiance for R, G and B.
pub const RELIT_DIM: usize = 3 * SH9;

/// Incident radiance per voxel (order-3 SH per colour channel, `[R 9 | G 9 | B 9]`) of a
/// 324-D transfer volume lit by one sky, with the validity mask of the bake.
///
/// Sampling ([`RelitVolume::incident`]) is trilinear between voxel centres (a voxel's value sits
/// at the centre of its cell of the grid's box, as in [`GridField`]; clamped to the box of
/// centres outside it) over the **valid** corners only, their weights renormalised to sum to
/// one; a point whose eight corners are all invalid has no value. An engine does the same with
/// hardware filtering by storing `valid · value` and `valid` and dividing.
#[derive(Debug, Clone, PartialEq)]
pub struct RelitVolume {
    field: GridField,
    valid: Vec<bool>,
}

impl RelitVolume {
    /// Relights a 324-D transfer volume (the baker's layout) with `sky`.
    ///
    /// Errors: [`RenderError::InvalidOption`] when the field is not 324-D or `valid` does not
    /// have one entry per voxel.
    pub fn from_transfer(
        transfer: &GridField,
        valid: &[bool],
        sky: &Sky,
    ) -> Result<Self, RenderError> {
        if transfer.dim() != TRANSFER_DIM {
            return Err(RenderError::InvalidOption {
                what: "transfer volume",
                why: format!("{}-D vectors, not {TRANSFER_DIM}", transfer.dim()),
            });
        }
        check_mask(transfer.num_voxels(), valid)?;
        let mut field = GridField::new(transfer.dims(), transfer.bounds(), RELIT_DIM)?;
        let out = field
            .data_mut()
            .into_slice()
            .ok_or_else(|| RenderError::InvalidOption {
                what: "relit volume",
                why: "not contiguous".into(),
            })?;
        out.par_chunks_mut(RELIT_DIM)
            .enumerate()
            .for_each(|(v, out)| {
                let l = incident_radiance(transfer.voxel(v), sky);
                for (c, l) in l.iter().enumerate() {
                    out[c * SH9..(c + 1) * SH9].copy_from_slice(l);
                }
            });
        field.check_finite()?;
        Ok(Self {
            field,
            valid: valid.to_vec(),
        })
    }

    /// Relights a model of the transfer (e.g. an MBD container read back) evaluated at the
    /// voxel centres of a `dims` grid over `bounds`: the volume an engine would sample.
    ///
    /// Errors: a model that is not 324-D, a mask of the wrong length, an evaluation error.
    pub fn from_model(
        model: &dyn FieldModel,
        dims: [usize; 3],
        bounds: Aabb,
        valid: &[bool],
        sky: &Sky,
    ) -> Result<Self, RenderError> {
        if model.dim() != TRANSFER_DIM {
            return Err(RenderError::InvalidOption {
                what: "transfer model",
                why: format!("{}-D vectors, not {TRANSFER_DIM}", model.dim()),
            });
        }
        let transfer = resample_to_grid(model, dims, bounds)?;
        Self::from_transfer(&transfer, valid, sky)
    }

    /// The relit grid (`[R 9 | G 9 | B 9]` per voxel).
    pub fn field(&self) -> &GridField {
        &self.field
    }

    /// The validity mask (one entry per voxel, x fastest).
    pub fn valid(&self) -> &[bool] {
        &self.valid
    }

    /// Incident-radiance SH per channel at `p`, interpolated over the valid voxels; `None` when
    /// all eight surrounding voxel centres are invalid (or `p` is not finite).
    pub fn incident(&self, p: Vec3) -> Option<[[f32; SH9]; 3]> {
        let tw = self.field.trilinear_weights(p).ok()?;
        let mut sum = [[0.0f32; SH9]; 3];
        let mut total = 0.0f32;
        for (&v, &w) in tw.indices.iter().zip(&tw.weights) {
            if w == 0.0 || !self.valid[v] {
                continue;
            }
            total += w;
            let value = self.field.voxel(v);
            for (c, s) in sum.iter_mut().enumerate() {
                for (s, &x) in s.iter_mut().zip(&value[c * SH9..(c + 1) * SH9]) {
                    *s += w * x;
                }
            }
        }
        if total <= 0.0 {
            return None;
        }
        Some(sum.map(|s| s.map(|x| x / total)))
    }

    /// Diffuse irradiance (RGB) at `p` on a surface of unit normal `n`:
    /// [`prt_trace::irradiance`] of [`RelitVolume::incident`] per channel.
    pub fn irradiance(&self, p: Vec3, n: Vec3) -> Option<Vec3> {
        let l = self.incident(p)?;
        Some(Vec3::from_array(l.map(|l| irradiance(&l, n))))
    }
}

fn check_mask(voxels: usize, valid: &[bool]) -> Result<(), RenderError> {
    if valid.len() != voxels {
        return Err(RenderError::InvalidOption {
            what: "validity mask",
            why: format!("{} entries for {voxels} voxels", valid.len()),
        });
    }
    Ok(())
}

/// The box of a `dims` voxel grid whose voxel centres span `centres` (where a hat grid with one
/// node per voxel puts its nodes, e.g. an MBD container's coefficient kernels): `centres`
/// widened by half a voxel on each side. An axis of one voxel gets the edge length of the
/// largest other voxel edge (or 1 when every axis has one voxel).
pub fn grid_bounds(centres: Aabb, dims: [usize; 3]) -> Aabb {
    let size = centres.size();
    let edge: [Option<f32>; 3] =
        std::array::from_fn(|k| (dims[k] >= 2).then(|| size[k] / (dims[k] - 1) as f32));
    let fallback = edge.iter().flatten().copied().fold(0.0f32, f32::max);
    let fallback = if fallback > 0.0 { fallback } else { 1.0 };
    let half = Vec3::from_array(edge.map(|e| 0.5 * e.unwrap_or(fallback)));
    Aabb {
        min: centres.min - half,
        max: centres.max + half,
    }
}
