//! glTF 2.0 loading: geometry, diffuse materials, punctual lights and cameras.

use std::path::{Path, PathBuf};

use glam::{Mat4, Vec2, Vec3, Vec4};
use gltf::json::accessor::{ComponentType, Type};
use gltf::khr_lights_punctual::Kind;

use crate::TraceError;
use crate::scene::{Camera, LightKind, Material, PunctualLight, Scene};

/// Extensions whose meaning the loader honours; any other *required* extension outside
/// [`GEOMETRY_EXTENSIONS`] only warns, since the baker needs geometry and diffuse colour alone.
const UNDERSTOOD_EXTENSIONS: &[&str] = &[
    "KHR_lights_punctual",
    "KHR_materials_emissive_strength",
    "KHR_mesh_quantization",
];

/// Options and limits for [`Scene::load_gltf`].
#[derive(Debug, Clone, PartialEq)]
pub struct LoadOptions {
    /// Albedo used where a material's colour comes from a texture that is not decoded (and for
    /// primitives without a material). Sponza ships without textures: 0.5 grey.
    pub default_albedo: Vec3,
    /// Decode base-colour textures (PNG, JPEG, ...) to use their mean colour. When off, images are
    /// never opened. When on, a missing image file is [`TraceError::Image`]; an image in a format
    /// that cannot be decoded (e.g. DDS) only warns and falls back to `default_albedo`.
    pub decode_textures: bool,
    /// Largest glTF/GLB file and largest single buffer accepted, in bytes.
    pub max_bytes: u64,
    /// Largest number of (flattened, world-space) triangles accepted.
    pub max_triangles: u64,
}

impl Default for LoadOptions {
    fn default() -> Self {
        Self {
            default_albedo: Vec3::splat(0.5),
            decode_textures: false,
            max_bytes: 1 << 31,
            max_triangles: 50_000_000,
        }
    }
}

fn gltf_error(path: &Path, e: impl std::fmt::Display) -> TraceError {
    TraceError::Gltf {
        path: path.to_owned(),
        message: e.to_string(),
    }
}

fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

impl Scene {
    /// Loads a `.gltf` or `.glb` file: the default scene's node hierarchy is flattened to
    /// world-space triangles (each node's transform applied), materials become diffuse
    /// [`Material`]s, `KHR_lights_punctual` lights and perspective cameras are placed;
    /// `TEXCOORD_1` is kept as lightmap UVs when every primitive has it ([`Scene::lightmap_uvs`]).
    ///
    /// Everything read is checked first (the gltf crate's validation, then every accessor,
    /// buffer view, buffer length, stride, count, component type, index and node reference), so
    /// a malformed file is a typed error naming what is wrong, never a panic. Triangle strips and
    /// fans are triangulated; points and lines are skipped with a warning; a mirroring node
    /// transform flips the winding; morph targets are applied with their default weights;
    /// `KHR_mesh_quantization` positions are dequantised. Required extensions that only concern
    /// materials or textures (for example `AMD_split_roughnessMetallic`, `MSFT_texture_dds`)
    /// only warn ([`Scene::warnings`]); those that change geometry (Draco, meshopt, instancing)
    /// are [`TraceError::UnsupportedExtension`]. When warnings were gathered before a failure,
    /// the error is [`TraceError::WithWarnings`].
    pub fn load_gltf(path: impl AsRef<Path>, options: &LoadOptions) -> Result<Scene, TraceError> {
        let path = path.as_ref();
        let io = |source| TraceError::Io {
            path: path.to_owned(),
            source,
        };
        let len = std::fs::metadata(path).map_err(io)?.len();
        if len > options.max_bytes {
            return Err(TraceError::Limit {
                what: "glTF file bytes",
                limit: options.max_bytes,
                got: len,
            });
        }
        let bytes = std::fs::read(path).map_err(io)?;
        let base = path
            .parent()
            .map(Path::to_owned)
            .unwrap_or_else(|| PathBuf::from("."));
        load(&bytes, path, Some(&base), options)
    }

    /// Loads a glTF document (JSON or GLB) held in memory, with the checks of
    /// [`Scene::load_gltf`]. External buffer and image URIs are resolved against `base`; with
    /// `None` only the GLB binary chunk and `data:` URIs can be read.
    pub fn load_gltf_slice(
        bytes: &[u8],
        base: Option<&Path>,
        options: &LoadOptions,
    ) -> Result<Scene, TraceError> {
        if bytes.len() as u64 > options.max_bytes {
            return Err(TraceError::Limit {
                what: "glTF file bytes",
                limit: options.max_bytes,
                got: bytes.len() as u64,
            });
        }
        load(bytes, Path::new("<memory>"), base, options)
    }
}

/// Loads a document, attaching the warnings gathered so far to a failure.
fn load(
    bytes: &[u8],
    path: &Path,
    base: Option<&Path>,
    options: &LoadOptions,
) -> Result<Scene, TraceError> {
    let mut scene = Scene::empty();
    match load_into(&mut scene, bytes, path, base, options) {
        Ok(()) => Ok(scene),
        Err(error) if scene.warnings().is_empty() => Err(error),
        Err(error) => Err(TraceError::WithWarnings {
            error: Box::new(error),
            warnings: scene.warnings().to_vec(),
        }),
    }
}

