//! Quantisation of `f32` arrays to compact texel encodings, with known error bounds.
//!
//! | encoding | texel content | per-channel range | bound on abs error |
//! |---|---|---|---|
//! | [`Encoding::F32`] | the value | none | 0 |
//! | [`Encoding::F16`] | IEEE half | none | `|x|·2⁻¹¹` (normal), `2⁻²⁵` (subnormal) |
//! | [`Encoding::Unorm8`] / [`Encoding::Unorm16`] | `round((x-bias)/scale·(2ⁿ-1))` | min-max | `scale / (2·(2ⁿ-1))` |
//! | [`Encoding::Snorm8`] / [`Encoding::Snorm16`] | `round((x-bias)/scale·(2ⁿ⁻¹-1))` | centre, half-range | `scale / (2·(2ⁿ⁻¹-1))` |
//! | [`Encoding::Rgb9e5`] | shared exponent (EXT_texture_shared_exponent) | none | half a step of the shared exponent, at most `max(r,g,b)·2⁻⁸` |
//!
//! The scale/bias pair of a channel ([`ChannelRange`]) is fitted from the data (min-max), so a
//! constant channel is stored exactly (`scale = 0`). The "plus float rounding" in the bounds is a
//! few ulps of the largest magnitude of the channel: encoding and decoding run in f64 and only
//! the final value is rounded to f32.

use half::f16;
use serde::{Deserialize, Serialize};

use crate::TextureError;
use crate::format::{PixelFormat, RGB9E5_BIAS, RGB9E5_MANTISSA_BITS, exponent_of};
pub use crate::format::{RGB9E5_MAX, rgb9e5_decode, rgb9e5_encode};

/// Bound on `|x - decode(encode(x))|` for one channel `x` of an RGB9E5 triple whose largest
/// component is `max` (both in `[0, RGB9E5_MAX]`): half a step of the shared exponent, which is
/// at most `max · 2⁻⁸` (when rounding carries into the next exponent) and at least `2⁻²⁵`.
pub fn rgb9e5_error_bound(max: f32) -> f32 {
    let m = f64::from(max.clamp(0.0, RGB9E5_MAX));
    let e = if m > 0.0 {
        exponent_of(m).max(-RGB9E5_BIAS - 1)
    } else {
        -RGB9E5_BIAS - 1
    };
    // step of exponent e+1 (a carry into the next exponent doubles the step)
    (2f64.powi(e + 2 - RGB9E5_MANTISSA_BITS) * 0.5) as f32
}

/// A texel encoding for quantised arrays.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
#[non_exhaustive]
pub enum Encoding {
    /// IEEE single float, lossless.
    F32,
    /// IEEE half float, round to nearest even.
    F16,
    /// 8-bit unsigned normalised with per-channel min-max scale/bias.
    Unorm8,
    /// 8-bit signed normalised with per-channel centre/half-range scale/bias.
    Snorm8,
    /// 16-bit unsigned normalised with per-channel min-max scale/bias.
    Unorm16,
    /// 16-bit signed normalised with per-channel centre/half-range scale/bias.
    Snorm16,
    /// Shared-exponent RGB (non-negative values only), 3 channels per texel.
    Rgb9e5,
}

impl Encoding {
    /// The four-channel (three for RGB9E5) texture format that stores this encoding.
    pub fn rgba_format(self) -> PixelFormat {
        match self {
            Encoding::F32 => PixelFormat::R32G32B32A32Sfloat,
            Encoding::F16 => PixelFormat::R16G16B16A16Sfloat,
            Encoding::Unorm8 => PixelFormat::R8G8B8A8Unorm,
            Encoding::Snorm8 => PixelFormat::R8G8B8A8Snorm,
            Encoding::Unorm16 => PixelFormat::R16G16B16A16Unorm,
            Encoding::Snorm16 => PixelFormat::R16G16B16A16Snorm,
            Encoding::Rgb9e5 => PixelFormat::E5B9G9R9UfloatPack32,
        }
    }

    /// Whether values pass through a per-channel scale and bias.
    pub fn is_normalized(self) -> bool {
        matches!(
            self,
            Encoding::Unorm8 | Encoding::Snorm8 | Encoding::Unorm16 | Encoding::Snorm16
        )
    }

    /// Largest stored integer of a normalised encoding (255, 127, 65535, 32767).
    fn int_max(self) -> f64 {
        match self {
            Encoding::Unorm8 => 255.0,
            Encoding::Snorm8 => 127.0,
            Encoding::Unorm16 => 65535.0,
            Encoding::Snorm16 => 32767.0,
            _ => 1.0,
        }
    }

    fn is_signed(self) -> bool {
        matches!(self, Encoding::Snorm8 | Encoding::Snorm16)
    }
}

