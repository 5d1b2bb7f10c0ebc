//! Radiance RGBE (`.hdr`) images: reader (flat, old-style and new-style run-length encoding)
//! and writer (new-style RLE), after Greg Ward's format as documented in "Graphics Gems II"
//! (Real Pixels) and Radiance's `color.c`.
//!
//! A pixel stores three 8-bit mantissas and a shared exponent byte `E`; the value of a channel
//! is `m · 2^(E - 136)` (0 when `E = 0`). We round mantissas to nearest, so the error of a
//! channel is at most half a step, `max(r, g, b) · 2⁻⁸` (see [`rgbe_error_bound`]). Only the
//! standard `-Y height +X width` orientation (top row first) is supported.

use std::path::Path;

use crate::limits::checked_product;
use crate::{Limits, TextureError};

/// An RGB floating-point image, row-major with the top row first.
#[derive(Debug, Clone, PartialEq)]
pub struct RgbImage {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// `3 · width · height` values, channel-interleaved.
    pub data: Vec<f32>,
}

impl RgbImage {
    /// An image from its pixels; `data.len()` must be `3 · width · height`.
    pub fn new(width: u32, height: u32, data: Vec<f32>) -> Result<Self, TextureError> {
        let expected = 3 * width as usize * height as usize;
        if data.len() != expected {
            return Err(TextureError::LengthMismatch {
                what: "RGB image data",
                expected,
                got: data.len(),
            });
        }
        Ok(RgbImage {
            width,
            height,
            data,
        })
    }

    /// The pixel at column `x`, row `y` (0 = top).
    pub fn pixel(&self, x: u32, y: u32) -> [f32; 3] {
        let i = 3 * (y as usize * self.width as usize + x as usize);
        [self.data[i], self.data[i + 1], self.data[i + 2]]
    }
}

/// Encodes an RGB triple as RGBE. Negative components are clamped to 0. Pixels whose largest
/// component is below 2⁻¹²⁷ use the smallest exponent with a denormalised mantissa (down to
/// 2⁻¹³⁵); values above about 1.7·10³⁸ are clamped to the largest pixel.
pub fn rgbe_encode(rgb: [f32; 3]) -> [u8; 4] {
    let c = rgb.map(|v| f64::from(v.max(0.0)));
    let max = c[0].max(c[1]).max(c[2]);
    if max <= 0.0 {
        return [0; 4];
    }
    // max = f · 2^e with f in [0.5, 1): e = floor(log2 max) + 1, at least -127 (E = 1).
    let mut e = (((max.to_bits() >> 52) & 0x7ff) as i32 - 1022).max(-127);
    let quantize = |v: f64, e: i32| (v * 2f64.powi(8 - e) + 0.5).floor();
    if quantize(max, e) >= 256.0 {
        e += 1;
    }
    if e > 127 {
        return [255, 255, 255, 255];
    }
    let m = c.map(|v| quantize(v, e).min(255.0) as u8);
    if m == [0, 0, 0] {
        return [0; 4];
    }
    [m[0], m[1], m[2], (e + 128) as u8]
}

/// Decodes an RGBE pixel: `m · 2^(E - 136)`, black when `E = 0`.
pub fn rgbe_decode(rgbe: [u8; 4]) -> [f32; 3] {
    let scale = rgbe_scale(rgbe[3]);
    [0, 1, 2].map(|c| f32::from(rgbe[c]) * scale)
}

/// `2^(E - 136)` as f32 (0 for E = 0). Exact: the smallest, 2⁻¹³⁵, is an f32 subnormal, and an
/// 8-bit mantissa times it stays exact, so decoding in f32 equals decoding in f64.
fn rgbe_scale(e: u8) -> f32 {
    if e == 0 {
        0.0
    } else {
        2f64.powi(i32::from(e) - 136) as f32
    }
}

/// Bound on `|x - decode(encode(x))|` for a channel of a pixel whose largest component is
/// `max` (non-negative, representable): half a mantissa step, about `max · 2⁻⁸`, and never
/// less than half the smallest step, 2⁻¹³⁶.
pub fn rgbe_error_bound(max: f32) -> f32 {
    // A carry into the next exponent happens only for max >= 255.5 steps, hence 256/255.5.
    (f64::from(max) * 2f64.powi(-8) * (256.0 / 255.5) + 2f64.powi(-136)) as f32
}