/// The GLB header is checked here because the gltf crate subtracts its 12 bytes from the
/// declared length without checking it first. Returns the bytes the header declares: bytes
/// past them are ignored with a warning (the gltf crate would read them as a chunk).
fn check_glb_header<'b>(
    bytes: &'b [u8],
    path: &Path,
    scene: &mut Scene,
) -> Result<&'b [u8], TraceError> {
    if !bytes.starts_with(b"glTF") {
        return Ok(bytes);
    }
    let Some(declared) = bytes.get(8..12) else {
        return Err(gltf_error(path, "GLB header shorter than 12 bytes"));
    };
    let declared = u32::from_le_bytes([declared[0], declared[1], declared[2], declared[3]]);
    if declared < 20 {
        return Err(gltf_error(
            path,
            format!(
                "GLB declares a length of {declared} bytes, less than its header and a chunk header"
            ),
        ));
    }
    match bytes.get(..declared as usize) {
        Some(declared_bytes) if declared_bytes.len() < bytes.len() => {
            scene.warn(format!(
                "{} byte(s) after the GLB's declared length of {declared} are ignored",
                bytes.len() - declared_bytes.len()
            ));
            Ok(declared_bytes)
        }
        _ => Ok(bytes),
    }
}

/// The document's JSON and the GLB binary chunk, if any.
///
/// gltf-json refuses some documents glTF 2.0 allows: an animation channel without a target
/// node, a scene without a node list, an integer field written `1.0`. A document it refuses is
/// parsed again without animations (never read), with empty node lists filled in and integral
/// floats made integers, and refused with the first error only if that fails too.
fn parse(bytes: &[u8], path: &Path) -> Result<(gltf::json::Root, Option<Vec<u8>>), TraceError> {
    use gltf::json::deserialize::{from_slice, from_value};
    let (json, blob) = if bytes.starts_with(b"glTF") {
        let glb = gltf::Glb::from_slice(bytes).map_err(|e| gltf_error(path, describe(e)))?;
        (glb.json, glb.bin.map(std::borrow::Cow::into_owned))
    } else {
        (std::borrow::Cow::Borrowed(bytes), None)
    };
    let strict = match from_slice::<gltf::json::Root>(&json) {
        Ok(root) => return Ok((root, blob)),
        Err(e) => e,
    };
    let relaxed = from_slice::<gltf::json::Value>(&json)
        .ok()
        .and_then(|mut value| {
            integers_from_integral_floats(&mut value);
            let root = value.as_object_mut()?;
            root.remove("animations");
            for scene in root
                .get_mut("scenes")
                .and_then(gltf::json::Value::as_array_mut)
                .into_iter()
                .flatten()
            {
                if let Some(scene) = scene.as_object_mut() {
                    scene
                        .entry("nodes")
                        .or_insert_with(|| gltf::json::Value::Array(Vec::new()));
                }
            }
            from_value::<gltf::json::Root>(value).ok()
        });
    match relaxed {
        Some(root) => Ok((root, blob)),
        None => Err(gltf_error(path, strict)),
    }
}

/// Rewrites every number with an integral value written as a float (`1.0`) as an integer: JSON
/// does not tell them apart, glTF-Validator accepts them for integer fields, serde does not
/// (float fields take integers, so nothing else changes).
fn integers_from_integral_floats(value: &mut gltf::json::Value) {
    use gltf::json::Value;
    match value {
        Value::Number(n) => {
            if let Some(f) = n.as_f64().filter(|f| n.is_f64() && f.fract() == 0.0)
                && f.abs() < 9.0e15
            {
                *value = Value::from(f as i64);
            }
        }
        Value::Array(items) => items.iter_mut().for_each(integers_from_integral_floats),
        Value::Object(fields) => fields.values_mut().for_each(integers_from_integral_floats),
        _ => {}
    }
}

/// The gltf crate's validation, except for what glTF 2.0 allows: an accessor with neither a
/// buffer view nor sparse values (all zeros, "Accessors"), a primitive without POSITION.
fn validate(json: &gltf::json::Root, path: &Path) -> Result<(), TraceError> {
    use gltf::json::validation::{Error, Validate};
    let mut errors = Vec::new();
    json.validate(json, gltf::json::Path::new, &mut |at, error| {
        errors.push((at(), error))
    });
    errors.retain(|(at, error)| {
        !(matches!(error, Error::Missing)
            && (is_accessor_view(at.as_str()) || is_position(at.as_str())))
    });
    if errors.is_empty() {
        Ok(())
    } else {
        Err(gltf_error(path, describe(gltf::Error::Validation(errors))))
    }
}

/// Whether a JSON path is a primitive's POSITION attribute: glTF 2.0 lets a primitive omit it
/// (it is then not rendered, and skipped here).
fn is_position(at: &str) -> bool {
    at.starts_with("meshes[") && at.ends_with(".attributes[\"POSITION\"]")
}

/// Whether a JSON path is `accessors[N].bufferView`.
fn is_accessor_view(at: &str) -> bool {
    at.strip_prefix("accessors[")
        .and_then(|rest| rest.strip_suffix("].bufferView"))
        .is_some_and(|n| !n.is_empty() && n.bytes().all(|b| b.is_ascii_digit()))
}

