//! BRDF editing with basic incremental updates in Daubechies-4 (Overbeck's chapter 4, after
//! Ben-Artzi, Overbeck and Ramamoorthi, "Real-time BRDF editing in complex lighting", 2006).
//!
//! A 1D BRDF curve (here the microfacet distribution `D(θ_h)` sampled in 256 bins of
//! `θ_h ∈ [0, π/2)`) is edited interactively; each frame spends `k` Daubechies-4 terms on the
//! largest coefficients of the difference between the edited curve and the current
//! approximation. Because terms are assigned exactly and never chosen twice while the curve is
//! static, the approximation is exact (up to the f32 transform) at most `⌈256 / k⌉` frames after
//! the edits stop: 9 frames at 30 terms.
//!
//! On an image (fixed view and lighting), each pixel's glossy radiance is linear in the curve,
//! `B_p = Σ_b T_p[b] f[b]`, with an RGB transport row per pixel (`prt_trace`'s
//! `trace_half_angle_transport`). [`CurveTransport`] stores the rows in Daubechies-4, where
//! orthonormality gives `B_p = Σ_j T̂_p[j] f̂[j]`, keeping the largest coefficients per pixel;
//! [`CurveRelighter`] applies a [`CurveEditor`] frame's [`FrameUpdate`] to the image from the
//! changed coefficients only, `ΔB_p = Σ_{changed j} T̂_p[j] Δf̂[j]`.

use rayon::prelude::*;

use crate::WaveletError;
use crate::approx::{Approximator, BandMode, FrameUpdate, Policy};
use crate::daubechies::Daubechies4;

/// The Beckmann microfacet distribution `D(θ_h) = exp(−tan²θ_h / m²) / (π m² cos⁴θ_h)` of
/// roughness `m` (Cook and Torrance 1982) at the centres of `bins` bins over `[0, π/2)`.
/// Errors if `m` is not finite and positive or `bins` is zero.
pub fn beckmann_curve(roughness: f32, bins: usize) -> Result<Vec<f32>, WaveletError> {
    if !(roughness.is_finite() && roughness > 0.0) || bins == 0 {
        return Err(WaveletError::Invalid {
            what: "Beckmann curve",
            why: format!("roughness {roughness} must be finite and positive, bins {bins} non-zero"),
        });
    }
    let m2 = roughness as f64 * roughness as f64;
    Ok((0..bins)
        .map(|i| {
            let theta = (i as f64 + 0.5) / bins as f64 * std::f64::consts::FRAC_PI_2;
            let (c, t) = (theta.cos(), theta.tan());
            ((-t * t / m2).exp() / (std::f64::consts::PI * m2 * c.powi(4))) as f32
        })
        .collect())
}

/// A free-hand edit: adds a raised-cosine stroke of height `delta` and half-width `radius` bins
/// centred on bin `centre` to `curve` (values are clamped at 0, as a BRDF cannot be negative).
pub fn brush_stroke(curve: &mut [f32], centre: f32, radius: f32, delta: f32) {
    let r = radius.max(1e-3);
    for (i, v) in curve.iter_mut().enumerate() {
        let d = (i as f32 - centre).abs() / r;
        if d < 1.0 {
            *v = (*v + delta * 0.5 * (1.0 + (std::f32::consts::PI * d).cos())).max(0.0);
        }
    }
}

/// An interactive curve editor: BI (or another [`Policy`]) with `k` Daubechies-4 terms per
/// frame, all coefficients in one band.
#[derive(Debug, Clone)]
pub struct CurveEditor {
    transform: Daubechies4,
    approximator: Approximator,
    coefficients: Vec<f32>,
    curve: Vec<f32>,
    update: FrameUpdate,
}

impl CurveEditor {
    /// An editor for curves of `bins` samples (a power of two >= 2), `terms` per frame, BI.
    pub fn new(bins: usize, terms: usize) -> Result<Self, WaveletError> {
        Self::with_policy(bins, terms, Policy::Incremental)
    }

