//! Per-pixel wavelet transport for a fixed camera (Ng, Ramamoorthi and Hanrahan 2003): every
//! pixel's row over a `6 × n × n` cube map of distant light, Haar-transformed, truncated and
//! quantised into a [`SparseTransport`], so that relighting is `B = T L` in the wavelet domain.
//!
//! **What a row holds.** Materials are diffuse with one RGB albedo each, so the light leaving a
//! pixel's surface point `x` towards the camera under cube-map lighting `L` is
//! `ρ(x) ⊙ Σ_t T(x, t) L(t)`. Direct light gives `T(x, t) = (1/π) ∫_t V(x, ω) max(0, n·ω) dω`
//! ([`CubeRays::diffuse_row`]): it does not depend on colour, so the transport is stored once
//! (scalar, "white") and the albedo multiplies the product per pixel. That is exact, and a third
//! of the bytes and of the per-frame memory traffic of RGB transport. With one diffuse bounce
//! ([`Bounce`]) the light reaching `x` has been coloured by the albedo of the surfaces it came
//! from (colour bleeding), so the transport becomes RGB: three scalar transports, one per colour,
//! each applied to its lighting channel.
//!
//! **The bounce** gathers with `gathers` cosine-weighted rays per pixel (Owen-scrambled Sobol'
//! points, seeded per pixel): a ray hitting a surface `h` adds `ρ_h(c) / gathers` times `h`'s own
//! direct row to channel `c` (the cosine-weighted estimator of `(1/π) ∫ L_in cos`, with `L_in`
//! the light leaving `h`). The secondary rows are traced on demand.
//!
//! **Sparsification** ([`Sparsify`]): per row and channel, the largest Haar coefficients in
//! magnitude are kept until they hold `energy` of the row's squared L2 norm (the Haar basis is
//! orthonormal, so that is the fraction of the row's energy over the light directions), and at
//! most `max_terms`. The kept entries are then 16-bit quantised per column
//! ([`SparseTransport::from_sparse_rows`]).
//!
//! **Determinism.** A pixel's row depends only on the scene, the view, the options and the
//! seed; pixels run in parallel (rayon) and are assembled in pixel order, so the transport is
//! bit-identical on any thread count.
//!
//! **Files.** [`PixelTransport::write`] / [`PixelTransport::read`]: a little-endian binary file
//! (docs/formats.md, "Per-pixel wavelet transport"), written atomically, read with size limits
//! and every field checked.

use std::io::Read;
use std::path::Path;
use std::time::Instant;

use glam::Vec3;
use prt_core::Progress;
use prt_texture::{Limits, write_atomic};
use prt_wavelet::{CubemapHaar, FrameUpdate, Relighter, SparseTransport, TransportParts};
use rayon::prelude::*;

use crate::cube::CubeRays;
use crate::sampling::{cosine_hemisphere, hash_seed};
use crate::{GBuffer, PinholeView, RayTracer, Scene, TraceError};

/// Which Haar coefficients of a row are kept.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sparsify {
    /// Fraction of the row's energy (squared L2 norm) the kept coefficients must reach, in
    /// `(0, 1]`; 1 keeps every non-zero (up to `max_terms`).
    pub energy: f32,
    /// At most this many coefficients per row and channel (at least 1).
    pub max_terms: usize,
}

impl Default for Sparsify {
    /// 99.9 % of the energy, at most 1024 terms.
    fn default() -> Self {
        Self {
            energy: 0.999,
            max_terms: 1024,
        }
    }
}

impl Sparsify {
    /// The kept entries `(index, value)` of `row`, sorted by index: the fewest largest (ties to
    /// the lower index) reaching the energy fraction, at most `max_terms`. `order` is scratch.
    pub fn keep(&self, row: &[f32], order: &mut Vec<u32>) -> Vec<(u32, f32)> {
        order.clear();
        order.extend((0..row.len() as u32).filter(|&j| row[j as usize] != 0.0));
        order.sort_unstable_by(|a, b| {
            row[*b as usize]
                .abs()
                .total_cmp(&row[*a as usize].abs())
                .then(a.cmp(b))
        });
        let total: f64 = order
            .iter()
            .map(|&j| (row[j as usize] as f64).powi(2))
            .sum();
        let target = self.energy as f64 * total;
        let mut kept = 0.0f64;
        let mut count = 0;
        for &j in order.iter() {
            if count >= self.max_terms || (kept >= target && count > 0) {
                break;
            }
            kept += (row[j as usize] as f64).powi(2);
            count += 1;
        }
        order.truncate(count);
        order.sort_unstable();
        order.iter().map(|&j| (j, row[j as usize])).collect()
    }