/// Formats the gltf crate's error; validation failures become one line per JSON path.
fn describe(e: gltf::Error) -> String {
    match e {
        gltf::Error::Validation(errors) => {
            let lines: Vec<String> = errors
                .iter()
                .take(8)
                .map(|(path, error)| format!("{path}: {error}"))
                .collect();
            let more = errors.len().saturating_sub(lines.len());
            let mut message = format!("invalid document: {}", lines.join("; "));
            if more > 0 {
                message.push_str(&format!(" (and {more} more)"));
            }
            message
        }
        other => other.to_string(),
    }
}

/// The gltf crate's validation indexes `accessors` with each primitive's POSITION index, so
/// attribute references are checked before it runs.
fn check_attribute_references(json: &gltf::json::Root) -> Result<(), TraceError> {
    let n = json.accessors.len();
    for (mi, mesh) in json.meshes.iter().enumerate() {
        for (pi, primitive) in mesh.primitives.iter().enumerate() {
            for (semantic, accessor) in &primitive.attributes {
                if accessor.value() >= n {
                    return Err(TraceError::BadPrimitive {
                        mesh: mesh_label(mesh.name.as_deref(), mi),
                        primitive: pi,
                        why: format!(
                            "attribute {} refers to accessor {}, the document has {n}",
                            semantic_name(semantic),
                            accessor.value()
                        ),
                    });
                }
            }
        }
    }
    Ok(())
}

fn semantic_name(semantic: &gltf::json::validation::Checked<gltf::Semantic>) -> String {
    match semantic {
        gltf::json::validation::Checked::Valid(s) => s.to_string(),
        gltf::json::validation::Checked::Invalid => "<invalid>".to_owned(),
    }
}

fn mesh_label(name: Option<&str>, index: usize) -> String {
    name.map(str::to_owned)
        .unwrap_or_else(|| format!("#{index}"))
}

