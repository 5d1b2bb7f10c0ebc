//! The report's seam view: what each method's *basis* does to a smooth field.
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

use anyhow::{Result, ensure};
use ndarray::{Array3, Axis};
use prt_core::{GridField, KernelWeights, SpatialKernels};
use prt_kernels::HatGrid;
use rayon::prelude::*;

/// The basis a method applies at each voxel.
pub enum LocalBasis<'a> {
    /// MBD: `B(x) = Σₙ wₙ(x) Bₙ` with the basis grid's hat kernels; `basis` is nodes × L × D.
    Moving {
        kernels: &'a HatGrid,
        basis: &'a Array3<f32>,
    },
    /// BPCA, CPCA: voxel `v` uses the basis of cluster `labels[v]`; `bases` is K × L × D.
    Clustered {
        labels: &'a [u32],
        bases: &'a Array3<f32>,
    },
}

/// Orthonormalises the rows of `rows` (each of length `d`) in place by modified Gram–Schmidt in
/// f64; rows that are numerically dependent on the earlier ones become zero.
fn orthonormalise(rows: &mut [f64], d: usize) {
    for i in 0..rows.len() / d {
        let (done, rest) = rows.split_at_mut(i * d);
        let row = &mut rest[..d];
        let norm0 = row.iter().map(|x| x * x).sum::<f64>().sqrt();
        for q in done.chunks_exact(d) {
            let dot: f64 = q.iter().zip(row.iter()).map(|(a, b)| a * b).sum();
            row.iter_mut().zip(q).for_each(|(r, a)| *r -= dot * a);
        }
        let norm = row.iter().map(|x| x * x).sum::<f64>().sqrt();
        if norm <= 1e-6 * norm0 || norm == 0.0 {
            row.fill(0.0);
        } else {
            row.iter_mut().for_each(|x| *x /= norm);
        }
    }
}

/// `out = Qᵀ Q s − s` for orthonormal (or zero) rows `q`: the residual of projecting `s`.
fn residual(q: &[f64], s: &[f32], out: &mut [f32]) {
    let d = s.len();
    let mut projected = vec![0.0f64; d];
    for row in q.chunks_exact(d) {
        let dot: f64 = row.iter().zip(s).map(|(a, &b)| a * b as f64).sum();
        projected
            .iter_mut()
            .zip(row)
            .for_each(|(p, a)| *p += dot * a);
    }
    for ((o, p), &x) in out.iter_mut().zip(&projected).zip(s) {
        *o = (p - x as f64) as f32;
    }
}

/// Gaussian standard deviation of the denoising blur, in voxels.
pub const BLUR_SIGMA: f64 = 1.0;

/// The field blurred with a separable Gaussian of [`BLUR_SIGMA`] voxels over valid voxels only
/// (normalised convolution; invalid voxels are zero): prt-mbd's denoised seam reference.
pub fn smooth(field: &GridField, valid: &[bool]) -> Result<GridField> {
    Ok(prt_mbd::blur_valid(field, valid, BLUR_SIGMA)?)
}

/// The seam view of one method.
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