    fn check(&self) -> Result<(), TraceError> {
        if !(self.energy > 0.0 && self.energy <= 1.0) || self.max_terms == 0 {
            return Err(TraceError::InvalidOption {
                what: "sparsification",
                why: format!(
                    "energy {} must be in (0, 1] and max_terms {} at least 1",
                    self.energy, self.max_terms
                ),
            });
        }
        Ok(())
    }
}

/// One diffuse bounce: gather rays per pixel.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Bounce {
    /// Cosine-weighted gather rays per pixel (at least 1); each traces a whole secondary row.
    pub gathers: usize,
}

/// Options of [`PixelTransportBaker`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PixelTransportOptions {
    /// Image width in pixels.
    pub width: usize,
    /// Image height in pixels.
    pub height: usize,
    /// Cube-map face side `n` (a power of two; 32 by default, 64 supported).
    pub cube_size: usize,
    /// Sub-samples per texel side for the primary rows ([`CubeRays`]).
    pub samples: usize,
    /// Which coefficients are kept.
    pub sparsify: Sparsify,
    /// One diffuse bounce, or direct light only.
    pub bounce: Option<Bounce>,
    /// Seed of the gather rays.
    pub seed: u64,
    /// Shadow-ray offset along the normal, as a fraction of the scene's bounding-box diagonal.
    pub offset: f32,
}

impl Default for PixelTransportOptions {
    /// 128 × 128 pixels, 32 × 32 faces, one sample per texel, [`Sparsify::default`], direct
    /// light only, seed 1, offset 1e-4.
    fn default() -> Self {
        Self {
            width: 128,
            height: 128,
            cube_size: 32,
            samples: 1,
            sparsify: Sparsify::default(),
            bounce: None,
            seed: 1,
            offset: 1e-4,
        }
    }
}

/// What a bake will cost, from [`PixelTransportBaker::estimate`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PixelBakeEstimate {
    /// Pixels whose primary ray hits the scene (only they are traced).
    pub hit_pixels: usize,
    /// Shadow rays at most (every cube sub-sample of every hit pixel and gather).
    pub max_rays: u64,
    /// Bytes at most held at the peak: the kept rows (8 bytes per entry) plus the transport
    /// being built from them (10 bytes per entry while indexing) and per-thread row buffers.
    pub peak_bytes: u64,
    /// Bytes of the stored transport at most (4 per entry, `max_terms` per row and channel).
    pub stored_bytes: u64,
    /// Wall time, extrapolated from tracing a probe of evenly spread pixels on this machine's
    /// rayon pool as it is loaded now.
    pub seconds: f64,
}