fn load_into(
    scene: &mut Scene,
    bytes: &[u8],
    path: &Path,
    base: Option<&Path>,
    options: &LoadOptions,
) -> Result<(), TraceError> {
    let bytes = check_glb_header(bytes, path, scene)?;
    let (mut json, mut blob) = parse(bytes, path)?;

    // The gltf crate's validation rejects every required extension it does not know; ours
    // refuses those that change geometry and only warns about the rest.
    let quantized = json
        .extensions_used
        .iter()
        .chain(&json.extensions_required)
        .any(|e| e == "KHR_mesh_quantization");
    for ext in std::mem::take(&mut json.extensions_required) {
        if GEOMETRY_EXTENSIONS.contains(&ext.as_str()) {
            return Err(TraceError::UnsupportedExtension { name: ext });
        }
        if !UNDERSTOOD_EXTENSIONS.contains(&ext.as_str()) {
            scene.warn(format!(
                "required extension {ext} is not supported; its data is ignored"
            ));
        }
    }
    // A geometry extension that is used but not required leaves a fallback without it: read
    // that, unless its data is missing (accessors without any, or a buffer that cannot load).
    let geometry_used = json
        .extensions_used
        .iter()
        .find(|e| GEOMETRY_EXTENSIONS.contains(&e.as_str()))
        .cloned();
    if let Some(ext) = &geometry_used {
        if json
            .accessors
            .iter()
            .any(|a| a.buffer_view.is_none() && a.sparse.is_none())
        {
            return Err(TraceError::UnsupportedExtension { name: ext.clone() });
        }
        scene.warn(format!(
            "extension {ext} is not supported; the document's fallback geometry without it is read"
        ));
    }
    check_attribute_references(&json)?;
    validate(&json, path)?;
    let document = gltf::Document::from_json_without_validation(json);

    let used = needed_buffers(&document, options.decode_textures);
    let mut buffers = Vec::new();
    for buffer in document.buffers() {
        let uri = match buffer.source() {
            gltf::buffer::Source::Bin => "<GLB BIN chunk>".to_owned(),
            gltf::buffer::Source::Uri(uri) => uri.chars().take(120).collect(),
        };
        // A URI that does not decode is malformed even if the buffer is never read.
        if let gltf::buffer::Source::Uri(full) = buffer.source()
            && !percent_decodes_to_utf8(full)
        {
            return Err(TraceError::Buffer {
                index: buffer.index(),
                uri,
                message: "the URI's percent-encoding does not decode to UTF-8".to_owned(),
            });
        }
        if !used.contains(&buffer.index()) {
            buffers.push(gltf::buffer::Data(Vec::new()));
            continue;
        }
        let unsupported = |error: TraceError| match &geometry_used {
            Some(ext) => TraceError::UnsupportedExtension { name: ext.clone() },
            None => error,
        };
        if buffer.length() as u64 > options.max_bytes {
            return Err(TraceError::Limit {
                what: "glTF buffer bytes",
                limit: options.max_bytes,
                got: buffer.length() as u64,
            });
        }
        if matches!(buffer.source(), gltf::buffer::Source::Bin) && blob.is_none() {
            return Err(unsupported(TraceError::Buffer {
                index: buffer.index(),
                uri,
                message: "it has no uri, and the document has no GLB binary chunk for it \
                          (only a .glb file's first buffer may omit its uri)"
                    .to_owned(),
            }));
        }
        let data = gltf::buffer::Data::from_source_and_blob(buffer.source(), base, &mut blob)
            .map_err(|e| {
                unsupported(TraceError::Buffer {
                    index: buffer.index(),
                    uri: uri.clone(),
                    message: e.to_string(),
                })
            })?;
        if data.len() < buffer.length() {
            return Err(TraceError::Buffer {
                index: buffer.index(),
                uri,
                message: format!(
                    "{} bytes, the document declares {}",
                    data.len(),
                    buffer.length()
                ),
            });
        }
        buffers.push(data);
    }

    let material_ids = load_materials(&document, &buffers, base, options, scene)?;
    let reader = AccessorReader {
        json: document.as_json(),
        buffers: &buffers,
        max_bytes: options.max_bytes,
    };
    let mut default_material = None;

    let Some(root) = document
        .default_scene()
        .or_else(|| document.scenes().next())
    else {
        scene.warn("the document has no scene".to_owned());
        return Ok(());
    };
    // Depth-first over the hierarchy; glTF nodes form disjoint trees, so a node reached twice
    // is a cycle or a node with two parents, both invalid.
    let mut visited = vec![false; document.nodes().len()];
    let mut stack: Vec<(gltf::Node<'_>, Mat4)> =
        root.nodes().map(|n| (n, Mat4::IDENTITY)).collect();
    let mut triangle_count: u64 = 0;
    let mut skipped_modes = Vec::new();
    let mut positionless = Vec::new();
    let mut without_data = Vec::new();
    // TEXCOORD_1 of every kept triangle, used only if every primitive with triangles has it.
    let mut lightmap_uvs: Vec<[Vec2; 3]> = Vec::new();
    let mut lightmap_uvs_everywhere = true;
    while let Some((node, parent)) = stack.pop() {
        if std::mem::replace(&mut visited[node.index()], true) {
            return Err(TraceError::BadNode {
                node: node.index(),
                why: "reached twice: the hierarchy has a cycle or a node with two parents"
                    .to_owned(),
            });
        }
        let world = parent * Mat4::from_cols_array_2d(&node.transform().matrix());
        if let Some(mesh) = node.mesh() {
            let mesh_name = mesh_label(mesh.name(), mesh.index());
            let weights = node.weights().or(mesh.weights()).unwrap_or(&[]);
            // A mirroring transform turns counter-clockwise triangles clockwise (glTF 2.0,
            // "Transformations"): swap two corners to keep the front face.
            let mirrored = world.determinant() < 0.0;
            for primitive in mesh.primitives() {
                let pi = primitive.index();
                let what = format!("mesh '{mesh_name}' primitive {pi}");
                use gltf::mesh::Mode;
                let mode = primitive.mode();
                if !matches!(
                    mode,
                    Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan
                ) {
                    skipped_modes.push(format!("{what} ({mode:?})"));
                    continue;
                }
                let bad = |why: String| TraceError::BadPrimitive {
                    mesh: mesh_name.clone(),
                    primitive: pi,
                    why,
                };
                let Some(position) = primitive.get(&gltf::Semantic::Positions) else {
                    positionless.push(what);
                    continue;
                };
                // An accessor without data is all zeros: zero positions that no weighted morph
                // target moves, or zero indices, make only degenerate triangles. They are
                // skipped unread, so a large count in a tiny file allocates nothing.
                let moved = primitive.morph_targets().enumerate().any(|(k, target)| {
                    target.positions().is_some_and(|a| has_data(&a))
                        && weights.get(k).is_some_and(|&w| w != 0.0)
                });
                if (!has_data(&position) && !moved)
                    || primitive.indices().is_some_and(|ix| !has_data(&ix))
                {
                    without_data.push(what);
                    continue;
                }
                let mut positions =
                    reader.positions(position.index(), quantized, &format!("{what} POSITION"))?;
                for (k, target) in primitive.morph_targets().enumerate() {
                    let (Some(offsets), Some(&w)) = (target.positions(), weights.get(k)) else {
                        continue;
                    };
                    if w == 0.0 || !has_data(&offsets) {
                        continue;
                    }
                    let offsets = reader.positions(
                        offsets.index(),
                        quantized,
                        &format!("{what} morph target {k} POSITION"),
                    )?;
                    if offsets.len() != positions.len() {
                        return Err(bad(format!(
                            "morph target {k} has {} positions for {} vertices",
                            offsets.len(),
                            positions.len()
                        )));
                    }
                    for (p, d) in positions.iter_mut().zip(offsets) {
                        *p += w * d;
                    }
                }
                let positions: Vec<Vec3> = positions
                    .into_iter()
                    .map(|p| world.transform_point3(p))
                    .collect();
                let indices: Vec<u32> = match primitive.indices() {
                    Some(ix) => {
                        reader.indices(ix.index(), positions.len(), &format!("{what} indices"))?
                    }
                    None => (0..positions.len() as u32).collect(),
                };
                let texcoords = match primitive.get(&gltf::Semantic::TexCoords(1)) {
                    Some(a) if has_data(&a) => {
                        let uv = reader.texcoords(a.index(), &format!("{what} TEXCOORD_1"))?;
                        if uv.len() != positions.len() {
                            return Err(bad(format!(
                                "TEXCOORD_1 has {} values for {} vertices",
                                uv.len(),
                                positions.len()
                            )));
                        }
                        Some(uv)
                    }
                    _ => {
                        lightmap_uvs_everywhere = false;
                        None
                    }
                };
                let triangles = triangulate(mode, &indices);
                if mode == Mode::Triangles && !indices.len().is_multiple_of(3) {
                    scene.warn(format!(
                        "{what}: {} indices is not a multiple of 3; the rest is ignored",
                        indices.len()
                    ));
                }
                triangle_count += triangles.len() as u64;
                if triangle_count > options.max_triangles {
                    return Err(TraceError::Limit {
                        what: "triangles",
                        limit: options.max_triangles,
                        got: triangle_count,
                    });
                }
                let material = match primitive.material().index() {
                    Some(i) => material_ids[i],
                    None => *default_material.get_or_insert_with(|| {
                        scene.push_material(Material::diffuse("default", options.default_albedo))
                    }),
                };
                for (k, tri) in triangles.into_iter().enumerate() {
                    let [a, b, c] = tri.map(|i| positions[i as usize]);
                    let t = if mirrored { [a, c, b] } else { [a, b, c] };
                    let kept = scene.triangles().len();
                    scene.push_triangle(t, material, &what, k)?;
                    if let Some(uv) = &texcoords
                        && scene.triangles().len() > kept
                    {
                        let [a, b, c] = tri.map(|i| uv[i as usize]);
                        lightmap_uvs.push(if mirrored { [a, c, b] } else { [a, b, c] });
                    }
                }
            }
        }
        if let Some(light) = node.light() {
            let kind = match light.kind() {
                Kind::Directional => LightKind::Directional,
                Kind::Point => LightKind::Point,
                Kind::Spot {
                    inner_cone_angle,
                    outer_cone_angle,
                } => LightKind::Spot {
                    inner_cone_angle,
                    outer_cone_angle,
                },
            };
            scene.push_light(PunctualLight {
                name: light.name().map(str::to_owned),
                kind,
                color: Vec3::from_array(light.color()),
                intensity: light.intensity(),
                range: light.range(),
                position: world.transform_point3(Vec3::ZERO),
                direction: world.transform_vector3(Vec3::NEG_Z).normalize_or_zero(),
            });
        }
        if let Some(camera) = node.camera() {
            match camera.projection() {
                gltf::camera::Projection::Perspective(p) => scene.push_camera(Camera {
                    name: camera.name().map(str::to_owned),
                    to_world: world,
                    yfov: p.yfov(),
                    aspect_ratio: p.aspect_ratio(),
                    znear: p.znear(),
                }),
                gltf::camera::Projection::Orthographic(_) => {
                    scene.warn(format!("orthographic camera {} skipped", camera.index()))
                }
            }
        }
        stack.extend(node.children().map(|c| (c, world)));
    }
    if lightmap_uvs_everywhere && lightmap_uvs.len() == scene.triangles().len() {
        scene.set_lightmap_uvs(lightmap_uvs);
    }
    if !without_data.is_empty() {
        scene.warn(format!(
            "{} primitive(s) skipped whose positions or indices have no data (all zeros: no \
             area): {}",
            without_data.len(),
            without_data.join(", ")
        ));
    }
    if !positionless.is_empty() {
        scene.warn(format!(
            "{} primitive(s) without POSITION skipped (glTF does not render them): {}",
            positionless.len(),
            positionless.join(", ")
        ));
    }
    if !skipped_modes.is_empty() {
        scene.warn(format!(
            "{} point or line primitive(s) skipped (only surfaces are traced): {}",
            skipped_modes.len(),
            skipped_modes.join(", ")
        ));
    }
    Ok(())
}

/// Whether an accessor has a buffer view or sparse values; one with neither is all zeros.
fn has_data(accessor: &gltf::Accessor<'_>) -> bool {
    accessor.view().is_some() || accessor.sparse().is_some()
}

/// The buffers the loader reads: those holding the positions, indices, `TEXCOORD_1` and
/// morph-target positions of any primitive (and the images, when textures are decoded). Others (animations,
/// skins, other attributes, placeholders) are never loaded, so they cannot fail a load.
fn needed_buffers(
    document: &gltf::Document,
    decode_textures: bool,
) -> std::collections::HashSet<usize> {
    let mut accessors = Vec::new();
    for primitive in document.meshes().flat_map(|m| m.primitives()) {
        accessors.extend(primitive.get(&gltf::Semantic::Positions));
        accessors.extend(primitive.indices());
        accessors.extend(primitive.get(&gltf::Semantic::TexCoords(1)));
        accessors.extend(primitive.morph_targets().filter_map(|t| t.positions()));
    }
    let mut buffers = std::collections::HashSet::new();
    for accessor in accessors {
        buffers.extend(accessor.view().map(|v| v.buffer().index()));
        if let Some(sparse) = accessor.sparse() {
            buffers.insert(sparse.indices().view().buffer().index());
            buffers.insert(sparse.values().view().buffer().index());
        }
    }
    if decode_textures {
        for image in document.images() {
            if let gltf::image::Source::View { view, .. } = image.source() {
                buffers.insert(view.buffer().index());
            }
        }
    }
    buffers
}

/// Whether a relative URI's `%XX` escapes decode to UTF-8: the gltf crate unwraps that
/// decoding. URIs with a scheme (`data:`, `file:`) are not decoded.
fn percent_decodes_to_utf8(uri: &str) -> bool {
    if uri.contains(':') {
        return true;
    }
    let hex = |b: u8| (b as char).to_digit(16);
    let bytes = uri.as_bytes();
    let mut decoded = Vec::with_capacity(bytes.len());
    let mut i = 0;
    while i < bytes.len() {
        let escape = (bytes[i] == b'%')
            .then(|| Some(hex(*bytes.get(i + 1)?)? * 16 + hex(*bytes.get(i + 2)?)?))
            .flatten();
        match escape {
            Some(b) => {
                decoded.push(b as u8);
                i += 3;
            }
            None => {
                decoded.push(bytes[i]);
                i += 1;
            }
        }
    }
    String::from_utf8(decoded).is_ok()
}

/// Extensions that change how geometry is stored or placed: a file requiring one of them
/// cannot be read correctly without it.
const GEOMETRY_EXTENSIONS: &[&str] = &[
    "KHR_draco_mesh_compression",
    "EXT_meshopt_compression",
    "EXT_mesh_gpu_instancing",
];

/// Vertex index triples of a triangle list, strip or fan (glTF 2.0, "Meshes").
fn triangulate(mode: gltf::mesh::Mode, indices: &[u32]) -> Vec<[u32; 3]> {
    use gltf::mesh::Mode;
    let n = indices.len();
    match mode {
        Mode::TriangleStrip => (0..n.saturating_sub(2))
            .map(|i| {
                // Every other triangle of a strip is wound the other way round.
                let odd = i % 2;
                [indices[i], indices[i + 1 + odd], indices[i + 2 - odd]]
            })
            .collect(),
        Mode::TriangleFan => (0..n.saturating_sub(2))
            .map(|i| [indices[i + 1], indices[i + 2], indices[0]])
            .collect(),
        _ => indices
            .chunks_exact(3)
            .map(|t| [t[0], t[1], t[2]])
            .collect(),
    }
}

/// Reads accessors with every offset, stride, count and length checked against the buffers
/// actually loaded (the gltf crate's reader asserts or indexes out of bounds instead).
struct AccessorReader<'a> {
    json: &'a gltf::json::Root,
    buffers: &'a [gltf::buffer::Data],
    max_bytes: u64,
}

