//! The probe-volume textures engines load directly.
//!
//! * [`bevy_irradiance_volume`]: Bevy's irradiance volume (bevy_pbr's `irradiance_volume`): an
//!   ambient-cube volume of resolution (Rx, Ry, Rz) as one RGB9E5 (or RGBA16F,
//!   [`bevy_irradiance_volume_as`]) 3D texture of (Rx, 2Ry, 3Rz). The side S of voxel
//!   (x, y, z) sits at texel `s = x`, `t = y + (S negative ? Ry : 0)`,
//!   `p = z + {X: 0, Y: Rz, Z: 2Rz}`: where Bevy's shader reads it (it adds half the texture
//!   height for a negative normal component; the module's prose formula has the halves the
//!   other way round, which its shader does not follow).
//! * [`sh_l1_volume`]: L1 spherical-harmonics probe volumes (L0 + L1 per colour channel) as
//!   the three or four RGBA half-float 3D textures engines sample with hardware filtering.
//!
//! Volumes are node-major, x fastest, then y, then z; texture texel (x, y, z) is voxel
//! (x, y, z).

use prt_texture::ktx2::Shape;
use prt_texture::{Ktx2Texture, PixelFormat};

use crate::ExportError;

/// Ambient-cube sides in the order of [`AmbientCubeVolume::data`]: +X, -X, +Y, -Y, +Z, -Z.
pub const AMBIENT_CUBE_SIDES: [&str; 6] = ["+X", "-X", "+Y", "-Y", "+Z", "-Z"];

/// Ambient cubes on a grid: per voxel, six RGB colours (sides +X, -X, +Y, -Y, +Z, -Z).
#[derive(Debug, Clone, PartialEq)]
pub struct AmbientCubeVolume {
    /// Voxels along x, y, z.
    pub dims: [u32; 3],
    /// `18 · voxels` values: voxel-major, then side, then RGB.
    pub data: Vec<f32>,
}

fn voxel_count(dims: [u32; 3]) -> Result<usize, ExportError> {
    if dims.contains(&0) {
        return Err(ExportError::invalid("volume dimensions", "zero size"));
    }
    dims.iter()
        .try_fold(1usize, |n, &d| n.checked_mul(d as usize))
        .ok_or_else(|| ExportError::invalid("volume dimensions", format!("{dims:?} overflow")))
}

/// The error of `got` values where `expected` were needed.
fn length_mismatch(what: &'static str, expected: usize, got: usize) -> ExportError {
    ExportError::invalid(what, format!("{got} values, expected {expected}"))
}

/// Bevy's irradiance-volume texture: (Rx, 2Ry, 3Rz), `E5B9G9R9_UFLOAT_PACK32`.
///
/// Values must be finite, non-negative and at most [`prt_texture::quant::RGB9E5_MAX`] (typed errors
/// otherwise); each channel is then stored within [`prt_texture::quant::rgb9e5_error_bound`].
pub fn bevy_irradiance_volume(volume: &AmbientCubeVolume) -> Result<Ktx2Texture, ExportError> {
    bevy_irradiance_volume_as(volume, PixelFormat::E5B9G9R9UfloatPack32)
}

/// Bevy's irradiance-volume texture in `format`: `E5B9G9R9UfloatPack32` (as
/// [`bevy_irradiance_volume`]) or `R16G16B16A16Sfloat` (alpha 1; values must be finite and
/// within ±65504).
pub fn bevy_irradiance_volume_as(
    volume: &AmbientCubeVolume,
    format: PixelFormat,
) -> Result<Ktx2Texture, ExportError> {
    let channels = match format {
        PixelFormat::E5B9G9R9UfloatPack32 => 3,
        PixelFormat::R16G16B16A16Sfloat => 4,
        other => {
            return Err(ExportError::invalid(
                "Bevy volume format",
                format!("{other:?} (must be RGB9E5 or RGBA16F)"),
            ));
        }
    };
    let [rx, ry, rz] = volume.dims;
    let voxels = voxel_count(volume.dims)?;
    if volume.data.len() != 18 * voxels {
        return Err(length_mismatch(
            "ambient cube data",
            18 * voxels,
            volume.data.len(),
        ));
    }
    for d in [2 * u64::from(ry), 3 * u64::from(rz)] {
        if d > u64::from(u32::MAX) {
            return Err(ExportError::invalid(
                "Bevy volume texture dimension",
                format!("{d} over {}", u32::MAX),
            ));
        }
    }
    let (w, h) = (rx as usize, 2 * ry as usize);
    let mut texels = vec![1f32; channels * voxels * 6];
    for z in 0..rz as usize {
        for y in 0..ry as usize {
            for x in 0..rx as usize {
                let voxel = x + rx as usize * (y + ry as usize * z);
                for side in 0..6 {
                    let (axis, negative) = (side / 2, side % 2 == 1);
                    let t = y + if negative { ry as usize } else { 0 };
                    let p = z + axis * rz as usize;
                    let texel = x + w * (t + h * p);
                    let src = 18 * voxel + 3 * side;
                    texels[channels * texel..channels * texel + 3]
                        .copy_from_slice(&volume.data[src..src + 3]);
                }
            }
        }
    }
    Ok(Ktx2Texture::from_f32(
        format,
        Shape::d3(rx, 2 * ry, 3 * rz),
        &[texels],
    )?)
}

