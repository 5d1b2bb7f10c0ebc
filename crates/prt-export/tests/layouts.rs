//! The layouts checked independently: each exported file read back (prt's reader and the
//! `ktx2` crate) and sampled the way Bevy's and three.js's shaders sample it.

mod common;

use std::path::PathBuf;

use common::*;
use glam::Vec3;
use proptest::prelude::*;
use prt_core::Aabb;
use prt_export::layout::*;
use prt_export::*;
use prt_sphere::eval_sh;
use prt_texture::exr_io::read_exr;
use prt_texture::quant::rgb9e5_error_bound;
use prt_texture::{Ktx2Texture, Limits};
use prt_trace::LitVolume;

fn temp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("prt-export-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

/// A small volume of random radiance, a few voxels invalid.
fn volume(dims: [usize; 3], seed: u64) -> LitVolume {
    let n = dims.iter().product();
    LitVolume {
        dims,
        bounds: Aabb::new(Vec3::new(-1.0, 0.0, 2.0), Vec3::new(2.0, 1.5, 3.0)),
        valid: (0..n).map(|v| v % 5 != 3).collect(),
        radiance: (0..n).map(|v| random_radiance(seed + v as u64)).collect(),
    }
}

/// Reads a KTX2 with the `ktx2` crate and checks its dims and vkFormat.
fn check_ktx2(path: &std::path::Path, dims: [u32; 3], vk_format: u32) {
    let bytes = std::fs::read(path).unwrap();
    let reader = ktx2::Reader::new(&bytes[..]).unwrap();
    let h = reader.header();
    assert_eq!(
        (h.pixel_width, h.pixel_height, h.pixel_depth),
        (dims[0], dims[1], dims[2]),
        "{}",
        path.display()
    );
    assert_eq!(
        h.format.map(|f| f.value()),
        Some(vk_format),
        "{}",
        path.display()
    );
    assert_eq!(h.level_count, 1);
}

const VK_R8_UNORM: u32 = 9;
const VK_RGBA16F: u32 = 97;
const VK_RGB9E5: u32 = 123;

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    /// prt's SH re-expressed in three.js's basis gives the same radiance in every direction.
    #[test]
    fn threejs_basis_is_prts_rotated(seed in 0u64..10_000, dir in prop::array::uniform3(-1.0f32..1.0)) {
        let d = Vec3::from(dir);
        prop_assume!(d.length() > 0.1);
        let d = d.normalize();
        let l = random_radiance(seed)[0];
        let t = sh_to_threejs(&l);
        let mut y = [0f32; 9];
        eval_sh(3, d, &mut y);
        let prt: f32 = (0..9).map(|j| l[j] * y[j]).sum();
        let (x, yy, z) = (d.x, d.y, d.z);
        let basis = [
            0.282095, 0.488603 * yy, 0.488603 * z, 0.488603 * x, 1.092548 * x * yy,
            1.092548 * yy * z, 0.315392 * (3.0 * z * z - 1.0), 1.092548 * x * z,
            0.546274 * (x * x - yy * yy),
        ];
        let three: f32 = (0..9).map(|k| t[k] * basis[k]).sum();
        prop_assert!((prt - three).abs() < 2e-5 * (1.0 + prt.abs()), "{prt} vs {three}");
    }

    /// Bevy's blend of the axis fit is within the stated bound of E/π everywhere, and exact on
    /// the axes.
    #[test]
    fn axis_fit_stays_within_its_bound(seed in 0u64..10_000) {
        let l = random_radiance(seed);
        let cube = ambient_cube(&l, AmbientCubeFit::Axes);
        let bound = Vec3::from(ambient_cube_error_bound(&l));
        for (k, &d) in SIDES.iter().enumerate() {
            let e = Vec3::new(
                prt_trace::lit::irradiance(&l[0], d),
                prt_trace::lit::irradiance(&l[1], d),
                prt_trace::lit::irradiance(&l[2], d),
            ) / std::f32::consts::PI;
            prop_assert!((Vec3::from(cube[k]) - e).abs().max_element() < 1e-4);
        }
        for d in random_directions(64, seed) {
            let e = Vec3::new(
                prt_trace::lit::irradiance(&l[0], d),
                prt_trace::lit::irradiance(&l[1], d),
                prt_trace::lit::irradiance(&l[2], d),
            ) / std::f32::consts::PI;
            let err = (ambient_cube_blend(&cube, d) - e).abs();
            prop_assert!(err.cmple(bound + 1e-4).all(), "error {err} bound {bound}");
        }
    }
}

