//! Irradiance lightmaps for engines: the scene as a GLB whose primitives carry the lightmap UVs
//! as `TEXCOORD_1`, the lightmap as an RGBA16F KTX2 in the engine's units, and a placement JSON.

use std::path::Path;

use glam::{Vec2, Vec3};
use prt_texture::{Ktx2Texture, PixelFormat, Shape};
use prt_trace::Scene;
use serde_json::json;

use crate::write::{prepare, write_bytes, write_json, write_ktx2};
use crate::{ExportError, WrittenFile};

/// File name of the scene (binary glTF) of a lightmap export.
pub const LIGHTMAP_SCENE: &str = "lightmap_scene.glb";
/// File name of the lightmap texture of a lightmap export.
pub const LIGHTMAP_TEXTURE: &str = "lightmap.ktx2";
/// File name of the placement document of a lightmap export.
pub const LIGHTMAP_PLACEMENT: &str = "lightmap.json";

/// The engine a lightmap export is for: it decides the texture's units.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LightmapEngine {
    /// Bevy's `Lightmap` component (samples `UV_1`; the pixel is `diffuse colour × texel ×
    /// StandardMaterial::lightmap_exposure`): texels store `E/π`.
    Bevy,
    /// three.js's `material.lightMap` with `lightMap.channel = 1` (samples `uv1`; the pixel is
    /// `diffuse colour / π × texel × lightMapIntensity`): texels store `E`.
    Threejs,
}

impl LightmapEngine {
    /// `bevy` or `threejs`.
    pub fn label(self) -> &'static str {
        match self {
            LightmapEngine::Bevy => "bevy",
            LightmapEngine::Threejs => "threejs",
        }
    }

    /// What a texel holds for this engine, per unit of irradiance `E`.
    pub fn scale(self) -> f32 {
        match self {
            LightmapEngine::Bevy => std::f32::consts::FRAC_1_PI,
            LightmapEngine::Threejs => 1.0,
        }
    }
}

/// An irradiance lightmap: `E` per texel, linear RGB, rows from the top (UV origin top-left).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LightmapTexels<'a> {
    /// Width in texels.
    pub width: u32,
    /// Height in texels.
    pub height: u32,
    /// `3 · width · height` values.
    pub irradiance: &'a [f32],
}

/// What [`export_lightmap`] wrote.
#[derive(Debug, Clone, PartialEq)]
pub struct LightmapExport {
    /// The scene, the texture and the placement.
    pub files: Vec<WrittenFile>,
}

