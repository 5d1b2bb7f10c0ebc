//! # prt-texture — texture formats for precomputed light transport
//!
//! Everything prt writes for engines, and everything it reads from disk, goes through this
//! crate. It knows no basis and no solver: it stores named, typed arrays.
//!
//! | module | what |
//! |---|---|
//! | [`ktx2`] | KTX 2.0 writer and reader (our own; Khronos KTX 2.0 spec + Khronos Data Format Specification 1.3 descriptors) |
//! | [`format`](mod@format) | the pixel formats, their `VkFormat` numbers, DFDs and texel encode/decode |
//! | [`quant`] | f16, unorm/snorm 8/16 with per-channel scale/bias, RGB9E5 — with error bounds |
//! | [`exr_io`] | OpenEXR through the `exr` crate (RGB/RGBA, f16/f32, layers) |
//! | [`hdr`] | Radiance RGBE (`.hdr`) read (flat, old and new RLE) and write (new RLE) |
//! | [`dds`] | DDS output through `ddsfile` (DXGI RGBA32F, RGBA16F, RGB9E5) |
//! | [`container`] | the prt container: versioned JSON manifest + one KTX2 texture per array (MBD models) |
//!
//! ## Method
//! * **KTX2** files are laid out as the specification prescribes (header, level index, DFD,
//!   sorted key/value data, levels from smallest to largest aligned to lcm(texel size, 4)); the
//!   DFD of each format is byte-identical to the one the `ktx2` crate generates (tested), and
//!   every file we write parses with that crate with identical contents.
//! * **Quantisation** of a channel with range `[lo, hi]` stores `round((x - bias)/scale · M)`
//!   with `M = 2ⁿ-1` (unorm; `bias = lo`, `scale = hi - lo`) or `M = 2ⁿ⁻¹-1` (snorm; centre and
//!   half-range), so the error is at most half a step, `scale / 2M`, plus f32 rounding.
//!   RGB9E5 follows EXT_texture_shared_exponent (error at most half a step of the shared
//!   exponent, `≤ max(r,g,b)·2⁻⁸`); RGBE (Ward, "Real Pixels", Graphics Gems II, 1991) the
//!   same with 8-bit mantissas.
//! * **The container** stores a Moving Basis Decomposition model (Silvennoinen & Sloan, EGSR
//!   2021) as a coefficient grid (L channels packed in RGBA 3D textures) and a basis grid
//!   (D x L per node), with the kernels and quantisation parameters in the manifest; bytes per
//!   voxel are counted from the files actually written.
//!
//! ## Untrusted input
//! Every reader takes a [`Limits`] and checks each size, count and offset against it and
//! against the input length before allocating; malformed files give a typed
//! [`TextureError`], never a panic or a huge allocation. The readers are fuzzed (`fuzz/`) and a
//! corpus of malformed files is tested. Writers write a temporary file and rename it
//! ([`write_atomic`]). NaN/Inf in data to be written is an error naming its index.
//!
//! ```
//! use prt_texture::container::{ArrayLayout, Container, GridArray, LoadedContainer};
//! use prt_texture::{Encoding, Limits};
//!
//! // A 4x4x4 grid of 6 coefficients, stored as 16-bit unorm with per-channel ranges.
//! let values: Vec<f32> = (0..64 * 6).map(|i| (i % 7) as f32 - 3.0).collect();
//! let mut container = Container::default();
//! container.arrays.push((
//!     "coefficients".into(),
//!     GridArray::new([4, 4, 4], 6, values.clone())?,
//!     Encoding::Unorm16,
//!     ArrayLayout::Volume,
//! ));
//! let (manifest, files) = container.encode()?;
//! let json = manifest.to_json()?;
//! let back = LoadedContainer::decode(&json, &Limits::default(), |_| Ok(files[0].1.clone()))?;
//! let step = 6.0 / 65535.0; // range 6 over 65535 steps
//! for (a, b) in values.iter().zip(&back.arrays[0].1.data) {
//!     assert!((a - b).abs() <= 0.5 * step + 1e-5);
//! }
//! # Ok::<(), prt_texture::TextureError>(())
//! ```
#![deny(missing_docs)]

mod atomic;
mod bricks;
pub mod container;
pub mod dds;
mod error;
pub mod exr_io;
pub mod format;
pub mod hdr;
pub mod ktx2;
mod limits;
pub mod quant;

pub use atomic::{write_atomic, write_atomic_with};
pub use error::TextureError;
pub use format::PixelFormat;
pub use ktx2::{Ktx2Texture, Shape};
pub use limits::Limits;
pub use quant::{
    ChannelRange, Encoding, Quantized, RangeFit, dequantize, quantize, quantize_with_ranges,
};
