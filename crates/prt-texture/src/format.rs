//! Pixel formats that prt writes, with their Vulkan numbers, texel sizes, data format
//! descriptors and the conversion of texels to and from `f32`.

use half::f16;

use crate::TextureError;

/// Largest value RGB9E5 represents: `(2⁹-1)/2⁹ · 2¹⁶` = 65408.
pub const RGB9E5_MAX: f32 = 65408.0;
pub(crate) const RGB9E5_MANTISSA_BITS: i32 = 9;
pub(crate) const RGB9E5_BIAS: i32 = 15;
const RGB9E5_MAX_EXPONENT: i32 = 31;

/// Packs an RGB triple into E5B9G9R9 (R in bits 0-8, G 9-17, B 18-26, exponent 27-31).
///
/// Follows the encoding of EXT_texture_shared_exponent: components are clamped to
/// `[0, RGB9E5_MAX]` (NaN becomes 0), the shared exponent is chosen from the largest component,
/// and mantissas are rounded to nearest.
pub fn rgb9e5_encode(rgb: [f32; 3]) -> u32 {
    let clamp = |v: f32| {
        if v > 0.0 {
            v.min(RGB9E5_MAX) as f64
        } else {
            0.0
        }
    };
    let c = rgb.map(clamp);
    let max = c[0].max(c[1]).max(c[2]);
    // floor(log2(max)) from the f64 exponent field is exact, unlike log2().floor().
    let floor_log2 = if max > 0.0 {
        exponent_of(max)
    } else {
        i32::MIN / 2
    };
    let mut exp = floor_log2.max(-RGB9E5_BIAS - 1) + 1 + RGB9E5_BIAS;
    let step = |e: i32| 2f64.powi(e - RGB9E5_BIAS - RGB9E5_MANTISSA_BITS);
    if (max / step(exp) + 0.5).floor() as i64 == 1 << RGB9E5_MANTISSA_BITS {
        exp += 1;
    }
    let exp = exp.clamp(0, RGB9E5_MAX_EXPONENT);
    let m = c.map(|v| ((v / step(exp) + 0.5).floor() as u32).min(511));
    m[0] | (m[1] << 9) | (m[2] << 18) | ((exp as u32) << 27)
}

/// Unpacks an E5B9G9R9 texel: `mantissa · 2^(exponent - 24)` per channel.
pub fn rgb9e5_decode(packed: u32) -> [f32; 3] {
    let exp = (packed >> 27) as i32;
    let scale = 2f64.powi(exp - RGB9E5_BIAS - RGB9E5_MANTISSA_BITS);
    [0, 9, 18].map(|shift| (f64::from((packed >> shift) & 511) * scale) as f32)
}

pub(crate) fn exponent_of(v: f64) -> i32 {
    // v > 0 and finite here; f64 has no subnormals in RGB9E5's range.
    ((v.to_bits() >> 52) & 0x7ff) as i32 - 1023
}

/// A pixel format of a KTX2 / DDS texture that this crate reads and writes.
///
/// Names follow Vulkan's `VkFormat`. Normalised formats (`*_UNORM`, `*_SNORM`) map texel
/// integers linearly onto `[0, 1]` / `[-1, 1]`; the per-channel scale and bias that map those onto
/// physical values live in the `quant` module and in the manifest, not in the texture.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[non_exhaustive]
pub enum PixelFormat {
    /// One 8-bit unsigned normalised channel.
    R8Unorm,
    /// Four 8-bit unsigned normalised channels.
    R8G8B8A8Unorm,
    /// Four 8-bit signed normalised channels (texels -127..=127).
    R8G8B8A8Snorm,
    /// Four 16-bit unsigned normalised channels.
    R16G16B16A16Unorm,
    /// Four 16-bit signed normalised channels (texels -32767..=32767).
    R16G16B16A16Snorm,
    /// One IEEE half-float channel.
    R16Sfloat,
    /// Four IEEE half-float channels.
    R16G16B16A16Sfloat,
    /// One IEEE single-float channel.
    R32Sfloat,
    /// Four IEEE single-float channels.
    R32G32B32A32Sfloat,
    /// Three unsigned floats sharing one 5-bit exponent, 9-bit mantissas, packed in 32 bits.
    E5B9G9R9UfloatPack32,
}

/// How the integer content of a channel is interpreted.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Numeric {
    Unorm,
    Snorm,
    Sfloat,
    SharedExponent,
}

impl PixelFormat {
    /// Every supported format, for tests and tools that iterate over them.
    pub const ALL: [PixelFormat; 10] = [
        PixelFormat::R8Unorm,
        PixelFormat::R8G8B8A8Unorm,
        PixelFormat::R8G8B8A8Snorm,
        PixelFormat::R16G16B16A16Unorm,
        PixelFormat::R16G16B16A16Snorm,
        PixelFormat::R16Sfloat,
        PixelFormat::R16G16B16A16Sfloat,
        PixelFormat::R32Sfloat,
        PixelFormat::R32G32B32A32Sfloat,
        PixelFormat::E5B9G9R9UfloatPack32,
    ];