fn component_size(c: ComponentType) -> usize {
    match c {
        ComponentType::I8 | ComponentType::U8 => 1,
        ComponentType::I16 | ComponentType::U16 => 2,
        ComponentType::U32 | ComponentType::F32 => 4,
    }
}

/// One little-endian component; `bytes` holds at least its size.
fn component(bytes: &[u8], c: ComponentType) -> f64 {
    match c {
        ComponentType::I8 => bytes[0] as i8 as f64,
        ComponentType::U8 => bytes[0] as f64,
        ComponentType::I16 => i16::from_le_bytes([bytes[0], bytes[1]]) as f64,
        ComponentType::U16 => u16::from_le_bytes([bytes[0], bytes[1]]) as f64,
        ComponentType::U32 => u32::from_le_bytes([bytes[0], bytes[1], bytes[2], bytes[3]]) as f64,
        ComponentType::F32 => f32::from_le_bytes([bytes[0], bytes[1], bytes[2], bytes[3]]) as f64,
    }
}

/// The glTF mapping of a normalised integer to [-1, 1] or [0, 1].
fn normalize(v: f64, c: ComponentType) -> f64 {
    match c {
        ComponentType::I8 => (v / 127.0).max(-1.0),
        ComponentType::U8 => v / 255.0,
        ComponentType::I16 => (v / 32767.0).max(-1.0),
        ComponentType::U16 => v / 65535.0,
        ComponentType::U32 | ComponentType::F32 => v,
    }
}

