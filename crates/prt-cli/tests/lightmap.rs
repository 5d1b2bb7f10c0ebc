//! `prt lightmap` on the Cornell box glTF of ../shared at a tiny size: the files it writes and
//! the knobs it refuses with a one-line error.

mod common;

use common::{assert_clean_failure, prt, scratch, shared_cornell, stderr};
use prt_texture::exr_io::read_exr;
use prt_texture::{Ktx2Texture, Limits};

#[test]
#[cfg_attr(prt_skip_shared, ignore = "needs ../shared/scenes")]
fn a_tiny_cornell_lightmap_writes_its_textures_previews_and_manifest() {
    let scene = shared_cornell();
    let out = scratch("lightmap");
    let scene = scene.to_str().unwrap();
    let dir = out.to_str().unwrap();
    let args = [
        "lightmap",
        scene,
        "--samples",
        "8",
        "--pass",
        "4",
        "--preview-every",
        "4",
        "--texels-per-metre",
        "4",
        "--view-size",
        "32",
        "--out",
        dir,
    ];
    let run = prt(&args);
    assert!(run.status.success(), "{}", stderr(&run));
    let manifest: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("manifest.json")).unwrap()).unwrap();
    assert_eq!(manifest["basis"], "sg:9");
    assert_eq!(manifest["encoder"], "plsq-nonneg");
    assert_eq!(manifest["samples_per_texel"], 8);
    assert_eq!(manifest["cancelled"], false);
    assert_eq!(manifest["overlapping_texels"], 0);
    let (w, h) = (
        manifest["width"].as_u64().unwrap() as u32,
        manifest["height"].as_u64().unwrap() as u32,
    );
    let layers = read_exr(&out.join("lightmap.exr"), &Limits::default()).unwrap();
    assert_eq!(layers.len(), 10);
    assert_eq!(layers[0].name.as_deref(), Some("irradiance"));
    assert!(layers.iter().all(|l| l.width == w && l.height == h));
    // Non-negative PLSQ: nothing negative, and the box is lit.
    assert!(layers.iter().flat_map(|l| &l.data).all(|&v| v >= 0.0));
    assert!(layers[0].data.iter().any(|&v| v > 0.01));
    let ktx = Ktx2Texture::read_file(&out.join("lightmap.ktx2"), &Limits::default()).unwrap();
    let level = ktx.level_f32(0).unwrap();
    assert_eq!(level.len(), 10 * (w * h) as usize * 4);
    assert_eq!(
        level[0..4 * (w * h) as usize]
            .chunks(4)
            .map(|t| t[1])
            .collect::<Vec<_>>(),
        layers[0].data.chunks(3).map(|t| t[1]).collect::<Vec<_>>()
    );
    let triangles = 32;
    assert_eq!(
        std::fs::metadata(out.join("lightmap_uvs.bin"))
            .unwrap()
            .len(),
        triangles * 6 * 4
    );
    for file in [
        "view.png",
        "view.exr",
        "atlas.png",
        "preview/view00004.png",
        "preview/atlas00004.png",
    ] {
        assert!(out.join(file).is_file(), "{file} missing");
    }
}

#[test]
#[cfg_attr(prt_skip_shared, ignore = "needs ../shared/scenes")]
fn bad_knobs_are_one_line_errors() {
    let scene = shared_cornell();
    let out = scratch("lightmap-bad");
    let (scene, dir) = (scene.to_str().unwrap(), out.to_str().unwrap());
    let run = |extra: &[&str]| {
        let mut args = vec!["lightmap", scene, "--samples", "4", "--out", dir];
        args.extend_from_slice(extra);
        prt(&args)
    };
    assert_clean_failure(&run(&["--basis", "sg:0"]), "SG lobes");
    assert_clean_failure(&run(&["--view-size", "0"]), "view-size");
    assert_clean_failure(&run(&["--encoder", "fast"]), "encoder");
    assert_clean_failure(&run(&["--max-memory", "0.00001"]), "budget");
    assert_clean_failure(&run(&["--texels-per-metre", "0"]), "texels per metre");
    assert_clean_failure(&run(&["--engine", "unity"]), "--engine");
}

/// A GLB of a 1 m × 1 m floor quad facing up whose TEXCOORD_1 fills the unit square.
fn floor_with_texcoord_1() -> Vec<u8> {
    let positions: [[f32; 3]; 4] = [
        [0.0, 0.0, 0.0],
        [0.0, 0.0, 1.0],
        [1.0, 0.0, 1.0],
        [1.0, 0.0, 0.0],
    ];
    let uvs: [[f32; 2]; 4] = [[0.0, 0.0], [0.0, 1.0], [1.0, 1.0], [1.0, 0.0]];
    let indices: [u16; 6] = [0, 1, 2, 0, 2, 3];
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
    let mut json = format!(
        r#"{{"asset": {{"version": "2.0"}}, "scene": 0, "scenes": [{{"nodes": [0]}}],
        "nodes": [{{"mesh": 0}}],
        "meshes": [{{"primitives": [{{"attributes": {{"POSITION": 0, "TEXCOORD_1": 1}}, "indices": 2}}]}}],
        "buffers": [{{"byteLength": {len}}}],
        "bufferViews": [{{"buffer": 0, "byteOffset": 0, "byteLength": 48}},
                        {{"buffer": 0, "byteOffset": 48, "byteLength": 32}},
                        {{"buffer": 0, "byteOffset": 80, "byteLength": 12}}],
        "accessors": [
          {{"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3", "min": [0, 0, 0], "max": [1, 0, 1]}},
          {{"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC2"}},
          {{"bufferView": 2, "componentType": 5123, "count": 6, "type": "SCALAR"}}]}}"#,
        len = bin.len()
    )
    .into_bytes();
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

