//! Kept volumes: a small bake's traced volume and baselines round trip through their container
//! within f16 rounding, and damaged containers are typed errors.

use prt_bake::container::ContainerError;
use prt_bake::volumes::{REFERENCE, kept_volume_bytes, read_volumes, write_volumes};
use prt_bake::{BakeConfig, SceneInput, bake};
use prt_core::NoProgress;
use prt_texture::container::MANIFEST_FILE;
use prt_texture::{Encoding, Limits};

fn small_bake() -> prt_bake::Bake {
    let config = BakeConfig {
        resolution: 6,
        rays_per_voxel: 24,
        cache_rays: 8,
        rank: 2,
        basis_nodes: 2,
        max_iterations: 4,
        ..BakeConfig::default()
    };
    bake(&SceneInput::cornell_box(), &config, &NoProgress).expect("the small bake runs")
}

#[test]
fn the_reference_and_the_baselines_round_trip_within_f16_rounding() {
    let baked = small_bake();
    let dir = std::env::temp_dir().join(format!("prt-bake-volumes-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let report = write_volumes(&dir, &baked, Encoding::F16).expect("written");
    assert!(report.total_bytes >= kept_volume_bytes(&baked, Encoding::F16));
    let kept = read_volumes(&dir, &Limits::default()).expect("read back");
    assert_eq!(kept.grid, baked.volume.field.dims());
    assert_eq!(kept.bounds, baked.volume.field.bounds());
    assert_eq!(kept.valid, baked.volume.valid);
    let names: Vec<&str> = kept.volumes.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(names, [REFERENCE, "bpca", "cpca"]);
    let originals = std::iter::once(baked.volume.field.clone()).chain(
        baked
            .baselines
            .iter()
            .map(|b| b.model.reconstruct().expect("reconstruction")),
    );
    for ((name, back), original) in kept.volumes.iter().zip(originals) {
        for (a, b) in original.data().iter().zip(back.data()) {
            // f16: relative 2⁻¹¹, absolute 2⁻²⁵ for subnormals.
            let bound = a.abs() * 2f32.powi(-11) + 2f32.powi(-24);
            assert!((a - b).abs() <= bound, "{name}: {a} read back as {b}");
        }
    }
    assert!(kept.get("cpca").is_some() && kept.get("mbd").is_none());

    // A manifest naming a volume whose arrays are missing is a typed error.
    let manifest = dir.join(MANIFEST_FILE);
    let mut json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&manifest).unwrap()).unwrap();
    json["attributes"]["volumes"]
        .as_array_mut()
        .expect("the manifest lists the volumes")
        .push("lost".into());
    std::fs::write(&manifest, serde_json::to_vec(&json).unwrap()).unwrap();
    match read_volumes(&dir, &Limits::default()) {
        Err(ContainerError::Inconsistent(why)) => assert!(why.contains("lost.0"), "{why}"),
        other => panic!("expected an inconsistency, got {other:?}"),
    }

    // A name listed many times would allocate a volume each time: refused before allocating.
    let volumes = json["attributes"]["volumes"].as_array_mut().unwrap();
    volumes.pop();
    volumes.extend(std::iter::repeat_n(REFERENCE.into(), 1000));
    std::fs::write(&manifest, serde_json::to_vec(&json).unwrap()).unwrap();
    match read_volumes(&dir, &Limits::default()) {
        Err(ContainerError::Inconsistent(why)) => assert!(why.contains("twice"), "{why}"),
        other => panic!("expected an inconsistency, got {other:?}"),
    }

    // The volumes together must fit the reader's limits.
    let volumes = json["attributes"]["volumes"].as_array_mut().unwrap();
    volumes.truncate(3);
    std::fs::write(&manifest, serde_json::to_vec(&json).unwrap()).unwrap();
    assert!(read_volumes(&dir, &Limits::default()).is_ok());
    let need = 3 * baked.volume.field.num_voxels() as u64 * 324 * 4;
    let tight = Limits {
        max_bytes: need - 1,
        ..Limits::default()
    };
    match read_volumes(&dir, &tight) {
        Err(ContainerError::Texture(prt_texture::TextureError::TooLarge { value, .. })) => {
            assert_eq!(value, need)
        }
        other => panic!("expected the limit, got {other:?}"),
    }
    std::fs::remove_dir_all(&dir).unwrap();
}