impl AccessorReader<'_> {
    fn bad(&self, accessor: usize, used_as: &str, why: String) -> TraceError {
        TraceError::BadAccessor {
            accessor,
            used_as: used_as.to_owned(),
            why,
        }
    }

    /// The bytes of a buffer view, checked against its buffer's declared and loaded lengths.
    fn view(&self, view: usize, accessor: usize, used_as: &str) -> Result<&[u8], TraceError> {
        let v = &self.json.buffer_views[view];
        let buffer = v.buffer.value();
        let declared = self.json.buffers[buffer].byte_length.0;
        let offset = v.byte_offset.map_or(0, |o| o.0);
        let end = offset
            .checked_add(v.byte_length.0)
            .filter(|&e| e <= declared);
        let data = &self.buffers[buffer].0;
        end.and_then(|end| data.get(offset as usize..end as usize))
            .ok_or_else(|| {
                self.bad(
                    accessor,
                    used_as,
                    format!(
                        "bufferView {view} (offset {offset}, length {}) runs past buffer {buffer} ({declared} bytes)",
                        v.byte_length.0
                    ),
                )
            })
    }

    /// Every component of accessor `index` (normalised if the accessor says so), after checking
    /// its type is `dims` components of one of `allowed`.
    fn read(
        &self,
        index: usize,
        dims: usize,
        allowed: &[ComponentType],
        used_as: &str,
    ) -> Result<(Vec<f64>, ComponentType), TraceError> {
        use gltf::json::validation::Checked;
        let a = &self.json.accessors[index];
        let bad = |why: String| self.bad(index, used_as, why);
        let (Checked::Valid(ty), Checked::Valid(ct)) = (a.type_, a.component_type) else {
            return Err(bad("invalid type or componentType".to_owned()));
        };
        let ct = ct.0;
        let vector = !matches!(ty, Type::Mat2 | Type::Mat3 | Type::Mat4);
        if ty.multiplicity() != dims || !vector || !allowed.contains(&ct) {
            return Err(bad(format!(
                "{ty:?} of {ct:?}, expected {dims} component(s) of {allowed:?}"
            )));
        }
        let count = a.count.0;
        if count == 0 {
            return Err(bad("count is 0".to_owned()));
        }
        let size = component_size(ct);
        let elem = (dims * size) as u64;
        let mut values = match a.buffer_view {
            Some(view) => {
                let bytes = self.view(view.value(), index, used_as)?;
                let stride = self.json.buffer_views[view.value()]
                    .byte_stride
                    .map_or(elem, |s| s.0 as u64);
                if stride < elem {
                    return Err(bad(format!(
                        "byteStride {stride} is smaller than its {elem}-byte elements"
                    )));
                }
                let offset = a.byte_offset.map_or(0, |o| o.0);
                let need = (count - 1)
                    .checked_mul(stride)
                    .and_then(|n| n.checked_add(offset))
                    .and_then(|n| n.checked_add(elem));
                if need.is_none_or(|n| n > bytes.len() as u64) {
                    return Err(bad(format!(
                        "count {count} at stride {stride} from offset {offset} runs past its bufferView ({} bytes)",
                        bytes.len()
                    )));
                }
                let mut values = Vec::with_capacity(count as usize * dims);
                for i in 0..count {
                    let at = (offset + i * stride) as usize;
                    for c in 0..dims {
                        values.push(component(&bytes[at + c * size..], ct));
                    }
                }
                values
            }
            None => {
                // An accessor without a view is zeros (then the sparse values, if any): no stored
                // data bounds its count, so the decoded size (8 bytes a component) is bounded
                // like a buffer's.
                let decoded = count.saturating_mul(dims as u64 * 8);
                if decoded > self.max_bytes {
                    return Err(TraceError::Limit {
                        what: "glTF accessor bytes",
                        limit: self.max_bytes,
                        got: decoded,
                    });
                }
                vec![0.0; count as usize * dims]
            }
        };
        if let Some(sparse) = &a.sparse {
            self.apply_sparse(sparse, &mut values, count, dims, ct, index, used_as)?;
        }
        if a.normalized {
            values.iter_mut().for_each(|v| *v = normalize(*v, ct));
        }
        Ok((values, ct))
    }

    #[allow(clippy::too_many_arguments)]
    fn apply_sparse(
        &self,
        sparse: &gltf::json::accessor::sparse::Sparse,
        values: &mut [f64],
        count: u64,
        dims: usize,
        ct: ComponentType,
        index: usize,
        used_as: &str,
    ) -> Result<(), TraceError> {
        use gltf::json::validation::Checked;
        let bad = |why: String| self.bad(index, used_as, why);
        let n = sparse.count.0;
        if n == 0 || n > count {
            return Err(bad(format!("sparse count {n} for {count} elements")));
        }
        let Checked::Valid(ict) = sparse.indices.component_type else {
            return Err(bad("invalid sparse index componentType".to_owned()));
        };
        let ict = ict.0;
        if !matches!(
            ict,
            ComponentType::U8 | ComponentType::U16 | ComponentType::U32
        ) {
            return Err(bad(format!("sparse indices of {ict:?}")));
        }
        let isize = component_size(ict) as u64;
        let elem = (dims * component_size(ct)) as u64;
        let slice = |view: usize, offset: u64, each: u64| -> Result<&[u8], TraceError> {
            let bytes = self.view(view, index, used_as)?;
            let need = n.checked_mul(each).and_then(|x| x.checked_add(offset));
            match need {
                Some(end) if end <= bytes.len() as u64 => Ok(&bytes[offset as usize..end as usize]),
                _ => Err(bad(format!(
                    "sparse data ({n} × {each} bytes from offset {offset}) runs past bufferView {view}"
                ))),
            }
        };
        let ix = slice(
            sparse.indices.buffer_view.value(),
            sparse.indices.byte_offset.0,
            isize,
        )?;
        let vals = slice(
            sparse.values.buffer_view.value(),
            sparse.values.byte_offset.0,
            elem,
        )?;
        let size = component_size(ct);
        for k in 0..n as usize {
            let target = component(&ix[k * isize as usize..], ict) as u64;
            if target >= count {
                return Err(bad(format!("sparse index {target} past {count} elements")));
            }
            for c in 0..dims {
                values[target as usize * dims + c] =
                    component(&vals[k * elem as usize + c * size..], ct);
            }
        }
        Ok(())
    }

    /// Vertex positions: VEC3 of FLOAT, or with `KHR_mesh_quantization` of (normalised) 8- or
    /// 16-bit integers, dequantised.
    fn positions(
        &self,
        index: usize,
        quantized: bool,
        used_as: &str,
    ) -> Result<Vec<Vec3>, TraceError> {
        let allowed: &[ComponentType] = if quantized {
            &[
                ComponentType::F32,
                ComponentType::I8,
                ComponentType::U8,
                ComponentType::I16,
                ComponentType::U16,
            ]
        } else {
            &[ComponentType::F32]
        };
        let (values, _) = self.read(index, 3, allowed, used_as)?;
        Ok(values
            .chunks_exact(3)
            .map(|p| Vec3::new(p[0] as f32, p[1] as f32, p[2] as f32))
            .collect())
    }

    /// Texture coordinates: VEC2 of FLOAT, or of normalised unsigned 8- or 16-bit integers.
    fn texcoords(&self, index: usize, used_as: &str) -> Result<Vec<Vec2>, TraceError> {
        let (values, _) = self.read(
            index,
            2,
            &[ComponentType::F32, ComponentType::U8, ComponentType::U16],
            used_as,
        )?;
        Ok(values
            .chunks_exact(2)
            .map(|p| Vec2::new(p[0] as f32, p[1] as f32))
            .collect())
    }

    /// Triangle indices: SCALAR of unsigned 8-, 16- or 32-bit integers, each below `vertices`.
    fn indices(
        &self,
        index: usize,
        vertices: usize,
        used_as: &str,
    ) -> Result<Vec<u32>, TraceError> {
        let (values, _) = self.read(
            index,
            1,
            &[ComponentType::U8, ComponentType::U16, ComponentType::U32],
            used_as,
        )?;
        if self.json.accessors[index].normalized {
            return Err(self.bad(index, used_as, "indices are normalized".to_owned()));
        }
        values
            .into_iter()
            .map(|v| {
                let v = v as u32;
                if (v as usize) < vertices {
                    Ok(v)
                } else {
                    Err(self.bad(
                        index,
                        used_as,
                        format!("index {v} past {vertices} vertices"),
                    ))
                }
            })
            .collect()
    }
}

