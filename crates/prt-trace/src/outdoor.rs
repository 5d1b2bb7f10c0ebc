//! The built-in outdoor scene: terrain with a few buildings, for the production (hybrid 2D × 3D)
//! layout of Moving Basis Decomposition.

use std::f32::consts::TAU;

use glam::Vec3;

use crate::scene::{Material, Scene};

/// Half the side of the square terrain (metres).
const TERRAIN_HALF: f32 = 64.0;
/// Terrain quads per side (2 m spacing).
const TERRAIN_QUADS: usize = 64;

/// Height of every building's floor, below the lowest terrain point (about 0.07 m).
const BUILDING_BASE: f32 = -2.0;

/// A building: footprint centre (x, z), half extents (x, z), height above the highest terrain
/// point under it, albedo.
type Building = ([f32; 2], [f32; 2], f32, [f32; 3]);

#[rustfmt::skip]
const BUILDINGS: [Building; 6] = [
    ([-30.0, -20.0], [8.0, 6.0], 9.0, [0.62, 0.58, 0.52]),
    ([-5.0, 25.0], [6.0, 10.0], 6.0, [0.70, 0.45, 0.35]),
    ([20.0, -15.0], [10.0, 7.0], 10.0, [0.55, 0.55, 0.60]),
    ([35.0, 30.0], [5.0, 5.0], 11.0, [0.75, 0.72, 0.65]),
    ([-40.0, 35.0], [7.0, 4.0], 4.0, [0.50, 0.40, 0.30]),
    ([5.0, -40.0], [12.0, 5.0], 5.0, [0.65, 0.65, 0.62]),
];

/// Terrain height at `(x, z)`: a few summed sinusoids, between about 0 and 5.4 m.
pub(crate) fn terrain_height(x: f32, z: f32) -> f32 {
    2.7 + 1.6 * (TAU * x / 97.0 + 0.3).sin() * (TAU * z / 71.0 + 1.1).cos()
        + 0.8 * (TAU * (x + z) / 43.0 + 2.0).sin()
        + 0.3 * (TAU * (x - 2.0 * z) / 29.0).sin()
}

impl Scene {
    /// A small outdoor town: a 128 m × 128 m terrain centred at the origin (a heightfield of
    /// summed sinusoids, 0 to about 5.4 m high, 2 m quads, front faces up, single-sided so that
    /// voxels under it are invalid) and six closed box buildings (4 to 11 m above the terrain,
    /// outward single-sided faces, floors at y = -2 below the terrain). Y up; bounds
    /// `[-64, -2, -64]`–`[64, 14.94, 64]`; 8264 triangles, deterministic.
    ///
    /// The test bed of the production configuration of Moving Basis Decomposition (a 2D basis
    /// over the terrain, coefficients in a 3D volume).
    pub fn outdoor_town() -> Self {
        let mut scene = Self::default();
        let ground = scene.push_material(Material {
            double_sided: false,
            ..Material::diffuse("terrain", Vec3::new(0.24, 0.30, 0.16))
        });
        let n = TERRAIN_QUADS;
        let step = 2.0 * TERRAIN_HALF / n as f32;
        let vertex = |i: usize, k: usize| {
            let (x, z) = (
                -TERRAIN_HALF + i as f32 * step,
                -TERRAIN_HALF + k as f32 * step,
            );
            Vec3::new(x, terrain_height(x, z), z)
        };
        let mut index = 0;
        for k in 0..n {
            for i in 0..n {
                let (a, b, c, d) = (
                    vertex(i, k),
                    vertex(i + 1, k),
                    vertex(i + 1, k + 1),
                    vertex(i, k + 1),
                );
                // Counter-clockwise seen from above: the winding normal points up.
                for t in [[a, d, c], [a, c, b]] {
                    if scene.push_triangle(t, ground, "terrain", index).is_err() {
                        unreachable!("finite built-in terrain");
                    }
                    index += 1;
                }
            }
        }
        for (b, (centre, half, height, albedo)) in BUILDINGS.into_iter().enumerate() {
            let m = scene.push_material(Material {
                double_sided: false,
                ..Material::diffuse(&format!("building{b}"), Vec3::from_array(albedo))
            });
            // The highest terrain under the footprint (its corners, centre and edge midpoints;
            // the terrain is smooth at this scale) sets the roof; the base sits below the
            // lowest terrain anywhere, so no voxel under the ground sees a building's floor.
            let heights: Vec<f32> = [-1.0f32, 0.0, 1.0]
                .into_iter()
                .flat_map(|u| {
                    [-1.0f32, 0.0, 1.0]
                        .map(|v| terrain_height(centre[0] + u * half[0], centre[1] + v * half[1]))
                })
                .collect();
            let high = heights.iter().copied().fold(f32::NEG_INFINITY, f32::max);
            let min = Vec3::new(centre[0] - half[0], BUILDING_BASE, centre[1] - half[1]);
            let max = Vec3::new(centre[0] + half[0], high + height, centre[1] + half[1]);
            scene.push_box(min, max, false, m, "building");
        }
        scene
    }
}