/// The residual `e = P s − s` of every valid voxel of the smoothed field (`voxels × D`, zero for
/// invalid voxels).
fn residual_volume(
    smoothed: &GridField,
    valid: &[bool],
    basis: &LocalBasis<'_>,
) -> Result<Vec<f32>> {
    let d = smoothed.dim();
    let mut out = vec![0.0f32; smoothed.num_voxels() * d];
    match basis {
        LocalBasis::Clustered { labels, bases } => {
            ensure!(labels.len() == valid.len(), "labels size");
            ensure!(bases.dim().2 == d, "basis dimension");
            // Each cluster's rows, orthonormalised once.
            let q: Vec<Vec<f64>> = bases
                .axis_iter(Axis(0))
                .map(|b| {
                    let mut rows: Vec<f64> = b.iter().map(|&x| x as f64).collect();
                    orthonormalise(&mut rows, d);
                    rows
                })
                .collect();
            out.par_chunks_mut(d).enumerate().for_each(|(v, e)| {
                if valid[v] {
                    residual(&q[labels[v] as usize], smoothed.voxel(v), e);
                }
            });
        }
        LocalBasis::Moving { kernels, basis } => {
            ensure!(basis.dim().2 == d, "basis dimension");
            let rank = basis.dim().1;
            out.par_chunks_mut(d).enumerate().try_for_each_init(
                || (KernelWeights::default(), vec![0.0f64; rank * d]),
                |(weights, rows), (v, e)| -> Result<()> {
                    if !valid[v] {
                        return Ok(());
                    }
                    kernels.eval(smoothed.centre_of(v), weights)?;
                    rows.fill(0.0);
                    for (n, w) in weights.iter() {
                        let node = basis.index_axis(Axis(0), n as usize);
                        rows.iter_mut()
                            .zip(node.iter())
                            .for_each(|(r, &b)| *r += w as f64 * b as f64);
                    }
                    orthonormalise(rows, d);
                    residual(rows, smoothed.voxel(v), e);
                    Ok(())
                },
            )?;
        }
    }
    Ok(out)
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
/// on the smoothed field, with images of the horizontal slice `y`.
pub fn seam_view(
    smoothed: &GridField,
    valid: &[bool],
    labels: &[u32],
    basis: &LocalBasis<'_>,
    y: usize,
) -> Result<SeamView> {
    ensure!(labels.len() == smoothed.num_voxels(), "labels size");
    let e = residual_volume(smoothed, valid, basis)?;
    let d = smoothed.dim();
    let err = |v: usize| &e[v * d..(v + 1) * d];
    let dims = smoothed.dims();
    let strides = [1, dims[0], dims[0] * dims[1]];

    // [boundary sum, boundary count, interior sum, interior count], per z-slab then in order.
    let slabs: Vec<[f64; 4]> = (0..dims[2])
        .into_par_iter()
        .map(|z| {
            let mut acc = [0.0f64; 4];
            for yy in 0..dims[1] {
                for x in 0..dims[0] {
                    let v = smoothed.index(x, yy, z);
                    if !valid[v] {
                        continue;
                    }
                    for (k, c) in [x, yy, z].into_iter().enumerate() {
                        let u = v + strides[k];
                        if c + 1 >= dims[k] || !valid[u] {
                            continue;
                        }
                        let slot = if labels[u] != labels[v] { 0 } else { 2 };
                        acc[slot] += distance(err(u), err(v)).powi(2);
                        acc[slot + 1] += 1.0;
                    }
                }
            }
            acc
        })
        .collect();
    let acc = slabs.iter().fold([0.0f64; 4], |mut a, s| {
        a.iter_mut().zip(s).for_each(|(a, b)| *a += b);
        a
    });
    let rms = |sum: f64, count: f64| {
        if count > 0.0 {
            (sum / count).sqrt()
        } else {
            0.0
        }
    };
    let interior = rms(acc[2], acc[3]);
    let seam_ratio = if interior > 0.0 {
        rms(acc[0], acc[1]) / interior
    } else {
        0.0
    };

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
        let kernels = HatGrid::new([2, 2, 2], field.bounds()).expect("kernels");
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

    #[test]
    fn residual_removes_the_span_and_keeps_the_complement() {
        // Rows span e0 and e0 + e1 (not orthonormal); s = 2 e0 + 3 e1 + 5 e2.
        let mut rows = vec![1.0, 0.0, 0.0, 1.0, 1.0, 0.0];
        orthonormalise(&mut rows, 3);
        let mut e = vec![0.0f32; 3];
        residual(&rows, &[2.0, 3.0, 5.0], &mut e);
        assert!(e[0].abs() < 1e-6 && e[1].abs() < 1e-6);
        assert!((e[2] + 5.0).abs() < 1e-6);
    }

    #[test]
    fn dependent_rows_are_dropped() {
        let mut rows = vec![1.0, 1.0, 2.0, 2.0];
        orthonormalise(&mut rows, 2);
        assert_eq!(&rows[2..], &[0.0, 0.0]);
        let mut e = vec![0.0f32; 2];
        residual(&rows, &[1.0, 0.0], &mut e);
        assert!((e[0] + 0.5).abs() < 1e-6 && (e[1] - 0.5).abs() < 1e-6);
    }
}
