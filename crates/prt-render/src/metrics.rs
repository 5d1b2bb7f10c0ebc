//! How far a render is from a reference render as a person sees them: both tone-mapped alike,
//! scored by ꟻLIP and by grey-level statistics over the surfaces.

use crate::{RenderError, Rendered, ToneMap, luminance};

/// Grey levels (of 255) beyond which a surface pixel counts as visibly off in
/// [`ImageMetrics::share_off`].
pub const VISIBLE_LEVELS: f32 = 10.0;

/// Image error of a render against a reference render of the same view, both tone-mapped by
/// the same [`ToneMap`] (the reference's exposure), over the pixels where the reference's
/// primary rays hit a surface.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImageMetrics {
    /// Mean LDR-ꟻLIP error (Andersson et al. 2020, NVIDIA's reference code through `nv-flip`,
    /// 67 pixels per degree: a 0.7 m view of a 24" 4K screen) in [0, 1].
    pub flip: f64,
    /// Mean absolute difference of the 8-bit display values, averaged over R, G and B.
    pub mean_levels: f64,
    /// Share of pixels whose difference (averaged over R, G, B) exceeds [`VISIBLE_LEVELS`].
    pub share_off: f64,
    /// [`ImageMetrics::mean_levels`] over the darkest quartile of the reference's pixels (by
    /// luminance): where dim interiors go wrong.
    pub dark_levels: f64,
    /// Median of `|L − L_ref| / max(L_ref, 1 % of the mean L_ref)` of the linear luminance.
    pub median_relative: f64,
    /// Pixels compared.
    pub pixels: usize,
}

/// Scores `test` against `reference` (same size) as [`ImageMetrics`] says.
///
/// Errors: [`RenderError::InvalidOption`] when the sizes differ.
pub fn image_metrics(
    reference: &Rendered,
    test: &Rendered,
    tone: &ToneMap,
) -> Result<ImageMetrics, RenderError> {
    if (reference.width, reference.height) != (test.width, test.height) {
        return Err(RenderError::InvalidOption {
            what: "image metrics",
            why: format!(
                "a {}×{} render against a {}×{} reference",
                test.width, test.height, reference.width, reference.height
            ),
        });
    }
    let (w, h) = (reference.width as u32, reference.height as u32);
    let (a, b) = (tone.apply(reference), tone.apply(test));
    let flip_map = nv_flip::flip(
        nv_flip::FlipImageRgb8::with_data(w, h, &a),
        nv_flip::FlipImageRgb8::with_data(w, h, &b),
        nv_flip::DEFAULT_PIXELS_PER_DEGREE,
    )
    .to_vec();
    let surface: Vec<usize> = (0..reference.pixels.len())
        .filter(|&i| reference.hit[i])
        .collect();
    let levels = |i: usize| -> f64 {
        (0..3)
            .map(|c| (f64::from(a[3 * i + c]) - f64::from(b[3 * i + c])).abs())
            .sum::<f64>()
            / 3.0
    };
    let n = surface.len().max(1) as f64;
    let mean = |indices: &[usize]| -> f64 {
        indices.iter().map(|&i| levels(i)).sum::<f64>() / indices.len().max(1) as f64
    };
    let mut by_brightness = surface.clone();
    by_brightness.sort_by(|&i, &j| {
        luminance(reference.pixels[i]).total_cmp(&luminance(reference.pixels[j]))
    });
    let dark = &by_brightness[..by_brightness.len().div_ceil(4)];
    // Pixels far darker than the view's mean (a view from inside geometry) would divide by
    // nearly zero: their error is taken relative to 1 % of the mean luminance instead.
    let floor = 0.01
        * surface
            .iter()
            .map(|&i| f64::from(luminance(reference.pixels[i])))
            .sum::<f64>()
        / n;
    let mut relative: Vec<f64> = surface
        .iter()
        .map(|&i| {
            let (r, t) = (luminance(reference.pixels[i]), luminance(test.pixels[i]));
            f64::from((t - r).abs()) / f64::from(r.abs()).max(floor).max(1e-12)
        })
        .collect();
    relative.sort_by(f64::total_cmp);
    Ok(ImageMetrics {
        flip: surface.iter().map(|&i| f64::from(flip_map[i])).sum::<f64>() / n,
        mean_levels: mean(&surface),
        share_off: surface
            .iter()
            .filter(|&&i| levels(i) > f64::from(VISIBLE_LEVELS))
            .count() as f64
            / n,
        dark_levels: mean(dark),
        median_relative: relative.get(relative.len() / 2).copied().unwrap_or(0.0),
        pixels: surface.len(),
    })
}
