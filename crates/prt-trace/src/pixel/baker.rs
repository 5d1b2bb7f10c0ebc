//! Tracing a [`PixelTransport`]: per pixel, its direct (and bounce) rows over the cube map,
//! Haar-transformed and sparsified.

use std::time::Instant;

use glam::Vec3;
use prt_core::Progress;
use prt_wavelet::{CubemapHaar, SparseTransport};
use rayon::prelude::*;

use crate::camera::{GBuffer, PinholeView};
use crate::cube::CubeRays;
use crate::sampling::{cosine_hemisphere, hash_seed};
use crate::{RayTracer, Scene, TraceError};

use super::{Bounce, PixelBakeEstimate, PixelTransport, PixelTransportOptions};

/// Traces [`PixelTransport`]s of a scene seen through a view.
#[derive(Debug)]
pub struct PixelTransportBaker<'a> {
    scene: &'a Scene,
    tracer: &'a RayTracer,
    view: PinholeView,
    options: PixelTransportOptions,
    gbuffer: GBuffer,
    rays: CubeRays,
    haar: CubemapHaar,
    offset: f32,
}

impl<'a> PixelTransportBaker<'a> {
    /// Renders the G-buffer and prepares the cube rays. Errors: [`TraceError::InvalidOption`]
    /// for a cube side that is not a power of two (or above 256), zero samples or gathers, a bad
    /// sparsification or offset, or an empty image; [`TraceError::EmptyScene`] without
    /// triangles.
    pub fn new(
        scene: &'a Scene,
        tracer: &'a RayTracer,
        view: PinholeView,
        options: PixelTransportOptions,
    ) -> Result<Self, TraceError> {
        let n = options.cube_size;
        if !n.is_power_of_two() || n > 256 {
            return Err(TraceError::InvalidOption {
                what: "cube size",
                why: format!("{n} is not a power of two in 1..=256"),
            });
        }
        options.sparsify.check()?;
        if options.bounce.is_some_and(|b| b.gathers == 0) {
            return Err(TraceError::InvalidOption {
                what: "bounce gathers",
                why: "at least one gather ray per pixel".into(),
            });
        }
        if !(options.offset.is_finite() && options.offset >= 0.0) {
            return Err(TraceError::InvalidOption {
                what: "ray offset",
                why: format!("{} is not a finite non-negative fraction", options.offset),
            });
        }
        let bounds = scene.bounds().ok_or(TraceError::EmptyScene)?;
        let offset = options.offset * bounds.size().length();
        let gbuffer = GBuffer::render(scene, tracer, &view, options.width, options.height)?;
        let rays = CubeRays::new(n, options.samples)?;
        let haar = CubemapHaar::new(n)?;
        Ok(Self {
            scene,
            tracer,
            view,
            options,
            gbuffer,
            rays,
            haar,
            offset,
        })
    }

    /// The G-buffer the transport is traced from.
    pub fn gbuffer(&self) -> &GBuffer {
        &self.gbuffer
    }

    /// Channels of the transport: 1 (direct light) or 3 (with a bounce).
    pub fn channels(&self) -> usize {
        if self.options.bounce.is_some() { 3 } else { 1 }
    }

    /// Rays, memory and time of [`Self::bake`], the time measured by tracing up to `probe`
    /// evenly spread hit pixels now.
    pub fn estimate(&self, probe: usize) -> PixelBakeEstimate {
        let hits: Vec<usize> = (0..self.gbuffer.points.len())
            .filter(|&p| self.gbuffer.points[p].is_some())
            .collect();
        let texels = self.rays.texels() as u64;
        let sub = (self.options.samples * self.options.samples) as u64;
        let gathers = self.options.bounce.map_or(0, |b| b.gathers) as u64;
        let per_pixel_rays = texels * sub + gathers * (texels + 1);
        let channels = self.channels() as u64;
        let kept_max = (self.options.sparsify.max_terms as u64).min(texels);
        let entries = hits.len() as u64 * channels * kept_max;
        let threads = rayon::current_num_threads() as u64;
        let peak_bytes = entries * (8 + 10) + threads * 4 * texels * (2 + channels);
        let probe = probe.clamp(1, hits.len().max(1));
        let chosen: Vec<usize> = (0..probe)
            .filter_map(|i| hits.get(i * hits.len() / probe).copied())
            .collect();
        let start = Instant::now();
        chosen.par_iter().for_each_init(
            || RowScratch::new(self.rays.texels(), &self.haar),
            |scratch, &p| {
                let _ = self.pixel_rows(p, scratch);
            },
        );
        let per_pixel = start.elapsed().as_secs_f64() / chosen.len().max(1) as f64;
        PixelBakeEstimate {
            hit_pixels: hits.len(),
            max_rays: hits.len() as u64 * per_pixel_rays,
            peak_bytes,
            stored_bytes: entries * 4,
            seconds: per_pixel * hits.len() as f64,
        }
    }

