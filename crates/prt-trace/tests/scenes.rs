//! Scene construction and glTF loading.
mod common;

use glam::Vec3;
use prt_trace::scene::Material;
use prt_trace::{LoadOptions, Scene, TraceError};

fn write_gltf(dir: &std::path::Path, json: &str, bin: Option<&[u8]>) -> std::path::PathBuf {
    if let Some(b) = bin {
        std::fs::write(dir.join("data.bin"), b).expect("write bin");
    }
    let p = dir.join("scene.gltf");
    std::fs::write(&p, json).expect("write gltf");
    p
}

/// One triangle (3 f32 VEC3 positions, no indices) in `data.bin`, with a mesh `mode`,
/// optional required extensions and a two-level node hierarchy.
fn triangle_gltf(mode: u32, required: &str, positions: [[f32; 3]; 3]) -> (String, Vec<u8>) {
    let bin: Vec<u8> = positions
        .iter()
        .flatten()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    let json = format!(
        r#"{{
  "asset": {{"version": "2.0"}},
  "extensionsUsed": ["KHR_materials_emissive_strength", "KHR_lights_punctual"{extra_used}],
  "extensionsRequired": [{required}],
  "extensions": {{"KHR_lights_punctual": {{"lights": [{{"type": "point", "color": [1, 0.5, 0.25], "intensity": 3}}]}}}},
  "buffers": [{{"uri": "data.bin", "byteLength": 36}}],
  "bufferViews": [{{"buffer": 0, "byteOffset": 0, "byteLength": 36}}],
  "accessors": [{{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
                  "min": [-10, -10, -10], "max": [10, 10, 10]}}],
  "materials": [{{"name": "glow", "doubleSided": true, "emissiveFactor": [1, 1, 0.5],
                  "extensions": {{"KHR_materials_emissive_strength": {{"emissiveStrength": 4}}}},
                  "pbrMetallicRoughness": {{"baseColorFactor": [0.2, 0.4, 0.6, 1]}}}}],
  "meshes": [{{"name": "tri", "primitives": [{{"attributes": {{"POSITION": 0}}, "material": 0, "mode": {mode}}}]}}],
  "nodes": [{{"children": [1], "scale": [2, 2, 2]}},
            {{"mesh": 0, "translation": [1, 0, 0]}},
            {{"translation": [0, 5, 0], "extensions": {{"KHR_lights_punctual": {{"light": 0}}}}}}],
  "scenes": [{{"nodes": [0, 2]}}],
  "scene": 0
}}"#,
        extra_used = if required.is_empty() {
            String::new()
        } else {
            format!(", {required}")
        },
    );
    (json, bin)
}

#[test]
fn gltf_hierarchy_materials_and_lights_are_applied() {
    let dir = common::temp_dir("hierarchy");
    let (json, bin) = triangle_gltf(4, "", [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]);
    let scene = Scene::load_gltf(write_gltf(&dir, &json, Some(&bin)), &LoadOptions::default())
        .expect("loads");
    assert_eq!(scene.triangles().len(), 1);
    // World = parent scale 2 * (child translation (1, 0, 0) + p).
    let t = scene.triangles()[0];
    assert_eq!(t[0], Vec3::new(2.0, 0.0, 0.0));
    assert_eq!(t[1], Vec3::new(4.0, 0.0, 0.0));
    assert_eq!(t[2], Vec3::new(2.0, 2.0, 0.0));
    let m = scene.material_of(0);
    assert_eq!(m.albedo, Vec3::new(0.2, 0.4, 0.6));
    assert_eq!(m.emissive, Vec3::new(4.0, 4.0, 2.0));
    assert!(m.double_sided);
    assert_eq!(scene.lights().len(), 1);
    assert_eq!(scene.lights()[0].position, Vec3::new(0.0, 5.0, 0.0));
    assert_eq!(scene.lights()[0].intensity, 3.0);
    assert!(scene.warnings().is_empty(), "{:?}", scene.warnings());
}