    /// [`Self::new`] with another policy, e.g. [`Policy::NonIncremental`] (NWA: the `k`
    /// largest coefficients of the edited curve each frame).
    pub fn with_policy(bins: usize, terms: usize, policy: Policy) -> Result<Self, WaveletError> {
        let transform = Daubechies4::new(bins)?;
        let approximator = Approximator::new(vec![0; bins], vec![1.0; bins], 1, terms, policy)?;
        Ok(Self {
            transform,
            approximator,
            coefficients: vec![0.0; bins],
            curve: vec![0.0; bins],
            update: FrameUpdate::default(),
        })
    }

    /// One frame towards the edited curve `target`; returns the displayed (approximated) curve.
    /// Errors on a length mismatch or a non-finite sample.
    pub fn step(&mut self, target: &[f32]) -> Result<&[f32], WaveletError> {
        WaveletError::check_len("BRDF curve", self.coefficients.len(), target.len())?;
        WaveletError::check_finite("BRDF curve", target)?;
        self.coefficients.copy_from_slice(target);
        self.transform.forward(&mut self.coefficients)?;
        self.update
            .clone_from(self.approximator.step(&self.coefficients)?);
        self.curve
            .copy_from_slice(self.approximator.approximation());
        self.transform.inverse(&mut self.curve)?;
        Ok(&self.curve)
    }

    /// The displayed curve of the last frame.
    pub fn curve(&self) -> &[f32] {
        &self.curve
    }

    /// The displayed curve's Daubechies-4 coefficients `f̃` of the last frame.
    pub fn coefficients(&self) -> &[f32] {
        self.approximator.approximation()
    }

    /// What the last frame changed in `f̃` (for [`CurveRelighter::apply`]).
    pub fn update(&self) -> &FrameUpdate {
        &self.update
    }
}

/// One stored transport entry: a pixel and its RGB value at one curve coefficient.
#[derive(Debug, Clone, Copy, PartialEq)]
struct CurveEntry {
    pixel: u32,
    rgb: [f32; 3],
}

/// One pixel's kept `(coefficient, RGB)` entries and its dropped energy per channel.
struct PixelRow {
    kept: Vec<(u32, [f32; 3])>,
    dropped: [f32; 3],
}

/// Per-pixel RGB transport against a curve's Daubechies-4 coefficients, sparsified per pixel
/// and stored by coefficient (a frame reads only the columns of its changed coefficients).
///
/// Sparsification keeps, per pixel, the `keep` coefficients `j` of largest energy
/// `Σ_c T̂_{p,c}[j]²` (all three channels of a kept coefficient; ties towards the lower index;
/// exact zeros never). By Cauchy–Schwarz and Parseval the glossy error this costs a pixel in
/// channel `c` is at most `√(dropped energy) · ‖f‖₂` for any curve `f`
/// ([`Self::dropped_energy`]).
#[derive(Debug, Clone, PartialEq)]
pub struct CurveTransport {
    pixels: usize,
    bins: usize,
    /// Entries of coefficient `j`: `entries[col_start[j]..col_start[j + 1]]`, by pixel.
    col_start: Vec<usize>,
    entries: Vec<CurveEntry>,
    dropped: Vec<[f32; 3]>,
}

