//! DDS output through the `ddsfile` crate, with a DX10 header: DXGI `R32G32B32A32_FLOAT`,
//! `R16G16B16A16_FLOAT` and `R9G9B9E5_SHAREDEXP`, for 2D, 2D-array, cubemap and 3D textures
//! with any number of mip levels.
//!
//! DDS orders data layer-major (every mip of layer 0, then every mip of layer 1, ...), whereas
//! KTX2 is level-major; [`encode_dds`] reorders a [`Ktx2Texture`]'s levels accordingly.

use std::path::Path;

use ddsfile::{AlphaMode, Caps2, D3D10ResourceDimension, Dds, DxgiFormat, NewDxgiParams};

use crate::ktx2::{Ktx2Texture, Shape, level_bytes};
use crate::{PixelFormat, TextureError};

/// The DXGI format for a pixel format, when DDS output supports it.
pub fn dxgi_format(format: PixelFormat) -> Option<DxgiFormat> {
    match format {
        PixelFormat::R32G32B32A32Sfloat => Some(DxgiFormat::R32G32B32A32_Float),
        PixelFormat::R16G16B16A16Sfloat => Some(DxgiFormat::R16G16B16A16_Float),
        PixelFormat::E5B9G9R9UfloatPack32 => Some(DxgiFormat::R9G9B9E5_SharedExp),
        _ => None,
    }
}

/// Encodes a texture as a DDS file (texel bytes are identical in both containers).
pub fn encode_dds(texture: &Ktx2Texture) -> Result<Vec<u8>, TextureError> {
    let format = texture.format();
    let dxgi = dxgi_format(format).ok_or_else(|| TextureError::Unsupported {
        what: "DDS format",
        why: format!("{format:?} (DDS output takes RGBA32F, RGBA16F or RGB9E5)"),
    })?;
    let shape = texture.shape();
    let Shape {
        width,
        height,
        depth,
        layers,
        faces,
    } = shape;
    if height == 0 {
        return Err(TextureError::Unsupported {
            what: "DDS shape",
            why: "1D textures".into(),
        });
    }
    let images = layers.max(1) * faces; // 2D images per level
    let levels = texture.levels();
    // ddsfile sizes its buffer in u32 arithmetic: keep the total well inside it.
    let total: u64 = levels.iter().map(|l| l.len() as u64).sum();
    crate::limits::check_at_most("DDS bytes", total, u64::from(u32::MAX) / 2)?;
    let mut dds = Dds::new_dxgi(NewDxgiParams {
        height,
        width,
        depth: (depth > 0).then_some(depth),
        format: dxgi,
        mipmap_levels: (levels.len() > 1).then_some(levels.len() as u32),
        array_layers: (images > 1).then_some(images),
        caps2: (depth > 0).then_some(Caps2::VOLUME),
        is_cubemap: faces == 6,
        resource_dimension: if depth > 0 {
            D3D10ResourceDimension::Texture3D
        } else {
            D3D10ResourceDimension::Texture2D
        },
        alpha_mode: AlphaMode::Straight,
    })
    .map_err(|e| TextureError::Dds(e.to_string()))?;
    if dds.data.len() as u64 != total {
        return Err(TextureError::Dds(format!(
            "ddsfile sized the data {} bytes, the texture has {total}",
            dds.data.len()
        )));
    }
    let mut at = 0;
    for image in 0..images as usize {
        for (level, bytes) in levels.iter().enumerate() {
            let per_image =
                (level_bytes(format, &shape, level as u32)? / u64::from(images)) as usize;
            let src = &bytes[image * per_image..(image + 1) * per_image];
            dds.data[at..at + per_image].copy_from_slice(src);
            at += per_image;
        }
    }
    let mut out = Vec::with_capacity(dds.data.len() + 148);
    dds.write(&mut out)
        .map_err(|e| TextureError::Dds(e.to_string()))?;
    Ok(out)
}

/// Writes a texture as a DDS file, atomically.
pub fn write_dds(path: &Path, texture: &Ktx2Texture) -> Result<(), TextureError> {
    crate::write_atomic(path, &encode_dds(texture)?)
}
