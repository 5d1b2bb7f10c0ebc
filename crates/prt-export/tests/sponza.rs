//! Dilation on Sponza: near walls, engines' trilinear filtering blends valid voxels with the
//! voxels inside geometry; after dilation no valid voxel's interpolated irradiance drops by
//! more than `MAX_DROP_AFTER` because of them. Needs ../shared (skipped, visibly, without it).

use std::path::PathBuf;

use glam::Vec3;
use prt_bake::container::read_container;
use prt_bake::{BakeConfig, SceneInput, bake};
use prt_core::NoProgress;
use prt_export::layout::SIDES;
use prt_export::{DilateConfig, dilate};
use prt_sphere::Sky;
use prt_texture::Limits;
use prt_trace::LitVolume;

/// The stated bounds on the drop after dilation (default radius 1, one pass): the largest
/// (a filled voxel averages valid neighbours that can be darker, across a thin wall) and the
/// 99th percentile.
const MAX_DROP_AFTER: f64 = 0.7;
const P99_DROP_AFTER: f64 = 0.45;

/// Luminance of the irradiance summed over the six axis normals.
fn brightness(e: impl Fn(Vec3) -> Vec3) -> f64 {
    SIDES
        .iter()
        .map(|&n| f64::from(e(n).dot(Vec3::new(0.2126, 0.7152, 0.0722))))
        .sum()
}

/// For every valid voxel with an invalid neighbour, at the points half a voxel towards each of
/// its 26 neighbours: `1 − interpolated / interpolated-from-valid-voxels-only` (the drop the
/// invalid voxels cause), at points whose valid-only brightness is at least 5 % of the mean of
/// the valid voxels (in darker corners a relative drop says nothing). Returns the largest drop,
/// the 99th percentile, the mean, and the number of points.
fn wall_drops(volume: &LitVolume, original_valid: &[bool]) -> (f64, f64, f64, usize) {
    let size = volume.voxel_size();
    let valid: Vec<usize> = (0..volume.voxels())
        .filter(|&v| original_valid[v])
        .collect();
    let mean = valid
        .iter()
        .map(|&v| brightness(|n| volume.irradiance(v, n)))
        .sum::<f64>()
        / valid.len() as f64;
    let [nx, ny, nz] = volume.dims.map(|d| d as isize);
    let mut drops = Vec::new();
    for v in 0..volume.voxels() {
        if !original_valid[v] {
            continue;
        }
        let [x, y, z] = volume.coords(v).map(|i| i as isize);
        let mut near_wall = false;
        for o in 0..27 {
            let (dx, dy, dz) = (o % 3 - 1, o / 3 % 3 - 1, o / 9 - 1);
            let (px, py, pz) = (x + dx, y + dy, z + dz);
            if (0..nx).contains(&px) && (0..ny).contains(&py) && (0..nz).contains(&pz) {
                near_wall |= !original_valid[(px + nx * (py + ny * pz)) as usize];
            }
        }
        if !near_wall {
            continue;
        }
        for o in 0..27 {
            let offset = Vec3::new(
                (o % 3 - 1) as f32,
                (o / 3 % 3 - 1) as f32,
                (o / 9 - 1) as f32,
            );
            let p = volume.voxel_centre(v) + 0.5 * offset * size;
            let corners = volume.trilinear(p);
            let valid_weight: f32 = corners
                .iter()
                .filter(|(u, _)| original_valid[*u])
                .map(|(_, w)| w)
                .sum();
            if valid_weight < 1e-3 {
                continue;
            }
            let interpolate = |only_valid: bool, n: Vec3| {
                let mut e = Vec3::ZERO;
                for &(u, w) in &corners {
                    if only_valid && !original_valid[u] {
                        continue;
                    }
                    let scale = if only_valid { w / valid_weight } else { w };
                    e += scale * volume.irradiance(u, n);
                }
                e
            };
            let ideal = brightness(|n| interpolate(true, n));
            if ideal < 0.05 * mean {
                continue;
            }
            drops.push((1.0 - brightness(|n| interpolate(false, n)) / ideal).max(0.0));
        }
    }
    drops.sort_by(f64::total_cmp);
    let count = drops.len();
    let p99 = drops[(count * 99 / 100).min(count - 1)];
    (
        drops[count - 1],
        p99,
        drops.iter().sum::<f64>() / count as f64,
        count,
    )
}

#[test]
#[cfg_attr(
    prt_skip_shared_scenes,
    ignore = "needs ../shared/scenes, absent at build time (PRT_REQUIRE_SHARED=1 requires it)"
)]
fn dilation_stops_walls_from_darkening_sponzas_probes() {
    let scene =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/scenes/sponza/Sponza.gltf");
    let dir = std::env::temp_dir().join(format!("prt-export-sponza-{}", std::process::id()));
    let config = BakeConfig {
        resolution: 20,
        rays_per_voxel: 48,
        cache_rays: 16,
        rank: 4,
        basis_nodes: 4,
        max_iterations: 16,
        baselines: false,
        container: Some(dir.join("mbd")),
        ..BakeConfig::default()
    };
    bake(
        &SceneInput::load_gltf(&scene).unwrap(),
        &config,
        &NoProgress,
    )
    .unwrap();
    let container = read_container(&dir.join("mbd"), &Limits::default()).unwrap();
    let lit = container.light(&Sky::default(), &NoProgress).unwrap();
    let (before, before_p99, before_mean, points) = wall_drops(&lit, &lit.valid);
    let dilated = dilate(&lit, &DilateConfig::default()).unwrap();
    let (after, after_p99, after_mean, _) = wall_drops(&dilated.volume, &lit.valid);
    eprintln!(
        "Sponza {:?}: {points} points within one voxel of a wall; drop largest / p99 / mean: \
         before dilation {before:.3} / {before_p99:.3} / {before_mean:.4}, after {after:.3} / \
         {after_p99:.3} / {after_mean:.4}; {} voxels filled, {} left",
        lit.dims, dilated.filled, dilated.unfilled
    );
    assert!(points > 100);
    assert!(
        after <= MAX_DROP_AFTER,
        "largest drop after dilation {after}"
    );
    assert!(
        after_p99 <= P99_DROP_AFTER,
        "99th percentile after dilation {after_p99}"
    );
    assert!(
        after_mean < 0.5 * before_mean,
        "dilation did not help: {before_mean} -> {after_mean}"
    );
}