/// The affine map of one channel: `value = bias + scale · normalized`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ChannelRange {
    /// Multiplier of the normalised texel value.
    pub scale: f32,
    /// Offset added after scaling.
    pub bias: f32,
}

impl ChannelRange {
    /// The identity map (used by the float encodings).
    pub const IDENTITY: ChannelRange = ChannelRange {
        scale: 1.0,
        bias: 0.0,
    };

    /// Half a quantisation step of this channel under `encoding` (0 for float encodings, whose
    /// bounds are relative; see the module table).
    pub fn half_step(&self, encoding: Encoding) -> f32 {
        if encoding.is_normalized() {
            (f64::from(self.scale) / (2.0 * encoding.int_max())) as f32
        } else {
            0.0
        }
    }
}

/// A quantised array: channel-interleaved texel bytes plus what is needed to decode them.
#[derive(Debug, Clone, PartialEq)]
pub struct Quantized {
    /// The encoding of `bytes`.
    pub encoding: Encoding,
    /// Channels per element of the original array.
    pub channels: usize,
    /// Per-channel affine map (identity for float encodings and RGB9E5).
    pub ranges: Vec<ChannelRange>,
    /// Little-endian texel data, `channels` values per element.
    pub bytes: Vec<u8>,
}

/// Fits per-channel ranges and quantises `values` (`channels` interleaved values per element).
///
/// NaN/Inf is a `NonFinite` error naming its index. RGB9E5 needs `channels == 3` and values in
/// `[0, RGB9E5_MAX]`; f16 needs `|x| <= 65504`; otherwise `OutOfRange`. An empty array gives an
/// empty result with identity ranges.
pub fn quantize(
    values: &[f32],
    channels: usize,
    encoding: Encoding,
) -> Result<Quantized, TextureError> {
    let ranges = if encoding.is_normalized() {
        let mut fit = RangeFit::new(channels);
        fit.add(values);
        fit.ranges(encoding)
    } else {
        vec![ChannelRange::IDENTITY; channels]
    };
    quantize_with_ranges(values, channels, encoding, ranges)
}

/// Quantises `values` (`channels` interleaved values per element) with given per-channel
/// `ranges` (ignored by the encodings without ranges): what [`quantize`] does after fitting
/// them, for an array quantised a part at a time with the ranges of the whole ([`RangeFit`]).
/// The same errors as [`quantize`]; ranges other than one per channel.
pub fn quantize_with_ranges(
    values: &[f32],
    channels: usize,
    encoding: Encoding,
    ranges: Vec<ChannelRange>,
) -> Result<Quantized, TextureError> {
    if channels == 0 {
        return Err(TextureError::invalid("channels", "must be at least 1"));
    }
    if !values.len().is_multiple_of(channels) {
        return Err(TextureError::LengthMismatch {
            what: "quantised values (a multiple of the channel count)",
            expected: values.len().next_multiple_of(channels),
            got: values.len(),
        });
    }
    if ranges.len() != channels {
        return Err(TextureError::LengthMismatch {
            what: "channel ranges",
            expected: channels,
            got: ranges.len(),
        });
    }
    if encoding == Encoding::Rgb9e5 && channels != 3 {
        return Err(TextureError::invalid(
            "channels",
            "RGB9E5 stores exactly 3 channels",
        ));
    }
    TextureError::check_finite("quantised values", values)?;
    let bytes = match encoding {
        Encoding::F32 => values.iter().flat_map(|v| v.to_le_bytes()).collect(),
        Encoding::F16 => {
            let mut out = Vec::with_capacity(values.len() * 2);
            for (index, &v) in values.iter().enumerate() {
                let h = f16::from_f32(v);
                if h.is_infinite() {
                    return Err(TextureError::OutOfRange {
                        what: "quantised values (f16)",
                        index,
                        value: v,
                    });
                }
                out.extend_from_slice(&h.to_bits().to_le_bytes());
            }
            out
        }
        Encoding::Rgb9e5 => PixelFormat::E5B9G9R9UfloatPack32.encode(values)?,
        _ => {
            let max = encoding.int_max();
            let wide = matches!(encoding, Encoding::Unorm16 | Encoding::Snorm16);
            let mut out = Vec::with_capacity(values.len() * if wide { 2 } else { 1 });
            // value → texel: (v - bias) · (M / scale), clamped to the integer range; a
            // constant channel (scale 0) stores 0.
            let lowest = if encoding.is_signed() { -max } else { 0.0 };
            let factors: Vec<(f64, f64)> = ranges
                .iter()
                .map(|r| {
                    let factor = if r.scale == 0.0 {
                        0.0
                    } else {
                        max / f64::from(r.scale)
                    };
                    (f64::from(r.bias), factor)
                })
                .collect();
            for element in values.chunks_exact(channels) {
                for (&v, &(bias, factor)) in element.iter().zip(&factors) {
                    let q = ((f64::from(v) - bias) * factor).clamp(lowest, max).round() as i32;
                    if wide {
                        out.extend_from_slice(&(q as u16).to_le_bytes());
                    } else {
                        out.push(q as u8);
                    }
                }
            }
            out
        }
    };
    Ok(Quantized {
        encoding,
        channels,
        ranges,
        bytes,
    })
}

