//! Plain L1 / L2 SH probe volumes for custom engines and importers.

use std::path::Path;

use prt_trace::LitVolume;

use crate::textures::{ShL1Layout, ShL1Volume, sh_l1_volume};
use prt_texture::exr_io::{ExrLayer, ExrSample, encode_exr};
use prt_texture::{Ktx2Texture, PixelFormat, Shape};
use serde_json::json;

use crate::write::{grid_json, prepare, write_bytes, write_json, write_ktx2, write_validity};
use crate::{ExportError, WrittenFile};

/// Files of the L1 volume, one per colour channel (texel = L0, L1₋₁, L1₀, L1₁).
pub const SH_L1_FILES: [&str; 3] = ["sh_l1_r.ktx2", "sh_l1_g.ktx2", "sh_l1_b.ktx2"];
/// File of the L2 volume: 9 slabs along z, slab j = coefficient j, texel = (R, G, B, 1).
pub const SH_L2_FILE: &str = "sh_l2.ktx2";
/// The EXR of all 9 coefficients: one RGB layer per coefficient, z slices stacked downwards.
pub const SH_EXR_FILE: &str = "sh.exr";
/// The manifest.
pub const SH_MANIFEST: &str = "sh.json";
/// EXR layer names, in prt's coefficient order `l(l+1)+m`.
pub const SH_LAYER_NAMES: [&str; 9] = [
    "L0M0", "L1M-1", "L1M0", "L1M1", "L2M-2", "L2M-1", "L2M0", "L2M1", "L2M2",
];

/// Options of [`export_sh`] (none yet; every layout is written).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct ShConfig {}

/// What [`export_sh`] wrote.
#[derive(Debug, Clone, PartialEq)]
pub struct ShExport {
    /// Textures, EXR, manifest and validity mask.
    pub files: Vec<WrittenFile>,
}

/// The L2 texture: RGBA16F `(nx, ny, 9 nz)`, slab `j` (slices `j·nz .. (j+1)·nz`) holds
/// coefficient `j` of every voxel as `(R, G, B, 1)`.
pub fn sh_l2_texture(volume: &LitVolume) -> Result<Ktx2Texture, ExportError> {
    volume.check()?;
    let [nx, ny, nz] = volume.dims;
    let n = volume.voxels();
    let mut texels = vec![1f32; 4 * 9 * n];
    for (v, l) in volume.radiance.iter().enumerate() {
        for j in 0..9 {
            let texel = v + j * n;
            for c in 0..3 {
                texels[4 * texel + c] = l[c][j];
            }
        }
    }
    Ok(Ktx2Texture::from_f32(
        PixelFormat::R16G16B16A16Sfloat,
        Shape::d3(nx as u32, ny as u32, 9 * nz as u32),
        &[texels],
    )?)
}

/// The L1 volume (the first four coefficients of each channel) in prt_texture's layout.
pub fn sh_l1(volume: &LitVolume) -> ShL1Volume {
    let mut data = Vec::with_capacity(12 * volume.voxels());
    for l in &volume.radiance {
        for j in 0..4 {
            data.extend((0..3).map(|c| l[c][j]));
        }
    }
    ShL1Volume {
        dims: volume.dims.map(|d| d as u32),
        data,
    }
}

/// Writes `volume` as SH volumes into `folder`: [`SH_L1_FILES`], [`SH_L2_FILE`] (RGBA16F KTX2
/// 3D textures), [`SH_EXR_FILE`] (f32) and [`SH_MANIFEST`] (bounds, convention, normalisation,
/// files), plus the validity mask.
pub fn export_sh(
    volume: &LitVolume,
    _config: &ShConfig,
    folder: &Path,
) -> Result<ShExport, ExportError> {
    let l2 = sh_l2_texture(volume)?;
    let l1 = sh_l1_volume(
        &sh_l1(volume),
        ShL1Layout::PerChannel,
        PixelFormat::R16G16B16A16Sfloat,
    )?;
    let [nx, ny, nz] = volume.dims;
    let layers: Vec<ExrLayer> = SH_LAYER_NAMES
        .iter()
        .enumerate()
        .map(|(j, name)| ExrLayer {
            name: Some((*name).to_string()),
            width: nx as u32,
            height: (ny * nz) as u32,
            channels: 3,
            data: volume
                .radiance
                .iter()
                .flat_map(|l| [l[0][j], l[1][j], l[2][j]])
                .collect(),
        })
        .collect();
    let exr = encode_exr(&layers, ExrSample::F32)?;
    prepare(folder)?;
    let mut files = Vec::new();
    for (name, texture) in SH_L1_FILES.iter().zip(&l1) {
        files.push(write_ktx2(folder, name, texture)?);
    }
    files.push(write_ktx2(folder, SH_L2_FILE, &l2)?);
    files.push(write_bytes(folder, SH_EXR_FILE, &exr)?);
    let manifest = json!({
        "format": "prt SH probe volumes, version 1",
        "quantity": "incident radiance at each voxel centre, projected on real SH of order 3 (L2) per colour channel",
        "convention": "orthonormal real SH with the Condon-Shortley phase, right-handed, +Y up (glTF frame), polar axis +Y; coefficient index l(l+1)+m: 0: 0.282095, 1: -0.488603 x, 2: 0.488603 y, 3: -0.488603 z, 4: 1.092548 xz, 5: -1.092548 xy, 6: 0.315392 (3y^2-1), 7: -1.092548 yz, 8: 0.546274 (z^2-x^2)",
        "irradiance": "E(n) = sum_j A_l(j) c_j Y_j(n), A_0 = pi, A_1 = 2pi/3, A_2 = pi/4; divide by pi for a white Lambertian surface's exit radiance",
        "l1": {
            "files": SH_L1_FILES,
            "texel_format": "R16G16B16A16_SFLOAT",
            "texel": "one file per colour channel R, G, B; texel = (c0, c1, c2, c3)",
        },
        "l2": {
            "file": SH_L2_FILE,
            "texel_format": "R16G16B16A16_SFLOAT",
            "shape": [nx, ny, 9 * nz],
            "texel": "slab j (slices j*nz .. (j+1)*nz) holds coefficient j as (R, G, B, 1)",
        },
        "exr": {
            "file": SH_EXR_FILE,
            "layers": SH_LAYER_NAMES,
            "layout": "one RGB f32 layer per coefficient, width nx, height ny*nz, row y + ny*z from the top",
        },
        "grid": grid_json(volume),
    });
    files.push(write_json(folder, SH_MANIFEST, &manifest)?);
    files.push(write_validity(folder, volume)?);
    Ok(ShExport { files })
}