#[test]
fn bevy_texture_sampled_as_bevy_does_gives_back_irradiance() {
    let lit = volume([3, 4, 2], 7);
    for (format, vk) in [
        (BevyFormat::Rgb9e5, VK_RGB9E5),
        (BevyFormat::Rgba16f, VK_RGBA16F),
    ] {
        let dir = temp(&format!("bevy-{format:?}"));
        let config = BevyConfig {
            format,
            ..BevyConfig::default()
        };
        let out = export_bevy(&lit, &config, &dir).unwrap();
        assert_eq!(out.files.len(), 3);
        // Padded by one voxel layer on every side: 5 × 6 × 4 probes.
        check_ktx2(&dir.join(BEVY_TEXTURE), [5, 12, 12], vk);
        check_ktx2(&dir.join(VALIDITY_FILE), [5, 6, 4], VK_R8_UNORM);
        let texture = Ktx2Texture::read_file(&dir.join(BEVY_TEXTURE), &Limits::default()).unwrap();
        let channels = texture.format().channels();
        let texels = texture.level_f32(0).unwrap();
        let placement: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(dir.join(BEVY_PLACEMENT)).unwrap())
                .unwrap();
        let scale = placement["transform"]["scale"].as_array().unwrap();
        assert!((scale[0].as_f64().unwrap() - 5.0).abs() < 1e-6);
        for v in 0..lit.voxels() {
            let l = &lit.radiance[v];
            let storage = |e: Vec3| match format {
                BevyFormat::Rgb9e5 => rgb9e5_error_bound(e.max_element() * 1.01) + 1e-6,
                BevyFormat::Rgba16f => f16_bound(e.max_element() * 1.01),
            };
            let cube_bound = Vec3::from(ambient_cube_error_bound(l));
            for (k, d) in SIDES
                .iter()
                .copied()
                .chain(random_directions(32, v as u64))
                .enumerate()
            {
                let e = lit.irradiance(v, d) / std::f32::consts::PI;
                let at = unit_pos(lit.dims, ENGINE_PADDING, v);
                let got = bevy_sample(&texels, channels, [5, 12, 12], at, d);
                let fit = if k < 6 { Vec3::ZERO } else { cube_bound };
                let err = (got - e).abs();
                assert!(
                    err.cmple(fit + Vec3::splat(storage(e) + 1e-5)).all(),
                    "{format:?} voxel {v} direction {d}: {got} vs {e}"
                );
            }
        }
    }
}

#[test]
fn threejs_atlas_decodes_to_each_voxels_sh_within_f16_rounding() {
    let lit = volume([3, 2, 4], 11);
    let dir = temp("threejs");
    export_threejs(&lit, &ThreejsConfig::default(), &dir).unwrap();
    // Padded by one voxel layer on every side: 5 × 4 × 6 probes.
    let atlas_dims = [5u32, 4, 7 * (6 + 2)];
    check_ktx2(&dir.join(THREEJS_TEXTURE), atlas_dims, VK_RGBA16F);
    check_ktx2(&dir.join(VALIDITY_FILE), [5, 4, 6], VK_R8_UNORM);
    let texture = Ktx2Texture::read_file(&dir.join(THREEJS_TEXTURE), &Limits::default()).unwrap();
    let texels = texture.level_f32(0).unwrap();
    let doc: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join(THREEJS_PLACEMENT)).unwrap())
            .unwrap();
    let v3 = |key: &str| {
        let a = doc[key].as_array().unwrap();
        Vec3::new(
            a[0].as_f64().unwrap() as f32,
            a[1].as_f64().unwrap() as f32,
            a[2].as_f64().unwrap() as f32,
        )
    };
    let (position, size) = (v3("position"), v3("size"));
    let (min, max) = (position - 0.5 * size, position + 0.5 * size);
    let atlas = atlas_dims.map(|d| d as usize);
    for v in 0..lit.voxels() {
        let [x, y, z] = lit.coords(v);
        // Coefficients by the packing formula: sub-volume t, slice t (nz + 2) + z + 1, of the
        // padded grid (voxel (x, y, z) is padded voxel (x + 1, y + 1, z + 1)).
        let (x, y, z) = (x + 1, y + 1, z + 1);
        let mut flat = Vec::new();
        for t in 0..7 {
            let texel = x + 5 * (y + 4 * (t * 8 + z + 1));
            flat.extend_from_slice(&texels[4 * texel..4 * texel + 4]);
        }
        for c in 0..3 {
            let want = sh_to_threejs(&lit.radiance[v][c]);
            for k in 0..9 {
                let got = flat[3 * k + c];
                assert!(
                    (got - want[k]).abs() <= f16_bound(want[k]),
                    "voxel {v} c{k}"
                );
            }
        }
        assert_eq!(flat[27], 1.0);
        // The atlas's padding slices and the grid's padding layer repeat the edge slices.
        if z == 1 {
            for t in 0..7 {
                let slab = |s: usize| x + 5 * (y + 4 * (t * 8 + s));
                let (pad, layer, data) = (slab(0), slab(1), slab(2));
                assert_eq!(
                    texels[4 * layer..4 * layer + 4],
                    texels[4 * data..4 * data + 4]
                );
                assert_eq!(texels[4 * pad..4 * pad + 4], texels[4 * data..4 * data + 4]);
            }
        }
        // three.js's shader at the probe: its irradiance is prt's to f16 rounding.
        for d in random_directions(8, v as u64) {
            let res = lit.dims.map(|d| d + 2 * ENGINE_PADDING);
            let got = threejs_sample(&texels, atlas, min, max, res, lit.voxel_centre(v), d);
            let want = lit.irradiance(v, d);
            for c in 0..3 {
                let bound = f16_irradiance_bound(&lit.radiance[v][c]) + 1e-3 * want[c].abs();
                assert!(
                    (got[c] - want[c]).abs() <= bound,
                    "voxel {v}: {got} vs {want}"
                );
            }
        }
    }
}

