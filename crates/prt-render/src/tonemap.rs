//! From linear radiance to display values: exposure, the ACES filmic curve, sRGB.

use crate::Rendered;

/// Middle grey: the display value [`ToneMap::auto`] maps the log-average luminance to.
pub const MIDDLE_GREY: f32 = 0.18;

/// A tone map: `display = srgb(aces(exposure · radiance))` per channel, where `aces` is
/// Narkowicz's fit of the ACES filmic curve, `x (2.51 x + 0.03) / (x (2.43 x + 0.59) + 0.14)`
/// clamped to [0, 1], and `srgb` the sRGB transfer function (IEC 61966-2-1).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ToneMap {
    /// Linear factor applied to the radiance first.
    pub exposure: f32,
}

impl ToneMap {
    /// The exposure that maps the log-average luminance (Rec. 709 weights) of the pixels that
    /// hit the scene to [`MIDDLE_GREY`] (Reinhard et al. 2002's key); exposure 1 for an image
    /// without a lit hit.
    pub fn auto(image: &Rendered) -> ToneMap {
        let (sum, count) = image
            .pixels
            .iter()
            .zip(&image.hit)
            .filter(|(_, hit)| **hit)
            .map(|(p, _)| luminance(*p))
            .filter(|&l| l > 0.0 && l.is_finite())
            .fold((0.0f64, 0usize), |(s, n), l| (s + f64::from(l).ln(), n + 1));
        if count == 0 {
            return ToneMap { exposure: 1.0 };
        }
        let log_average = (sum / count as f64).exp() as f32;
        ToneMap {
            exposure: MIDDLE_GREY / log_average,
        }
    }

    /// Display value in [0, 1] of one linear channel value.
    pub fn display(&self, v: f32) -> f32 {
        let x = (v * self.exposure).max(0.0);
        let filmic = (x * (2.51 * x + 0.03)) / (x * (2.43 * x + 0.59) + 0.14);
        let c = if filmic.is_nan() {
            0.0
        } else {
            filmic.clamp(0.0, 1.0)
        };
        if c <= 0.003_130_8 {
            12.92 * c
        } else {
            1.055 * c.powf(1.0 / 2.4) - 0.055
        }
    }

    /// The image as 8-bit sRGB, row-major RGB bytes.
    pub fn apply(&self, image: &Rendered) -> Vec<u8> {
        image
            .pixels
            .iter()
            .flatten()
            .map(|&v| (self.display(v) * 255.0).round() as u8)
            .collect()
    }
}

/// Rec. 709 luminance of linear RGB.
pub fn luminance(rgb: [f32; 3]) -> f32 {
    0.2126 * rgb[0] + 0.7152 * rgb[1] + 0.0722 * rgb[2]
}