/// A baked per-pixel transport: the G-buffer's albedo and emission and one or three sparse
/// transports (white, or R, G, B with a bounce) of `width × height` rows.
#[derive(Debug, Clone, PartialEq)]
pub struct PixelTransport {
    /// The options it was baked with.
    pub options: PixelTransportOptions,
    /// The camera.
    pub view: PinholeView,
    /// Diffuse albedo per pixel (zero where nothing is hit or a back face is seen).
    pub albedo: Vec<[f32; 3]>,
    /// Emitted radiance per pixel, added to the relit image.
    pub emission: Vec<[f32; 3]>,
    /// Whether each pixel's primary ray hit the scene.
    pub hit: Vec<bool>,
    /// One transport (direct light: colour-free) or three (with a bounce: R, G, B).
    pub transport: Vec<SparseTransport>,
}

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
        let point = |p: usize, f: fn(&crate::GatherPoint) -> Vec3| {
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

impl PixelTransport {
    /// Pixels (rows of every transport).
    pub fn pixels(&self) -> usize {
        self.albedo.len()
    }

    /// Lighting coefficients per channel plane (`6 n²`).
    pub fn cols(&self) -> usize {
        self.transport.first().map_or(0, SparseTransport::cols)
    }

    /// Stored entries over all channels.
    pub fn nnz(&self) -> usize {
        self.transport.iter().map(SparseTransport::nnz).sum()
    }

    /// Bytes of the transport as the engine holds it (4 per entry; indices not counted).
    pub fn entry_bytes(&self) -> usize {
        4 * self.nnz()
    }

    /// Writes the transport to `path` atomically (docs/formats.md, "Per-pixel wavelet
    /// transport").
    pub fn write(&self, path: &Path) -> Result<(), TraceError> {
        let mut out = Vec::new();
        out.extend_from_slice(MAGIC);
        let o = &self.options;
        for v in [
            VERSION,
            o.width as u32,
            o.height as u32,
            o.cube_size as u32,
            o.samples as u32,
            o.sparsify.max_terms as u32,
            o.bounce.map_or(0, |b| b.gathers as u32),
            self.transport.len() as u32,
        ] {
            out.extend_from_slice(&v.to_le_bytes());
        }
        out.extend_from_slice(&o.seed.to_le_bytes());
        let v = &self.view;
        for f in [o.sparsify.energy, o.offset]
            .into_iter()
            .chain(v.position.to_array())
            .chain(v.forward.to_array())
            .chain(v.up.to_array())
            .chain([v.yfov])
        {
            out.extend_from_slice(&f.to_le_bytes());
        }
        for p in 0..self.pixels() {
            out.push(self.hit[p] as u8);
            for f in self.albedo[p].iter().chain(&self.emission[p]) {
                out.extend_from_slice(&f.to_le_bytes());
            }
        }
        for t in &self.transport {
            let parts = t.to_parts();
            out.extend_from_slice(&(parts.rows as u64).to_le_bytes());
            out.extend_from_slice(&(parts.cols as u64).to_le_bytes());
            out.extend_from_slice(&(parts.entry_rows.len() as u64).to_le_bytes());
            for s in &parts.scale {
                out.extend_from_slice(&s.to_le_bytes());
            }
            for s in &parts.col_start {
                out.extend_from_slice(&s.to_le_bytes());
            }
            for r in &parts.entry_rows {
                out.extend_from_slice(&r.to_le_bytes());
            }
            for q in &parts.quantised {
                out.extend_from_slice(&q.to_le_bytes());
            }
        }
        write_atomic(path, &out).map_err(|source| TraceError::Write {
            path: path.to_path_buf(),
            source,
        })
    }

    /// Reads a file written by [`Self::write`]. Errors: [`TraceError::Io`] when it cannot be
    /// read, [`TraceError::BadTransportFile`] naming the first field that is wrong (magic,
    /// version, sizes beyond `limits.max_bytes`, a truncated file, a non-finite value, an
    /// inconsistent transport).
    pub fn read(path: &Path, limits: &Limits) -> Result<Self, TraceError> {
        let bad = |why: String| TraceError::BadTransportFile {
            path: path.to_path_buf(),
            why,
        };
        let file = std::fs::File::open(path).map_err(|source| TraceError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        let len = file
            .metadata()
            .map_err(|source| TraceError::Io {
                path: path.to_path_buf(),
                source,
            })?
            .len();
        if len > limits.max_bytes {
            return Err(bad(format!(
                "{len} bytes exceed the limit of {}",
                limits.max_bytes
            )));
        }
        let mut bytes = Vec::with_capacity(len as usize);
        file.take(limits.max_bytes)
            .read_to_end(&mut bytes)
            .map_err(|source| TraceError::Io {
                path: path.to_path_buf(),
                source,
            })?;
        let mut r = Reader {
            bytes: &bytes,
            at: 0,
        };
        if r.take(MAGIC.len()).map_err(&bad)? != MAGIC {
            return Err(bad("not a prt pixel-transport file (bad magic)".into()));
        }
        let version = r.u32().map_err(&bad)?;
        if version != VERSION {
            return Err(bad(format!("version {version}, expected {VERSION}")));
        }
        let mut header = [0u32; 7];
        for h in &mut header {
            *h = r.u32().map_err(&bad)?;
        }
        let [
            width,
            height,
            cube_size,
            samples,
            max_terms,
            gathers,
            channels,
        ] = header.map(|v| v as usize);
        let seed = r.u64().map_err(&bad)?;
        let mut floats = [0f32; 12];
        for f in &mut floats {
            *f = r.f32().map_err(&bad)?;
        }
        if let Some(i) = floats.iter().position(|f| !f.is_finite()) {
            return Err(bad(format!("header float {i} is not finite")));
        }
        if !(channels == 1 || channels == 3) || (channels == 3) != (gathers > 0) {
            return Err(bad(format!(
                "{channels} channels with {gathers} gathers (expected 1 without a bounce, 3 with)"
            )));
        }
        if !cube_size.is_power_of_two() || cube_size > 256 {
            return Err(bad(format!("cube size {cube_size}")));
        }
        let pixels = width
            .checked_mul(height)
            .filter(|&p| (p as u64).saturating_mul(25) <= len)
            .ok_or_else(|| bad(format!("{width} × {height} pixels do not fit the file")))?;
        let options = PixelTransportOptions {
            width,
            height,
            cube_size,
            samples,
            sparsify: Sparsify {
                energy: floats[0],
                max_terms,
            },
            bounce: (gathers > 0).then_some(Bounce { gathers }),
            seed,
            offset: floats[1],
        };
        let v3 = |i: usize| Vec3::new(floats[i], floats[i + 1], floats[i + 2]);
        let view = PinholeView {
            position: v3(2),
            forward: v3(5),
            up: v3(8),
            yfov: floats[11],
        };
        let (mut albedo, mut emission, mut hit) = (
            Vec::with_capacity(pixels),
            Vec::with_capacity(pixels),
            Vec::with_capacity(pixels),
        );
        for p in 0..pixels {
            hit.push(r.take(1).map_err(&bad)?[0] != 0);
            let mut v = [0f32; 6];
            for f in &mut v {
                *f = r.f32().map_err(&bad)?;
            }
            if v.iter().any(|f| !f.is_finite()) {
                return Err(bad(format!("pixel {p}'s albedo or emission is not finite")));
            }
            albedo.push([v[0], v[1], v[2]]);
            emission.push([v[3], v[4], v[5]]);
        }
        let mut transport = Vec::with_capacity(channels);
        for c in 0..channels {
            let rows = r.u64().map_err(&bad)? as usize;
            let cols = r.u64().map_err(&bad)? as usize;
            let nnz = r.u64().map_err(&bad)? as usize;
            if rows != pixels || cols != 6 * cube_size * cube_size {
                return Err(bad(format!(
                    "transport {c} is {rows} × {cols}, expected {pixels} × {}",
                    6 * cube_size * cube_size
                )));
            }
            let needed = (cols as u64) * 12 + 8 + (nnz as u64) * 6;
            if needed > (bytes.len() - r.at) as u64 {
                return Err(bad(format!("transport {c} is truncated")));
            }
            let scale = (0..cols).map(|_| r.f32()).collect::<Result<Vec<_>, _>>();
            let col_start = (0..=cols).map(|_| r.u64()).collect::<Result<Vec<_>, _>>();
            let entry_rows = (0..nnz).map(|_| r.u32()).collect::<Result<Vec<_>, _>>();
            let quantised = (0..nnz)
                .map(|_| r.take(2).map(|b| i16::from_le_bytes([b[0], b[1]])))
                .collect::<Result<Vec<_>, _>>();
            let parts = TransportParts {
                rows,
                cols,
                col_start: col_start.map_err(&bad)?,
                entry_rows: entry_rows.map_err(&bad)?,
                quantised: quantised.map_err(&bad)?,
                scale: scale.map_err(&bad)?,
            };
            transport.push(
                SparseTransport::from_parts(parts)
                    .map_err(|e| bad(format!("transport {c}: {e}")))?,
            );
        }
        if r.at != bytes.len() {
            return Err(bad(format!("{} trailing bytes", bytes.len() - r.at)));
        }
        Ok(Self {
            options,
            view,
            albedo,
            emission,
            hit,
            transport,
        })
    }
}

const MAGIC: &[u8; 8] = b"PRTPIXT\0";
const VERSION: u32 = 1;

/// A cursor over a file's bytes whose reads fail (never panic) past the end.
struct Reader<'b> {
    bytes: &'b [u8],
    at: usize,
}

impl<'b> Reader<'b> {
    fn take(&mut self, n: usize) -> Result<&'b [u8], String> {
        let end = self.at.checked_add(n).filter(|&e| e <= self.bytes.len());
        let end = end.ok_or_else(|| format!("truncated at byte {}", self.at))?;
        let out = &self.bytes[self.at..end];
        self.at = end;
        Ok(out)
    }

    fn u32(&mut self) -> Result<u32, String> {
        let b = self.take(4)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }

    fn u64(&mut self) -> Result<u64, String> {
        let b = self.take(8)?;
        Ok(u64::from_le_bytes(b.try_into().map_err(|_| "short read")?))
    }

    fn f32(&mut self) -> Result<f32, String> {
        Ok(f32::from_bits(self.u32()?))
    }
}