/// The per-channel min-max ranges [`quantize`] fits, accumulated over an array's parts in any
/// order (for [`quantize_with_ranges`]).
#[derive(Debug, Clone, PartialEq)]
pub struct RangeFit {
    lo: Vec<f64>,
    hi: Vec<f64>,
}

impl RangeFit {
    /// No values yet, `channels` per element.
    pub fn new(channels: usize) -> RangeFit {
        RangeFit {
            lo: vec![f64::INFINITY; channels],
            hi: vec![f64::NEG_INFINITY; channels],
        }
    }

    /// Adds whole elements of `values` (`channels` interleaved values each).
    pub fn add(&mut self, values: &[f32]) {
        if self.lo.is_empty() {
            return;
        }
        for element in values.chunks_exact(self.lo.len()) {
            for (c, &v) in element.iter().enumerate() {
                self.lo[c] = self.lo[c].min(f64::from(v));
                self.hi[c] = self.hi[c].max(f64::from(v));
            }
        }
    }

    /// The ranges of the values added, as `encoding` stores them (identity without values).
    pub fn ranges(&self, encoding: Encoding) -> Vec<ChannelRange> {
        let (lo, hi) = (&self.lo, &self.hi);
        (0..lo.len())
            .map(|c| {
                if lo[c] > hi[c] {
                    return ChannelRange::IDENTITY; // no elements
                }
                let (scale, bias) = if encoding.is_signed() {
                    ((hi[c] - lo[c]) * 0.5, (hi[c] + lo[c]) * 0.5)
                } else {
                    (hi[c] - lo[c], lo[c])
                };
                // Round the scale up to the next f32 so that the extreme values stay within [-1, 1].
                let mut s = scale as f32;
                if f64::from(s) < scale {
                    s = f32::from_bits(s.to_bits() + 1);
                }
                ChannelRange {
                    scale: s,
                    bias: bias as f32,
                }
            })
            .collect()
    }
}

/// Decodes a [`Quantized`] array back to `f32` values, channel-interleaved.
pub fn dequantize(q: &Quantized) -> Result<Vec<f32>, TextureError> {
    if q.ranges.len() != q.channels {
        return Err(TextureError::LengthMismatch {
            what: "channel ranges",
            expected: q.channels,
            got: q.ranges.len(),
        });
    }
    let normalized = match q.encoding {
        Encoding::F32 => PixelFormat::R32Sfloat.decode(&q.bytes)?,
        Encoding::F16 => PixelFormat::R16Sfloat.decode(&q.bytes)?,
        Encoding::Rgb9e5 => PixelFormat::E5B9G9R9UfloatPack32.decode(&q.bytes)?,
        Encoding::Unorm8 | Encoding::Snorm8 => {
            let signed = q.encoding.is_signed();
            q.bytes
                .iter()
                .map(|&b| {
                    if signed {
                        f32::from(b as i8)
                    } else {
                        f32::from(b)
                    }
                })
                .collect()
        }
        Encoding::Unorm16 | Encoding::Snorm16 => {
            if !q.bytes.len().is_multiple_of(2) {
                return Err(TextureError::LengthMismatch {
                    what: "16-bit texel bytes",
                    expected: q.bytes.len() + 1,
                    got: q.bytes.len(),
                });
            }
            let signed = q.encoding.is_signed();
            q.bytes
                .chunks_exact(2)
                .map(|b| {
                    let u = u16::from_le_bytes([b[0], b[1]]);
                    if signed {
                        f32::from(u as i16)
                    } else {
                        f32::from(u)
                    }
                })
                .collect()
        }
    };
    if normalized.len() % q.channels != 0 {
        return Err(TextureError::LengthMismatch {
            what: "decoded values (a multiple of the channel count)",
            expected: normalized.len().next_multiple_of(q.channels),
            got: normalized.len(),
        });
    }
    if !q.encoding.is_normalized() {
        return Ok(normalized);
    }
    let max = q.encoding.int_max();
    let maps: Vec<(f64, f64)> = q
        .ranges
        .iter()
        .map(|r| (f64::from(r.bias), f64::from(r.scale) / max))
        .collect();
    let mut out = normalized;
    for element in out.chunks_exact_mut(q.channels) {
        for (v, &(bias, step)) in element.iter_mut().zip(&maps) {
            // Snorm's most negative integer decodes to -1 as in Vulkan.
            let n = f64::from(*v).max(-max);
            *v = (bias + step * n) as f32;
        }
    }
    Ok(out)
}