    /// The `VkFormat` enumerant stored in a KTX2 header.
    pub fn vk_format(self) -> u32 {
        match self {
            PixelFormat::R8Unorm => 9,
            PixelFormat::R8G8B8A8Unorm => 37,
            PixelFormat::R8G8B8A8Snorm => 38,
            PixelFormat::R16Sfloat => 76,
            PixelFormat::R16G16B16A16Unorm => 91,
            PixelFormat::R16G16B16A16Snorm => 92,
            PixelFormat::R16G16B16A16Sfloat => 97,
            PixelFormat::R32Sfloat => 100,
            PixelFormat::R32G32B32A32Sfloat => 109,
            PixelFormat::E5B9G9R9UfloatPack32 => 123,
        }
    }

    /// The format with the given `VkFormat` number, if this crate supports it.
    pub fn from_vk_format(vk: u32) -> Option<PixelFormat> {
        PixelFormat::ALL.into_iter().find(|f| f.vk_format() == vk)
    }

    /// Number of channels one texel decodes to (3 for RGB9E5).
    pub fn channels(self) -> usize {
        match self {
            PixelFormat::R8Unorm | PixelFormat::R16Sfloat | PixelFormat::R32Sfloat => 1,
            PixelFormat::E5B9G9R9UfloatPack32 => 3,
            _ => 4,
        }
    }

    /// Bytes of one texel.
    pub fn bytes_per_texel(self) -> usize {
        match self {
            PixelFormat::R8Unorm => 1,
            PixelFormat::R16Sfloat => 2,
            PixelFormat::R8G8B8A8Unorm
            | PixelFormat::R8G8B8A8Snorm
            | PixelFormat::R32Sfloat
            | PixelFormat::E5B9G9R9UfloatPack32 => 4,
            PixelFormat::R16G16B16A16Unorm
            | PixelFormat::R16G16B16A16Snorm
            | PixelFormat::R16G16B16A16Sfloat => 8,
            PixelFormat::R32G32B32A32Sfloat => 16,
        }
    }

    /// KTX2 `typeSize`: the size of the unit that endianness applies to.
    pub fn type_size(self) -> u32 {
        match self {
            PixelFormat::R8Unorm | PixelFormat::R8G8B8A8Unorm | PixelFormat::R8G8B8A8Snorm => 1,
            PixelFormat::R16Sfloat
            | PixelFormat::R16G16B16A16Unorm
            | PixelFormat::R16G16B16A16Snorm
            | PixelFormat::R16G16B16A16Sfloat => 2,
            PixelFormat::R32Sfloat
            | PixelFormat::R32G32B32A32Sfloat
            | PixelFormat::E5B9G9R9UfloatPack32 => 4,
        }
    }

    /// Bits of each channel (the mantissa width for RGB9E5).
    pub(crate) fn channel_bits(self) -> u32 {
        match self {
            PixelFormat::R8Unorm | PixelFormat::R8G8B8A8Unorm | PixelFormat::R8G8B8A8Snorm => 8,
            PixelFormat::R16Sfloat
            | PixelFormat::R16G16B16A16Unorm
            | PixelFormat::R16G16B16A16Snorm
            | PixelFormat::R16G16B16A16Sfloat => 16,
            PixelFormat::R32Sfloat | PixelFormat::R32G32B32A32Sfloat => 32,
            PixelFormat::E5B9G9R9UfloatPack32 => 9,
        }
    }

    pub(crate) fn numeric(self) -> Numeric {
        match self {
            PixelFormat::R8Unorm | PixelFormat::R8G8B8A8Unorm | PixelFormat::R16G16B16A16Unorm => {
                Numeric::Unorm
            }
            PixelFormat::R8G8B8A8Snorm | PixelFormat::R16G16B16A16Snorm => Numeric::Snorm,
            PixelFormat::R16Sfloat
            | PixelFormat::R16G16B16A16Sfloat
            | PixelFormat::R32Sfloat
            | PixelFormat::R32G32B32A32Sfloat => Numeric::Sfloat,
            PixelFormat::E5B9G9R9UfloatPack32 => Numeric::SharedExponent,
        }
    }