/// Converts every material of the document, returning the scene material index of each.
fn load_materials(
    document: &gltf::Document,
    buffers: &[gltf::buffer::Data],
    base: Option<&Path>,
    options: &LoadOptions,
    scene: &mut Scene,
) -> Result<Vec<u32>, TraceError> {
    let mut ids = Vec::new();
    let mut undecoded = 0usize;
    for m in document.materials() {
        let pbr = m.pbr_metallic_roughness();
        let [r, g, b, _] = pbr.base_color_factor();
        let factor = Vec3::new(r, g, b);
        let texture_mean = match pbr.base_color_texture() {
            None => Vec3::ONE,
            Some(info) if options.decode_textures => {
                let mean = match info.texture().source() {
                    Some(image) => texture_mean(image, buffers, base)?,
                    None => None,
                };
                match mean {
                    Some(mean) => mean,
                    None => {
                        undecoded += 1;
                        options.default_albedo
                    }
                }
            }
            Some(_) => {
                undecoded += 1;
                options.default_albedo
            }
        };
        let emissive = Vec3::from_array(m.emissive_factor()) * m.emissive_strength().unwrap_or(1.0);
        let name = m
            .name()
            .map(str::to_owned)
            .unwrap_or_else(|| format!("#{}", ids.len()));
        ids.push(scene.push_material(Material {
            name,
            albedo: factor * texture_mean,
            emissive,
            double_sided: m.double_sided(),
        }));
    }
    if undecoded > 0 {
        scene.warn(format!(
            "{undecoded} material(s) take their colour from a texture that was not decoded: default albedo {:?} used",
            options.default_albedo.to_array()
        ));
    }
    Ok(ids)
}

