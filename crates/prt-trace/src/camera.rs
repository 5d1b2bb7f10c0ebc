//! The camera of the per-pixel methods (many lights, wavelet relighting, BRDF editing, renders):
//! a pinhole view and the G-buffer of surface points its pixels see.

use std::f32::consts::PI;

use glam::Vec3;
use prt_core::Aabb;
use rayon::prelude::*;

use crate::scene::Camera;
use crate::{RayTracer, Scene, TraceError};

/// A pinhole view: where the camera is, where it looks, its vertical field of view.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PinholeView {
    /// Eye position.
    pub position: Vec3,
    /// Unit viewing direction.
    pub forward: Vec3,
    /// Unit up vector (orthogonal to `forward`).
    pub up: Vec3,
    /// Vertical field of view (radians).
    pub yfov: f32,
}

impl PinholeView {
    /// The view of a glTF camera (looking down its local -Z, +Y up).
    pub fn from_camera(camera: &Camera) -> Self {
        let forward = camera.to_world.transform_vector3(Vec3::NEG_Z).normalize();
        let up = camera.to_world.transform_vector3(Vec3::Y);
        let up = (up - forward * up.dot(forward)).normalize_or(Vec3::Y);
        Self {
            position: camera.to_world.transform_point3(Vec3::ZERO),
            forward,
            up,
            yfov: camera.yfov,
        }
    }

    /// Looks along -Z at the centre of `bounds` from far enough in +Z that the box's front face
    /// (its x-y extent) fills the vertical field of view `yfov`. For the Cornell box this is the
    /// classic view through the open side.
    pub fn framing(bounds: &Aabb, yfov: f32) -> Self {
        let centre = 0.5 * (bounds.min + bounds.max);
        let half = 0.5 * (bounds.max - bounds.min);
        let fit = half.x.max(half.y).max(1e-6) / (0.5 * yfov).tan();
        Self {
            position: Vec3::new(centre.x, centre.y, bounds.max.z + fit),
            forward: Vec3::NEG_Z,
            up: Vec3::Y,
            yfov,
        }
    }

    /// The scene's first glTF camera, else [`PinholeView::framing`] of its bounds with a 40°
    /// field of view. Errors: [`TraceError::EmptyScene`] when neither exists.
    pub fn for_scene(scene: &Scene) -> Result<Self, TraceError> {
        if let Some(c) = scene.cameras().first() {
            return Ok(Self::from_camera(c));
        }
        let bounds = scene.bounds().ok_or(TraceError::EmptyScene)?;
        Ok(Self::framing(&bounds, 40f32.to_radians()))
    }

    /// The unit ray direction through the centre of pixel `(x, y)` of a `width × height` image
    /// (row 0 at the top).
    pub fn ray(&self, x: usize, y: usize, width: usize, height: usize) -> Vec3 {
        let right = self.forward.cross(self.up);
        let t = (0.5 * self.yfov).tan();
        let aspect = width as f32 / height.max(1) as f32;
        let sx = ((x as f32 + 0.5) / width as f32 * 2.0 - 1.0) * t * aspect;
        let sy = (1.0 - (y as f32 + 0.5) / height as f32 * 2.0) * t;
        (self.forward + right * sx + self.up * sy).normalize()
    }
}

/// A surface point seen through a pixel.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GatherPoint {
    /// World-space position.
    pub position: Vec3,
    /// Unit normal facing the camera.
    pub normal: Vec3,
    /// Diffuse albedo (zero on the back of a single-sided surface).
    pub albedo: Vec3,
    /// Emitted radiance towards the camera (the material's emission on a visible side, else
    /// zero): what a pixel shows of an emitter seen directly.
    pub emission: Vec3,
}

/// Gather points per pixel, row-major from the top-left; `None` where the primary ray misses.
#[derive(Debug, Clone, PartialEq)]
pub struct GBuffer {
    /// Image width.
    pub width: usize,
    /// Image height.
    pub height: usize,
    /// One entry per pixel.
    pub points: Vec<Option<GatherPoint>>,
}

impl GBuffer {
    /// Traces one primary ray per pixel centre, in parallel.
    ///
    /// Errors: [`TraceError::InvalidOption`] for a zero width or height or a non-finite view.
    pub fn render(
        scene: &Scene,
        tracer: &RayTracer,
        view: &PinholeView,
        width: usize,
        height: usize,
    ) -> Result<Self, TraceError> {
        if width == 0 || height == 0 {
            return Err(TraceError::InvalidOption {
                what: "image size",
                why: format!("{width} × {height} has no pixels"),
            });
        }
        let finite = view.position.is_finite()
            && view.forward.is_finite()
            && view.up.is_finite()
            && view.yfov.is_finite()
            && view.yfov > 0.0
            && view.yfov < PI;
        if !finite {
            return Err(TraceError::InvalidOption {
                what: "view",
                why: format!("{view:?} is not a finite view with 0 < yfov < π"),
            });
        }
        let points = (0..width * height)
            .into_par_iter()
            .with_min_len(64)
            .map(|p| {
                let dir = view.ray(p % width, p / width, width, height);
                let hit = tracer.closest_hit(view.position, dir, 0.0, f32::INFINITY)?;
                let material = scene.material_of(hit.triangle as usize);
                let visible_side = hit.front_face || material.double_sided;
                Some(GatherPoint {
                    position: view.position + dir * hit.t,
                    normal: if hit.front_face {
                        hit.normal
                    } else {
                        -hit.normal
                    },
                    albedo: if visible_side {
                        material.albedo
                    } else {
                        Vec3::ZERO
                    },
                    emission: if visible_side {
                        material.emissive
                    } else {
                        Vec3::ZERO
                    },
                })
            })
            .collect();
        Ok(Self {
            width,
            height,
            points,
        })
    }
}