    /// The data format descriptor (KDFS 1.3 basic block) of this format, including the leading
    /// `dfdTotalSize` word, exactly as it is stored in a KTX2 file.
    ///
    /// Colour model RGBSDA, BT.709 primaries, linear transfer, straight alpha, 1x1x1x1 texel
    /// blocks, one plane. One sample per channel in ascending bit order; RGB9E5 has a mantissa
    /// and an exponent sample per channel, as in the KTX 2.0 specification's example.
    pub fn dfd_bytes(self) -> Vec<u8> {
        let samples = self.dfd_samples();
        let block_size = 24 + 16 * samples.len();
        let mut out = Vec::with_capacity(4 + block_size);
        out.extend_from_slice(&((4 + block_size) as u32).to_le_bytes());
        // vendorId 0 (Khronos) | descriptorType 0 (basic) << 17.
        out.extend_from_slice(&0u32.to_le_bytes());
        out.extend_from_slice(&DFD_VERSION.to_le_bytes());
        out.extend_from_slice(&(block_size as u16).to_le_bytes());
        out.extend_from_slice(&[
            DFD_MODEL_RGBSDA,
            DFD_PRIMARIES_BT709,
            DFD_TRANSFER_LINEAR,
            0, // flags: straight alpha
        ]);
        out.extend_from_slice(&[0, 0, 0, 0]); // texelBlockDimension - 1
        let mut planes = [0u8; 8];
        planes[0] = self.bytes_per_texel() as u8;
        out.extend_from_slice(&planes);
        for s in samples {
            out.extend_from_slice(&s.bit_offset.to_le_bytes());
            out.push(s.bit_length - 1);
            out.push(s.channel | (s.qualifiers << 4));
            out.extend_from_slice(&[0, 0, 0, 0]); // sample position
            out.extend_from_slice(&s.lower.to_le_bytes());
            out.extend_from_slice(&s.upper.to_le_bytes());
        }
        out
    }

    pub(crate) fn dfd_samples(self) -> Vec<DfdSample> {
        const CHANNEL_IDS: [u8; 4] = [0, 1, 2, 15]; // R, G, B, A of RGBSDA
        let bits = self.channel_bits();
        match self.numeric() {
            Numeric::SharedExponent => (0..3)
                .flat_map(|c| {
                    [
                        DfdSample {
                            bit_offset: 9 * c as u16,
                            bit_length: 9,
                            channel: CHANNEL_IDS[c],
                            qualifiers: 0,
                            lower: 0,
                            upper: RGB9E5_MANTISSA_UPPER,
                        },
                        DfdSample {
                            bit_offset: 27,
                            bit_length: 5,
                            channel: CHANNEL_IDS[c],
                            qualifiers: QUALIFIER_EXPONENT,
                            lower: 15,
                            upper: 31,
                        },
                    ]
                })
                .collect(),
            numeric => (0..self.channels())
                .map(|c| {
                    let (qualifiers, lower, upper) = match numeric {
                        Numeric::Unorm => (0, 0, (1u32 << bits) - 1),
                        Numeric::Snorm => {
                            let max = (1u32 << (bits - 1)) - 1;
                            (QUALIFIER_SIGNED, (max as i32).wrapping_neg() as u32, max)
                        }
                        _ => (
                            QUALIFIER_SIGNED | QUALIFIER_FLOAT,
                            (-1.0f32).to_bits(),
                            1.0f32.to_bits(),
                        ),
                    };
                    DfdSample {
                        bit_offset: (c as u32 * bits) as u16,
                        bit_length: bits as u8,
                        channel: CHANNEL_IDS[c],
                        qualifiers,
                        lower,
                        upper,
                    }
                })
                .collect(),
        }
    }

    /// Encodes `values` (channel-interleaved, `channels()` per texel) into texel bytes.
    ///
    /// Normalised formats take values already in `[0, 1]` (unorm) or `[-1, 1]` (snorm) and round
    /// to nearest; RGB9E5 takes non-negative values up to [`RGB9E5_MAX`]; f16
    /// rounds to nearest even. NaN/Inf and values outside a format's range are typed errors
    /// naming the index.
    pub fn encode(self, values: &[f32]) -> Result<Vec<u8>, TextureError> {
        let channels = self.channels();
        if !values.len().is_multiple_of(channels) {
            return Err(TextureError::LengthMismatch {
                what: "texel values (a multiple of the channel count)",
                expected: values.len().next_multiple_of(channels),
                got: values.len(),
            });
        }
        TextureError::check_finite("texel values", values)?;
        let out_of_range = |index: usize| TextureError::OutOfRange {
            what: "texel values",
            index,
            value: values[index],
        };
        let mut out = Vec::with_capacity(values.len() / channels * self.bytes_per_texel());
        match (self.numeric(), self.channel_bits()) {
            (Numeric::Unorm, bits) => {
                let max = ((1u32 << bits) - 1) as f32;
                for (i, &v) in values.iter().enumerate() {
                    if !(0.0..=1.0).contains(&v) {
                        return Err(out_of_range(i));
                    }
                    let q = (v * max).round() as u32;
                    push_int(&mut out, q, bits);
                }
            }
            (Numeric::Snorm, bits) => {
                let max = ((1u32 << (bits - 1)) - 1) as f32;
                for (i, &v) in values.iter().enumerate() {
                    if !(-1.0..=1.0).contains(&v) {
                        return Err(out_of_range(i));
                    }
                    let q = (v * max).round() as i32;
                    push_int(&mut out, q as u32, bits);
                }
            }
            (Numeric::Sfloat, 16) => {
                for (i, &v) in values.iter().enumerate() {
                    let h = f16::from_f32(v);
                    if h.is_infinite() {
                        return Err(out_of_range(i));
                    }
                    out.extend_from_slice(&h.to_bits().to_le_bytes());
                }
            }
            (Numeric::Sfloat, _) => {
                for &v in values {
                    out.extend_from_slice(&v.to_le_bytes());
                }
            }
            (Numeric::SharedExponent, _) => {
                for (t, rgb) in values.chunks_exact(3).enumerate() {
                    for (c, &v) in rgb.iter().enumerate() {
                        if !(0.0..=RGB9E5_MAX).contains(&v) {
                            return Err(out_of_range(3 * t + c));
                        }
                    }
                    let packed = rgb9e5_encode([rgb[0], rgb[1], rgb[2]]);
                    out.extend_from_slice(&packed.to_le_bytes());
                }
            }
        }
        Ok(out)
    }

