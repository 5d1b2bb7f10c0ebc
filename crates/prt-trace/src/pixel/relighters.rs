//! Relighting a [`PixelTransport`] frame by frame with prt-wavelet's engines.

use std::time::Instant;

use prt_wavelet::{FrameUpdate, Relighter};

use crate::TraceError;

use super::PixelTransport;

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