/// The relighting engine over a [`PixelTransport`]: one [`Relighter`] per transport channel
/// (a white transport is applied to all three lighting channels at once; RGB transports each to
/// their own), then the per-pixel albedo and emission.
#[derive(Debug, Clone)]
pub struct PixelRelighter {
    engines: Vec<Relighter>,
    albedo: Vec<[f32; 3]>,
    emission: Vec<[f32; 3]>,
    split: FrameUpdate,
}

impl PixelRelighter {
    /// An engine for RGB lighting updates over `bands` bands, starting from black lighting.
    /// Errors: no transport, or `bands` zero.
    pub fn new(transport: &PixelTransport, bands: usize) -> Result<Self, TraceError> {
        if transport.transport.is_empty() {
            return Err(TraceError::InvalidOption {
                what: "pixel transport",
                why: "has no channels".into(),
            });
        }
        let lighting_channels = if transport.transport.len() == 1 { 3 } else { 1 };
        let engines = transport
            .transport
            .iter()
            .map(|t| Relighter::new(t.clone(), lighting_channels, bands))
            .collect::<Result<Vec<_>, _>>()?;
        Ok(Self {
            engines,
            albedo: transport.albedo.clone(),
            emission: transport.emission.clone(),
            split: FrameUpdate::default(),
        })
    }