#[test]
fn material_only_required_extensions_only_warn() {
    let dir = common::temp_dir("required");
    let (json, bin) = triangle_gltf(
        4,
        r#""AMD_split_roughnessMetallic""#,
        [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
    );
    let scene = Scene::load_gltf(write_gltf(&dir, &json, Some(&bin)), &LoadOptions::default())
        .expect("loads");
    assert_eq!(scene.triangles().len(), 1);
    assert!(
        scene
            .warnings()
            .iter()
            .any(|w| w.contains("AMD_split_roughnessMetallic"))
    );
}

#[test]
fn point_and_line_primitives_are_skipped_with_a_warning() {
    let dir = common::temp_dir("mode");
    for mode in [0, 1, 2, 3] {
        let (json, bin) = triangle_gltf(
            mode,
            "",
            [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
        );
        let scene = Scene::load_gltf(write_gltf(&dir, &json, Some(&bin)), &LoadOptions::default())
            .expect("loads");
        assert!(scene.triangles().is_empty(), "mode {mode}");
        assert!(
            scene
                .warnings()
                .iter()
                .any(|w| w.contains("mesh 'tri' primitive 0") && w.contains("skipped")),
            "mode {mode}: {:?}",
            scene.warnings()
        );
    }
}

#[test]
fn missing_buffer_is_a_typed_error_naming_the_uri() {
    let dir = common::temp_dir("missing");
    let (json, _) = triangle_gltf(4, "", [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]);
    match Scene::load_gltf(write_gltf(&dir, &json, None), &LoadOptions::default()) {
        Err(TraceError::Buffer { uri, index, .. }) => {
            assert_eq!(uri, "data.bin");
            assert_eq!(index, 0);
        }
        other => panic!("expected Buffer error, got {other:?}"),
    }
}

#[test]
fn non_finite_positions_are_a_typed_error() {
    let dir = common::temp_dir("nan");
    let (json, bin) = triangle_gltf(
        4,
        "",
        [[0.0, 0.0, 0.0], [f32::NAN, 0.0, 0.0], [0.0, 1.0, 0.0]],
    );
    match Scene::load_gltf(write_gltf(&dir, &json, Some(&bin)), &LoadOptions::default()) {
        Err(TraceError::NonFinitePosition { what, triangle }) => {
            assert!(what.contains("tri"), "{what}");
            assert_eq!(triangle, 0);
        }
        other => panic!("expected NonFinitePosition, got {other:?}"),
    }
    let r = Scene::from_triangles(
        vec![[Vec3::ZERO, Vec3::X, Vec3::new(0.0, f32::INFINITY, 0.0)]],
        vec![0],
        vec![Material::diffuse("m", Vec3::ONE)],
    );
    assert!(matches!(
        r,
        Err(TraceError::NonFinitePosition { triangle: 0, .. })
    ));
}

#[test]
fn degenerate_triangles_are_dropped_and_counted() {
    let tris = vec![
        [Vec3::ZERO, Vec3::X, Vec3::Y],
        [Vec3::ZERO, Vec3::X, 2.0 * Vec3::X], // collinear
        [Vec3::ONE, Vec3::ONE, Vec3::ONE],    // a point
        [Vec3::ZERO, Vec3::Z, Vec3::Y],
    ];
    let scene = Scene::from_triangles(tris, vec![0; 4], vec![Material::diffuse("m", Vec3::ONE)])
        .expect("finite");
    assert_eq!(scene.triangles().len(), 2);
    assert_eq!(scene.degenerate_dropped(), 2);
    // Material indices are checked too.
    assert!(Scene::from_triangles(vec![[Vec3::ZERO, Vec3::X, Vec3::Y]], vec![3], vec![]).is_err());
}

#[test]
fn built_in_scenes_have_the_documented_shape() {
    let cornell = Scene::cornell_box();
    assert_eq!(cornell.triangles().len(), 32);
    assert_eq!(cornell.materials().len(), 8);
    let b = cornell.bounds().expect("non-empty");
    assert!((b.max.y - 1.99).abs() < 1e-6 && b.min.y == 0.0);
    assert_eq!(Scene::empty().bounds(), None);
    let plane = Scene::ground_plane(10.0, Vec3::splat(0.3));
    assert_eq!(plane.triangles().len(), 2);
    for t in plane.triangles() {
        assert!((t[1] - t[0]).cross(t[2] - t[0]).y > 0.0, "plane faces up");
    }
    let closed = Scene::closed_box(1.0, Vec3::ONE);
    assert_eq!(closed.triangles().len(), 12);
    for t in closed.triangles() {
        let n = (t[1] - t[0]).cross(t[2] - t[0]);
        let c = (t[0] + t[1] + t[2]) / 3.0;
        assert!(n.dot(-c) > 0.0, "box faces point inwards");
    }
}

#[test]
#[cfg_attr(
    prt_skip_shared_scenes,
    ignore = "needs ../shared/scenes, absent at build time (PRT_REQUIRE_SHARED=1 requires it)"
)]
fn built_in_cornell_box_matches_the_shared_gltf() {
    let path = common::shared_scene("cornell_box/CornellBox-Original.gltf");
    let file = Scene::load_gltf(path, &LoadOptions::default()).expect("loads");
    let builtin = Scene::cornell_box();
    assert_eq!(file.triangles().len(), builtin.triangles().len());
    for (k, (a, b)) in file.triangles().iter().zip(builtin.triangles()).enumerate() {
        for c in 0..3 {
            assert!(
                (a[c] - b[c]).length() < 1e-4,
                "triangle {k} vertex {c}: {} vs {}",
                a[c],
                b[c]
            );
        }
        let (ma, mb) = (file.material_of(k), builtin.material_of(k));
        assert_eq!(ma.name, mb.name);
        assert!((ma.albedo - mb.albedo).abs().max_element() < 1e-6);
        assert_eq!(ma.emissive, mb.emissive);
    }
}