/// The mean linear colour of an image, `None` if its format cannot be decoded.
fn texture_mean(
    image: gltf::Image<'_>,
    buffers: &[gltf::buffer::Data],
    base: Option<&Path>,
) -> Result<Option<Vec3>, TraceError> {
    let index = image.index();
    let bytes = match image.source() {
        gltf::image::Source::Uri { uri, .. } => {
            if uri.starts_with("data:") {
                return Ok(None);
            }
            let image_error = |message: String| TraceError::Image {
                index,
                uri: uri.to_owned(),
                message,
            };
            let base = base.ok_or_else(|| {
                image_error("no directory to resolve it against (loaded from memory)".to_owned())
            })?;
            std::fs::read(base.join(uri)).map_err(|e| image_error(e.to_string()))?
        }
        gltf::image::Source::View { view, .. } => {
            let data = buffers
                .get(view.buffer().index())
                .map(|d| &d.0[..])
                .unwrap_or(&[]);
            let range = view
                .offset()
                .checked_add(view.length())
                .map(|end| view.offset()..end);
            match range.and_then(|r| data.get(r)) {
                Some(s) => s.to_vec(),
                None => return Ok(None),
            }
        }
    };
    let Ok(img) = image::load_from_memory(&bytes) else {
        return Ok(None);
    };
    let rgb = img.to_rgb32f();
    let n = (rgb.width() as u64 * rgb.height() as u64).max(1) as f64;
    let mut sum = [0.0f64; 3];
    for p in rgb.pixels() {
        for c in 0..3 {
            sum[c] += srgb_to_linear(p.0[c]) as f64;
        }
    }
    let mean = Vec4::new(
        (sum[0] / n) as f32,
        (sum[1] / n) as f32,
        (sum[2] / n) as f32,
        0.0,
    );
    Ok(Some(mean.truncate()))
}
