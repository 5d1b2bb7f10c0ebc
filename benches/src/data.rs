//! The shared data the experiments read (../shared next to the repository: scenes and
//! environment maps), the folder where they cache what is slow to recompute, and PNG output.

use std::path::{Path, PathBuf};

use prt_bake::SceneInput;
use prt_sphere::LatLongMap;
use prt_texture::Limits;
use prt_trace::{LoadOptions, Scene};

/// The benches package's folder.
fn benches_dir() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// The shared data folder, `../shared` beside the repository (scenes, envmaps, design notes).
pub fn shared_dir() -> PathBuf {
    benches_dir().join("../../shared")
}

/// The folder `target/<kind>` of the workspace, where experiments cache results that take
/// minutes (brute-force references, traced volumes). Not created here.
pub fn cache_dir(kind: &str) -> PathBuf {
    benches_dir().join("../target").join(kind)
}

/// The environment map `../shared/envmaps/<name>.hdr` as a lat-long map, or why it cannot be
/// read.
pub fn load_envmap(name: &str) -> Result<LatLongMap, String> {
    let path = shared_dir().join("envmaps").join(format!("{name}.hdr"));
    let image = image::open(&path)
        .map_err(|e| format!("{}: {e}", path.display()))?
        .into_rgb32f();
    let (w, h) = image.dimensions();
    LatLongMap::new(w as usize, h as usize, image.into_raw())
        .map_err(|e| format!("{}: {e}", path.display()))
}

/// The names (file stems) of every `.hdr` map in `../shared/envmaps`, sorted; empty when the
/// folder is absent.
pub fn envmap_names() -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(shared_dir().join("envmaps"))
        .map(|dir| {
            dir.filter_map(|e| {
                let path = e.ok()?.path();
                (path.extension()? == "hdr")
                    .then(|| path.file_stem()?.to_str().map(String::from))?
            })
            .collect()
        })
        .unwrap_or_default();
    names.sort();
    names
}

/// A scene by name: `cornell` or `town` (prt-trace's built-in Cornell box and outdoor town),
/// `sponza` or `gas_station` (glTF in `../shared/scenes`), or why it cannot be loaded.
pub fn load_scene(name: &str) -> Result<Scene, String> {
    let file = match name {
        "cornell" => return Ok(Scene::cornell_box()),
        "town" => return Ok(Scene::outdoor_town()),
        "sponza" => "sponza/Sponza.gltf",
        "gas_station" => "gas_station/GasStation.gltf",
        other => {
            return Err(format!(
                "unknown scene {other} (cornell, town, sponza or gas_station)"
            ));
        }
    };
    let path = shared_dir().join("scenes").join(file);
    Scene::load_gltf(&path, &LoadOptions::default()).map_err(|e| format!("{}: {e}", path.display()))
}

/// [`load_scene`] with its name, as `prt_bake::bake` takes a scene.
pub fn load_scene_input(name: &str) -> Result<SceneInput, String> {
    Ok(SceneInput {
        name: name.to_string(),
        scene: load_scene(name)?,
    })
}

/// Reading limits for the large files the experiments read back from their own runs (bakes,
/// kept volumes, caches): 16 GiB instead of prt-texture's default, which guards against
/// untrusted files.
pub fn large_file_limits() -> Limits {
    Limits {
        max_bytes: 16 << 30,
        ..Limits::default()
    }
}

/// Writes `image` as a PNG at `path`: under a temporary name first, then renamed, so that a
/// figure in docs/images is never left half written.
pub fn save_png(image: &image::RgbImage, path: &Path) -> Result<(), String> {
    let mut partial = path.as_os_str().to_owned();
    partial.push(".partial");
    let partial = PathBuf::from(partial);
    image
        .save_with_format(&partial, image::ImageFormat::Png)
        .and_then(|()| std::fs::rename(&partial, path).map_err(image::ImageError::IoError))
        .map_err(|e| format!("{}: {e}", path.display()))
}

/// A temporary folder for a binary's outputs (`NAME_TAG_PID` under the system's temp folder),
/// removed on drop.
pub struct Scratch(PathBuf);

impl Scratch {
    /// The folder for binary `name` and `tag` (not created).
    pub fn new(name: &str, tag: &str) -> Scratch {
        Scratch(std::env::temp_dir().join(format!("{name}_{tag}_{}", std::process::id())))
    }

    /// Its path.
    pub fn path(&self) -> &Path {
        &self.0
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unknown_names_are_errors_not_panics() {
        assert!(load_scene("no such scene").is_err());
        assert!(load_envmap("no such map").is_err());
        assert!(load_scene("cornell").is_ok());
    }
}
