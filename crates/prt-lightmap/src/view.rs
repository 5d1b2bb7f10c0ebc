//! Looking at a lightmap: bilinear lookups and a pinhole view of the lightmapped scene.

use glam::{Vec2, Vec3};
use prt_trace::camera::PinholeView;
use prt_trace::{RayTracer, Scene};
use rayon::prelude::*;

use crate::{Atlas, Lightmap, LightmapError};

impl Lightmap {
    /// Bilinear lookup of the irradiance at atlas position `uv` in texels (texel centres at
    /// `i + 0.5`, clamped at the atlas edges), as a GPU's filtered fetch reads it.
    pub fn irradiance_at(&self, uv: Vec2) -> Vec3 {
        let (w, h) = (self.width as i64, self.height as i64);
        let p = uv - Vec2::splat(0.5);
        let (x0, y0) = (p.x.floor(), p.y.floor());
        let (fx, fy) = (p.x - x0, p.y - y0);
        let fetch = |x: i64, y: i64| {
            let i = (y.clamp(0, h - 1) * w + x.clamp(0, w - 1)) as usize;
            Vec3::from_slice(&self.irradiance[3 * i..3 * i + 3])
        };
        let (x0, y0) = (x0 as i64, y0 as i64);
        let top = fetch(x0, y0).lerp(fetch(x0 + 1, y0), fx);
        let bottom = fetch(x0, y0 + 1).lerp(fetch(x0 + 1, y0 + 1), fx);
        top.lerp(bottom, fy)
    }
}

/// Renders `scene` from `view` at `width × height` lit by `lightmap` only: each pixel's primary
/// ray shows `emission + albedo/π · E`, with `E` the lightmap's bilinear irradiance at the hit's
/// lightmap UV; misses and back faces of single-sided surfaces are black. Row-major RGB, top
/// row first.
///
/// Errors: an atlas or lightmap that does not belong to the scene, a zero size.
pub fn render_view(
    scene: &Scene,
    atlas: &Atlas,
    lightmap: &Lightmap,
    view: &PinholeView,
    width: usize,
    height: usize,
) -> Result<Vec<[f32; 3]>, LightmapError> {
    if atlas.uvs.len() != scene.triangles().len() {
        return Err(LightmapError::invalid("atlas", "made for other triangles"));
    }
    if (atlas.width, atlas.height) != (lightmap.width, lightmap.height) {
        return Err(LightmapError::invalid(
            "lightmap",
            "its size differs from the atlas's",
        ));
    }
    if width == 0 || height == 0 {
        return Err(LightmapError::invalid(
            "view size",
            format!("{width}×{height}"),
        ));
    }
    let tracer = RayTracer::new(scene.triangles());
    Ok((0..width * height)
        .into_par_iter()
        .map(|i| {
            let dir = view.ray(i % width, i / width, width, height);
            let Some(hit) = tracer.closest_hit(view.position, dir, 0.0, f32::INFINITY) else {
                return [0.0; 3];
            };
            let t = hit.triangle as usize;
            let material = scene.material_of(t);
            if !hit.front_face && !material.double_sided {
                return [0.0; 3];
            }
            let uv = atlas.uvs[t];
            let b = hit.barycentrics;
            let at = uv[0] * (1.0 - b.x - b.y) + uv[1] * b.x + uv[2] * b.y;
            let emission = if hit.front_face {
                material.emissive
            } else {
                Vec3::ZERO
            };
            (emission + material.albedo / std::f32::consts::PI * lightmap.irradiance_at(at))
                .to_array()
        })
        .collect())
}
