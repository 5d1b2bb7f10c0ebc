//! Laws: lighting is linear in the transfer and follows the sky's rotation; dilation never
//! changes a valid voxel, keeps a constant volume constant and by default fills every voxel;
//! padding is invisible inside the baked box; removing negative light leaves no negative
//! irradiance and touches nothing else; the engines' lookups light every surface of the box.

mod common;

use common::random_radiance;
use glam::{Mat3, Vec3};
use proptest::prelude::*;
use prt_core::{Aabb, GridField, NoProgress};
use prt_export::layout::{ambient_cube, ambient_cube_blend, test_directions};
use prt_export::{
    AmbientCubeFit, DilateConfig, Engine, EngineLookup, dilate, remove_negative_light,
};
use prt_sphere::Sky;
use prt_trace::LitVolume;

fn lit(dims: [usize; 3], mask: u64, seed: u64) -> LitVolume {
    let n: usize = dims.iter().product();
    LitVolume {
        dims,
        bounds: Aabb::new(Vec3::ZERO, Vec3::new(2.0, 1.0, 1.5)),
        valid: (0..n).map(|v| mask >> (v % 64) & 1 == 1).collect(),
        radiance: (0..n).map(|v| random_radiance(seed + v as u64)).collect(),
    }
}

/// A point on face `face` (0..6: −x +x −y +y −z +z) of `bounds` at `(u, v)` across it, and the
/// face's inward normal.
fn on_face(bounds: Aabb, face: usize, u: f32, v: f32) -> (Vec3, Vec3) {
    let axis = face / 2;
    let (a, b) = ((axis + 1) % 3, (axis + 2) % 3);
    let mut p = Vec3::ZERO;
    p[a] = bounds.min[a] + u * bounds.size()[a];
    p[b] = bounds.min[b] + v * bounds.size()[b];
    let mut n = Vec3::ZERO;
    if face.is_multiple_of(2) {
        p[axis] = bounds.min[axis];
        n[axis] = 1.0;
    } else {
        p[axis] = bounds.max[axis];
        n[axis] = -1.0;
    }
    (p, n)
}

