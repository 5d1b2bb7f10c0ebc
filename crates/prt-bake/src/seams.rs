//! The seam view: what each method's *basis* does to a smooth field.
//!
//! The traced reference carries Monte Carlo noise from voxel to voxel and every reconstruction
//! keeps part of it, so error maps against the reference show noise rather than seams. A seam is
//! a property of the basis, not of the noise: BPCA and CPCA give every block or cluster its own
//! rank-L basis, so the part of a field they cannot represent changes abruptly where the basis
//! changes; MBD's basis `B(x) = Σₙ wₙ(x) Bₙ` moves continuously with `x`, so it cannot jump.
//!
//! The seam view therefore projects a *denoised* reference `s` (the traced field blurred with a
//! Gaussian of [`BLUR_SIGMA`] voxels over valid voxels) onto the basis each method uses at every
//! voxel, `e(x) = P(x) s(x) − s(x)`. Projection is exactly how BPCA and CPCA compute their
//! coefficients; for MBD it is the least-squares coefficient the solver approximates at a voxel
//! centre. Without the noise, the jump `‖e_u − e_v‖` between neighbouring voxels is large only
//! where the basis jumps: at block and cluster boundaries.
//!
//! The residuals and the volume's seam ratio come from [`prt_mbd::projection_seam_ratio`] and
//! [`prt_mbd::expert::projection_residuals`]; this module adds the per-pixel maps of one
//! horizontal slice, which the report draws.

use prt_core::GridField;
use prt_mbd::{LocalBasis, MbdError};

/// Gaussian standard deviation of the denoising blur, in voxels.
pub const BLUR_SIGMA: f64 = 1.0;

/// The field blurred with a separable Gaussian of [`BLUR_SIGMA`] voxels over valid voxels only
/// (normalised convolution; invalid voxels are zero): prt-mbd's denoised seam reference.
pub(crate) fn smooth(field: &GridField, valid: &[bool]) -> Result<GridField, MbdError> {
    prt_mbd::expert::blur_valid(field, valid, BLUR_SIGMA)
}

/// The seam view of one method: its basis applied to the denoised reference.
#[derive(Debug, Clone, PartialEq)]
pub struct SeamView {
    /// Per pixel of the horizontal slice `y` (x fastest): the largest jump of the residual to an
    /// in-slice neighbour, `‖e_v − e_u‖ / max(‖s_v‖, ‖s_u‖, floor)`; `None` for invalid voxels.
    /// `floor` is a tenth of the smoothed field's RMS norm over valid voxels.
    pub jump: Vec<Option<f32>>,
    /// Per pixel of the slice: the relative residual `‖e_v‖ / max(‖s_v‖, floor)`.
    pub residual: Vec<Option<f32>>,
    /// Over the whole volume: RMS jump `‖e_u − e_v‖` between valid neighbours with different
    /// labels, over the same between neighbours with equal labels. About 1 without seams.
    pub seam_ratio: f64,
}

fn norm(x: &[f32]) -> f64 {
    x.iter().map(|&a| a as f64 * a as f64).sum::<f64>().sqrt()
}

fn distance(a: &[f32], b: &[f32]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(&x, &y)| (x as f64 - y as f64).powi(2))
        .sum::<f64>()
        .sqrt()
}

