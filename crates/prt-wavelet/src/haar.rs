//! Orthonormal Haar wavelets: 1D multilevel and the 2D non-standard decomposition.
//!
//! Conventions (identical to PyWavelets' `'haar'` with `mode='periodization'`, tested against it):
//! one step maps a pair `(a, b)` to the average `(a + b)/√2` and the detail `(a − b)/√2`. The 1D
//! result is laid out as `[scaling, d_coarsest, d_next (2), ..., d_finest (n/2)]`.
//!
//! The 2D non-standard decomposition (Ng, Ramamoorthi and Hanrahan 2003, after Beylkin, Coifman
//! and Rokhlin) alternates one row step and one column step per level, which for Haar is one
//! 2 × 2 block step: texels `a b / c d` become the average `(a+b+c+d)/2`, the left-minus-right
//! detail `(a−b+c−d)/2`, the top-minus-bottom detail `(a+b−c−d)/2` and the diagonal detail
//! `(a−b−c+d)/2`. At a level whose averages occupy the top-left `s × s` block, the three detail
//! blocks of the next finer level sit at `x ∈ [s, 2s), y < s` (left-minus-right),
//! `x < s, y ∈ [s, 2s)` (top-minus-bottom) and `x, y ∈ [s, 2s)` (diagonal); the single scaling
//! coefficient ends at `(0, 0)`.

use crate::WaveletError;

const FRAC_1_SQRT_2: f32 = std::f32::consts::FRAC_1_SQRT_2;

/// Full multilevel orthonormal Haar transform of `data` in place.
///
/// `data.len()` must be a power of two (1 is allowed and leaves the signal unchanged).
pub fn haar_forward(data: &mut [f32]) -> Result<(), WaveletError> {
    WaveletError::check_pow2("signal", data.len(), 1)?;
    let mut scratch = vec![0.0f32; data.len()];
    let mut n = data.len();
    while n > 1 {
        let h = n / 2;
        for k in 0..h {
            let (a, b) = (data[2 * k], data[2 * k + 1]);
            scratch[k] = (a + b) * FRAC_1_SQRT_2;
            scratch[h + k] = (a - b) * FRAC_1_SQRT_2;
        }
        data[..n].copy_from_slice(&scratch[..n]);
        n = h;
    }
    Ok(())
}

/// Inverse of [`haar_forward`], in place.
pub fn haar_inverse(data: &mut [f32]) -> Result<(), WaveletError> {
    WaveletError::check_pow2("signal", data.len(), 1)?;
    let mut scratch = vec![0.0f32; data.len()];
    let mut n = 2;
    while n <= data.len() {
        let h = n / 2;
        for k in 0..h {
            let (s, d) = (data[k], data[h + k]);
            scratch[2 * k] = (s + d) * FRAC_1_SQRT_2;
            scratch[2 * k + 1] = (s - d) * FRAC_1_SQRT_2;
        }
        data[..n].copy_from_slice(&scratch[..n]);
        n *= 2;
    }
    Ok(())
}

/// The 2D non-standard Haar decomposition of square `size × size` images (row-major), with
/// its scratch buffer allocated once so that repeated transforms do not allocate.
#[derive(Debug, Clone)]
pub struct Haar2d {
    size: usize,
    scratch: Vec<f32>,
}

impl Haar2d {
    /// A transform for `size × size` images; `size` must be a power of two (1 is allowed).
    pub fn new(size: usize) -> Result<Self, WaveletError> {
        WaveletError::check_pow2("image side", size, 1)?;
        Ok(Self {
            size,
            scratch: vec![0.0; size * size],
        })
    }

    /// The side length.
    pub fn size(&self) -> usize {
        self.size
    }

    /// Forward transform of one image in place.
    pub fn forward(&mut self, image: &mut [f32]) -> Result<(), WaveletError> {
        WaveletError::check_len("image", self.size * self.size, image.len())?;
        forward_2d(image, self.size, &mut self.scratch);
        Ok(())
    }

    /// Inverse transform of one image in place.
    pub fn inverse(&mut self, image: &mut [f32]) -> Result<(), WaveletError> {
        WaveletError::check_len("image", self.size * self.size, image.len())?;
        inverse_2d(image, self.size, &mut self.scratch);
        Ok(())
    }
}

/// Forward non-standard decomposition of an `n × n` row-major image; `scratch` (at least `n²`
/// long) receives each level's `s × s` output before it is copied back.
pub(crate) fn forward_2d(image: &mut [f32], n: usize, scratch: &mut [f32]) {
    let mut s = n;
    while s > 1 {
        let h = s / 2;
        let (out, _) = scratch.split_at_mut(s * s);
        for y in 0..h {
            let top = &image[2 * y * n..2 * y * n + s];
            let bottom = &image[(2 * y + 1) * n..(2 * y + 1) * n + s];
            let (upper, lower) = out.split_at_mut(h * s);
            let (avg, horiz) = upper[y * s..(y + 1) * s].split_at_mut(h);
            let (vert, diag) = lower[y * s..(y + 1) * s].split_at_mut(h);
            for x in 0..h {
                let (a, b) = (top[2 * x], top[2 * x + 1]);
                let (c, d) = (bottom[2 * x], bottom[2 * x + 1]);
                let (sum_top, dif_top) = (a + b, a - b);
                let (sum_bot, dif_bot) = (c + d, c - d);
                avg[x] = 0.5 * (sum_top + sum_bot);
                horiz[x] = 0.5 * (dif_top + dif_bot);
                vert[x] = 0.5 * (sum_top - sum_bot);
                diag[x] = 0.5 * (dif_top - dif_bot);
            }
        }
        for y in 0..s {
            image[y * n..y * n + s].copy_from_slice(&out[y * s..(y + 1) * s]);
        }
        s = h;
    }
}

/// Inverse of [`forward_2d`].
pub(crate) fn inverse_2d(image: &mut [f32], n: usize, scratch: &mut [f32]) {
    let mut s = 2;
    while s <= n {
        let h = s / 2;
        let (out, _) = scratch.split_at_mut(s * s);
        for y in 0..h {
            let (avg, horiz) = image[y * n..y * n + s].split_at(h);
            let (vert, diag) = image[(y + h) * n..(y + h) * n + s].split_at(h);
            let (top, bottom) = out[2 * y * s..(2 * y + 2) * s].split_at_mut(s);
            for x in 0..h {
                let (p, q, r, t) = (avg[x], horiz[x], vert[x], diag[x]);
                let (pr, qt) = (p + r, q + t);
                let (pmr, qmt) = (p - r, q - t);
                top[2 * x] = 0.5 * (pr + qt);
                top[2 * x + 1] = 0.5 * (pr - qt);
                bottom[2 * x] = 0.5 * (pmr + qmt);
                bottom[2 * x + 1] = 0.5 * (pmr - qmt);
            }
        }
        for y in 0..s {
            image[y * n..y * n + s].copy_from_slice(&out[y * s..(y + 1) * s]);
        }
        s *= 2;
    }
}

/// The band (wavelet level) of the non-standard 2D coefficient at `(x, y)`: 0 for the scaling
/// coefficient, `j ≥ 1` for the details with `max(x, y) ∈ [2^(j−1), 2^j)` (1 = coarsest).
pub fn band_of_2d(x: usize, y: usize) -> usize {
    let m = x.max(y);
    if m == 0 {
        0
    } else {
        (usize::BITS - m.leading_zeros()) as usize
    }
}