/// Writes an irradiance lightmap for `engine` into `folder`: [`LIGHTMAP_SCENE`] (the scene as
/// prt sees it — flat triangles, one primitive per material with its albedo as base colour,
/// metallic 0, roughness 1 and `KHR_materials_specular` factor 0, so that the surface is the
/// Lambertian one prt baked —, positions, face normals, `TEXCOORD_1` = `uvs`, which are per
/// triangle in 0..1 with the origin top-left, and `TEXCOORD_0` the same, since glTF wants
/// texture coordinate sets numbered from 0), [`LIGHTMAP_TEXTURE`] (`R16G16B16A16_SFLOAT`,
/// `E · engine.scale()`, alpha 1) and [`LIGHTMAP_PLACEMENT`]. Vertices are not shared between
/// triangles, so UV seams and generated charts need no splitting.
///
/// Errors: UVs for other triangles, a non-finite UV or texel (naming it), a texel over f16's
/// range, a zero-sized lightmap, a write failure.
pub fn export_lightmap(
    scene: &Scene,
    uvs: &[[Vec2; 3]],
    texels: &LightmapTexels<'_>,
    engine: LightmapEngine,
    folder: &Path,
) -> Result<LightmapExport, ExportError> {
    let triangles = scene.triangles();
    if triangles.is_empty() {
        return Err(ExportError::invalid("scene", "it has no triangles"));
    }
    if uvs.len() != triangles.len() {
        return Err(ExportError::invalid(
            "lightmap UVs",
            format!("{} triangles' for {} triangles", uvs.len(), triangles.len()),
        ));
    }
    if let Some(t) = uvs.iter().position(|t| !t.iter().all(|p| p.is_finite())) {
        return Err(ExportError::invalid(
            "lightmap UVs",
            format!("triangle {t} has a non-finite UV"),
        ));
    }
    let (width, height) = (texels.width, texels.height);
    if width == 0 || height == 0 {
        return Err(ExportError::invalid(
            "lightmap size",
            format!("{width}×{height}"),
        ));
    }
    let count = 3 * width as usize * height as usize;
    if texels.irradiance.len() != count {
        return Err(ExportError::invalid(
            "lightmap texels",
            format!(
                "{} values for {width}×{height} RGB",
                texels.irradiance.len()
            ),
        ));
    }
    if let Some(i) = texels.irradiance.iter().position(|v| !v.is_finite()) {
        return Err(ExportError::invalid(
            "lightmap texels",
            format!(
                "texel ({}, {}) is not finite",
                (i / 3) % width as usize,
                i / 3 / width as usize
            ),
        ));
    }
    let scale = engine.scale();
    let rgba: Vec<f32> = texels
        .irradiance
        .chunks_exact(3)
        .flat_map(|c| [c[0] * scale, c[1] * scale, c[2] * scale, 1.0])
        .collect();
    let texture = Ktx2Texture::from_f32(
        PixelFormat::R16G16B16A16Sfloat,
        Shape::d2(width, height),
        &[rgba],
    )?;
    let glb = scene_glb(scene, uvs)?;
    let (lo, hi) = triangles
        .iter()
        .flatten()
        .fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), &p| {
            (lo.min(p), hi.max(p))
        });
    prepare(folder)?;
    let mut files = vec![
        write_bytes(folder, LIGHTMAP_SCENE, &glb)?,
        write_ktx2(folder, LIGHTMAP_TEXTURE, &texture)?,
    ];
    let (values, usage) = match engine {
        LightmapEngine::Bevy => (
            "irradiance / pi (a white Lambertian surface's exit radiance)",
            "on every mesh entity of the scene: Lightmap { image: the texture, uv_rect: (0, 0)..(1, 1), bicubic_sampling: false }; StandardMaterial::lightmap_exposure 1",
        ),
        LightmapEngine::Threejs => (
            "irradiance",
            "for every mesh of the scene: material.lightMap = the texture (KTX2Loader), lightMap.channel = 1, material.lightMapIntensity = 1",
        ),
    };
    let placement = json!({
        "format": "prt lightmap placement, version 1",
        "engine": engine.label(),
        "scene": LIGHTMAP_SCENE,
        "texture": LIGHTMAP_TEXTURE,
        "texel_format": "R16G16B16A16_SFLOAT",
        "width": width,
        "height": height,
        "uv": "TEXCOORD_1 (Bevy's UV_1, three.js's uv1), origin top-left, texel centres at (i + 0.5) / width",
        "values": values,
        "usage": usage,
        "bounds": { "min": lo.to_array(), "max": hi.to_array() },
    });
    files.push(write_json(folder, LIGHTMAP_PLACEMENT, &placement)?);
    Ok(LightmapExport { files })
}