/// The seam view of a method with voxel `labels` (its blocks, clusters or, for MBD, basis cells)
/// on the smoothed field, with the maps of the horizontal slice `y`.
pub(crate) fn seam_view(
    smoothed: &GridField,
    valid: &[bool],
    labels: &[u32],
    basis: &LocalBasis<'_>,
    y: usize,
) -> Result<SeamView, MbdError> {
    let e = prt_mbd::expert::projection_residuals(smoothed, valid, basis)?;
    let seam_ratio = prt_mbd::expert::residual_seam_ratio(smoothed, valid, labels, &e)?;
    let d = smoothed.dim();
    let err = |v: usize| &e[v * d..(v + 1) * d];
    let dims = smoothed.dims();
    let strides = [1, dims[0], dims[0] * dims[1]];

    // Relative measures divide by the field's norm, but never by less than a tenth of its RMS:
    // enclosed voxels that no light reaches (a zero field) would otherwise turn noise-level
    // residuals into 100 %.
    let (energy, count) = (0..smoothed.num_voxels())
        .filter(|&v| valid[v])
        .fold((0.0f64, 0usize), |(e, n), v| {
            (e + norm(smoothed.voxel(v)).powi(2), n + 1)
        });
    let floor = 0.1 * (energy / count.max(1) as f64).sqrt();
    let (nx, nz) = (dims[0], dims[2]);
    let mut jump = Vec::with_capacity(nx * nz);
    let mut residual = Vec::with_capacity(nx * nz);
    for z in 0..nz {
        for x in 0..nx {
            let v = smoothed.index(x, y, z);
            if !valid[v] {
                jump.push(None);
                residual.push(None);
                continue;
            }
            let sv = norm(smoothed.voxel(v)).max(floor);
            let neighbours = [
                (x > 0).then(|| v - 1),
                (x + 1 < nx).then(|| v + 1),
                (z > 0).then(|| v - strides[2]),
                (z + 1 < nz).then(|| v + strides[2]),
            ];
            let largest = neighbours
                .into_iter()
                .flatten()
                .filter(|&u| valid[u])
                .map(|u| {
                    let scale = sv.max(norm(smoothed.voxel(u)));
                    if scale > 0.0 {
                        distance(err(u), err(v)) / scale
                    } else {
                        0.0
                    }
                })
                .fold(0.0f64, f64::max);
            jump.push(Some(largest as f32));
            residual.push(Some(if sv > 0.0 {
                (norm(err(v)) / sv) as f32
            } else {
                0.0
            }));
        }
    }
    Ok(SeamView {
        jump,
        residual,
        seam_ratio,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    use glam::Vec3;
    use ndarray::Array3;
    use prt_core::Aabb;

    /// f(x) = (1, 0.5 + x, 0.2) on an 8 × 2 × 2 grid over [0, 1]³: smooth, with every voxel valid.
    fn ramp() -> GridField {
        let bounds = Aabb::new(Vec3::ZERO, Vec3::ONE);
        GridField::from_fn([8, 2, 2], bounds, 3, |p, out| {
            out.copy_from_slice(&[1.0, 0.5 + p.x, 0.2])
        })
        .expect("finite")
    }

    /// Labels splitting the ramp into its left and right halves.
    fn halves(field: &GridField) -> Vec<u32> {
        (0..field.num_voxels())
            .map(|v| u32::from(field.coords(v)[0] >= 4))
            .collect()
    }

    fn max_jump(view: &SeamView) -> f32 {
        view.jump.iter().flatten().fold(0.0f32, |a, &b| a.max(b))
    }

    #[test]
    fn smoothing_keeps_a_constant_and_ignores_invalid_voxels() {
        let bounds = Aabb::new(Vec3::ZERO, Vec3::ONE);
        let mut field = GridField::from_fn([5, 4, 3], bounds, 2, |_, out| {
            out.copy_from_slice(&[2.0, -1.0])
        })
        .expect("finite");
        // Invalid voxels hold garbage that must not leak into their neighbours.
        let valid: Vec<bool> = (0..field.num_voxels()).map(|v| v % 7 != 3).collect();
        for v in (0..field.num_voxels()).filter(|&v| !valid[v]) {
            field.voxel_mut(v).copy_from_slice(&[1e3, 1e3]);
        }
        let smoothed = smooth(&field, &valid).expect("smooth");
        for v in 0..field.num_voxels() {
            let want: &[f32] = if valid[v] { &[2.0, -1.0] } else { &[0.0, 0.0] };
            for (a, b) in smoothed.voxel(v).iter().zip(want) {
                assert!((a - b).abs() < 1e-5, "voxel {v}: {a} vs {b}");
            }
        }
    }

    #[test]
    fn a_basis_that_jumps_between_clusters_makes_a_seam() {
        let field = ramp();
        let valid = vec![true; field.num_voxels()];
        let labels = halves(&field);
        let e0 = [1.0f32, 0.0, 0.0];
        let e1 = [0.0f32, 1.0, 0.0];
        let bases = |right: [f32; 3]| {
            Array3::from_shape_vec((2, 1, 3), [e0, right].concat()).expect("shape")
        };
        let (same, different) = (bases(e0), bases(e1));
        let view = |bases: &Array3<f32>| {
            let basis = LocalBasis::Clustered {
                labels: &labels,
                bases,
            };
            seam_view(&field, &valid, &labels, &basis, 0).expect("seam view")
        };
        let (smooth_view, seam) = (view(&same), view(&different));
        // With one basis everywhere the boundary is like any other x-neighbour pair; with two,
        // the residual jumps from (0, -(0.5 + x), -0.2) to (-1, 0, -0.2) across it.
        assert!(
            seam.seam_ratio > 5.0 * smooth_view.seam_ratio,
            "{} vs {}",
            seam.seam_ratio,
            smooth_view.seam_ratio
        );
        assert!(max_jump(&seam) > 0.5, "{}", max_jump(&seam));
        // Residual of e0 on the left half: ‖(0, 0.5 + x, 0.2)‖ / ‖(1, 0.5 + x, 0.2)‖ at x = 1/16.
        let r = seam.residual[0].expect("valid");
        let (a, b) = (0.5f32 + 1.0 / 16.0, 0.2f32);
        let want = (a * a + b * b).sqrt() / (1.0 + a * a + b * b).sqrt();
        assert!((r - want).abs() < 1e-5, "{r} vs {want}");
    }

    #[test]
    fn a_dark_region_is_not_reported_as_unrepresentable() {
        // Left half: a noise-level field orthogonal to the basis (relative residual 100 %).
        let bounds = Aabb::new(Vec3::ZERO, Vec3::ONE);
        let field = GridField::from_fn([8, 2, 2], bounds, 3, |p, out| {
            let v = if p.x < 0.5 {
                [0.0, 0.0, 1e-6]
            } else {
                [1.0, 0.5 + p.x, 0.2]
            };
            out.copy_from_slice(&v)
        })
        .expect("finite");
        let valid = vec![true; field.num_voxels()];
        let labels = vec![0u32; field.num_voxels()];
        let bases = Array3::from_shape_vec((1, 1, 3), vec![1.0, 0.0, 0.0]).expect("shape");
        let basis = LocalBasis::Clustered {
            labels: &labels,
            bases: &bases,
        };
        let view = seam_view(&field, &valid, &labels, &basis, 0).expect("seam view");
        let dark = view.residual[0].expect("valid");
        assert!(dark < 1e-3, "residual of a dark voxel {dark}");
        let lit = view.residual[7].expect("valid");
        assert!(lit > 0.5, "residual of a lit voxel {lit}");
    }

    #[test]
    fn a_moving_basis_does_not_jump() {
        let field = ramp();
        let valid = vec![true; field.num_voxels()];
        let labels = halves(&field);
        // Two basis nodes along x (e0 on the left, e1 on the right), blended by hat kernels.
        let kernels = prt_kernels::HatGrid::new([2, 2, 2], field.bounds()).expect("kernels");
        let mut data = Vec::new();
        for node in 0..8 {
            data.extend(if node % 2 == 0 {
                [1.0f32, 0.0, 0.0]
            } else {
                [0.0, 1.0, 0.0]
            });
        }
        let moving = Array3::from_shape_vec((8, 1, 3), data).expect("shape");
        let bases =
            Array3::from_shape_vec((2, 1, 3), vec![1.0, 0.0, 0.0, 0.0, 1.0, 0.0]).expect("shape");
        let moving_view = seam_view(
            &field,
            &valid,
            &labels,
            &LocalBasis::Moving {
                kernels: &kernels,
                basis: &moving,
            },
            0,
        )
        .expect("moving");
        let clustered_view = seam_view(
            &field,
            &valid,
            &labels,
            &LocalBasis::Clustered {
                labels: &labels,
                bases: &bases,
            },
            0,
        )
        .expect("clustered");
        assert!(
            max_jump(&moving_view) < 0.5 * max_jump(&clustered_view),
            "{} vs {}",
            max_jump(&moving_view),
            max_jump(&clustered_view)
        );
        assert!(moving_view.seam_ratio < 0.5 * clustered_view.seam_ratio);
    }
}
