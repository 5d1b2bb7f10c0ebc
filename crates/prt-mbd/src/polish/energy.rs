//! Exact `∫ ‖f‖²` of a trilinearly interpolated grid field.

use super::*;

/// `∫ ‖f(x)‖² dx` of the trilinear interpolation of `field` over its box (clamped in the outer
/// half voxels, as [`GridField::sample`]), in units of one voxel's volume, computed exactly.
/// Applied to the difference between a grid reconstruction (e.g. a [`crate::PiecewisePcaModel`]'s,
/// which is sampled trilinearly) and the field, it is that reconstruction's exact error, the
/// counterpart of [`ExactLoss::data`] (divide by the field's own value for the relative MSE).
pub fn trilinear_energy(field: &GridField) -> f64 {
    let voxels = field.dims();
    let mass = [0, 1, 2].map(|k| match voxels[k] {
        1 => vec![[0.0, 1.0, 0.0]],
        n => mass_matrix(&Axis::new(n, 2, (0.0, n as f64)), n),
    });
    trilinear_energy_with(field, mass)
}

/// `∫ φ_i φ_{i+δ}` along one axis, as `[δ = −1, 0, +1]` per voxel, from the axis' rule (exact:
/// degree 2).
pub(super) fn mass_matrix(axis: &Axis, voxels: usize) -> Vec<[f64; 3]> {
    let mut m = vec![[0.0; 3]; voxels];
    for p in &axis.points {
        let (lo, hi) = (p.ci, p.ci + 1);
        let (wl, wh) = (1.0 - p.ct, p.ct);
        m[lo][1] += p.w * wl * wl;
        m[hi][1] += p.w * wh * wh;
        m[lo][2] += p.w * wl * wh;
        m[hi][0] += p.w * wl * wh;
    }
    m
}

/// `Σ_{v,v'} f_v·f_v' Π_k mass_k`, over the 27 neighbours of every voxel, in fixed chunks.
pub(super) fn trilinear_energy_with(field: &GridField, mass: [Vec<[f64; 3]>; 3]) -> f64 {
    let [nx, ny, nz] = field.dims();
    let partial: Vec<f64> = (0..field.num_voxels())
        .collect::<Vec<_>>()
        .par_chunks(NODE_CHUNK)
        .map(|chunk| {
            let mut sum = 0.0;
            for &v in chunk {
                let at = [v % nx, v / nx % ny, v / (nx * ny)];
                let fv = field.voxel(v);
                for nbr in 0..27 {
                    let delta = [nbr % 3, nbr / 3 % 3, nbr / 9].map(|t| t as isize - 1);
                    let q = [0, 1, 2].map(|k| at[k] as isize + delta[k]);
                    if (0..3).any(|k| q[k] < 0 || q[k] >= [nx, ny, nz][k] as isize) {
                        continue;
                    }
                    let weight: f64 = (0..3)
                        .map(|k| mass[k][at[k]][(delta[k] + 1) as usize])
                        .product();
                    if weight == 0.0 {
                        continue;
                    }
                    let u = q[0] as usize + nx * (q[1] as usize + ny * q[2] as usize);
                    let dot: f64 = fv
                        .iter()
                        .zip(field.voxel(u))
                        .map(|(&a, &b)| a as f64 * b as f64)
                        .sum();
                    sum += weight * dot;
                }
            }
            sum
        })
        .collect();
    partial.iter().sum()
}
