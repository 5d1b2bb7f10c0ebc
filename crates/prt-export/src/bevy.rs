//! Bevy's irradiance volume: the ambient-cube KTX2 and its placement.

use std::path::Path;

use prt_trace::LitVolume;

use crate::textures::{AmbientCubeVolume, bevy_irradiance_volume_as};
use prt_texture::PixelFormat;
use serde_json::json;

use crate::ambient::ambient_cube;
use crate::threejs::ENGINE_PADDING;
use crate::write::{grid_json, prepare, write_json, write_ktx2, write_validity};
use crate::{AmbientCubeFit, ExportError, WrittenFile};

/// File name of the Bevy irradiance-volume texture.
pub const BEVY_TEXTURE: &str = "irradiance_volume.ktx2";
/// File name of its placement document.
pub const BEVY_PLACEMENT: &str = "irradiance_volume.json";

/// Texel format of the Bevy texture.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum BevyFormat {
    /// `E5B9G9R9_UFLOAT_PACK32`, 4 bytes per texel (Bevy's default).
    #[default]
    Rgb9e5,
    /// `R16G16B16A16_SFLOAT`, 8 bytes per texel.
    Rgba16f,
}

/// Options of [`export_bevy`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BevyConfig {
    /// Texel format.
    pub format: BevyFormat,
    /// How the six sides are fitted.
    pub fit: AmbientCubeFit,
    /// The `IrradianceVolume::intensity` written into the placement (Bevy multiplies the
    /// stored values, which are in the sky's units, by it to get cd/m²).
    pub intensity: f32,
}

impl Default for BevyConfig {
    /// RGB9E5, axis fit, intensity 1.
    fn default() -> Self {
        BevyConfig {
            format: BevyFormat::Rgb9e5,
            fit: AmbientCubeFit::Axes,
            intensity: 1.0,
        }
    }
}

/// What [`export_bevy`] wrote.
#[derive(Debug, Clone, PartialEq)]
pub struct BevyExport {
    /// The texture, the placement and the validity mask.
    pub files: Vec<WrittenFile>,
    /// Side values that were negative (SH ringing) and stored as 0.
    pub clamped: usize,
}

/// Writes `volume` as a Bevy irradiance volume into `folder`: [`BEVY_TEXTURE`] (ambient cubes
/// of `E/π`, Bevy's layout, of the volume padded by [`ENGINE_PADDING`]), [`BEVY_PLACEMENT`]
/// (the Transform that stretches Bevy's unit cube `[-½, ½]³` over the padded grid's bounds, so
/// that Bevy's light-probe weight, 0 on the cube's faces, is 1 on every surface of the baked
/// box; the intensity; the grid) and the padded grid's validity mask.
pub fn export_bevy(
    volume: &LitVolume,
    config: &BevyConfig,
    folder: &Path,
) -> Result<BevyExport, ExportError> {
    volume.check()?;
    let unpadded = volume;
    let volume = &volume.padded(ENGINE_PADDING);
    if !config.intensity.is_finite() || config.intensity < 0.0 {
        return Err(ExportError::invalid(
            "Bevy intensity",
            format!("{} (must be finite and >= 0)", config.intensity),
        ));
    }
    // Counted on the bake's own voxels, not on the padding's copies of them.
    let clamped = unpadded
        .radiance
        .iter()
        .flat_map(|l| ambient_cube(l, config.fit))
        .flatten()
        .filter(|&v| v < 0.0)
        .count();
    let mut data = Vec::with_capacity(18 * volume.voxels());
    for l in &volume.radiance {
        for side in ambient_cube(l, config.fit) {
            data.extend(side.map(|v| v.max(0.0)));
        }
    }
    let cubes = AmbientCubeVolume {
        dims: volume.dims.map(|d| d as u32),
        data,
    };
    let format = match config.format {
        BevyFormat::Rgb9e5 => PixelFormat::E5B9G9R9UfloatPack32,
        BevyFormat::Rgba16f => PixelFormat::R16G16B16A16Sfloat,
    };
    let texture = bevy_irradiance_volume_as(&cubes, format)?;
    prepare(folder)?;
    let mut files = vec![write_ktx2(folder, BEVY_TEXTURE, &texture)?];
    let placement = json!({
        "format": "prt Bevy irradiance volume placement, version 2",
        "texture": BEVY_TEXTURE,
        "texel_format": match config.format {
            BevyFormat::Rgb9e5 => "E5B9G9R9_UFLOAT_PACK32",
            BevyFormat::Rgba16f => "R16G16B16A16_SFLOAT",
        },
        "transform": {
            "translation": volume.bounds.centre().to_array(),
            "rotation": [0.0, 0.0, 0.0, 1.0],
            "scale": volume.bounds.size().to_array(),
        },
        "padding": ENGINE_PADDING,
        "bounds": {
            "min": unpadded.bounds.min.to_array(),
            "max": unpadded.bounds.max.to_array(),
        },
        "intensity": config.intensity,
        "values": "irradiance / pi of the sky-lit bake (a white Lambertian surface's exit radiance), in the sky's units",
        "fit": match config.fit {
            AmbientCubeFit::Axes => "axes",
            AmbientCubeFit::LeastSquares => "least-squares",
        },
        "grid": grid_json(volume),
    });
    files.push(write_json(folder, BEVY_PLACEMENT, &placement)?);
    files.push(write_validity(folder, volume)?);
    Ok(BevyExport { files, clamped })
}
