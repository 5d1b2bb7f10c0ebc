//! Primary rays through a pinhole, shaded with the diffuse irradiance of a lit volume.

use std::f32::consts::PI;

use glam::Vec3;
use prt_core::{GridField, Progress};
use prt_sphere::Sky;
use prt_trace::camera::{GBuffer, PinholeView};
use prt_trace::{LitVolume, RayTracer, Scene};
use rayon::prelude::*;

use crate::RenderError;

/// Options of [`render`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RenderConfig {
    /// Image width in pixels.
    pub width: usize,
    /// Image height in pixels.
    pub height: usize,
}

impl Default for RenderConfig {
    /// 512 × 512 pixels.
    fn default() -> Self {
        Self {
            width: 512,
            height: 512,
        }
    }
}

/// What lights the surfaces [`render`] shades: diffuse irradiance at a surface point.
pub trait SurfaceLight: Sync {
    /// Irradiance (RGB) at the surface point `position` of unit normal `normal` (facing the
    /// viewer); `None` where nothing lights it.
    fn surface_irradiance(&self, position: Vec3, normal: Vec3) -> Option<Vec3>;
}

/// prt's own lookup: [`LitVolume::valid_irradiance_at`] half a voxel off the surface along its normal
/// (per axis: `½ n ⊙ voxel size`), which keeps a wall's lookup from leaning on the voxels
/// behind it, over the valid voxels only.
impl SurfaceLight for LitVolume {
    fn surface_irradiance(&self, position: Vec3, normal: Vec3) -> Option<Vec3> {
        let offset = NORMAL_OFFSET * self.voxel_size();
        self.valid_irradiance_at(position + normal * offset, normal)
    }
}

/// How far prt's lookup moves off the surface, in voxel edges.
const NORMAL_OFFSET: f32 = 0.5;

/// A rendered image: linear RGB radiance per pixel, row-major from the top-left.
#[derive(Debug, Clone, PartialEq)]
pub struct Rendered {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// Radiance per pixel (linear RGB).
    pub pixels: Vec<[f32; 3]>,
    /// Whether each pixel's primary ray hit the scene (else it shows the sky).
    pub hit: Vec<bool>,
    /// Pixels whose surface point had no valid voxel around it: they show only emission.
    pub unlit: usize,
}

impl Rendered {
    /// Root-mean-square difference of the radiance over every channel of every pixel, against
    /// an image of the same size (`None` if the sizes differ).
    pub fn rmse(&self, other: &Rendered) -> Option<f64> {
        if (self.width, self.height) != (other.width, other.height) {
            return None;
        }
        let sum: f64 = self
            .pixels
            .iter()
            .zip(&other.pixels)
            .flat_map(|(a, b)| (0..3).map(move |c| (f64::from(a[c]) - f64::from(b[c])).powi(2)))
            .sum();
        Some((sum / (3 * self.pixels.len().max(1)) as f64).sqrt())
    }

    /// The pixels as one interleaved RGB slice (for EXR).
    pub fn interleaved(&self) -> Vec<f32> {
        self.pixels.iter().flatten().copied().collect()
    }
}

/// Renders `scene` from `view`: one primary ray per pixel centre (prt-trace's [`GBuffer`]);
/// a hit shows `emission + albedo/π · E`, with `E` the irradiance `light` gives the hit point
/// and its normal facing the viewer ([`SurfaceLight`]; for a [`LitVolume`], prt's lookup);
/// a miss shows the sky's radiance along the ray. The back
/// of a single-sided surface is black. Shading runs in parallel over rows, reporting one unit
/// per row to `progress` and stopping when it is cancelled; the image is the same on any
/// thread count. `tracer` must have been built over `scene.triangles()`.
///
/// Errors: [`RenderError::Trace`] for a view that is not finite, [`RenderError::Core`] when
/// cancelled.
pub fn render(
    scene: &Scene,
    tracer: &RayTracer,
    view: &PinholeView,
    light: &dyn SurfaceLight,
    sky: &Sky,
    config: &RenderConfig,
    progress: &dyn Progress,
) -> Result<Rendered, RenderError> {
    let (width, height) = (config.width, config.height);
    let gbuffer = GBuffer::render(scene, tracer, view, width, height)?;
    progress.set_len(height as u64);
    let rows: Vec<Vec<([f32; 3], bool, bool)>> = (0..height)
        .into_par_iter()
        .map(|y| {
            progress.check()?;
            let row = (0..width)
                .map(|x| match &gbuffer.points[y * width + x] {
                    None => (
                        sky.radiance(view.ray(x, y, width, height)).to_array(),
                        false,
                        false,
                    ),
                    Some(point) => {
                        let e = light.surface_irradiance(point.position, point.normal);
                        let radiance = point.emission + point.albedo / PI * e.unwrap_or(Vec3::ZERO);
                        (radiance.to_array(), true, e.is_none())
                    }
                })
                .collect();
            progress.inc(1);
            Ok(row)
        })
        .collect::<Result<_, RenderError>>()?;
    let mut out = Rendered {
        width,
        height,
        pixels: Vec::with_capacity(width * height),
        hit: Vec::with_capacity(width * height),
        unlit: 0,
    };
    for (radiance, hit, unlit) in rows.into_iter().flatten() {
        out.pixels.push(radiance);
        out.hit.push(hit);
        out.unlit += usize::from(unlit);
    }
    Ok(out)
}

/// The voxels of a grid with `grid`'s dimensions and box that [`render`] reads for this view
/// and configuration with prt's lookup (every voxel with a non-zero interpolation weight at some pixel's lookup
/// point), so that work per voxel can be limited to them (x fastest, one flag per voxel).
///
/// Errors: as [`render`].
pub fn voxels_read(
    scene: &Scene,
    tracer: &RayTracer,
    view: &PinholeView,
    grid: &GridField,
    config: &RenderConfig,
) -> Result<Vec<bool>, RenderError> {
    let gbuffer = GBuffer::render(scene, tracer, view, config.width, config.height)?;
    let offset = NORMAL_OFFSET * grid.voxel_size();
    let mut read = vec![false; grid.num_voxels()];
    for point in gbuffer.points.iter().flatten() {
        let Ok(tw) = grid.trilinear_weights(point.position + point.normal * offset) else {
            continue;
        };
        for (&v, &w) in tw.indices.iter().zip(&tw.weights) {
            if w > 0.0 {
                read[v] = true;
            }
        }
    }
    Ok(read)
}