    /// Traces, transforms and sparsifies every pixel's rows. Progress counts pixels; errors:
    /// cancellation through `progress`, or a transport too large to index (over `u32::MAX`
    /// entries).
    pub fn bake(&self, progress: &dyn Progress) -> Result<PixelTransport, TraceError> {
        let pixels = self.gbuffer.points.len();
        progress.set_len(pixels as u64);
        let rows: Vec<Option<PixelRows>> = (0..pixels)
            .into_par_iter()
            .with_min_len(16)
            .map_init(
                || RowScratch::new(self.rays.texels(), &self.haar),
                |scratch, p| {
                    if progress.is_cancelled() {
                        return Ok(None);
                    }
                    let rows = self.pixel_rows(p, scratch)?;
                    progress.inc(1);
                    Ok(Some(rows))
                },
            )
            .collect::<Result<_, TraceError>>()?;
        if progress.is_cancelled() || rows.iter().any(Option::is_none) {
            return Err(TraceError::Core(prt_core::CoreError::Cancelled));
        }
        let rows: Vec<PixelRows> = rows.into_iter().flatten().collect();
        let mut transport = Vec::with_capacity(self.channels());
        for c in 0..self.channels() {
            let channel: Vec<Vec<(u32, f32)>> = rows
                .iter()
                .map(|r| r.get(c).cloned().unwrap_or_default())
                .collect();
            transport.push(SparseTransport::from_sparse_rows(
                self.rays.texels(),
                &channel,
            )?);
        }
        let point = |p: usize, f: fn(&crate::camera::GatherPoint) -> Vec3| {
            self.gbuffer.points[p]
                .as_ref()
                .map_or([0.0; 3], |g| f(g).to_array())
        };
        Ok(PixelTransport {
            options: self.options,
            view: self.view,
            albedo: (0..pixels).map(|p| point(p, |g| g.albedo)).collect(),
            emission: (0..pixels).map(|p| point(p, |g| g.emission)).collect(),
            hit: self.gbuffer.points.iter().map(Option::is_some).collect(),
            transport,
        })
    }

    /// The sparsified wavelet rows of pixel `p` (one per channel; empty rows where nothing is
    /// hit).
    fn pixel_rows(&self, p: usize, scratch: &mut RowScratch) -> Result<PixelRows, TraceError> {
        let channels = self.channels();
        let Some(point) = self.gbuffer.points[p] else {
            return Ok(vec![Vec::new(); channels]);
        };
        let RowScratch {
            direct,
            secondary,
            bounce,
            haar,
            order,
        } = scratch;
        self.rays.diffuse_row(
            self.tracer,
            point.position,
            point.normal,
            self.offset,
            direct,
        );
        let Some(Bounce { gathers }) = self.options.bounce else {
            haar.forward(direct)?;
            return Ok(vec![self.options.sparsify.keep(direct, order)]);
        };
        for b in bounce.iter_mut() {
            b.fill(0.0);
        }
        let origin = point.position + point.normal * self.offset;
        let scramble = hash_seed(self.options.seed, p as u64, 0x0b0c);
        let secondary_rays = self.secondary_rays();
        for g in 0..gathers {
            let u1 = sobol_burley::sample(g as u32, 0, scramble);
            let u2 = sobol_burley::sample(g as u32, 1, scramble);
            let dir = cosine_hemisphere(point.normal, u1, u2);
            let Some(hit) = self.tracer.closest_hit(origin, dir, 0.0, f32::INFINITY) else {
                continue;
            };
            let material = self.scene.material_of(hit.triangle as usize);
            if !(hit.front_face || material.double_sided) {
                continue;
            }
            let normal = if hit.front_face {
                hit.normal
            } else {
                -hit.normal
            };
            secondary_rays.diffuse_row(
                self.tracer,
                origin + dir * hit.t,
                normal,
                self.offset,
                secondary,
            );
            let albedo = material.albedo.to_array();
            for (b, rho) in bounce.iter_mut().zip(albedo) {
                let w = rho / gathers as f32;
                for (b, s) in b.iter_mut().zip(secondary.iter()) {
                    *b += w * s;
                }
            }
        }
        let mut out = Vec::with_capacity(3);
        for b in bounce.iter_mut() {
            for (b, d) in b.iter_mut().zip(direct.iter()) {
                *b += d;
            }
            haar.forward(b)?;
            out.push(self.options.sparsify.keep(b, order));
        }
        Ok(out)
    }

    /// Secondary rows use one sample per texel: they are averaged over the gathers anyway.
    fn secondary_rays(&self) -> &CubeRays {
        &self.rays
    }
}

/// A pixel's sparsified rows, one per transport channel: `(coefficient, value)`.
type PixelRows = Vec<Vec<(u32, f32)>>;

/// Per-thread buffers of one pixel's rows.
struct RowScratch {
    direct: Vec<f32>,
    secondary: Vec<f32>,
    bounce: [Vec<f32>; 3],
    haar: CubemapHaar,
    order: Vec<u32>,
}

impl RowScratch {
    fn new(texels: usize, haar: &CubemapHaar) -> Self {
        Self {
            direct: vec![0.0; texels],
            secondary: vec![0.0; texels],
            bounce: [vec![0.0; texels], vec![0.0; texels], vec![0.0; texels]],
            haar: haar.clone(),
            order: Vec::with_capacity(texels),
        }
    }
}
