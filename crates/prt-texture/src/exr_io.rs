//! OpenEXR read and write through the `exr` crate: RGB / RGBA layers of f16 or f32 samples, one
//! layer per cubemap face or array slice.
//!
//! The reader first parses only the headers, checks every layer's size and the total decoded
//! bytes against a [`Limits`], and only then decodes the pixels.

use std::io::Cursor;
use std::path::Path;

use exr::prelude::{self as x, ReadChannels, ReadLayers, WritableImage};

use crate::limits::checked_product;
use crate::{Limits, TextureError};

/// Layer names used for the six faces of a cubemap, in KTX2 / Vulkan order.
pub const CUBE_FACE_NAMES: [&str; 6] = ["+X", "-X", "+Y", "-Y", "+Z", "-Z"];

/// The sample type written to an EXR file.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ExrSample {
    /// IEEE half floats (values beyond ±65504 are an error).
    F16,
    /// IEEE single floats.
    F32,
}

/// One named layer of 3 (RGB) or 4 (RGBA) channels, row-major with the top row first.
#[derive(Debug, Clone, PartialEq)]
pub struct ExrLayer {
    /// Layer name (`None` for the single unnamed layer of a plain image).
    pub name: Option<String>,
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// 3 or 4.
    pub channels: usize,
    /// `channels · width · height` values, channel-interleaved.
    pub data: Vec<f32>,
}

impl ExrLayer {
    fn check(&self) -> Result<(), TextureError> {
        if !(3..=4).contains(&self.channels) {
            return Err(TextureError::invalid(
                "EXR channels",
                format!("{} (must be 3 or 4)", self.channels),
            ));
        }
        if self.width == 0 || self.height == 0 {
            return Err(TextureError::invalid(
                "EXR layer size",
                "zero width or height",
            ));
        }
        let expected = self.channels * self.width as usize * self.height as usize;
        if self.data.len() != expected {
            return Err(TextureError::LengthMismatch {
                what: "EXR layer data",
                expected,
                got: self.data.len(),
            });
        }
        TextureError::check_finite("EXR layer data", &self.data)
    }
}

/// Encodes layers (all of the same size) as an EXR file, ZIP-compressed (lossless).
pub fn encode_exr(layers: &[ExrLayer], sample: ExrSample) -> Result<Vec<u8>, TextureError> {
    let Some(first) = layers.first() else {
        return Err(TextureError::invalid("EXR layers", "no layer"));
    };
    let mut out_layers = Vec::with_capacity(layers.len());
    for layer in layers {
        layer.check()?;
        if (layer.width, layer.height) != (first.width, first.height) {
            return Err(TextureError::invalid(
                "EXR layers",
                "layers of different sizes",
            ));
        }
        let names = ["R", "G", "B", "A"];
        let mut channels = x::SmallVec::new();
        for (c, name) in names.iter().enumerate().take(layer.channels) {
            let plane = layer.data.iter().skip(c).step_by(layer.channels).copied();
            let samples = match sample {
                ExrSample::F32 => x::FlatSamples::F32(plane.collect()),
                ExrSample::F16 => {
                    let mut halves = Vec::with_capacity(layer.data.len() / layer.channels);
                    for (i, v) in plane.enumerate() {
                        let h = x::f16::from_f32(v);
                        if h.is_infinite() {
                            return Err(TextureError::OutOfRange {
                                what: "EXR layer data (f16)",
                                index: i * layer.channels + c,
                                value: v,
                            });
                        }
                        halves.push(h);
                    }
                    x::FlatSamples::F16(halves)
                }
            };
            channels.push(x::AnyChannel::new(*name, samples));
        }
        let attributes = match &layer.name {
            Some(name) => x::LayerAttributes::named(name.as_str()),
            None => x::LayerAttributes::default(),
        };
        out_layers.push(x::Layer::new(
            (layer.width as usize, layer.height as usize),
            attributes,
            x::Encoding::SMALL_LOSSLESS,
            x::AnyChannels::sort(channels),
        ));
    }
    let size = (first.width as usize, first.height as usize);
    let image = x::Image::from_layers(
        x::ImageAttributes::new(x::IntegerBounds::from_dimensions(size)),
        out_layers,
    );
    let mut out = Cursor::new(Vec::new());
    image
        .write()
        .non_parallel()
        .to_buffered(&mut out)
        .map_err(|e| TextureError::Exr(e.to_string()))?;
    Ok(out.into_inner())
}

