//! Per-pixel wavelet transport for a fixed camera (Ng, Ramamoorthi and Hanrahan 2003): every
//! pixel's row over a `6 × n × n` cube map of distant light, Haar-transformed, truncated and
//! quantised into a [`SparseTransport`], so that relighting is `B = T L` in the wavelet domain.
//!
//! **What a row holds.** Materials are diffuse with one RGB albedo each, so the light leaving a
//! pixel's surface point `x` towards the camera under cube-map lighting `L` is
//! `ρ(x) ⊙ Σ_t T(x, t) L(t)`. Direct light gives `T(x, t) = (1/π) ∫_t V(x, ω) max(0, n·ω) dω`
//! ([`CubeRays::diffuse_row`](crate::cube::CubeRays::diffuse_row)): it does not depend on colour, so the transport is stored once
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
//!
//! **Layout.** The types here; the baker in `baker.rs`, the file format in `file.rs`, the
//! relighters in `relighters.rs`.

use prt_wavelet::SparseTransport;

use crate::TraceError;
use crate::camera::PinholeView;

mod baker;
mod file;
mod relighters;

pub use baker::PixelTransportBaker;
pub use relighters::{MethodRelighter, PixelRelighter, RelightMethod, RelitFrame};

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
    /// Sub-samples per texel side for the primary rows ([`CubeRays`](crate::cube::CubeRays)).
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
}
