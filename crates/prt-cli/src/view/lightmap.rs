//! The files `prt view` shows a lightmap from, which `prt lightmap` writes into its folder: the
//! scene's triangles with their lightmap UVs and materials (once, before the bake) and the
//! current irradiance (after every preview and at the end, replaced atomically), plus the small
//! state the page polls to notice a new one.
//!
//! Both are little-endian. `view_mesh.bin`: the 8 bytes `PRTLMV1\n`, the triangle count (u32),
//! the camera (10 f32: position, forward, up, vertical field of view in radians), then per
//! triangle corner 11 f32: position (3), lightmap UV (2; 0..1, origin top-left), albedo (3),
//! emission (3). `view_irradiance.bin`: the 8 bytes `PRTLMI1\n`, width, height and samples per
//! texel (u32 each), then the irradiance, RGB f32 per texel, top row first.

use std::path::Path;
use std::time::UNIX_EPOCH;

use anyhow::{Context, Result};
use prt_lightmap::{Atlas, Lightmap};
use prt_texture::write_atomic;
use prt_trace::Scene;
use prt_trace::camera::PinholeView;
use serde_json::json;

/// The scene with its lightmap UVs, as the page draws it.
pub const MESH_FILE: &str = "view_mesh.bin";
/// The latest irradiance.
pub const IRRADIANCE_FILE: &str = "view_irradiance.bin";
const MESH_MAGIC: &[u8; 8] = b"PRTLMV1\n";
const IRRADIANCE_MAGIC: &[u8; 8] = b"PRTLMI1\n";
const IRRADIANCE_HEADER: usize = 20;

/// Writes `dir/view_mesh.bin` for `scene` and its `atlas`, seen from `view`.
pub fn write_mesh(dir: &Path, scene: &Scene, atlas: &Atlas, view: &PinholeView) -> Result<()> {
    let uvs = atlas.normalized_uvs();
    let triangles = scene.triangles();
    let mut bytes = Vec::with_capacity(8 + 4 + 40 + triangles.len() * 3 * 44);
    bytes.extend_from_slice(MESH_MAGIC);
    bytes.extend_from_slice(&(triangles.len() as u32).to_le_bytes());
    let camera = [view.position, view.forward, view.up]
        .into_iter()
        .flat_map(|v| v.to_array())
        .chain([view.yfov]);
    for v in camera {
        bytes.extend_from_slice(&v.to_le_bytes());
    }
    for (t, (tri, uv)) in triangles.iter().zip(&uvs).enumerate() {
        let material = scene.material_of(t);
        for (p, q) in tri.iter().zip(uv) {
            let corner = p
                .to_array()
                .into_iter()
                .chain(q.to_array())
                .chain(material.albedo.to_array())
                .chain(material.emissive.to_array());
            for v in corner {
                bytes.extend_from_slice(&v.to_le_bytes());
            }
        }
    }
    let path = dir.join(MESH_FILE);
    write_atomic(&path, &bytes).with_context(|| format!("cannot write {}", path.display()))
}

/// Replaces `dir/view_irradiance.bin` with `lightmap`'s irradiance.
pub fn write_irradiance(dir: &Path, lightmap: &Lightmap) -> Result<()> {
    let mut bytes = Vec::with_capacity(IRRADIANCE_HEADER + 4 * lightmap.irradiance.len());
    bytes.extend_from_slice(IRRADIANCE_MAGIC);
    for v in [lightmap.width, lightmap.height, lightmap.samples_per_texel] {
        bytes.extend_from_slice(&v.to_le_bytes());
    }
    for v in &lightmap.irradiance {
        bytes.extend_from_slice(&v.to_le_bytes());
    }
    let path = dir.join(IRRADIANCE_FILE);
    write_atomic(&path, &bytes).with_context(|| format!("cannot write {}", path.display()))
}

/// Whether `dir` holds a lightmap the page can show.
pub fn is_lightmap_folder(dir: &Path) -> bool {
    dir.join(MESH_FILE).is_file()
}

/// What the page polls: the samples per texel of the current irradiance and a stamp that
/// changes with the file (its samples, modification time and length), or `null`s before the first one.
pub fn state_json(dir: &Path) -> String {
    let path = dir.join(IRRADIANCE_FILE);
    let read = || -> Option<(u32, String)> {
        let meta = std::fs::metadata(&path).ok()?;
        let modified = meta.modified().ok()?.duration_since(UNIX_EPOCH).ok()?;
        let mut head = [0u8; IRRADIANCE_HEADER];
        std::io::Read::read_exact(&mut std::fs::File::open(&path).ok()?, &mut head).ok()?;
        if &head[..8] != IRRADIANCE_MAGIC {
            return None;
        }
        let samples = u32::from_le_bytes(head[16..20].try_into().ok()?);
        let stamp = format!("{samples}-{}-{}", modified.as_nanos(), meta.len());
        Some((samples, stamp))
    };
    match read() {
        Some((samples, stamp)) => json!({ "samples": samples, "stamp": stamp }),
        None => json!({ "samples": null, "stamp": null }),
    }
    .to_string()
}
