//! The basis-projection seam measure: what each method's *basis* does to a smooth field.
//!
//! A traced reference carries Monte Carlo noise from voxel to voxel and every reconstruction
//! keeps part of it, so error maps against the reference show noise rather than seams. A seam is
//! a property of the basis, not of the noise: BPCA and CPCA give every block or cluster its own
//! rank-L basis, so the part of a field they cannot represent changes abruptly where the basis
//! changes; MBD's basis `B(x) = Σ_n ψ_n(x) B_n` moves continuously with `x` (for any continuous
//! basis kernels: hats, [`crate::expert::LabelKernels`]), so it cannot jump.
//!
//! [`projection_residuals`] therefore projects a *denoised* reference `s` (e.g. the traced field
//! blurred by [`crate::expert::blur_valid`]) onto the basis each method uses at every voxel,
//! `e(x) = P(x) s(x) − s(x)`. Projection is exactly how BPCA and CPCA compute their
//! coefficients; for MBD it is the least-squares coefficient the solver approximates at a voxel
//! centre. Without the noise, the jump `‖e_u − e_v‖` between neighbouring voxels is large only
//! where the basis jumps; [`residual_seam_ratio`] compares it across cluster boundaries with the
//! same inside clusters.

use ndarray::{Array3, Axis};
use prt_core::{CoreError, GridField, KernelWeights, SpatialKernels};
use rayon::prelude::*;

use crate::MbdError;
use crate::eval::neighbour_jumps;

/// The basis a method applies at each voxel.
pub enum LocalBasis<'a> {
    /// MBD: `B(x) = Σ_n ψ_n(x) B_n` with the basis kernels `kernels`; `basis` is N × L × D.
    Moving {
        /// The basis kernels.
        kernels: &'a dyn SpatialKernels,
        /// The basis tensor, N × L × D.
        basis: &'a Array3<f32>,
    },
    /// BPCA, CPCA: voxel `v` uses the basis of cluster `labels[v]`; `bases` is K × L × D.
    Clustered {
        /// The cluster of each voxel.
        labels: &'a [u32],
        /// The clusters' bases, K × L × D.
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
        let dot: f64 = row.iter().zip(s).map(|(&a, &b)| a * b as f64).sum();
        projected
            .iter_mut()
            .zip(row)
            .for_each(|(p, &a)| *p += dot * a);
    }
    for ((o, &p), &x) in out.iter_mut().zip(&projected).zip(s) {
        *o = (p - x as f64) as f32;
    }
}

fn check_len(what: &'static str, expected: usize, got: usize) -> Result<(), MbdError> {
    if expected == got {
        Ok(())
    } else {
        Err(CoreError::LengthMismatch {
            what,
            expected,
            got,
        }
        .into())
    }
}

/// The residual `e = P s − s` of the projection of every valid voxel of `smoothed` onto the
/// basis `basis` applies there (`voxels × D`, zero for invalid voxels).
///
/// # Errors
/// `valid` or the labels not one per voxel, a basis of another dimension than the field's, a
/// label without a basis, or kernels that cannot be evaluated at a voxel centre.
pub fn projection_residuals(
    smoothed: &GridField,
    valid: &[bool],
    basis: &LocalBasis<'_>,
) -> Result<Vec<f32>, MbdError> {
    let d = smoothed.dim();
    let voxels = smoothed.num_voxels();
    check_len("validity mask", voxels, valid.len())?;
    let mut out = vec![0.0f32; voxels * d];
    match basis {
        LocalBasis::Clustered { labels, bases } => {
            check_len("labels", voxels, labels.len())?;
            check_len("basis dimension", d, bases.dim().2)?;
            if let Some(&k) = labels.iter().find(|&&k| k as usize >= bases.dim().0) {
                return Err(MbdError::ShapeMismatch {
                    what: "cluster bases",
                    expected: vec![k as usize + 1],
                    got: bases.shape().to_vec(),
                });
            }
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
            check_len("basis dimension", d, basis.dim().2)?;
            check_len("basis nodes", kernels.len(), basis.dim().0)?;
            let rank = basis.dim().1;
            out.par_chunks_mut(d).enumerate().try_for_each_init(
                || (KernelWeights::default(), vec![0.0f64; rank * d]),
                |(weights, rows), (v, e)| -> Result<(), MbdError> {
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

/// The RMS jump `‖e_u − e_v‖` of `residuals` (from [`projection_residuals`]) between valid
/// face neighbours with different `labels`, over the same between neighbours with equal labels:
/// about 1 without seams, well above 1 where the basis jumps at the boundaries (0 without
/// interior jumps).
///
/// # Errors
/// `valid`, `labels` or `residuals` not of the field's size.
pub fn residual_seam_ratio(
    smoothed: &GridField,
    valid: &[bool],
    labels: &[u32],
    residuals: &[f32],
) -> Result<f64, MbdError> {
    let voxels = smoothed.num_voxels();
    let d = smoothed.dim();
    check_len("validity mask", voxels, valid.len())?;
    check_len("labels", voxels, labels.len())?;
    check_len("residuals", voxels * d, residuals.len())?;
    let jumps = neighbour_jumps(smoothed.dims(), d, &|v: usize| valid[v], labels, residuals);
    let sum = |i: usize| jumps.iter().map(|axis| axis[i]).sum::<f64>();
    let rms = |sum: f64, count: f64| {
        if count > 0.0 {
            (sum / count).sqrt()
        } else {
            0.0
        }
    };
    let interior = rms(sum(2), sum(3));
    Ok(if interior > 0.0 {
        rms(sum(0), sum(1)) / interior
    } else {
        0.0
    })
}

/// [`residual_seam_ratio`] of the [`projection_residuals`] of `basis`.
///
/// # Errors
/// As those two.
pub fn projection_seam_ratio(
    smoothed: &GridField,
    valid: &[bool],
    labels: &[u32],
    basis: &LocalBasis<'_>,
) -> Result<f64, MbdError> {
    let residuals = projection_residuals(smoothed, valid, basis)?;
    residual_seam_ratio(smoothed, valid, labels, &residuals)
}

#[cfg(test)]
mod tests {
    use super::*;

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
