//! three.js `LightProbeGrid`: the SH atlas and its placement.

use std::path::Path;

use prt_texture::{Ktx2Texture, PixelFormat, Shape};
use serde_json::json;

use prt_trace::LitVolume;

use crate::write::{grid_json, prepare, write_json, write_ktx2, write_validity};
use crate::{ExportError, WrittenFile};

/// File name of the three.js atlas.
pub const THREEJS_TEXTURE: &str = "light_probe_grid.ktx2";
/// File name of its placement document.
pub const THREEJS_PLACEMENT: &str = "light_probe_grid.json";
/// Sub-volumes of the atlas: 27 coefficients (+ one spare) in 7 RGBA texels.
pub const ATLAS_SUBVOLUMES: usize = 7;

/// prt's order-3 SH coefficients (Condon-Shortley, polar axis +Y) re-expressed in the basis
/// three.js uses (`SphericalHarmonics3`, `LightProbeGrid`): `1, y, z, x, xy, yz, 3z²−1, xz,
/// x²−y²` with positive constants. The map is orthogonal: band 0 and 1 and the `xy, yz, xz`
/// terms are signed copies; the two zonal/sectoral terms mix by a 120° rotation.
pub fn sh_to_threejs(p: &[f32; 9]) -> [f32; 9] {
    let h = 0.866_025_403_784_438_6f32; // √3 / 2
    [
        p[0],
        p[2],
        -p[3],
        -p[1],
        -p[5],
        -p[7],
        -0.5 * p[6] + h * p[8],
        p[4],
        -h * p[6] - 0.5 * p[8],
    ]
}

/// Options of [`export_threejs`] (none yet; the atlas layout is three.js's).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct ThreejsConfig {}

/// What [`export_threejs`] wrote.
#[derive(Debug, Clone, PartialEq)]
pub struct ThreejsExport {
    /// The atlas, the placement and the validity mask.
    pub files: Vec<WrittenFile>,
}

/// The atlas texels: `(nx, ny, 7 (nz + 2))` RGBA, sub-volume `t` holding values `4t..4t+4` of
/// each probe's 27 coefficients (coefficient-major, RGB within; the 28th value is 1), its first
/// and last slice repeating the nearest data slice.
pub fn threejs_atlas(volume: &LitVolume) -> Result<Ktx2Texture, ExportError> {
    volume.check()?;
    let [nx, ny, nz] = volume.dims;
    let slice = nx * ny;
    let padded = nz + 2;
    let mut texels = vec![0f32; 4 * slice * ATLAS_SUBVOLUMES * padded];
    for v in 0..volume.voxels() {
        let l = &volume.radiance[v];
        let t: [[f32; 9]; 3] = [
            sh_to_threejs(&l[0]),
            sh_to_threejs(&l[1]),
            sh_to_threejs(&l[2]),
        ];
        let mut flat = [1f32; 28];
        for k in 0..9 {
            for c in 0..3 {
                flat[3 * k + c] = t[c][k];
            }
        }
        let (xy, z) = (v % slice, v / slice);
        for sub in 0..ATLAS_SUBVOLUMES {
            let value = &flat[4 * sub..4 * sub + 4];
            let mut put = |slab: usize| {
                let texel = xy + slice * (sub * padded + slab);
                texels[4 * texel..4 * texel + 4].copy_from_slice(value);
            };
            put(z + 1);
            if z == 0 {
                put(0);
            }
            if z == nz - 1 {
                put(nz + 1);
            }
        }
    }
    let depth = ATLAS_SUBVOLUMES * padded;
    Ok(Ktx2Texture::from_f32(
        PixelFormat::R16G16B16A16Sfloat,
        Shape::d3(nx as u32, ny as u32, depth as u32),
        &[texels],
    )?)
}

/// Reads the 27 coefficients (three.js basis, per channel) of voxel `(x, y, z)` back from atlas
/// texels, by three.js's packing formula.
pub fn threejs_atlas_probe(texels: &[f32], dims: [usize; 3], voxel: [usize; 3]) -> [[f32; 9]; 3] {
    let [nx, ny, nz] = dims;
    let mut flat = [0f32; 28];
    for sub in 0..ATLAS_SUBVOLUMES {
        let slab = sub * (nz + 2) + voxel[2] + 1;
        let texel = voxel[0] + nx * (voxel[1] + ny * slab);
        flat[4 * sub..4 * sub + 4].copy_from_slice(&texels[4 * texel..4 * texel + 4]);
    }
    std::array::from_fn(|c| std::array::from_fn(|k| flat[3 * k + c]))
}

/// Voxel layers [`export_threejs`] and [`export_bevy`](crate::export_bevy) add on every side
/// of the grid ([`LitVolume::padded`]), so that every surface of the baked box lies a whole
/// voxel inside the box the engine is given.
pub const ENGINE_PADDING: usize = 1;

/// Writes `volume` as a three.js `LightProbeGrid` (three.js 0.187 and later) into `folder`:
/// [`THREEJS_TEXTURE`] (the RGBA16F 3D atlas of the volume padded by [`ENGINE_PADDING`]),
/// [`THREEJS_PLACEMENT`] (position, size and resolution of the grid: three.js ≥ 0.187 splits
/// its box into one cell per probe with the probe at the cell's centre, which is prt's voxel
/// layout, so the box is the padded grid's bounds) and the validity mask of the padded grid.
pub fn export_threejs(
    volume: &LitVolume,
    _config: &ThreejsConfig,
    folder: &Path,
) -> Result<ThreejsExport, ExportError> {
    volume.check()?;
    let padded = volume.padded(ENGINE_PADDING);
    let atlas = threejs_atlas(&padded)?;
    prepare(folder)?;
    let mut files = vec![write_ktx2(folder, THREEJS_TEXTURE, &atlas)?];
    let placement = json!({
        "format": "prt three.js LightProbeGrid placement, version 2",
        "three": ">= 0.187 (one cell per probe, probes at cell centres)",
        "texture": THREEJS_TEXTURE,
        "position": padded.bounds.centre().to_array(),
        "size": padded.bounds.size().to_array(),
        "resolution": padded.dims,
        "padding": ENGINE_PADDING,
        "bounds": {
            "min": volume.bounds.min.to_array(),
            "max": volume.bounds.max.to_array(),
        },
        "atlas": {
            "shape": [padded.dims[0], padded.dims[1], ATLAS_SUBVOLUMES * (padded.dims[2] + 2)],
            "texel_format": "R16G16B16A16_SFLOAT",
            "packing": "sub-volume t (nz + 2 slices, first and last repeat the edge slice) holds values 4t..4t+3 of c0.rgb c1.rgb ... c8.rgb 1",
            "coefficients": "radiance SH in three.js's basis: 1, y, z, x, xy, yz, 3z^2-1, xz, x^2-y^2",
        },
        "grid": grid_json(&padded),
    });
    files.push(write_json(folder, THREEJS_PLACEMENT, &placement)?);
    files.push(write_validity(folder, &padded)?);
    Ok(ThreejsExport { files })
}