#[test]
#[cfg_attr(
    prt_skip_shared_scenes,
    ignore = "needs ../shared/scenes, absent at build time (PRT_REQUIRE_SHARED=1 requires it)"
)]
fn shared_sponza_loads_with_warnings() {
    let path = common::shared_scene("sponza/Sponza.gltf");
    let s = Scene::load_gltf(&path, &LoadOptions::default()).expect("Sponza loads");
    assert_eq!(s.triangles().len() + s.degenerate_dropped(), 262_087);
    assert!(
        s.warnings()
            .iter()
            .any(|w| w.contains("AMD_split_roughnessMetallic"))
    );
    // No textures are shipped: every material falls back to the 0.5 grey default.
    assert!(s.materials().iter().all(|m| m.albedo == Vec3::splat(0.5)));
    assert_eq!(s.cameras().len(), 4);
    // Decoding textures that are missing is a typed error naming the URI.
    let strict = LoadOptions {
        decode_textures: true,
        ..LoadOptions::default()
    };
    let error = Scene::load_gltf(path, &strict).expect_err("Sponza's textures are not shipped");
    // The warnings gathered before the failure come with it.
    let (error, warnings) = error.without_warnings();
    assert!(
        warnings
            .iter()
            .any(|w| w.contains("AMD_split_roughnessMetallic"))
    );
    match error {
        TraceError::Image { uri, .. } => {
            assert!(uri.ends_with(".png") || uri.ends_with(".dds"), "{uri}")
        }
        other => panic!("expected an Image error, got {other:?}"),
    }
}

#[test]
#[cfg_attr(
    prt_skip_shared_scenes,
    ignore = "needs ../shared/scenes, absent at build time (PRT_REQUIRE_SHARED=1 requires it)"
)]
fn shared_gas_station_loads_with_warnings() {
    let path = common::shared_scene("gas_station/GasStation.gltf");
    let s = Scene::load_gltf(path, &LoadOptions::default()).expect("Gas station loads");
    assert_eq!(s.triangles().len() + s.degenerate_dropped(), 99_002);
    assert!(s.warnings().iter().any(|w| w.contains("MSFT_texture_dds")));
    assert_eq!(s.cameras().len(), 2);
}