impl CurveTransport {
    /// Projects `rows` (pixel-major bin-domain transport, `rows[(p · 3 + c) · bins + b]`, as
    /// traced) onto Daubechies-4 and keeps `keep` coefficients per pixel (`bins` or more keeps
    /// every non-zero). Errors: `bins` not a power of two >= 2, a length that is not a whole
    /// number of pixels, a non-finite entry, more than `u32::MAX` pixels.
    pub fn new(rows: &[f32], bins: usize, keep: usize) -> Result<Self, WaveletError> {
        let transform = Daubechies4::new(bins)?;
        WaveletError::check_finite("BRDF transport", rows)?;
        let row_len = 3 * bins;
        if !rows.len().is_multiple_of(row_len) || rows.len() / row_len > u32::MAX as usize {
            return Err(WaveletError::Invalid {
                what: "BRDF transport",
                why: format!(
                    "{} values are not whole pixels of 3 × {bins} (or too many pixels)",
                    rows.len()
                ),
            });
        }
        let pixels = rows.len() / row_len;
        let kept: Vec<PixelRow> = rows
            .par_chunks_exact(row_len)
            .map_init(
                || (transform.clone(), vec![0.0f32; row_len], Vec::new()),
                |(transform, projected, order), row| {
                    projected.copy_from_slice(row);
                    for channel in projected.chunks_exact_mut(bins) {
                        transform.forward(channel).expect("length checked");
                    }
                    let energy = |j: usize| -> f64 {
                        (0..3)
                            .map(|c| (projected[c * bins + j] as f64).powi(2))
                            .sum()
                    };
                    order.clear();
                    order.extend((0..bins).filter(|&j| energy(j) > 0.0));
                    let larger =
                        |a: &usize, b: &usize| energy(*b).total_cmp(&energy(*a)).then(a.cmp(b));
                    if keep > 0 && order.len() > keep {
                        order.select_nth_unstable_by(keep - 1, larger);
                    }
                    order.truncate(keep);
                    order.sort_unstable();
                    let rgb = |j: usize| [0, 1, 2].map(|c| projected[c * bins + j]);
                    let mut dropped = [0.0f64; 3];
                    let mut next = order.iter().peekable();
                    for j in 0..bins {
                        if next.peek() == Some(&&j) {
                            next.next();
                        } else {
                            for (c, d) in dropped.iter_mut().enumerate() {
                                *d += (projected[c * bins + j] as f64).powi(2);
                            }
                        }
                    }
                    PixelRow {
                        kept: order.iter().map(|&j| (j as u32, rgb(j))).collect(),
                        dropped: dropped.map(|d| d as f32),
                    }
                },
            )
            .collect();
        let mut col_start = vec![0usize; bins + 1];
        for row in &kept {
            for &(j, _) in &row.kept {
                col_start[j as usize + 1] += 1;
            }
        }
        for j in 0..bins {
            col_start[j + 1] += col_start[j];
        }
        let mut fill = col_start.clone();
        let mut entries = vec![
            CurveEntry {
                pixel: 0,
                rgb: [0.0; 3]
            };
            col_start[bins]
        ];
        let mut dropped = Vec::with_capacity(pixels);
        for (p, row) in kept.into_iter().enumerate() {
            for (j, rgb) in row.kept {
                entries[fill[j as usize]] = CurveEntry {
                    pixel: p as u32,
                    rgb,
                };
                fill[j as usize] += 1;
            }
            dropped.push(row.dropped);
        }
        Ok(Self {
            pixels,
            bins,
            col_start,
            entries,
            dropped,
        })
    }

    /// Pixels.
    pub fn pixels(&self) -> usize {
        self.pixels
    }

    /// Curve bins (= Daubechies-4 coefficients).
    pub fn bins(&self) -> usize {
        self.bins
    }

    /// Stored (pixel, coefficient) entries.
    pub fn nnz(&self) -> usize {
        self.entries.len()
    }

    /// Bytes of the stored entries (16 each: pixel index and RGB value).
    pub fn bytes(&self) -> usize {
        self.entries.len() * size_of::<CurveEntry>()
    }

    /// Per pixel and channel, the energy `Σ_{dropped j} T̂_{p,c}[j]²` that sparsification left
    /// out.
    pub fn dropped_energy(&self) -> &[[f32; 3]] {
        &self.dropped
    }

    /// The glossy image `B_p = Σ_j T̂_p[j] coefficients[j]` over every stored coefficient
    /// (pixel-major RGB, f64 accumulation): the exact path for a curve given by its
    /// Daubechies-4 coefficients. Errors on a length mismatch or a non-finite coefficient.
    pub fn image(&self, coefficients: &[f32]) -> Result<Vec<f32>, WaveletError> {
        WaveletError::check_len("curve coefficients", self.bins, coefficients.len())?;
        WaveletError::check_finite("curve coefficients", coefficients)?;
        let mut image = vec![0.0f64; 3 * self.pixels];
        let changes: Vec<(usize, f64)> = coefficients
            .iter()
            .enumerate()
            .map(|(j, &v)| (j, v as f64))
            .collect();
        self.accumulate(&changes, &mut image);
        Ok(image.into_iter().map(|v| v as f32).collect())
    }

