//! The scene a bake starts from.

use std::path::Path;

use prt_trace::{LoadOptions, Scene};

use crate::BakeError;
use crate::tiles::Fnv1a64;

/// A scene to bake and the name the container records for it.
#[derive(Debug, Clone)]
pub struct SceneInput {
    /// Recorded as the container's `scene` attribute.
    pub name: String,
    /// The triangles, materials and lights.
    pub scene: Scene,
}

impl SceneInput {
    /// The built-in Cornell box, named `cornell_box`.
    pub fn cornell_box() -> SceneInput {
        SceneInput {
            name: "cornell_box".into(),
            scene: Scene::cornell_box(),
        }
    }

    /// A glTF 2.0 file, named after its lower-cased file stem. Errors if the file is missing,
    /// cannot be loaded, or holds no triangles.
    pub fn load_gltf(path: &Path) -> Result<SceneInput, BakeError> {
        if !path.exists() {
            return Err(BakeError::MissingScene(path.to_path_buf()));
        }
        let name = path
            .file_stem()
            .map(|s| s.to_string_lossy().to_lowercase())
            .unwrap_or_else(|| "scene".into());
        let scene = Scene::load_gltf(path, &LoadOptions::default()).map_err(|source| {
            BakeError::LoadScene {
                path: path.to_path_buf(),
                source,
            }
        })?;
        if scene.triangles().is_empty() {
            return Err(BakeError::EmptyScene {
                scene: path.display().to_string(),
            });
        }
        Ok(SceneInput { name, scene })
    }
}

/// A 64-bit FNV-1a hash of the loaded scene (triangles, materials, lights' count), as
/// `fnv1a64:HEX`: what a tile worker compares to refuse a scene edited since its plan, and what a cache of
/// traced data keys on.
pub fn scene_hash(scene: &Scene) -> String {
    let mut hash = Fnv1a64::default();
    for triangle in scene.triangles() {
        for vertex in triangle {
            for c in vertex.to_array() {
                hash.update(&c.to_le_bytes());
            }
        }
    }
    for id in scene.material_ids() {
        hash.update(&id.to_le_bytes());
    }
    for material in scene.materials() {
        for c in material
            .albedo
            .to_array()
            .into_iter()
            .chain(material.emissive.to_array())
        {
            hash.update(&c.to_le_bytes());
        }
        hash.update(&[u8::from(material.double_sided)]);
    }
    hash.update(&(scene.lights().len() as u64).to_le_bytes());
    hash.label()
}
