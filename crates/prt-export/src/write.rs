//! Atomic writes of textures and JSON documents into an export folder.

use std::path::{Path, PathBuf};

use prt_texture::{Ktx2Texture, PixelFormat, Shape, write_atomic};

use prt_trace::LitVolume;

use crate::ExportError;

/// One file an export wrote.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct WrittenFile {
    /// Where it is.
    pub path: PathBuf,
    /// Its size in bytes.
    pub bytes: u64,
}

/// File name of the validity mask every export writes.
pub const VALIDITY_FILE: &str = "validity.ktx2";

pub(crate) fn prepare(folder: &Path) -> Result<(), ExportError> {
    std::fs::create_dir_all(folder).map_err(|e| {
        ExportError::invalid(
            "output folder",
            format!("cannot create {}: {e}", folder.display()),
        )
    })
}

pub(crate) fn write_bytes(
    folder: &Path,
    name: &str,
    bytes: &[u8],
) -> Result<WrittenFile, ExportError> {
    let path = folder.join(name);
    write_atomic(&path, bytes)?;
    Ok(WrittenFile {
        path,
        bytes: bytes.len() as u64,
    })
}

pub(crate) fn write_ktx2(
    folder: &Path,
    name: &str,
    texture: &Ktx2Texture,
) -> Result<WrittenFile, ExportError> {
    write_bytes(folder, name, &texture.to_bytes()?)
}

pub(crate) fn write_json(
    folder: &Path,
    name: &str,
    doc: &serde_json::Value,
) -> Result<WrittenFile, ExportError> {
    let mut text = serde_json::to_string_pretty(doc)
        .map_err(|e| ExportError::invalid("JSON document", e.to_string()))?;
    text.push('\n');
    write_bytes(folder, name, text.as_bytes())
}

/// The bake's validity mask as an R8 3D texture of the grid (1 = valid, 0 = inside geometry).
pub(crate) fn write_validity(
    folder: &Path,
    volume: &LitVolume,
) -> Result<WrittenFile, ExportError> {
    let [nx, ny, nz] = volume.dims.map(|d| d as u32);
    let values: Vec<f32> = volume
        .valid
        .iter()
        .map(|&v| if v { 1.0 } else { 0.0 })
        .collect();
    let texture = Ktx2Texture::from_f32(PixelFormat::R8Unorm, Shape::d3(nx, ny, nz), &[values])?;
    write_ktx2(folder, VALIDITY_FILE, &texture)
}

/// The grid's placement, shared by every manifest.
pub(crate) fn grid_json(volume: &LitVolume) -> serde_json::Value {
    let centres = volume.centre_box();
    serde_json::json!({
        "resolution": volume.dims,
        "bounds_min": volume.bounds.min.to_array(),
        "bounds_max": volume.bounds.max.to_array(),
        "probe_min": centres.min.to_array(),
        "probe_max": centres.max.to_array(),
        "voxel_size": volume.voxel_size().to_array(),
        "valid_voxels": volume.valid.iter().filter(|&&v| v).count(),
        "validity": VALIDITY_FILE,
    })
}
