//! End to end on a small Cornell bake: irradiance read back from each exported file at the
//! voxel centres equals the irradiance of the container's model × the same sky within the
//! file's rounding; the model's own error against the full traced volume is reported apart.

mod common;

use common::*;
use glam::Vec3;
use prt_bake::container::read_container;
use prt_bake::{BakeConfig, SceneInput, bake};
use prt_core::{FieldModel, NoProgress};
use prt_export::layout::*;
use prt_export::*;
use prt_sphere::{Sky, SunSky};
use prt_texture::quant::rgb9e5_error_bound;
use prt_texture::{Ktx2Texture, Limits};
use prt_trace::LitVolume;

#[test]
fn exports_of_a_cornell_bake_give_back_its_irradiance() {
    let dir = std::env::temp_dir().join(format!("prt-export-cornell-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let config = BakeConfig {
        resolution: 10,
        rays_per_voxel: 96,
        cache_rays: 32,
        rank: 6,
        basis_nodes: 4,
        max_iterations: 24,
        baselines: false,
        container: Some(dir.join("mbd")),
        ..BakeConfig::default()
    };
    let baked = bake(&SceneInput::cornell_box(), &config, &NoProgress).unwrap();
    let container = read_container(&dir.join("mbd"), &Limits::default()).unwrap();
    let sky = Sky::sun_sky(&SunSky::default())
        .unwrap()
        .rotated_about_y(20.0);
    let lit = container.light(&sky, &NoProgress).unwrap();
    let reference =
        LitVolume::from_transfer(&baked.volume.field, &baked.volume.valid, &sky, &NoProgress)
            .unwrap();
    assert_eq!(lit.dims, reference.dims);
    assert!((lit.bounds.min - reference.bounds.min).length() < 1e-4);
    assert!((lit.bounds.max - reference.bounds.max).length() < 1e-4);

    // Lighting the basis once equals lighting the model's evaluation at each voxel.
    let mut t = vec![0.0; 324];
    for v in (0..lit.voxels()).step_by(7) {
        container.model.eval(lit.voxel_centre(v), &mut t).unwrap();
        let direct = prt_trace::lit::incident_radiance(&t, &sky);
        for c in 0..3 {
            for j in 0..9 {
                let (a, b) = (lit.radiance[v][c][j], direct[c][j]);
                assert!(
                    (a - b).abs() <= 1e-4 * (1.0 + b.abs()),
                    "voxel {v}: {a} vs {b}"
                );
            }
        }
    }

    // MBD's own error (not the exports'): valid voxels, irradiance over 6 axes, relative RMS.
    let (mut num, mut den) = (0.0f64, 0.0f64);
    for v in (0..lit.voxels()).filter(|&v| lit.valid[v]) {
        for d in SIDES {
            let (a, b) = (lit.irradiance(v, d), reference.irradiance(v, d));
            num += f64::from((a - b).length_squared());
            den += f64::from(b.length_squared());
        }
    }
    let mbd_error = (num / den).sqrt();
    eprintln!("MBD container vs full traced volume: relative RMS irradiance error {mbd_error:.3e}");
    assert!(mbd_error < 0.2, "MBD error {mbd_error}");

    // The two ambient-cube fits against E/π over valid voxels and random directions.
    let probe_dirs = random_directions(64, 9);
    for fit in [AmbientCubeFit::Axes, AmbientCubeFit::LeastSquares] {
        let (mut num, mut den, mut axes) = (0.0f64, 0.0f64, 0.0f64);
        for v in (0..lit.voxels()).filter(|&v| lit.valid[v]) {
            let cube = ambient_cube(&lit.radiance[v], fit);
            for &d in &probe_dirs {
                let want = lit.irradiance(v, d) / std::f32::consts::PI;
                num += f64::from((ambient_cube_blend(&cube, d) - want).length_squared());
                den += f64::from(want.length_squared());
            }
            for (k, d) in SIDES.iter().enumerate() {
                let want = lit.irradiance(v, *d) / std::f32::consts::PI;
                axes = axes.max(f64::from(
                    (Vec3::from(cube[k]) - want).abs().max_element() / want.max_element().max(1e-3),
                ));
            }
        }
        eprintln!(
            "ambient cube {fit:?}: relative RMS error over the sphere {:.3e}, worst relative error on the axes {axes:.2e}",
            (num / den).sqrt()
        );
    }

    let lit = dilate(&lit, &DilateConfig::default()).unwrap().volume;
    let dirs: Vec<Vec3> = SIDES
        .iter()
        .copied()
        .chain(random_directions(16, 5))
        .collect();

    // Bevy, RGB9E5: E/π within the axis-fit bound (0 on the axes) plus RGB9E5 rounding.
    let bevy_dir = dir.join("bevy");
    export_bevy(&lit, &BevyConfig::default(), &bevy_dir).unwrap();
    let tex = Ktx2Texture::read_file(&bevy_dir.join(BEVY_TEXTURE), &Limits::default()).unwrap();
    let texels = tex.level_f32(0).unwrap();
    let [nx, ny, nz] = lit.dims;
    let mut worst_bevy = 0.0f32;
    for v in 0..lit.voxels() {
        let bound = Vec3::from(ambient_cube_error_bound(&lit.radiance[v]));
        for (k, &d) in dirs.iter().enumerate() {
            // Sides are stored clamped at 0 (where the SH rings negative).
            let exact = lit.irradiance(v, d) / std::f32::consts::PI;
            let want = if k < 6 { exact.max(Vec3::ZERO) } else { exact };
            let atlas = [nx + 2, 2 * (ny + 2), 3 * (nz + 2)];
            let got = bevy_sample(&texels, 3, atlas, unit_pos(lit.dims, ENGINE_PADDING, v), d);
            let fit = if k < 6 { Vec3::ZERO } else { bound };
            let storage =
                rgb9e5_error_bound(want.max_element().max(0.0) + fit.max_element()) + 1e-6;
            let err = (got - want).abs();
            assert!(
                err.cmple(fit + Vec3::splat(storage)).all(),
                "voxel {v} {d}: {got} vs {want}"
            );
            if k < 6 {
                worst_bevy = worst_bevy.max(err.max_element() / want.max_element().max(1e-3));
            }
        }
    }
    eprintln!("Bevy RGB9E5 on the axes: worst relative error {worst_bevy:.2e}");

    // three.js: the shader's L2 irradiance from the atlas within f16 rounding.
    let three_dir = dir.join("threejs");
    export_threejs(&lit, &ThreejsConfig::default(), &three_dir).unwrap();
    let tex = Ktx2Texture::read_file(&three_dir.join(THREEJS_TEXTURE), &Limits::default()).unwrap();
    let texels = tex.level_f32(0).unwrap();
    let padded = lit.padded(ENGINE_PADDING);
    for v in 0..lit.voxels() {
        for &d in &dirs {
            let want = lit.irradiance(v, d);
            let got = threejs_sample(
                &texels,
                [nx + 2, ny + 2, 7 * (nz + 4)],
                padded.bounds.min,
                padded.bounds.max,
                padded.dims,
                lit.voxel_centre(v),
                d,
            );
            for c in 0..3 {
                let bound = f16_irradiance_bound(&lit.radiance[v][c]) + 1e-4 * want[c].abs() + 1e-5;
                assert!(
                    (got[c] - want[c]).abs() <= bound,
                    "voxel {v} {d}: {got} vs {want}"
                );
            }
        }
    }

    // SH: the L2 texture's coefficients give the irradiance within f16 rounding.
    let sh_dir = dir.join("sh");
    export_sh(&lit, &ShConfig::default(), &sh_dir).unwrap();
    let l2 = Ktx2Texture::read_file(&sh_dir.join(SH_L2_FILE), &Limits::default())
        .unwrap()
        .level_f32(0)
        .unwrap();
    for v in 0..lit.voxels() {
        let l: [[f32; 9]; 3] =
            std::array::from_fn(|c| std::array::from_fn(|j| l2[4 * (v + j * lit.voxels()) + c]));
        for &d in &dirs {
            let want = lit.irradiance(v, d);
            for c in 0..3 {
                let got = prt_trace::lit::irradiance(&l[c], d);
                let bound = f16_irradiance_bound(&lit.radiance[v][c]) + 1e-5;
                assert!(
                    (got - want[c]).abs() <= bound,
                    "voxel {v}: {got} vs {}",
                    want[c]
                );
            }
        }
    }
}