/// The scene as a binary glTF: one mesh, one non-indexed primitive per material used.
fn scene_glb(scene: &Scene, uvs: &[[Vec2; 3]]) -> Result<Vec<u8>, ExportError> {
    let triangles = scene.triangles();
    let mut bin: Vec<u8> = Vec::new();
    let mut views = Vec::new();
    let mut accessors = Vec::new();
    let mut primitives = Vec::new();
    let mut push_view = |bin: &mut Vec<u8>, values: &[f32]| {
        let offset = bin.len();
        bin.extend(values.iter().flat_map(|v| v.to_le_bytes()));
        views.push(json!({
            "buffer": 0,
            "byteOffset": offset,
            "byteLength": 4 * values.len(),
            "target": 34962,
        }));
        views.len() - 1
    };
    for (m, _) in scene.materials().iter().enumerate() {
        let ids: Vec<usize> = (0..triangles.len())
            .filter(|&t| scene.material_ids()[t] as usize == m)
            .collect();
        if ids.is_empty() {
            continue;
        }
        let mut positions = Vec::with_capacity(9 * ids.len());
        let mut normals = Vec::with_capacity(9 * ids.len());
        let mut texcoords = Vec::with_capacity(6 * ids.len());
        let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
        for &t in &ids {
            let [a, b, c] = triangles[t];
            let n = (b - a).cross(c - a).normalize_or(Vec3::Y);
            for (p, uv) in [a, b, c].into_iter().zip(uvs[t]) {
                positions.extend(p.to_array());
                normals.extend(n.to_array());
                texcoords.extend(uv.to_array());
                lo = lo.min(p);
                hi = hi.max(p);
            }
        }
        let vertices = 3 * ids.len();
        let view = push_view(&mut bin, &positions);
        let position = push_accessor(&mut accessors, view, vertices, "VEC3", Some((lo, hi)));
        let view = push_view(&mut bin, &normals);
        let normal = push_accessor(&mut accessors, view, vertices, "VEC3", None);
        let view = push_view(&mut bin, &texcoords);
        let texcoord = push_accessor(&mut accessors, view, vertices, "VEC2", None);
        primitives.push(json!({
            "attributes": {
                "POSITION": position,
                "NORMAL": normal,
                "TEXCOORD_0": texcoord,
                "TEXCOORD_1": texcoord,
            },
            "material": m,
            "mode": 4,
        }));
    }
    let materials: Vec<_> = scene
        .materials()
        .iter()
        .map(|material| {
            let albedo = material.albedo.clamp(Vec3::ZERO, Vec3::ONE);
            let strength = material.emissive.max_element().max(1.0);
            let mut doc = json!({
                "name": material.name,
                "pbrMetallicRoughness": {
                    "baseColorFactor": [albedo.x, albedo.y, albedo.z, 1.0],
                    "metallicFactor": 0.0,
                    "roughnessFactor": 1.0,
                },
                "emissiveFactor": (material.emissive.max(Vec3::ZERO) / strength).to_array(),
                "doubleSided": material.double_sided,
                "extensions": { "KHR_materials_specular": { "specularFactor": 0.0 } },
            });
            if strength > 1.0 {
                doc["extensions"]["KHR_materials_emissive_strength"] =
                    json!({ "emissiveStrength": strength });
            }
            doc
        })
        .collect();
    if let Some(m) = scene
        .materials()
        .iter()
        .position(|m| !(m.albedo.is_finite() && m.emissive.is_finite()))
    {
        return Err(ExportError::invalid(
            "scene material",
            format!("material {m} has a non-finite albedo or emission"),
        ));
    }
    while !bin.len().is_multiple_of(4) {
        bin.push(0);
    }
    let doc = json!({
        "asset": { "version": "2.0", "generator": concat!("prt-export ", env!("CARGO_PKG_VERSION")) },
        "extensionsUsed": ["KHR_materials_specular", "KHR_materials_emissive_strength"],
        "scene": 0,
        "scenes": [{ "nodes": [0] }],
        "nodes": [{ "mesh": 0, "name": "prt lightmapped scene" }],
        "meshes": [{ "primitives": primitives }],
        "materials": materials,
        "accessors": accessors,
        "bufferViews": views,
        "buffers": [{ "byteLength": bin.len() }],
    });
    let mut text = serde_json::to_vec(&doc)
        .map_err(|e| ExportError::invalid("glTF document", e.to_string()))?;
    while !text.len().is_multiple_of(4) {
        text.push(b' ');
    }
    let total = 12 + 8 + text.len() + 8 + bin.len();
    let total = u32::try_from(total).map_err(|_| {
        ExportError::invalid("scene", format!("{total} bytes exceed a GLB's 4 GiB"))
    })?;
    let mut glb = Vec::with_capacity(total as usize);
    glb.extend(b"glTF");
    glb.extend(2u32.to_le_bytes());
    glb.extend(total.to_le_bytes());
    glb.extend((text.len() as u32).to_le_bytes());
    glb.extend(b"JSON");
    glb.extend(text);
    glb.extend((bin.len() as u32).to_le_bytes());
    glb.extend(b"BIN\0");
    glb.extend(bin);
    Ok(glb)
}

/// A float accessor over a whole buffer view; positions carry their bounds, as glTF requires.
fn push_accessor(
    accessors: &mut Vec<serde_json::Value>,
    view: usize,
    count: usize,
    kind: &str,
    bounds: Option<(Vec3, Vec3)>,
) -> usize {
    let mut accessor = json!({
        "bufferView": view,
        "componentType": 5126,
        "count": count,
        "type": kind,
    });
    if let Some((lo, hi)) = bounds {
        accessor["min"] = json!(lo.to_array());
        accessor["max"] = json!(hi.to_array());
    }
    accessors.push(accessor);
    accessors.len() - 1
}

#[cfg(test)]
mod tests {
    use super::*;
    use prt_texture::Limits;

    /// The GLB's JSON document and binary chunk.
    fn read_glb(bytes: &[u8]) -> (serde_json::Value, Vec<u8>) {
        assert_eq!(&bytes[0..4], b"glTF");
        let word = |at: usize| u32::from_le_bytes(bytes[at..at + 4].try_into().unwrap()) as usize;
        assert_eq!(word(4), 2, "GLB version");
        assert_eq!(word(8), bytes.len(), "GLB length");
        let json_len = word(12);
        assert_eq!(&bytes[16..20], b"JSON");
        let doc = serde_json::from_slice(&bytes[20..20 + json_len]).expect("JSON chunk");
        let bin_at = 20 + json_len;
        assert_eq!(&bytes[bin_at + 4..bin_at + 8], b"BIN\0");
        let bin = bytes[bin_at + 8..bin_at + 8 + word(bin_at)].to_vec();
        (doc, bin)
    }