    /// Applies one frame's RGB update (values `[term][R, G, B]`, as from
    /// [`prt_wavelet::Approximator::step`] over 3 channels); returns the transport bytes read.
    pub fn apply(&mut self, update: &FrameUpdate) -> Result<usize, TraceError> {
        if self.engines.len() == 1 {
            return Ok(self.engines[0].apply(update)?);
        }
        let mut bytes = 0;
        for (c, engine) in self.engines.iter_mut().enumerate() {
            self.split.modes.clone_from(&update.modes);
            self.split.terms.clone_from(&update.terms);
            self.split.values.clear();
            self.split
                .values
                .extend(update.values.iter().skip(c).step_by(3).copied());
            self.split.residual = update.residual;
            bytes += engine.apply(&self.split)?;
        }
        Ok(bytes)
    }

    /// The relit image: `albedo ⊙ (T L̃) + emission` per pixel, linear RGB, row-major.
    pub fn image(&self) -> Vec<[f32; 3]> {
        let mut out: Vec<[f32; 3]> = vec![[0.0; 3]; self.albedo.len()];
        if self.engines.len() == 1 {
            let img = self.engines[0].image();
            for (o, p) in out.iter_mut().zip(img.chunks_exact(3)) {
                o.copy_from_slice(p);
            }
        } else {
            for (c, engine) in self.engines.iter().enumerate() {
                for (o, v) in out.iter_mut().zip(engine.image()) {
                    o[c] = v;
                }
            }
        }
        for ((o, a), e) in out.iter_mut().zip(&self.albedo).zip(&self.emission) {
            for c in 0..3 {
                o[c] = o[c] * a[c] + e[c];
            }
        }
        out
    }
}