#[test]
fn sh_volumes_hold_the_coefficients_in_every_file() {
    let lit = volume([2, 3, 2], 23);
    let dir = temp("sh");
    let out = export_sh(&lit, &ShConfig::default(), &dir).unwrap();
    assert_eq!(out.files.len(), 7);
    for name in SH_L1_FILES {
        check_ktx2(&dir.join(name), [2, 3, 2], VK_RGBA16F);
    }
    check_ktx2(&dir.join(SH_L2_FILE), [2, 3, 18], VK_RGBA16F);
    check_ktx2(&dir.join(VALIDITY_FILE), [2, 3, 2], VK_R8_UNORM);
    let read = |name: &str| {
        Ktx2Texture::read_file(&dir.join(name), &Limits::default())
            .unwrap()
            .level_f32(0)
            .unwrap()
    };
    let l2 = read(SH_L2_FILE);
    let l1: Vec<Vec<f32>> = SH_L1_FILES.iter().map(|n| read(n)).collect();
    let exr = read_exr(&dir.join(SH_EXR_FILE), &Limits::default()).unwrap();
    assert_eq!(exr.len(), 9);
    let validity = read(VALIDITY_FILE);
    for v in 0..lit.voxels() {
        assert_eq!(validity[v] > 0.5, lit.valid[v]);
        for c in 0..3 {
            for j in 0..9 {
                let want = lit.radiance[v][c][j];
                let texel = v + j * lit.voxels();
                assert!((l2[4 * texel + c] - want).abs() <= f16_bound(want));
                let layer = exr
                    .iter()
                    .find(|l| l.name.as_deref() == Some(SH_LAYER_NAMES[j]))
                    .unwrap();
                assert_eq!(layer.data[3 * v + c], want);
                if j < 4 {
                    assert!((l1[c][4 * v + j] - want).abs() <= f16_bound(want));
                }
            }
        }
    }
}

#[test]
fn sky_json_in_both_shapes_and_its_errors() {
    let per_channel =
        r#"{"sh": [[1,0,0.5,0,0,0,0,0,0],[2,0,0,0,0,0,0,0,0],[3,0,0,0,0,0,0,0,0.25]]}"#;
    let sky = sky_from_json(per_channel).unwrap();
    assert_eq!(sky.sh[0][2], 0.5);
    assert_eq!(sky.sh[2][8], 0.25);
    let triples = r#"{"coefficients_rgb": [[1,2,3],[0,0,0],[0.5,0,0],[0,0,0],[0,0,0],[0,0,0],[0,0,0],[0,0,0],[0,0,0.25]]}"#;
    assert_eq!(sky_from_json(triples).unwrap(), sky);
    let too_big = per_channel.replace("0.25", "1e39");
    assert!(matches!(
        sky_from_json(&too_big),
        Err(ExportError::Sphere(prt_sphere::SphereError::NonFinite {
            index: 26,
            ..
        }))
    ));
    for bad in [
        r#"{"sh": [[1,2],[3],[4]]}"#,
        r#"{"sh": [[1,0,0,0,0,0,0,0,null],[2,0,0,0,0,0,0,0,0],[3,0,0,0,0,0,0,0,0]]}"#,
        r#"{"other": 1}"#,
        "not json",
    ] {
        assert!(
            matches!(sky_from_json(bad), Err(ExportError::SkyJson(_))),
            "{bad}"
        );
    }
}