/// Encodes an image as a Radiance `.hdr` file with new-style run-length encoding (scanlines
/// of 8 to 32767 pixels; other widths are written flat, as the format requires).
///
/// NaN/Inf is a typed error naming its index; negative values are clamped to 0.
pub fn encode_hdr(image: &RgbImage) -> Result<Vec<u8>, TextureError> {
    let expected = 3 * image.width as usize * image.height as usize;
    if image.data.len() != expected {
        return Err(TextureError::LengthMismatch {
            what: "RGB image data",
            expected,
            got: image.data.len(),
        });
    }
    TextureError::check_finite("HDR image data", &image.data)?;
    let mut out = format!(
        "#?RADIANCE\n# written by prt-texture\nFORMAT=32-bit_rle_rgbe\n\n-Y {} +X {}\n",
        image.height, image.width
    )
    .into_bytes();
    let w = image.width as usize;
    let rle = (8..32768).contains(&w);
    let mut planes = vec![[0u8; 4]; w];
    for row in image
        .data
        .chunks_exact(3 * w.max(1))
        .take(image.height as usize)
    {
        for (p, px) in planes.iter_mut().zip(row.chunks_exact(3)) {
            *p = rgbe_encode([px[0], px[1], px[2]]);
        }
        if rle {
            out.extend_from_slice(&[2, 2, (w >> 8) as u8, (w & 0xff) as u8]);
            for c in 0..4 {
                let channel: Vec<u8> = planes.iter().map(|p| p[c]).collect();
                rle_encode_channel(&channel, &mut out);
            }
        } else {
            for p in &planes {
                out.extend_from_slice(p);
            }
        }
    }
    Ok(out)
}

/// Run-length encodes one channel of a scanline: runs of 3..=127 equal bytes as
/// `(128 + n, byte)`, everything else as literal packets `(n, bytes...)` of 1..=128.
fn rle_encode_channel(data: &[u8], out: &mut Vec<u8>) {
    let mut i = 0;
    let mut literal_start = 0;
    while i < data.len() {
        let mut run = 1;
        while i + run < data.len() && run < 127 && data[i + run] == data[i] {
            run += 1;
        }
        if run >= 3 {
            flush_literals(&data[literal_start..i], out);
            out.extend_from_slice(&[128 + run as u8, data[i]]);
            i += run;
            literal_start = i;
        } else {
            i += run;
        }
    }
    flush_literals(&data[literal_start..], out);
}

fn flush_literals(mut data: &[u8], out: &mut Vec<u8>) {
    while !data.is_empty() {
        let n = data.len().min(128);
        out.push(n as u8);
        out.extend_from_slice(&data[..n]);
        data = &data[n..];
    }
}

/// Writes an image as a Radiance `.hdr` file, atomically.
pub fn write_hdr(path: &Path, image: &RgbImage) -> Result<(), TextureError> {
    crate::write_atomic(path, &encode_hdr(image)?)
}

/// Reads a Radiance `.hdr` file (size-checked against `limits` before reading).
pub fn read_hdr(path: &Path, limits: &Limits) -> Result<RgbImage, TextureError> {
    let bytes = crate::atomic::read_limited(path, limits.max_bytes)?;
    decode_hdr(&bytes, limits)
}

/// Longest header we accept, in bytes (real headers are a few hundred).
const MAX_HEADER: usize = 64 * 1024;

/// Decodes a Radiance `.hdr` file held in memory.
///
/// Accepts the `#?RADIANCE` / `#?RGBE` signatures, `FORMAT=32-bit_rle_rgbe` (other formats,
/// such as XYZE, are `Unsupported`), flat pixels, old-style and new-style RLE. Every run is
/// checked against the scanline before it is written, so a malformed file is a typed error.
pub fn decode_hdr(bytes: &[u8], limits: &Limits) -> Result<RgbImage, TextureError> {
    let (width, height, mut at) = parse_header(bytes)?;
    limits.check_dimension("HDR width", u64::from(width))?;
    limits.check_dimension("HDR height", u64::from(height))?;
    let pixels = checked_product("HDR pixels", &[u64::from(width), u64::from(height)])?;
    limits.check_bytes("decoded HDR bytes", pixels.saturating_mul(12))?;
    let w = width as usize;
    let mut data = Vec::with_capacity(pixels as usize * 3);
    let mut scanline = vec![[0u8; 4]; w];
    let scales: Vec<f32> = (0..=255u8).map(rgbe_scale).collect();
    for _ in 0..height {
        at = read_scanline(bytes, at, &mut scanline)?;
        for p in &scanline {
            let s = scales[usize::from(p[3])];
            data.extend_from_slice(&[
                f32::from(p[0]) * s,
                f32::from(p[1]) * s,
                f32::from(p[2]) * s,
            ]);
        }
    }
    Ok(RgbImage {
        width,
        height,
        data,
    })
}

fn truncated(needed: usize, available: usize) -> TextureError {
    TextureError::Truncated {
        what: "HDR pixel data",
        needed: needed as u64,
        available: available as u64,
    }
}