/// Reads an ambient-cube volume back from a Bevy irradiance-volume texture.
pub fn bevy_irradiance_volume_decode(
    texture: &Ktx2Texture,
) -> Result<AmbientCubeVolume, ExportError> {
    let s = texture.shape();
    if !s.height.is_multiple_of(2)
        || !s.depth.is_multiple_of(3)
        || s.depth == 0
        || s.layers != 0
        || s.faces != 1
    {
        return Err(ExportError::invalid(
            "Bevy irradiance volume",
            "texture is not (Rx, 2Ry, 3Rz)",
        ));
    }
    let dims = [s.width, s.height / 2, s.depth / 3];
    let voxels = voxel_count(dims)?;
    let texels = texture.level_f32(0)?;
    let channels = texture.format().channels();
    if channels < 3 {
        return Err(ExportError::invalid(
            "Bevy irradiance volume",
            "fewer than 3 channels",
        ));
    }
    let (rx, ry, rz) = (dims[0] as usize, dims[1] as usize, dims[2] as usize);
    let mut data = vec![0f32; 18 * voxels];
    for voxel in 0..voxels {
        let (x, y, z) = (voxel % rx, voxel / rx % ry, voxel / (rx * ry));
        for side in 0..6 {
            let t = y + if side % 2 == 1 { ry } else { 0 };
            let p = z + side / 2 * rz;
            let texel = x + rx * (t + 2 * ry * p);
            for c in 0..3 {
                data[18 * voxel + 3 * side + c] = texels[channels * texel + c];
            }
        }
    }
    Ok(AmbientCubeVolume { dims, data })
}

/// L1 SH on a grid: per voxel, 4 coefficients (flat index `l(l+1)+m`: L0, then the three L1)
/// of R, G and B.
#[derive(Debug, Clone, PartialEq)]
pub struct ShL1Volume {
    /// Voxels along x, y, z.
    pub dims: [u32; 3],
    /// `12 · voxels` values: voxel-major, then coefficient, then RGB.
    pub data: Vec<f32>,
}

/// How an L1 SH volume is split into RGBA textures.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ShL1Layout {
    /// Three textures (R, G, B); texel = the channel's four coefficients.
    PerChannel,
    /// Four textures (L0, L1 m=-1, L1 m=0, L1 m=+1); texel = (R, G, B, 0).
    PerCoefficient,
}

/// L1 SH probe textures in `format` (`R16G16B16A16Sfloat` or `R32G32B32A32Sfloat`).
pub fn sh_l1_volume(
    volume: &ShL1Volume,
    layout: ShL1Layout,
    format: PixelFormat,
) -> Result<Vec<Ktx2Texture>, ExportError> {
    if !matches!(
        format,
        PixelFormat::R16G16B16A16Sfloat | PixelFormat::R32G32B32A32Sfloat
    ) {
        return Err(ExportError::invalid(
            "SH volume format",
            format!("{format:?} (must be RGBA16F or RGBA32F)"),
        ));
    }
    let voxels = voxel_count(volume.dims)?;
    if volume.data.len() != 12 * voxels {
        return Err(length_mismatch(
            "SH L1 data",
            12 * voxels,
            volume.data.len(),
        ));
    }
    let count = match layout {
        ShL1Layout::PerChannel => 3,
        ShL1Layout::PerCoefficient => 4,
    };
    let shape = Shape::d3(volume.dims[0], volume.dims[1], volume.dims[2]);
    (0..count)
        .map(|t| {
            let mut texels = vec![0f32; 4 * voxels];
            for (v, texel) in texels.chunks_exact_mut(4).enumerate() {
                let src = &volume.data[12 * v..12 * v + 12];
                match layout {
                    ShL1Layout::PerChannel => (0..4).for_each(|k| texel[k] = src[3 * k + t]),
                    ShL1Layout::PerCoefficient => {
                        texel[..3].copy_from_slice(&src[3 * t..3 * t + 3])
                    }
                }
            }
            Ok(Ktx2Texture::from_f32(format, shape, &[texels])?)
        })
        .collect()
}

/// Reads an L1 SH volume back from the textures of [`sh_l1_volume`].
pub fn sh_l1_volume_decode(
    textures: &[Ktx2Texture],
    layout: ShL1Layout,
) -> Result<ShL1Volume, ExportError> {
    let count = match layout {
        ShL1Layout::PerChannel => 3,
        ShL1Layout::PerCoefficient => 4,
    };
    let Some(first) = textures.first().filter(|_| textures.len() == count) else {
        return Err(length_mismatch("SH L1 textures", count, textures.len()));
    };
    let s = first.shape();
    if s.depth == 0
        || textures
            .iter()
            .any(|t| t.shape() != s || t.format().channels() != 4)
    {
        return Err(ExportError::invalid(
            "SH L1 volume",
            "textures of different shapes or formats",
        ));
    }
    let dims = [s.width, s.height, s.depth];
    let voxels = voxel_count(dims)?;
    let mut data = vec![0f32; 12 * voxels];
    for (t, texture) in textures.iter().enumerate() {
        let texels = texture.level_f32(0)?;
        for (v, texel) in texels.chunks_exact(4).enumerate() {
            let dst = &mut data[12 * v..12 * v + 12];
            match layout {
                ShL1Layout::PerChannel => (0..4).for_each(|k| dst[3 * k + t] = texel[k]),
                ShL1Layout::PerCoefficient => dst[3 * t..3 * t + 3].copy_from_slice(&texel[..3]),
            }
        }
    }
    Ok(ShL1Volume { dims, data })
}