/// A scene with TEXCOORD_1 is baked on its own UVs at the requested density (16 texels over
/// 1 m), unless --generate-uvs.
#[test]
fn texcoord_1_is_the_lightmap_uv_when_present() {
    let out = scratch("lightmap-uv1");
    let scene = out.join("floor.glb");
    std::fs::write(&scene, floor_with_texcoord_1()).unwrap();
    let (scene, dir) = (scene.to_str().unwrap(), out.join("bake"));
    let dir = dir.to_str().unwrap();
    for (extra, source, side) in [
        (None, "TEXCOORD_1", 16),
        (Some("--generate-uvs"), "charts", 0),
    ] {
        let mut args = vec![
            "lightmap",
            scene,
            "--samples",
            "4",
            "--preview-every",
            "0",
            "--view-size",
            "8",
            "--out",
            dir,
        ];
        args.extend(extra);
        let run = prt(&args);
        assert!(run.status.success(), "{}", stderr(&run));
        let manifest: serde_json::Value =
            serde_json::from_slice(&std::fs::read(out.join("bake/manifest.json")).unwrap())
                .unwrap();
        assert_eq!(manifest["uv_source"], source);
        if side > 0 {
            assert_eq!(manifest["width"], side);
            assert_eq!(manifest["texels"], side * side);
        }
    }
}

/// The JSON document and binary chunk of a GLB.
fn read_glb(bytes: &[u8]) -> (serde_json::Value, Vec<u8>) {
    assert_eq!(&bytes[0..4], b"glTF", "GLB magic");
    let word = |at: usize| u32::from_le_bytes(bytes[at..at + 4].try_into().unwrap()) as usize;
    assert_eq!(word(8), bytes.len(), "GLB length");
    let json_len = word(12);
    let doc = serde_json::from_slice(&bytes[20..20 + json_len]).expect("JSON chunk");
    let bin_at = 20 + json_len;
    (doc, bytes[bin_at + 8..bin_at + 8 + word(bin_at)].to_vec())
}

/// `--engine bevy --engine threejs` on a scene with its own TEXCOORD_1: each engine's GLB
/// carries those UVs as TEXCOORD_1 (per triangle, unshared vertices), and its KTX2 holds the
/// baked irradiance in the engine's units (`E/π` for Bevy, `E` for three.js).
#[test]
fn engine_exports_carry_the_scenes_lightmap_uvs_and_each_engines_units() {
    let out = scratch("lightmap-engines");
    let scene = out.join("floor.glb");
    std::fs::write(&scene, floor_with_texcoord_1()).unwrap();
    let bake = out.join("bake");
    let args = [
        "lightmap",
        scene.to_str().unwrap(),
        "--basis",
        "irradiance",
        "--samples",
        "4",
        "--preview-every",
        "0",
        "--view-size",
        "8",
        "--engine",
        "bevy",
        "--engine",
        "threejs",
        "--out",
        bake.to_str().unwrap(),
    ];
    let run = prt(&args);
    assert!(run.status.success(), "{}", stderr(&run));
    let irradiance = read_exr(&bake.join("lightmap.exr"), &Limits::default()).unwrap()[0]
        .data
        .clone();
    assert!(irradiance.iter().any(|&v| v > 0.0), "the floor is unlit");
    // The quad's two triangles, as the file indexes them.
    let want: Vec<f32> = [
        [0.0, 0.0],
        [0.0, 1.0],
        [1.0, 1.0],
        [0.0, 0.0],
        [1.0, 1.0],
        [1.0, 0.0],
    ]
    .into_iter()
    .flatten()
    .collect();
    for (engine, scale) in [("bevy", std::f32::consts::FRAC_1_PI), ("threejs", 1.0)] {
        let folder = bake.join(engine);
        let placement: serde_json::Value =
            serde_json::from_slice(&std::fs::read(folder.join("lightmap.json")).unwrap()).unwrap();
        assert_eq!(placement["engine"], engine);
        let (doc, bin) = read_glb(&std::fs::read(folder.join("lightmap_scene.glb")).unwrap());
        let primitive = &doc["meshes"][0]["primitives"][0];
        let accessor =
            &doc["accessors"][primitive["attributes"]["TEXCOORD_1"].as_u64().unwrap() as usize];
        let view = &doc["bufferViews"][accessor["bufferView"].as_u64().unwrap() as usize];
        let at = view["byteOffset"].as_u64().unwrap() as usize;
        let uvs: Vec<f32> = bin[at..at + view["byteLength"].as_u64().unwrap() as usize]
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes(b.try_into().unwrap()))
            .collect();
        assert_eq!(uvs.len(), want.len(), "{engine}: TEXCOORD_1 of 2 triangles");
        for (got, want) in uvs.iter().zip(&want) {
            assert!(
                (got - want).abs() < 1e-6,
                "{engine}: TEXCOORD_1 {uvs:?}, expected {want:?}"
            );
        }
        let ktx =
            Ktx2Texture::read_file(&folder.join("lightmap.ktx2"), &Limits::default()).unwrap();
        let level = ktx.level_f32(0).unwrap();
        assert_eq!(level.len(), irradiance.len() / 3 * 4);
        for (i, &e) in irradiance.iter().enumerate() {
            let got = level[4 * (i / 3) + i % 3];
            assert!(
                (got - e * scale).abs() <= 1e-3 * (e * scale).abs() + 1e-6,
                "{engine}: texel value {got} for E = {e}"
            );
        }
    }
}