fn close(a: Vec3, b: Vec3) -> bool {
    (a - b).abs().max_element() <= 1e-4 * (1.0 + b.abs().max_element())
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]

    #[test]
    fn padding_is_invisible_inside_the_baked_box(
        nx in 1usize..5, ny in 1usize..5, nz in 1usize..5, seed in 0u64..1000,
        t in prop::array::uniform3(0.0f32..=1.0), d in prop::array::uniform3(-1.0f32..1.0),
    ) {
        let volume = lit([nx, ny, nz], u64::MAX, seed);
        let padded = volume.padded(2);
        prop_assert_eq!(padded.dims, [nx + 4, ny + 4, nz + 4]);
        prop_assume!(Vec3::from_array(d).length() > 0.1);
        let n = Vec3::from_array(d).normalize();
        let p = volume.bounds.min + Vec3::from_array(t) * volume.bounds.size();
        prop_assert!(close(padded.irradiance_at(p, n), volume.irradiance_at(p, n)));
    }

    #[test]
    fn removing_negative_light_leaves_none_and_touches_nothing_else(
        seed in 0u64..1000, ring in 0.0f32..3.0,
    ) {
        let mut volume = lit([3, 2, 2], u64::MAX, seed);
        // Exaggerate bands 1-2 of some voxels so that their irradiance rings negative.
        for (v, l) in volume.radiance.iter_mut().enumerate() {
            if v % 3 == 0 {
                l.iter_mut().for_each(|c| c[1..].iter_mut().for_each(|x| *x *= 1.0 + ring * 4.0));
            }
        }
        volume.radiance[5][1] = [-1.0, 0.2, 0.0, 0.1, 0.0, 0.0, 0.0, 0.0, 0.3];
        let out = remove_negative_light(&volume).unwrap();
        prop_assert!(out.zeroed >= 1);
        let dirs = test_directions();
        let mut changed = 0;
        for v in 0..volume.voxels() {
            let before_ok = dirs.iter().all(|&n| volume.irradiance(v, n).min_element() >= 0.0);
            if before_ok {
                prop_assert_eq!(out.volume.radiance[v], volume.radiance[v]);
            }
            for &n in &dirs {
                let e = out.volume.irradiance(v, n);
                prop_assert!(e.min_element() >= -1e-5 * (1.0 + e.abs().max_element()), "voxel {v} {n}: {e}");
            }
            for c in 0..3 {
                if out.volume.radiance[v][c] != volume.radiance[v][c] {
                    changed += 1;
                    // The mean (band 0) stays unless the channel had no light to keep.
                    let kept = out.volume.radiance[v][c][0] == volume.radiance[v][c][0];
                    prop_assert!(kept || out.volume.radiance[v][c] == [0.0; 9]);
                }
            }
        }
        prop_assert_eq!(changed, out.scaled + out.zeroed);
    }

    /// On every face of the baked box, with its inward normal, Bevy's lookup has full weight
    /// and reads the ambient cube interpolated at the point itself, and three.js's reads the
    /// SH half a voxel inside: no surface of the box goes dark.
    #[test]
    fn engine_lookups_light_every_surface_of_the_baked_box(
        nx in 1usize..5, ny in 1usize..5, nz in 1usize..5, seed in 0u64..1000,
        face in 0usize..6, u in 0.0f32..=1.0, v in 0.0f32..=1.0,
    ) {
        let volume = lit([nx, ny, nz], u64::MAX, seed);
        let (p, n) = on_face(volume.bounds, face, u, v);
        let bevy = EngineLookup::new(&volume, Engine::Bevy, AmbientCubeFit::Axes).unwrap();
        let cubes: Vec<_> = volume.radiance.iter().map(|l| ambient_cube(l, AmbientCubeFit::Axes)).collect();
        let mut cube = [[0.0f32; 3]; 6];
        for (voxel, w) in volume.trilinear(p) {
            for (side, value) in cube.iter_mut().zip(&cubes[voxel]) {
                for c in 0..3 {
                    side[c] += w * value[c].max(0.0);
                }
            }
        }
        let want = std::f32::consts::PI * ambient_cube_blend(&cube, n);
        let got = bevy.irradiance(p, n);
        prop_assert!(got.is_some_and(|g| close(g, want)), "Bevy {got:?} vs {want}");

        let three = EngineLookup::new(&volume, Engine::Threejs, AmbientCubeFit::Axes).unwrap();
        let want = volume.irradiance_at(p + 0.5 * n * volume.voxel_size(), n).max(Vec3::ZERO);
        let got = three.irradiance(p, n);
        prop_assert!(got.is_some_and(|g| close(g, want)), "three.js {got:?} vs {want}");
    }

    #[test]
    fn dilation_keeps_valid_voxels_and_counts_what_it_fills(
        nx in 1usize..5, ny in 1usize..5, nz in 1usize..5,
        mask in any::<u64>(), seed in 0u64..1000, radius in 0usize..3, passes in 0usize..4,
    ) {
        let volume = lit([nx, ny, nz], mask, seed);
        let out = dilate(&volume, &DilateConfig { radius, passes }).unwrap();
        let invalid = volume.valid.iter().filter(|&&v| !v).count();
        prop_assert_eq!(out.filled + out.unfilled, invalid);
        prop_assert_eq!(&out.volume.valid, &volume.valid);
        let mut changed = 0;
        for v in 0..volume.voxels() {
            if volume.valid[v] {
                prop_assert_eq!(out.volume.radiance[v], volume.radiance[v]);
            } else if out.volume.radiance[v] != volume.radiance[v] {
                changed += 1;
            }
        }
        prop_assert!(changed <= out.filled);
        if radius == 0 || passes == 0 {
            prop_assert_eq!(out.filled, 0);
        }
        // By default every invalid voxel of a grid holding a valid one is filled.
        if volume.valid.iter().any(|&v| v) {
            let all = dilate(&volume, &DilateConfig::default()).unwrap();
            prop_assert_eq!(all.unfilled, 0);
        }
    }

    #[test]
    fn dilation_of_a_constant_volume_is_constant(mask in 1u64.., seed in 0u64..1000) {
        let mut volume = lit([4, 3, 5], mask, seed);
        let value = volume.radiance[0];
        volume.radiance.iter_mut().enumerate().for_each(|(v, l)| {
            if volume.valid[v] { *l = value } else { *l = [[0.0; 9]; 3] }
        });
        prop_assume!(volume.valid.iter().any(|&v| v));
        let out = dilate(&volume, &DilateConfig { radius: 1, passes: 64 }).unwrap();
        for l in &out.volume.radiance {
            for c in 0..3 {
                for j in 0..9 {
                    prop_assert!((l[c][j] - value[c][j]).abs() <= 1e-5 * (1.0 + value[c][j].abs()));
                }
            }
        }
    }

    /// light(a T1 + T2) = a light(T1) + light(T2), and a pass-through transfer lit by a
    /// rotated sky gives the rotated sky.
    #[test]
    fn lighting_is_linear_and_follows_the_sky(a in -2.0f32..2.0, seed in 0u64..1000, angle in -180.0f32..180.0) {
        let bounds = Aabb::new(Vec3::ZERO, Vec3::ONE);
        let value = |s: u64| move |p: Vec3, t: &mut [f32]| {
            for (i, x) in t.iter_mut().enumerate() {
                *x = ((i as f32 * 0.37 + s as f32 + p.x * 3.0 + p.z).sin()) * 0.1;
            }
        };
        let f1 = GridField::from_fn([2, 2, 3], bounds, 324, value(seed)).unwrap();
        let f2 = GridField::from_fn([2, 2, 3], bounds, 324, value(seed + 1)).unwrap();
        let sum = GridField::from_data(
            [2, 2, 3],
            bounds,
            f1.data() * a + f2.data(),
        ).unwrap();
        let sky = Sky::default().rotated_about_y(angle);
        let valid = vec![true; 12];
        let (l1, l2, ls) = (
            LitVolume::from_transfer(&f1, &valid, &sky, &NoProgress).unwrap(),
            LitVolume::from_transfer(&f2, &valid, &sky, &NoProgress).unwrap(),
            LitVolume::from_transfer(&sum, &valid, &sky, &NoProgress).unwrap(),
        );
        for v in 0..12 {
            for c in 0..3 {
                for j in 0..9 {
                    let want = a * l1.radiance[v][c][j] + l2.radiance[v][c][j];
                    prop_assert!((ls.radiance[v][c][j] - want).abs() < 1e-4);
                }
            }
        }
        let pass = GridField::from_fn([1, 1, 2], bounds, 324, |_, t| {
            (0..9).for_each(|i| t[i * 9 + i] = 1.0)
        }).unwrap();
        let turned = LitVolume::from_transfer(&pass, &[true, true], &sky, &NoProgress).unwrap();
        let r = Mat3::from_rotation_y(angle.to_radians());
        for d in [Vec3::X, Vec3::Y, Vec3::new(0.6, 0.0, 0.8)] {
            let l = &turned.radiance[0];
            let got = Sky { sh: *l }.radiance(r * d);
            let want = Sky::default().radiance(d);
            prop_assert!((got - want).abs().max_element() < 1e-4);
        }
    }
}