/// Writes layers as an EXR file, atomically.
pub fn write_exr(path: &Path, layers: &[ExrLayer], sample: ExrSample) -> Result<(), TextureError> {
    crate::write_atomic(path, &encode_exr(layers, sample)?)
}

/// Reads an EXR file (size-checked against `limits` first).
pub fn read_exr(path: &Path, limits: &Limits) -> Result<Vec<ExrLayer>, TextureError> {
    let bytes = crate::atomic::read_limited(path, limits.max_bytes)?;
    decode_exr(&bytes, limits)
}

/// Decodes every layer of an EXR file that has R, G, B (and optionally A) channels; other
/// channels are ignored, a layer without R, G and B is an `Unsupported` error. Samples of any
/// type (f16, f32, u32) are returned as `f32`. Deep data is `Unsupported`.
pub fn decode_exr(bytes: &[u8], limits: &Limits) -> Result<Vec<ExrLayer>, TextureError> {
    let meta = x::MetaData::read_from_buffered(Cursor::new(bytes), false)
        .map_err(|e| TextureError::Exr(e.to_string()))?;
    let mut total = 0u64;
    for header in &meta.headers {
        if header.deep {
            return Err(TextureError::Unsupported {
                what: "EXR",
                why: "deep data".into(),
            });
        }
        limits.check_dimension("EXR width", header.layer_size.0 as u64)?;
        limits.check_dimension("EXR height", header.layer_size.1 as u64)?;
        let layer_bytes = checked_product(
            "EXR layer bytes",
            &[
                header.layer_size.0 as u64,
                header.layer_size.1 as u64,
                header.channels.list.len() as u64,
                4,
            ],
        )?;
        total = total.saturating_add(layer_bytes);
        limits.check_bytes("decoded EXR bytes", total)?;
    }
    crate::limits::check_at_most(
        "EXR layers",
        meta.headers.len() as u64,
        u64::from(limits.max_layers),
    )?;

    let image = x::read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .all_layers()
        .all_attributes()
        .non_parallel()
        .from_buffered(Cursor::new(bytes))
        .map_err(|e| TextureError::Exr(e.to_string()))?;

    let mut out = Vec::with_capacity(image.layer_data.len());
    for layer in &image.layer_data {
        let find = |name: &str| layer.channel_data.list.iter().find(|c| c.name == *name);
        let (Some(r), Some(g), Some(b)) = (find("R"), find("G"), find("B")) else {
            return Err(TextureError::Unsupported {
                what: "EXR channels",
                why: "a layer without R, G and B channels".into(),
            });
        };
        let planes: Vec<Vec<f32>> = [Some(r), Some(g), Some(b), find("A")]
            .into_iter()
            .flatten()
            .map(|c| c.sample_data.values_as_f32().collect())
            .collect();
        let (width, height) = (layer.size.0, layer.size.1);
        let pixels = width * height;
        if planes.iter().any(|p| p.len() != pixels) {
            return Err(TextureError::malformed(
                "EXR layer",
                "channel sizes disagree with the layer size",
            ));
        }
        let channels = planes.len();
        let mut data = Vec::with_capacity(pixels * channels);
        for i in 0..pixels {
            data.extend(planes.iter().map(|p| p[i]));
        }
        out.push(ExrLayer {
            name: layer.attributes.layer_name.as_ref().map(|n| n.to_string()),
            width: width as u32,
            height: height as u32,
            channels,
            data,
        });
    }
    Ok(out)
}