/// A lighting approximation for [`MethodRelighter`], with its terms per frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RelightMethod {
    /// Every non-zero lighting coefficient each frame: the unapproximated product.
    Exact,
    /// Non-linear approximation: the `k` largest (area-weighted) coefficients of each frame.
    Nwa(usize),
    /// Basic incremental: the `k` largest of the difference to last frame's approximation.
    Bi(usize),
    /// Per-band incremental over level × face × quadrant bands, terms dealt to the bands
    /// (prt-wavelet's best PBI variant on rotating maps).
    Pbi(usize),
}

impl RelightMethod {
    /// A short name: `exact`, `nwa30`, `bi30`, `pbi30`.
    pub fn name(&self) -> String {
        match self {
            Self::Exact => "exact".into(),
            Self::Nwa(k) => format!("nwa{k}"),
            Self::Bi(k) => format!("bi{k}"),
            Self::Pbi(k) => format!("pbi{k}"),
        }
    }
}

/// One frame of a [`MethodRelighter`].
#[derive(Debug, Clone, PartialEq)]
pub struct RelitFrame {
    /// The relit image (linear RGB, row-major).
    pub image: Vec<[f32; 3]>,
    /// Area-weighted L1 error of the approximated lighting against the frame's texels.
    pub lighting_l1: f64,
    /// Terms chosen in each band this frame.
    pub terms_per_band: Vec<usize>,
    /// Transport bytes read by the engine this frame.
    pub bytes: usize,
    /// Bands replaced this frame (each streams its partial image and the total once).
    pub replaced_bands: usize,
    /// Wall time of the approximation step plus the engine's update (no image copy).
    pub seconds: f64,
}

/// One lighting approximation driving one engine over a sequence of frames.
#[derive(Debug, Clone)]
pub struct MethodRelighter {
    method: RelightMethod,
    approximator: prt_wavelet::Approximator,
    engine: PixelRelighter,
    error: prt_wavelet::analysis::LightingError,
}

impl MethodRelighter {
    /// An approximator (area-weighted selection, RGB) and an engine over `transport`.
    pub fn new(transport: &PixelTransport, method: RelightMethod) -> Result<Self, TraceError> {
        use prt_wavelet::{Approximator, BandStrategy, CubemapLayout, Policy};
        let n = transport.options.cube_size;
        let layout = CubemapLayout::new(n)?;
        let (bands, terms, policy) = match method {
            RelightMethod::Exact => (
                layout.bands().to_vec(),
                layout.len(),
                Policy::NonIncremental,
            ),
            RelightMethod::Nwa(k) => (layout.bands().to_vec(), k, Policy::NonIncremental),
            RelightMethod::Bi(k) => (layout.bands().to_vec(), k, Policy::Incremental),
            RelightMethod::Pbi(k) => (
                layout.level_face_tile_bands(2.min(n))?,
                k,
                Policy::PerBand(BandStrategy::Dealer),
            ),
        };
        let approximator =
            Approximator::new(bands, layout.area_weights().to_vec(), 3, terms, policy)?;
        let engine = PixelRelighter::new(transport, approximator.band_count())?;
        Ok(Self {
            method,
            approximator,
            engine,
            error: prt_wavelet::analysis::LightingError::new(n, 3)?,
        })
    }

    /// The method.
    pub fn method(&self) -> RelightMethod {
        self.method
    }

    /// Advances to the next frame: `coefficients` are the frame's planar RGB Haar
    /// coefficients, `texels` the same lighting before the transform (for the lighting error).
    pub fn frame(
        &mut self,
        coefficients: &[f32],
        texels: &[f32],
    ) -> Result<RelitFrame, TraceError> {
        let start = Instant::now();
        let update = self.approximator.step(coefficients)?;
        let bytes = self.engine.apply(update)?;
        let seconds = start.elapsed().as_secs_f64();
        let terms_per_band = update.terms_per_band();
        let replaced_bands = update
            .modes
            .iter()
            .filter(|m| **m == prt_wavelet::BandMode::Replace)
            .count();
        let lighting_l1 = self
            .error
            .error(self.approximator.approximation(), texels)?;
        Ok(RelitFrame {
            image: self.engine.image(),
            lighting_l1,
            terms_per_band,
            bytes,
            replaced_bands,
            seconds,
        })
    }
}
