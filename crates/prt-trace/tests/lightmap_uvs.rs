//! glTF `TEXCOORD_1` becomes the scene's lightmap UVs, per kept triangle and in its winding.

use glam::Vec2;
use prt_trace::{LoadOptions, Scene};

/// A GLB of one primitive: two triangles (the second degenerate), with TEXCOORD_1 when
/// `with_uv1`, and the node's transform mirrored when `mirrored`.
fn glb(with_uv1: bool, mirrored: bool) -> Vec<u8> {
    let positions: [[f32; 3]; 4] = [
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [2.0, 0.0, 0.0],
    ];
    let uvs: [[f32; 2]; 4] = [[0.1, 0.2], [0.3, 0.4], [0.5, 0.6], [0.7, 0.8]];
    let indices: [u16; 6] = [0, 1, 2, 0, 1, 3];
    let mut bin: Vec<u8> = positions
        .iter()
        .flatten()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    bin.extend(uvs.iter().flatten().flat_map(|v| v.to_le_bytes()));
    bin.extend(indices.iter().flat_map(|v| v.to_le_bytes()));
    while !bin.len().is_multiple_of(4) {
        bin.push(0);
    }
    let attributes = if with_uv1 {
        r#""POSITION": 0, "TEXCOORD_1": 1"#
    } else {
        r#""POSITION": 0"#
    };
    let scale = if mirrored {
        r#", "scale": [-1, 1, 1]"#
    } else {
        ""
    };
    let json = format!(
        r#"{{"asset": {{"version": "2.0"}}, "scene": 0, "scenes": [{{"nodes": [0]}}],
        "nodes": [{{"mesh": 0{scale}}}],
        "meshes": [{{"primitives": [{{"attributes": {{{attributes}}}, "indices": 2}}]}}],
        "buffers": [{{"byteLength": {len}}}],
        "bufferViews": [{{"buffer": 0, "byteOffset": 0, "byteLength": 48}},
                        {{"buffer": 0, "byteOffset": 48, "byteLength": 32}},
                        {{"buffer": 0, "byteOffset": 80, "byteLength": 12}}],
        "accessors": [
          {{"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3", "min": [0, 0, 0], "max": [2, 1, 0]}},
          {{"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC2"}},
          {{"bufferView": 2, "componentType": 5123, "count": 6, "type": "SCALAR"}}]}}"#,
        len = bin.len()
    );
    let mut json = json.into_bytes();
    while !json.len().is_multiple_of(4) {
        json.push(b' ');
    }
    let total = 12 + 8 + json.len() + 8 + bin.len();
    let mut out = Vec::with_capacity(total);
    out.extend(b"glTF");
    out.extend(2u32.to_le_bytes());
    out.extend((total as u32).to_le_bytes());
    out.extend((json.len() as u32).to_le_bytes());
    out.extend(b"JSON");
    out.extend(json);
    out.extend((bin.len() as u32).to_le_bytes());
    out.extend(b"BIN\0");
    out.extend(bin);
    out
}

#[test]
fn texcoord_1_follows_the_kept_triangles() {
    let scene = Scene::load_gltf_slice(&glb(true, false), None, &LoadOptions::default()).unwrap();
    assert_eq!(scene.triangles().len(), 1);
    assert_eq!(scene.degenerate_dropped(), 1);
    let uvs = scene.lightmap_uvs().expect("TEXCOORD_1 present");
    assert_eq!(
        uvs,
        [[
            Vec2::new(0.1, 0.2),
            Vec2::new(0.3, 0.4),
            Vec2::new(0.5, 0.6)
        ]]
    );
    // A mirroring node swaps two corners of the triangle and of its UVs alike.
    let scene = Scene::load_gltf_slice(&glb(true, true), None, &LoadOptions::default()).unwrap();
    assert_eq!(
        scene.lightmap_uvs().unwrap(),
        [[
            Vec2::new(0.1, 0.2),
            Vec2::new(0.5, 0.6),
            Vec2::new(0.3, 0.4)
        ]]
    );
    assert_eq!(scene.triangles()[0][1].y, 1.0);
}

#[test]
fn no_texcoord_1_means_no_lightmap_uvs() {
    let scene = Scene::load_gltf_slice(&glb(false, false), None, &LoadOptions::default()).unwrap();
    assert_eq!(scene.triangles().len(), 1);
    assert!(scene.lightmap_uvs().is_none());
    assert!(Scene::cornell_box().lightmap_uvs().is_none());
}