    /// Decodes texel bytes into channel-interleaved `f32` values (the inverse of
    /// [`encode`](Self::encode); exact for f32, f16 and every stored integer).
    ///
    /// Snorm texels of -128 / -32768 decode to -1 as in Vulkan. A length that is not a whole
    /// number of texels is an error.
    pub fn decode(self, bytes: &[u8]) -> Result<Vec<f32>, TextureError> {
        let texel = self.bytes_per_texel();
        if !bytes.len().is_multiple_of(texel) {
            return Err(TextureError::LengthMismatch {
                what: "texel bytes (a multiple of the texel size)",
                expected: bytes.len().next_multiple_of(texel),
                got: bytes.len(),
            });
        }
        let mut out = Vec::with_capacity(bytes.len() / texel * self.channels());
        match (self.numeric(), self.channel_bits()) {
            (Numeric::Unorm, 8) => out.extend(bytes.iter().map(|&b| f32::from(b) / 255.0)),
            (Numeric::Unorm, _) => out.extend(
                bytes
                    .chunks_exact(2)
                    .map(|b| f32::from(u16::from_le_bytes([b[0], b[1]])) / 65535.0),
            ),
            (Numeric::Snorm, 8) => out.extend(
                bytes
                    .iter()
                    .map(|&b| (f32::from(b as i8) / 127.0).max(-1.0)),
            ),
            (Numeric::Snorm, _) => out.extend(
                bytes
                    .chunks_exact(2)
                    .map(|b| (f32::from(i16::from_le_bytes([b[0], b[1]])) / 32767.0).max(-1.0)),
            ),
            (Numeric::Sfloat, 16) => out.extend(
                bytes
                    .chunks_exact(2)
                    .map(|b| f16::from_bits(u16::from_le_bytes([b[0], b[1]])).to_f32()),
            ),
            (Numeric::Sfloat, _) => out.extend(
                bytes
                    .chunks_exact(4)
                    .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])),
            ),
            (Numeric::SharedExponent, _) => {
                for b in bytes.chunks_exact(4) {
                    out.extend(rgb9e5_decode(u32::from_le_bytes([b[0], b[1], b[2], b[3]])));
                }
            }
        }
        Ok(out)
    }
}

fn push_int(out: &mut Vec<u8>, value: u32, bits: u32) {
    if bits == 8 {
        out.push(value as u8);
    } else {
        out.extend_from_slice(&(value as u16).to_le_bytes());
    }
}

/// Version of the KDFS basic descriptor block that we write (KDFS 1.3).
pub(crate) const DFD_VERSION: u16 = 2;
const DFD_MODEL_RGBSDA: u8 = 1;
const DFD_PRIMARIES_BT709: u8 = 1;
const DFD_TRANSFER_LINEAR: u8 = 1;
const QUALIFIER_EXPONENT: u8 = 1 << 1;
const QUALIFIER_SIGNED: u8 = 1 << 2;
const QUALIFIER_FLOAT: u8 = 1 << 3;
/// sampleUpper of an RGB9E5 mantissa in the KTX 2.0 specification's descriptor.
const RGB9E5_MANTISSA_UPPER: u32 = 8448;

/// One sample of a basic data format descriptor block.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct DfdSample {
    pub bit_offset: u16,
    pub bit_length: u8,
    pub channel: u8,
    pub qualifiers: u8,
    pub lower: u32,
    pub upper: u32,
}