    /// `image[p] += Σ_(j, δ) T̂_p[j] δ` over `changes`, in parallel over pixel chunks; each
    /// pixel sums in the order of `changes`, so the result is the same on any thread count.
    /// Returns the entries read.
    fn accumulate(&self, changes: &[(usize, f64)], image: &mut [f64]) -> usize {
        const CHUNK: usize = 4096;
        image
            .par_chunks_mut(3 * CHUNK)
            .enumerate()
            .for_each(|(chunk, out)| {
                let first = (chunk * CHUNK) as u32;
                let last = first + (out.len() / 3) as u32;
                for &(j, delta) in changes {
                    let column = &self.entries[self.col_start[j]..self.col_start[j + 1]];
                    let start = column.partition_point(|e| e.pixel < first);
                    let end = column.partition_point(|e| e.pixel < last);
                    for e in &column[start..end] {
                        let o = 3 * (e.pixel - first) as usize;
                        for c in 0..3 {
                            out[o + c] += e.rgb[c] as f64 * delta;
                        }
                    }
                }
            });
        changes
            .iter()
            .map(|&(j, _)| self.col_start[j + 1] - self.col_start[j])
            .sum()
    }
}

/// The BRDF-editing image engine: keeps the displayed curve's coefficients `f̃` and the glossy
/// image `B = T̂ f̃` (f64), and updates `B` from each frame's changed coefficients only.
#[derive(Debug, Clone)]
pub struct CurveRelighter {
    transport: CurveTransport,
    coefficients: Vec<f64>,
    /// The band each coefficient was last reported in (to clear replaced bands).
    bands: Vec<Option<u8>>,
    image: Vec<f64>,
    changes: Vec<(usize, f64)>,
}

impl CurveRelighter {
    /// An engine starting from `f̃ = 0` (a black glossy image).
    pub fn new(transport: CurveTransport) -> Self {
        let bins = transport.bins;
        Self {
            coefficients: vec![0.0; bins],
            bands: vec![None; bins],
            image: vec![0.0; 3 * transport.pixels],
            changes: Vec::new(),
            transport,
        }
    }

    /// The transport.
    pub fn transport(&self) -> &CurveTransport {
        &self.transport
    }

    /// The glossy image `B = T̂ f̃`, pixel-major RGB.
    pub fn image(&self) -> Vec<f32> {
        self.image.iter().map(|&v| v as f32).collect()
    }

    /// Applies one frame's update of a one-channel curve approximation: an incremental band's
    /// terms add their deltas, a replaced band is cleared and set to its terms. Only the
    /// coefficients that change are read from the transport; returns how many entries that
    /// was. Errors if the update does not fit (values per term, a coefficient out of range).
    pub fn apply(&mut self, update: &FrameUpdate) -> Result<usize, WaveletError> {
        WaveletError::check_len("update values", update.terms.len(), update.values.len())?;
        WaveletError::check_finite("update values", &update.values)?;
        if let Some(t) = update
            .terms
            .iter()
            .find(|t| t.index as usize >= self.transport.bins)
        {
            return Err(WaveletError::Invalid {
                what: "update term",
                why: format!("coefficient {} of {}", t.index, self.transport.bins),
            });
        }
        let mut next = self.coefficients.clone();
        for (b, mode) in update.modes.iter().enumerate() {
            if *mode == BandMode::Replace {
                for (v, band) in next.iter_mut().zip(&self.bands) {
                    if *band == Some(b as u8) {
                        *v = 0.0;
                    }
                }
            }
        }
        for (t, &value) in update.terms.iter().zip(&update.values) {
            let j = t.index as usize;
            let incremental = update.modes.get(t.band as usize) != Some(&BandMode::Replace);
            next[j] = if incremental {
                next[j] + value as f64
            } else {
                value as f64
            };
            self.bands[j] = Some(t.band);
        }
        self.changes.clear();
        self.changes.extend(
            next.iter()
                .zip(&self.coefficients)
                .enumerate()
                .filter(|(_, (n, o))| n != o)
                .map(|(j, (n, o))| (j, n - o)),
        );
        self.coefficients = next;
        Ok(self.transport.accumulate(&self.changes, &mut self.image))
    }
}
