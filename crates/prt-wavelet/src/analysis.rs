//! Analyses of approximated lighting sequences: the per-frame area-weighted L1 error
//! (Overbeck's figure 6.2), terms per band per frame (figure 5.3, from
//! [`crate::FrameUpdate::terms_per_band`]) and the spatio-temporal band energy (figure 5.4).

use crate::WaveletError;
use crate::cubemap::{CubemapHaar, texel_solid_angles};
use crate::haar::haar_forward;

/// Measures the area-weighted L1 error `Σ Ω(t)|L̃(t) − L(t)| / Σ Ω(t)` (averaged over channels)
/// of approximated cube-map coefficients against reference texels, reconstructing in place of a
/// reused buffer.
#[derive(Debug, Clone)]
pub struct LightingError {
    haar: CubemapHaar,
    weights: Vec<f32>,
    texels: Vec<f32>,
}

impl LightingError {
    /// For `channels` planes of `size × size` faces.
    pub fn new(size: usize, channels: usize) -> Result<Self, WaveletError> {
        let plane = texel_solid_angles(size);
        let weights = plane
            .iter()
            .copied()
            .cycle()
            .take(plane.len() * channels)
            .collect();
        Ok(Self {
            haar: CubemapHaar::new(size)?,
            weights,
            texels: Vec::new(),
        })
    }

    /// The error of `coefficients` (wavelet domain) against `reference` (texels).
    pub fn error(&mut self, coefficients: &[f32], reference: &[f32]) -> Result<f64, WaveletError> {
        WaveletError::check_len(
            "approximated coefficients",
            self.weights.len(),
            coefficients.len(),
        )?;
        self.texels.clear();
        self.texels.extend_from_slice(coefficients);
        self.haar.inverse(&mut self.texels)?;
        Ok(prt_core::metrics::area_weighted_l1(
            &self.texels,
            reference,
            &self.weights,
        )?)
    }
}

/// Spatio-temporal band energy (Overbeck's figure 5.4): every coefficient's time series over
/// the frames is Haar-transformed in time, and `energy[temporal][spatial]` sums the squares of
/// the results whose temporal level is `temporal` (0 = the temporal mean, then coarse to fine)
/// and whose spatial band is `spatial`.
///
/// `frames` holds one coefficient vector per frame (a power-of-two count; all of the same
/// length, a whole number of `bands.len()`-long channel planes). By Parseval the table sums to
/// the total energy of the sequence. Energy concentrated at fine temporal levels in a spatial
/// band means that band is temporally incoherent and poorly served by incremental updates.
pub fn band_energy(frames: &[Vec<f32>], bands: &[u8]) -> Result<Vec<Vec<f64>>, WaveletError> {
    WaveletError::check_pow2("frame count", frames.len(), 1)?;
    let len = frames[0].len();
    if bands.is_empty() || !len.is_multiple_of(bands.len()) {
        return Err(WaveletError::LengthMismatch {
            what: "coefficients per frame (a multiple of the band map)",
            expected: bands.len(),
            got: len,
        });
    }
    for (t, f) in frames.iter().enumerate() {
        WaveletError::check_len("frame coefficients", len, f.len())?;
        if let Some(i) = f.iter().position(|v| !v.is_finite()) {
            return Err(WaveletError::NonFinite {
                what: "frame coefficients",
                index: t * len + i,
            });
        }
    }
    let band_count = bands.iter().map(|&b| b as usize + 1).max().unwrap_or(1);
    let temporal_levels = frames.len().trailing_zeros() as usize + 1;
    let mut energy = vec![vec![0.0f64; band_count]; temporal_levels];
    let mut series = vec![0.0f32; frames.len()];
    for i in 0..len {
        for (t, f) in frames.iter().enumerate() {
            series[t] = f[i];
        }
        haar_forward(&mut series)?;
        let band = bands[i % bands.len()] as usize;
        for (t, &v) in series.iter().enumerate() {
            let level = if t == 0 {
                0
            } else {
                (usize::BITS - t.leading_zeros()) as usize
            };
            energy[level][band] += v as f64 * v as f64;
        }
    }
    Ok(energy)
}
