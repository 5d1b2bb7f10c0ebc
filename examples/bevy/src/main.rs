//! Renders a glTF scene lit by the irradiance volume that `prt export --target bevy` wrote.
//!
//! ```text
//! prt bake scene.gltf --out bake
//! prt export bake --target bevy --out bake/bevy
//! cargo run --release --manifest-path examples/bevy/Cargo.toml -- bake/bevy scene.gltf
//! ```
//!
//! The volume is Bevy's own `IrradianceVolume` on a `LightProbe`, placed by the transform in
//! `irradiance_volume.json`: nothing here decodes prt data. The scene has no other light, and
//! the camera's exposure (EV100 0, about 1:1) shows the volume's values, which are in the sky's
//! units, without a physical intensity.

use std::path::{Path, PathBuf};

use bevy::asset::{AssetPlugin, UnapprovedPathMode};
use bevy::camera::Exposure;
use bevy::light::{GlobalAmbientLight, IrradianceVolume, LightProbe};
use bevy::prelude::*;

/// What the program was given: asset paths (relative to the file-system root, where the asset
/// server is rooted) and the volume's placement.
#[derive(Resource)]
struct Inputs {
    volume: String,
    scene: String,
    translation: Vec3,
    scale: Vec3,
    intensity: f32,
}

fn main() -> AppExit {
    let args: Vec<String> = std::env::args().collect();
    let (Some(export), Some(scene)) = (args.get(1), args.get(2)) else {
        eprintln!("usage: prt-bevy-example EXPORT_DIR SCENE.gltf");
        return AppExit::error();
    };
    let inputs = match read_inputs(Path::new(export), Path::new(scene)) {
        Ok(inputs) => inputs,
        Err(e) => {
            eprintln!("error: {e}");
            return AppExit::error();
        }
    };
    App::new()
        .add_plugins(DefaultPlugins.set(AssetPlugin {
            file_path: "/".into(),
            unapproved_path_mode: UnapprovedPathMode::Allow,
            ..default()
        }))
        .insert_resource(GlobalAmbientLight {
            brightness: 0.0,
            ..default()
        })
        .insert_resource(inputs)
        .add_systems(Startup, setup)
        .run()
}

/// Reads the placement JSON beside the texture and makes both paths absolute.
fn read_inputs(export: &Path, scene: &Path) -> Result<Inputs, String> {
    let absolute = |p: &Path| -> Result<PathBuf, String> {
        p.canonicalize()
            .map_err(|e| format!("{}: {e}", p.display()))
    };
    let placement_path = export.join("irradiance_volume.json");
    let text = std::fs::read_to_string(&placement_path)
        .map_err(|e| format!("{}: {e}", placement_path.display()))?;
    let doc: serde_json::Value = serde_json::from_str(&text).map_err(|e| e.to_string())?;
    let vec3 = |key: &str| -> Result<Vec3, String> {
        let values: Vec<f32> = doc["transform"][key]
            .as_array()
            .map(|a| a.iter().filter_map(|v| v.as_f64()).map(|v| v as f32).collect())
            .unwrap_or_default();
        match values[..] {
            [x, y, z] => Ok(Vec3::new(x, y, z)),
            _ => Err(format!("transform.{key} is not three numbers")),
        }
    };
    let texture = doc["texture"].as_str().ok_or("no texture name")?;
    let root_relative = |p: PathBuf| p.to_string_lossy().trim_start_matches('/').to_string();
    Ok(Inputs {
        volume: root_relative(absolute(&export.join(texture))?),
        scene: root_relative(absolute(scene)?),
        translation: vec3("translation")?,
        scale: vec3("scale")?,
        intensity: doc["intensity"].as_f64().ok_or("no intensity")? as f32,
    })
}

fn setup(mut commands: Commands, assets: Res<AssetServer>, inputs: Res<Inputs>) {
    commands.spawn(WorldAssetRoot(
        assets.load(GltfAssetLabel::Scene(0).from_asset(inputs.scene.clone())),
    ));
    // Bevy's light probes are the unit cube [-0.5, 0.5]³ under their transform.
    commands.spawn((
        LightProbe::default(),
        IrradianceVolume {
            voxels: assets.load(inputs.volume.clone()),
            intensity: inputs.intensity,
            ..default()
        },
        Transform::from_translation(inputs.translation).with_scale(inputs.scale),
    ));
    let eye = inputs.translation + inputs.scale * Vec3::new(0.0, 0.1, 0.45);
    commands.spawn((
        Camera3d::default(),
        Exposure { ev100: 0.0 },
        Transform::from_translation(eye).looking_at(inputs.translation, Vec3::Y),
    ));
}
