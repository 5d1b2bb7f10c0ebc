//! Laws: lighting is linear in the transfer and follows the sky's rotation; dilation never
//! changes a valid voxel, keeps a constant volume constant and fills what it can reach.

mod common;

use common::random_radiance;
use glam::{Mat3, Vec3};
use proptest::prelude::*;
use prt_core::{Aabb, GridField, NoProgress};
use prt_export::{DilateConfig, LitVolume, dilate, light_field};
use prt_sphere::Sky;

fn lit(dims: [usize; 3], mask: u64, seed: u64) -> LitVolume {
    let n: usize = dims.iter().product();
    LitVolume {
        dims,
        bounds: Aabb::new(Vec3::ZERO, Vec3::new(2.0, 1.0, 1.5)),
        valid: (0..n).map(|v| mask >> (v % 64) & 1 == 1).collect(),
        radiance: (0..n).map(|v| random_radiance(seed + v as u64)).collect(),
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]

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
        // With enough passes every invalid voxel of a grid holding a valid one is filled.
        if radius >= 1 && volume.valid.iter().any(|&v| v) {
            let all = dilate(&volume, &DilateConfig { radius, passes: 64 }).unwrap();
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
            light_field(&f1, &valid, &sky, &NoProgress).unwrap(),
            light_field(&f2, &valid, &sky, &NoProgress).unwrap(),
            light_field(&sum, &valid, &sky, &NoProgress).unwrap(),
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
        let turned = light_field(&pass, &[true, true], &sky, &NoProgress).unwrap();
        let r = Mat3::from_rotation_y(angle.to_radians());
        for d in [Vec3::X, Vec3::Y, Vec3::new(0.6, 0.0, 0.8)] {
            let l = &turned.radiance[0];
            let got = Sky { sh: *l }.radiance(r * d);
            let want = Sky::default().radiance(d);
            prop_assert!((got - want).abs().max_element() < 1e-4);
        }
    }
}