#[test]
fn decoded_textures_contribute_their_mean_linear_colour() {
    let dir = common::temp_dir("texture");
    // 2x1 sRGB image: pure white and sRGB 0.5 grey in red only.
    let mut img = image::RgbImage::new(2, 1);
    img.put_pixel(0, 0, image::Rgb([255, 255, 255]));
    img.put_pixel(1, 0, image::Rgb([128, 0, 0]));
    img.save(dir.join("albedo.png")).expect("write png");
    let (json, bin) = triangle_gltf(4, "", [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]);
    let json = json
        .replace(
            r#""pbrMetallicRoughness": {"baseColorFactor": [0.2, 0.4, 0.6, 1]}"#,
            r#""pbrMetallicRoughness": {"baseColorFactor": [0.5, 1, 1, 1], "baseColorTexture": {"index": 0}}"#,
        )
        .replace(r#""meshes":"#, r#""images": [{"uri": "albedo.png"}], "textures": [{"source": 0}], "meshes":"#);
    let path = write_gltf(&dir, &json, Some(&bin));
    let decoded = LoadOptions {
        decode_textures: true,
        ..LoadOptions::default()
    };
    let scene = Scene::load_gltf(&path, &decoded).expect("loads with its texture");
    let srgb = |c: f32| {
        if c <= 0.04045 {
            c / 12.92
        } else {
            ((c + 0.055) / 1.055).powf(2.4)
        }
    };
    let mean_r = 0.5 * (1.0 + srgb(128.0 / 255.0));
    let expected = Vec3::new(0.5 * mean_r, 0.5, 0.5);
    let got = scene.material_of(0).albedo;
    assert!(
        (got - expected).abs().max_element() < 1e-4,
        "{got} vs {expected}"
    );
    // Not decoding: the default albedo stands in for the texture, with a warning.
    let scene = Scene::load_gltf(&path, &LoadOptions::default()).expect("loads");
    assert_eq!(scene.material_of(0).albedo, Vec3::new(0.25, 0.5, 0.5));
    assert!(scene.warnings().iter().any(|w| w.contains("texture")));
    // A missing image is a typed error naming its URI when textures are decoded.
    std::fs::remove_file(dir.join("albedo.png")).expect("remove");
    assert!(
        matches!(Scene::load_gltf(&path, &decoded), Err(TraceError::Image { uri, .. }) if uri == "albedo.png")
    );
}

mod malformed {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(48))]
        /// A damaged glTF (truncated, or with a byte replaced) loads or fails with a typed error:
        /// it never panics.
        #[test]
        fn damaged_gltf_never_panics(cut in 0usize..2000, at in 0usize..2000, byte in any::<u8>()) {
            let dir = common::temp_dir(&format!("damaged-{cut}-{at}-{byte}"));
            let (json, bin) = triangle_gltf(4, "", [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]);
            let mut bytes = json.into_bytes();
            if at < bytes.len() {
                bytes[at] = byte;
            }
            bytes.truncate(cut.max(1).min(bytes.len()));
            std::fs::write(dir.join("data.bin"), &bin).expect("write bin");
            let path = dir.join("scene.gltf");
            std::fs::write(&path, &bytes).expect("write gltf");
            let _ = Scene::load_gltf(&path, &LoadOptions::default());
            let _ = std::fs::remove_dir_all(&dir);
        }
    }
}

/// A one-mesh glTF over `data.bin`: `positions` as an accessor of `component` (VEC3), an
/// optional second accessor for morph target 0 (same layout, right after), a primitive `mode`,
/// the node's `node` JSON members, and `extra` top-level JSON members.
fn mesh_gltf(
    dir: &std::path::Path,
    positions: &[u8],
    count: usize,
    component: u32,
    mode: u32,
    node: &str,
    extra: &str,
    target: Option<&[u8]>,
) -> std::path::PathBuf {
    let mut bin = positions.to_vec();
    let (mut accessors, mut views) = (
        format!(
            r#"{{"bufferView": 0, "componentType": {component}, "normalized": {norm}, "count": {count}, "type": "VEC3", "min": [-9, -9, -9], "max": [9, 9, 9]}}"#,
            norm = component != 5126
        ),
        format!(r#"{{"buffer": 0, "byteLength": {}}}"#, positions.len()),
    );
    let mut targets = String::new();
    if let Some(t) = target {
        accessors.push_str(&format!(
            r#", {{"bufferView": 1, "componentType": 5126, "count": {count}, "type": "VEC3", "min": [-9, -9, -9], "max": [9, 9, 9]}}"#
        ));
        views.push_str(&format!(
            r#", {{"buffer": 0, "byteOffset": {}, "byteLength": {}}}"#,
            bin.len(),
            t.len()
        ));
        bin.extend_from_slice(t);
        targets = r#", "targets": [{"POSITION": 1}]"#.to_owned();
    }
    let json = format!(
        r#"{{"asset": {{"version": "2.0"}}{extra},
  "buffers": [{{"uri": "data.bin", "byteLength": {len}}}],
  "bufferViews": [{views}],
  "accessors": [{accessors}],
  "meshes": [{{"name": "m", "primitives": [{{"attributes": {{"POSITION": 0}}, "mode": {mode}{targets}}}]}}],
  "nodes": [{{"mesh": 0{node}}}],
  "scenes": [{{"nodes": [0]}}], "scene": 0}}"#,
        len = bin.len()
    );
    write_gltf(dir, &json, Some(&bin))
}

