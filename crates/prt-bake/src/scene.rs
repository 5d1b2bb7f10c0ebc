//! The scene a bake starts from.

use std::path::Path;

use prt_trace::{LoadOptions, Scene};

use crate::BakeError;

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