    fn floats(doc: &serde_json::Value, bin: &[u8], accessor: usize) -> Vec<f32> {
        let view = &doc["bufferViews"]
            [doc["accessors"][accessor]["bufferView"].as_u64().unwrap() as usize];
        let at = view["byteOffset"].as_u64().unwrap() as usize;
        let len = view["byteLength"].as_u64().unwrap() as usize;
        bin[at..at + len]
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes(b.try_into().unwrap()))
            .collect()
    }

    #[test]
    fn every_triangle_keeps_its_uvs_and_each_engine_gets_its_units() {
        let scene = Scene::cornell_box();
        let n = scene.triangles().len();
        let uvs: Vec<[Vec2; 3]> = (0..n)
            .map(|t| {
                let u = t as f32 / n as f32;
                [
                    Vec2::new(u, 0.1),
                    Vec2::new(u, 0.5),
                    Vec2::new(u + 0.01, 0.9),
                ]
            })
            .collect();
        let irradiance = [1.0, 2.0, 3.0, 0.0, 0.5, 40.0];
        let texels = LightmapTexels {
            width: 2,
            height: 1,
            irradiance: &irradiance,
        };
        let dir = std::env::temp_dir().join(format!("prt-export-lightmap-{}", std::process::id()));
        for engine in [LightmapEngine::Bevy, LightmapEngine::Threejs] {
            let folder = dir.join(engine.label());
            let export = export_lightmap(&scene, &uvs, &texels, engine, &folder).unwrap();
            assert_eq!(export.files.len(), 3);
            let (doc, bin) = read_glb(&std::fs::read(folder.join(LIGHTMAP_SCENE)).unwrap());
            // Every triangle's UVs appear, as TEXCOORD_1, in its material's primitive.
            let mut seen = 0;
            for primitive in doc["meshes"][0]["primitives"].as_array().unwrap() {
                let m = primitive["material"].as_u64().unwrap() as u32;
                let got = floats(
                    &doc,
                    &bin,
                    primitive["attributes"]["TEXCOORD_1"].as_u64().unwrap() as usize,
                );
                let want: Vec<f32> = (0..n)
                    .filter(|&t| scene.material_ids()[t] == m)
                    .flat_map(|t| uvs[t].iter().flat_map(|p| p.to_array()).collect::<Vec<_>>())
                    .collect();
                assert_eq!(got, want);
                seen += got.len() / 6;
            }
            assert_eq!(seen, n);
            let texture =
                Ktx2Texture::read_file(&folder.join(LIGHTMAP_TEXTURE), &Limits::default()).unwrap();
            let stored = texture.level_f32(0).unwrap();
            for (i, &e) in irradiance.iter().enumerate() {
                let want = e * engine.scale();
                let got = stored[4 * (i / 3) + i % 3];
                assert!(
                    (got - want).abs() <= 1e-3 * want.abs(),
                    "{engine:?}: {got} for {want}"
                );
            }
            assert_eq!(stored[3], 1.0);
        }
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn mismatched_uvs_and_non_finite_texels_are_refused() {
        let scene = Scene::cornell_box();
        let irradiance = [1.0; 3];
        let texels = LightmapTexels {
            width: 1,
            height: 1,
            irradiance: &irradiance,
        };
        let folder = std::env::temp_dir().join("prt-export-lightmap-refused");
        let short = vec![[Vec2::ZERO; 3]; scene.triangles().len() - 1];
        let e = export_lightmap(&scene, &short, &texels, LightmapEngine::Bevy, &folder);
        assert!(e.unwrap_err().to_string().contains("UVs"));
        let uvs = vec![[Vec2::ZERO; 3]; scene.triangles().len()];
        let nan = [1.0, f32::NAN, 1.0];
        let bad = LightmapTexels {
            irradiance: &nan,
            ..texels
        };
        let e = export_lightmap(&scene, &uvs, &bad, LightmapEngine::Threejs, &folder);
        assert!(e.unwrap_err().to_string().contains("texel (0, 0)"));
        assert!(
            !folder.exists(),
            "nothing is written when an input is refused"
        );
    }
}