fn f32_bytes(values: &[[f32; 3]]) -> Vec<u8> {
    values
        .iter()
        .flatten()
        .flat_map(|v| v.to_le_bytes())
        .collect()
}

fn normal(t: &[Vec3; 3]) -> Vec3 {
    (t[1] - t[0]).cross(t[2] - t[0]).normalize()
}

#[test]
fn mirroring_transforms_keep_the_front_face() {
    let dir = common::temp_dir("mirror");
    let tri = f32_bytes(&[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]);
    let load = |node: &str| {
        let path = mesh_gltf(&dir, &tri, 3, 5126, 4, node, "", None);
        Scene::load_gltf(path, &LoadOptions::default()).expect("loads")
    };
    let plain = load("");
    let mirrored = load(r#", "scale": [-1, 1, 1]"#);
    // The triangle faces +z; mirroring x maps +z to itself, so the front face stays +z.
    assert!(normal(&plain.triangles()[0]).z > 0.99);
    assert!(normal(&mirrored.triangles()[0]).z > 0.99);
    assert_eq!(mirrored.triangles()[0][0], Vec3::ZERO);
    // Two mirrors are a rotation: no flip.
    let rotated = load(r#", "scale": [-1, -1, 1]"#);
    assert!(normal(&rotated.triangles()[0]).z > 0.99);
}

#[test]
fn strips_and_fans_are_triangulated_with_a_consistent_facing() {
    let dir = common::temp_dir("strips");
    // A unit square in z = 0 seen from +z, as a strip and as a fan.
    let strip = f32_bytes(&[
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [1.0, 1.0, 0.0],
    ]);
    let fan = f32_bytes(&[
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [1.0, 1.0, 0.0],
        [0.0, 1.0, 0.0],
    ]);
    for (mode, bytes) in [(5, &strip), (6, &fan)] {
        let path = mesh_gltf(&dir, bytes, 4, 5126, mode, "", "", None);
        let scene = Scene::load_gltf(path, &LoadOptions::default()).expect("loads");
        assert_eq!(scene.triangles().len(), 2, "mode {mode}");
        let area: f32 = scene
            .triangles()
            .iter()
            .map(|t| 0.5 * (t[1] - t[0]).cross(t[2] - t[0]).length())
            .sum();
        assert!((area - 1.0).abs() < 1e-6, "mode {mode}: area {area}");
        for t in scene.triangles() {
            assert!(normal(t).z > 0.99, "mode {mode}: {t:?}");
        }
    }
}

#[test]
fn quantized_positions_are_dequantized() {
    let dir = common::temp_dir("quantized");
    let q: Vec<u8> = [0i16, 0, 0, 0, 32767, 0, 0, 0, 0, 32767, 0, 0]
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    // Four i16 per vertex (VEC3 plus padding) with byteStride 8.
    let extension = r#", "extensionsUsed": ["KHR_mesh_quantization"], "extensionsRequired": ["KHR_mesh_quantization"]"#;
    let path = mesh_gltf(
        &dir,
        &q,
        3,
        5122,
        4,
        r#", "scale": [2, 2, 2]"#,
        extension,
        None,
    );
    let json = std::fs::read_to_string(&path).expect("read").replace(
        r#""bufferViews": [{"buffer": 0, "byteLength": 24}]"#,
        r#""bufferViews": [{"buffer": 0, "byteLength": 24, "byteStride": 8}]"#,
    );
    std::fs::write(&path, json).expect("write");
    let scene = Scene::load_gltf(&path, &LoadOptions::default()).expect("loads");
    assert_eq!(
        scene.triangles()[0],
        [
            Vec3::ZERO,
            Vec3::new(2.0, 0.0, 0.0),
            Vec3::new(0.0, 2.0, 0.0)
        ]
    );
    assert!(scene.warnings().is_empty(), "{:?}", scene.warnings());
    // Without the extension, integer positions are refused rather than misread.
    let path = mesh_gltf(&dir, &q, 3, 5122, 4, "", "", None);
    let json = std::fs::read_to_string(&path).expect("read").replace(
        r#""byteLength": 24}]"#,
        r#""byteLength": 24, "byteStride": 8}]"#,
    );
    std::fs::write(&path, json).expect("write");
    assert!(matches!(
        Scene::load_gltf(&path, &LoadOptions::default()),
        Err(TraceError::BadAccessor { accessor: 0, .. })
    ));
}

#[test]
fn morph_targets_apply_their_default_weights() {
    let dir = common::temp_dir("morph");
    let tri = f32_bytes(&[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]);
    let up = f32_bytes(&[[0.0, 0.0, 2.0]; 3]);
    let load = |node: &str| {
        let path = mesh_gltf(&dir, &tri, 3, 5126, 4, node, "", Some(&up));
        let json = std::fs::read_to_string(&path)
            .expect("read")
            .replace(r#""name": "m","#, r#""name": "m", "weights": [0.25],"#);
        std::fs::write(&path, json).expect("write");
        Scene::load_gltf(&path, &LoadOptions::default()).expect("loads")
    };
    // The mesh's default weight 0.25 lifts the triangle by 0.5; a node's weights override it.
    assert!(load("").triangles()[0].iter().all(|v| v.z == 0.5));
    assert!(
        load(r#", "weights": [1.0]"#).triangles()[0]
            .iter()
            .all(|v| v.z == 2.0)
    );
}

#[test]
fn outdoor_town_is_terrain_with_closed_buildings() {
    let town = Scene::outdoor_town();
    assert_eq!(town.triangles().len(), 64 * 64 * 2 + 6 * 12);
    assert_eq!(town.materials().len(), 7);
    let b = town.bounds().expect("non-empty");
    assert_eq!(
        (b.min.x, b.max.x, b.min.z, b.max.z),
        (-64.0, 64.0, -64.0, 64.0)
    );
    assert!(b.min.y == -2.0 && (b.max.y - 14.94).abs() < 0.01, "{b:?}");
    // Terrain faces up; every building face points away from its box's centre.
    let terrain = town.material_ids().iter().filter(|&&m| m == 0).count();
    assert_eq!(terrain, 64 * 64 * 2);
    for (t, &m) in town.triangles().iter().zip(town.material_ids()) {
        let n = (t[1] - t[0]).cross(t[2] - t[0]);
        if m == 0 {
            assert!(n.y > 0.0, "terrain faces up");
        }
    }
    for m in 1..7u32 {
        let tris: Vec<_> = town
            .triangles()
            .iter()
            .zip(town.material_ids())
            .filter(|(_, id)| **id == m)
            .map(|(t, _)| *t)
            .collect();
        assert_eq!(tris.len(), 12);
        let centre = tris.iter().flatten().copied().sum::<Vec3>() / 36.0;
        for t in &tris {
            let n = (t[1] - t[0]).cross(t[2] - t[0]);
            let c = (t[0] + t[1] + t[2]) / 3.0;
            assert!(n.dot(c - centre) > 0.0, "building faces point outwards");
        }
    }
}

#[test]
fn outdoor_town_bakes_open_sky_above_and_invalid_voxels_below() {
    use prt_core::{Aabb, NoProgress};
    use prt_trace::{BakeOptions, TransferBaker};
    let town = Scene::outdoor_town();
    // A coarse column of voxels through a building (centre (35, 30)) and open terrain.
    let options = BakeOptions {
        resolution: [4, 16, 4],
        bounds: Some(Aabb::new(
            Vec3::new(30.0, -1.0, 25.0),
            Vec3::new(50.0, 15.0, 45.0),
        )),
        margin: 16.0,
        rays_per_voxel: 48,
        cache_rays: 8,
        ..BakeOptions::default()
    };
    let volume = TransferBaker::new(&town, options)
        .and_then(|baker| baker.bake(&NoProgress))
        .expect("bake");
    let field = &volume.field;
    // The top layer sees most of the sky; the bottom layer is under the terrain.
    let top: Vec<usize> = (0..4)
        .flat_map(|x| (0..4).map(move |z| (x, z)))
        .map(|(x, z)| field.index(x, 15, z))
        .collect();
    assert!(
        top.iter()
            .all(|&v| volume.valid[v] && volume.sky_visibility(v) > 0.5)
    );
    let bottom = (0..4).flat_map(|x| (0..4).map(move |z| (x, z)));
    assert!(
        bottom
            .map(|(x, z)| field.index(x, 0, z))
            .all(|v| !volume.valid[v])
    );
    // Inside the building (x in 30..40, z in 25..35, mid-height) voxels are invalid.
    assert!(!volume.valid[field.index(1, 9, 1)]);
}
