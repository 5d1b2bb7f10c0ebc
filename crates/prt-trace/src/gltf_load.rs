//! glTF 2.0 loading: geometry, diffuse materials, punctual lights and cameras.

use std::path::{Path, PathBuf};

use glam::{Mat4, Vec3, Vec4};
use gltf::khr_lights_punctual::Kind;

use crate::TraceError;
use crate::scene::{Camera, LightKind, Material, PunctualLight, Scene};

/// Extensions whose meaning the loader honours; any other *required* extension only warns,
/// since the baker needs geometry and diffuse colour alone.
const UNDERSTOOD_EXTENSIONS: &[&str] = &["KHR_lights_punctual", "KHR_materials_emissive_strength"];

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
    /// [`Material`]s, `KHR_lights_punctual` lights and perspective cameras are placed.
    ///
    /// Required extensions that only concern materials or textures (for example
    /// `AMD_split_roughnessMetallic`, `MSFT_texture_dds`) do not stop loading: they are listed in
    /// [`Scene::warnings`], and the rest of the document is validated as usual. Errors: an
    /// unreadable file, malformed JSON/GLB, a missing buffer (naming its URI), a primitive mode
    /// other than triangles (naming mesh and primitive), non-finite positions, exceeded limits.
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
        let gltf::Gltf { document, mut blob } =
            gltf::Gltf::from_slice_without_validation(&bytes).map_err(|e| gltf_error(path, e))?;
        drop(bytes);

        let mut scene = Scene::empty();
        // Validate everything except the required-extension list, which would reject files whose
        // required extensions only concern materials.
        let mut json = document.into_json();
        for ext in std::mem::take(&mut json.extensions_required) {
            if !UNDERSTOOD_EXTENSIONS.contains(&ext.as_str()) {
                scene.warn(format!(
                    "required extension {ext} is not supported; its data is ignored"
                ));
            }
        }
        let document =
            gltf::Document::from_json(json).map_err(|e| gltf_error(path, format!("{e:?}")))?;
        let base = path
            .parent()
            .map(Path::to_owned)
            .unwrap_or_else(|| PathBuf::from("."));

        let mut buffers = Vec::new();
        for buffer in document.buffers() {
            let uri = match buffer.source() {
                gltf::buffer::Source::Bin => "<GLB BIN chunk>".to_owned(),
                gltf::buffer::Source::Uri(uri) => uri.chars().take(120).collect(),
            };
            if buffer.length() as u64 > options.max_bytes {
                return Err(TraceError::Limit {
                    what: "glTF buffer bytes",
                    limit: options.max_bytes,
                    got: buffer.length() as u64,
                });
            }
            let data =
                gltf::buffer::Data::from_source_and_blob(buffer.source(), Some(&base), &mut blob)
                    .map_err(|e| TraceError::Buffer {
                    index: buffer.index(),
                    uri: uri.clone(),
                    message: e.to_string(),
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

        let material_ids = load_materials(&document, &buffers, &base, options, &mut scene)?;
        let mut default_material = None;

        let Some(root) = document
            .default_scene()
            .or_else(|| document.scenes().next())
        else {
            scene.warn("the document has no scene".to_owned());
            return Ok(scene);
        };
        // Depth-first over the hierarchy with an explicit stack; the step budget guards against
        // node cycles in a malformed file.
        let mut stack: Vec<(gltf::Node<'_>, Mat4)> =
            root.nodes().map(|n| (n, Mat4::IDENTITY)).collect();
        let mut budget = 4 * document.nodes().len() + 16;
        let mut triangle_count: u64 = 0;
        while let Some((node, parent)) = stack.pop() {
            budget = budget
                .checked_sub(1)
                .ok_or_else(|| gltf_error(path, "node hierarchy has a cycle"))?;
            let world = parent * Mat4::from_cols_array_2d(&node.transform().matrix());
            if let Some(mesh) = node.mesh() {
                let mesh_name = mesh
                    .name()
                    .map(str::to_owned)
                    .unwrap_or_else(|| format!("#{}", mesh.index()));
                for primitive in mesh.primitives() {
                    let pi = primitive.index();
                    if primitive.mode() != gltf::mesh::Mode::Triangles {
                        return Err(TraceError::UnsupportedMode {
                            mesh: mesh_name,
                            primitive: pi,
                            mode: format!("{:?}", primitive.mode()),
                        });
                    }
                    let bad = |why: String| TraceError::BadPrimitive {
                        mesh: mesh_name.clone(),
                        primitive: pi,
                        why,
                    };
                    let reader = primitive.reader(|b| buffers.get(b.index()).map(|d| &d.0[..]));
                    let positions: Vec<Vec3> = reader
                        .read_positions()
                        .ok_or_else(|| bad("no POSITION attribute".to_owned()))?
                        .map(|p| world.transform_point3(Vec3::from_array(p)))
                        .collect();
                    let indices: Vec<u32> = match reader.read_indices() {
                        Some(ix) => ix.into_u32().collect(),
                        None => (0..positions.len() as u32).collect(),
                    };
                    if !indices.len().is_multiple_of(3) {
                        scene.warn(format!(
                            "mesh '{mesh_name}' primitive {pi}: {} indices is not a multiple of 3; the rest is ignored",
                            indices.len()
                        ));
                    }
                    triangle_count += (indices.len() / 3) as u64;
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
                            scene
                                .push_material(Material::diffuse("default", options.default_albedo))
                        }),
                    };
                    let what = format!("mesh '{mesh_name}' primitive {pi}");
                    for (k, tri) in indices.chunks_exact(3).enumerate() {
                        let mut t = [Vec3::ZERO; 3];
                        for c in 0..3 {
                            t[c] = *positions.get(tri[c] as usize).ok_or_else(|| {
                                bad(format!(
                                    "index {} past {} vertices",
                                    tri[c],
                                    positions.len()
                                ))
                            })?;
                        }
                        scene.push_triangle(t, material, &what, k)?;
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
        Ok(scene)
    }
}

/// Converts every material of the document, returning the scene material index of each.
fn load_materials(
    document: &gltf::Document,
    buffers: &[gltf::buffer::Data],
    base: &Path,
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
    base: &Path,
) -> Result<Option<Vec3>, TraceError> {
    let index = image.index();
    let bytes = match image.source() {
        gltf::image::Source::Uri { uri, .. } => {
            if uri.starts_with("data:") {
                return Ok(None);
            }
            std::fs::read(base.join(uri)).map_err(|e| TraceError::Image {
                index,
                uri: uri.to_owned(),
                message: e.to_string(),
            })?
        }
        gltf::image::Source::View { view, .. } => {
            let data = buffers
                .get(view.buffer().index())
                .map(|d| &d.0[..])
                .unwrap_or(&[]);
            match data.get(view.offset()..view.offset() + view.length()) {
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
