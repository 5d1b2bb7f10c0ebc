//! # prt-texture — texture formats for precomputed light transport
#![deny(missing_docs)]

mod atomic;
pub mod container;
pub mod dds;
pub mod engine;
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
pub use quant::{ChannelRange, Encoding, Quantized, dequantize, quantize};
