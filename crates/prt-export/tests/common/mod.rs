//! Shared helpers of the export tests: random skies and SH, Bevy's and three.js's sampling
//! written from their shaders' descriptions, f16 and RGB9E5 rounding bounds.
#![allow(dead_code)]

use glam::Vec3;
use prt_trace::lit::RadianceSh;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;

/// Random radiance SH whose band 0 dominates (a plausible lit voxel: mostly positive).
pub fn random_radiance(seed: u64) -> RadianceSh {
    let mut rng = Pcg64::seed_from_u64(seed);
    std::array::from_fn(|_| {
        let l0 = rng.random_range(0.5f32..4.0);
        std::array::from_fn(|j| {
            if j == 0 {
                l0
            } else {
                rng.random_range(-0.3f32..0.3) * l0
            }
        })
    })
}

/// Uniform random unit directions.
pub fn random_directions(n: usize, seed: u64) -> Vec<Vec3> {
    let mut rng = Pcg64::seed_from_u64(seed);
    (0..n)
        .map(|_| {
            let z = rng.random_range(-1.0f32..1.0);
            let phi = rng.random_range(0.0f32..std::f32::consts::TAU);
            let r = (1.0 - z * z).max(0.0).sqrt();
            Vec3::new(r * phi.cos(), r * phi.sin(), z)
        })
        .collect()
}

/// Linear filtering of an RGBA-or-RGB 3D texture at normalised `uvw`, clamp-to-edge, texel
/// centres at `(i + ½) / size` (what a GPU sampler with linear min/mag filter does).
pub fn sample_linear(texels: &[f32], channels: usize, size: [usize; 3], uvw: Vec3) -> [f32; 4] {
    let mut lo = [0usize; 3];
    let mut t = [0f32; 3];
    for a in 0..3 {
        let p = (uvw[a] * size[a] as f32 - 0.5).clamp(0.0, (size[a] - 1) as f32);
        lo[a] = (p.floor() as usize).min(size[a].saturating_sub(2));
        t[a] = p - lo[a] as f32;
    }
    let mut out = [0f32; 4];
    for corner in 0..8 {
        let mut w = 1.0;
        let mut idx = [0usize; 3];
        for a in 0..3 {
            let up = corner >> a & 1 == 1;
            idx[a] = (lo[a] + usize::from(up)).min(size[a] - 1);
            w *= if up { t[a] } else { 1.0 - t[a] };
        }
        let texel = idx[0] + size[0] * (idx[1] + size[1] * idx[2]);
        for c in 0..channels {
            out[c] += w * texels[channels * texel + c];
        }
    }
    out
}

/// Bevy's `irradiance_volume_light` (bevy_pbr's irradiance_volume.wgsl), without intensity:
/// `unit_pos` is the point in the probe's unit cube `[-½, ½]³`.
pub fn bevy_sample(
    texels: &[f32],
    channels: usize,
    atlas: [usize; 3],
    unit_pos: Vec3,
    n: Vec3,
) -> Vec3 {
    let atlas_f = Vec3::new(atlas[0] as f32, atlas[1] as f32, atlas[2] as f32);
    let resolution = atlas_f / Vec3::new(1.0, 2.0, 3.0);
    let stp =
        ((unit_pos + 0.5) * resolution).clamp(Vec3::splat(0.5), resolution - Vec3::splat(0.5));
    let uvw = stp / atlas_f;
    let neg = |c: f32| if c < 0.0 { 0.5 } else { 0.0 };
    let rgb = |uvw: Vec3| {
        let s = sample_linear(texels, channels, atlas, uvw);
        Vec3::new(s[0], s[1], s[2])
    };
    let x = rgb(uvw + Vec3::new(0.0, neg(n.x), 0.0));
    let y = rgb(uvw + Vec3::new(0.0, neg(n.y), 1.0 / 3.0));
    let z = rgb(uvw + Vec3::new(0.0, neg(n.z), 2.0 / 3.0));
    x * n.x * n.x + y * n.y * n.y + z * n.z * n.z
}

/// three.js 0.187's `getLightProbeGridIrradiance` (lightprobes_pars_fragment) without the
/// half-spacing normal offset: the box holds one cell per probe, probes at cell centres, the
/// lookup clamped to the outermost probe centres; the atlas fetch and the L2 irradiance of its
/// basis (before the shader's clamp at 0).
pub fn threejs_sample(
    texels: &[f32],
    atlas: [usize; 3],
    box_min: Vec3,
    box_max: Vec3,
    res: [usize; 3],
    pos: Vec3,
    n: Vec3,
) -> Vec3 {
    let res_f = Vec3::new(res[0] as f32, res[1] as f32, res[2] as f32);
    let range = box_max - box_min;
    let uvw = ((pos - box_min) / range).clamp(0.5 / res_f, 1.0 - 0.5 / res_f);
    let nz = res_f.z;
    let padded = nz + 2.0;
    let depth = 7.0 * padded;
    let base = uvw.z * nz + 1.0;
    let s: Vec<[f32; 4]> = (0..7)
        .map(|t| {
            sample_linear(
                texels,
                4,
                atlas,
                Vec3::new(uvw.x, uvw.y, (base + t as f32 * padded) / depth),
            )
        })
        .collect();
    let flat: Vec<f32> = s.iter().flatten().copied().collect();
    let c = |k: usize| Vec3::new(flat[3 * k], flat[3 * k + 1], flat[3 * k + 2]);
    let (x, y, z) = (n.x, n.y, n.z);
    c(0) * 0.886227
        + c(1) * 2.0 * 0.511664 * y
        + c(2) * 2.0 * 0.511664 * z
        + c(3) * 2.0 * 0.511664 * x
        + c(4) * 2.0 * 0.429043 * x * y
        + c(5) * 2.0 * 0.429043 * y * z
        + c(6) * (0.743125 * z * z - 0.247708)
        + c(7) * 2.0 * 0.429043 * x * z
        + c(8) * 0.429043 * (x * x - y * y)
}

/// Bound on the irradiance error from storing each coefficient of `l` as f16 (relative 2⁻¹¹,
/// plus the smallest subnormal step): `Σ_j A_l |Y_j|_max |c_j| 2⁻¹¹`, with `|Y_j| ≤ 1.1`.
pub fn f16_irradiance_bound(l: &[f32; 9]) -> f32 {
    (0..9)
        .map(|j| prt_trace::expert::CLAMPED_COSINE[j] * 1.1 * (l[j].abs() * 2f32.powi(-11) + 6e-8))
        .sum()
}

/// f16 rounding of one value's bound (relative 2⁻¹¹ plus the subnormal step).
pub fn f16_bound(v: f32) -> f32 {
    v.abs() * 2f32.powi(-11) + 6e-8
}

/// Voxel `v` of a `dims` grid in Bevy's unit cube when the exported grid is that grid padded
/// by `pad` voxel layers on every side.
pub fn unit_pos(dims: [usize; 3], pad: usize, v: usize) -> Vec3 {
    let [nx, ny, _] = dims;
    let c = [v % nx, v / nx % ny, v / (nx * ny)];
    Vec3::from_array(std::array::from_fn(|a| {
        (c[a] as f32 + pad as f32 + 0.5) / (dims[a] + 2 * pad) as f32 - 0.5
    }))
}