fn parse_header(bytes: &[u8]) -> Result<(u32, u32, usize), TextureError> {
    let bad = |why: &str| TextureError::malformed("HDR header", why);
    let head = &bytes[..bytes.len().min(MAX_HEADER)];
    let mut lines = head.split(|&b| b == b'\n');
    let first = lines.next().unwrap_or_default();
    if !(first.starts_with(b"#?RADIANCE") || first.starts_with(b"#?RGBE")) {
        return Err(bad("missing #?RADIANCE signature"));
    }
    let mut at = first.len() + 1;
    loop {
        let Some(line) = lines.next() else {
            return Err(bad("no blank line ends the header"));
        };
        at += line.len() + 1;
        if line.is_empty() {
            break;
        }
        if let Some(format) = line.strip_prefix(b"FORMAT=")
            && format.trim_ascii() != b"32-bit_rle_rgbe"
        {
            return Err(TextureError::Unsupported {
                what: "HDR pixel format",
                why: String::from_utf8_lossy(format).into_owned(),
            });
        }
    }
    let Some(resolution) = lines.next() else {
        return Err(bad("no resolution line"));
    };
    at += resolution.len() + 1;
    if at > bytes.len() {
        return Err(bad("no newline after the resolution line"));
    }
    let text = std::str::from_utf8(resolution).map_err(|_| bad("resolution line is not text"))?;
    let parts: Vec<&str> = text.split_ascii_whitespace().collect();
    match parts.as_slice() {
        ["-Y", h, "+X", w] => {
            let parse = |s: &str| {
                s.parse::<u32>()
                    .map_err(|_| bad("resolution is not a number"))
            };
            Ok((parse(w)?, parse(h)?, at))
        }
        [_, _, _, _] => Err(TextureError::Unsupported {
            what: "HDR orientation",
            why: text.to_owned(),
        }),
        _ => Err(bad("resolution line is not '-Y h +X w'")),
    }
}

/// Reads one scanline starting at `at`; returns the offset after it.
fn read_scanline(bytes: &[u8], mut at: usize, line: &mut [[u8; 4]]) -> Result<usize, TextureError> {
    let w = line.len();
    let get = |i: usize| {
        bytes
            .get(i)
            .copied()
            .ok_or_else(|| truncated(i + 1, bytes.len()))
    };
    let new_rle = (8..32768).contains(&w)
        && bytes.get(at..at + 2) == Some(&[2, 2])
        && bytes.get(at + 2).is_some_and(|b| b & 0x80 == 0);
    if new_rle {
        let announced = (usize::from(get(at + 2)?) << 8) | usize::from(get(at + 3)?);
        if announced != w {
            return Err(TextureError::malformed(
                "HDR scanline",
                format!("RLE scanline of {announced} pixels in an image {w} wide"),
            ));
        }
        at += 4;
        for c in 0..4 {
            let mut x = 0;
            while x < w {
                let count = usize::from(get(at)?);
                at += 1;
                if count > 128 {
                    let n = count - 128;
                    if n > w - x {
                        return Err(TextureError::malformed(
                            "HDR scanline",
                            "run overflows the scanline",
                        ));
                    }
                    let v = get(at)?;
                    at += 1;
                    line[x..x + n].iter_mut().for_each(|p| p[c] = v);
                    x += n;
                } else {
                    if count == 0 || count > w - x {
                        return Err(TextureError::malformed(
                            "HDR scanline",
                            "literal packet empty or overflowing the scanline",
                        ));
                    }
                    let src = bytes
                        .get(at..at + count)
                        .ok_or_else(|| truncated(at + count, bytes.len()))?;
                    for (p, &v) in line[x..x + count].iter_mut().zip(src) {
                        p[c] = v;
                    }
                    at += count;
                    x += count;
                }
            }
        }
        return Ok(at);
    }
    // Flat pixels, possibly with old-style runs (1, 1, 1, n) repeating the previous pixel
    // n << shift times.
    let mut x = 0;
    let mut shift = 0u32;
    while x < w {
        let px = bytes
            .get(at..at + 4)
            .ok_or_else(|| truncated(at + 4, bytes.len()))?;
        at += 4;
        if px[..3] == [1, 1, 1] {
            if x == 0 || shift > 24 {
                return Err(TextureError::malformed(
                    "HDR scanline",
                    "old-style run without a previous pixel",
                ));
            }
            let n = (usize::from(px[3])) << shift;
            if n > w - x {
                return Err(TextureError::malformed(
                    "HDR scanline",
                    "old-style run overflows the scanline",
                ));
            }
            let prev = line[x - 1];
            line[x..x + n].iter_mut().for_each(|p| *p = prev);
            x += n;
            shift += 8;
        } else {
            line[x] = [px[0], px[1], px[2], px[3]];
            x += 1;
            shift = 0;
        }
    }
    Ok(at)
}
