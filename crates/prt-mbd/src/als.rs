//! Alternating least squares for MBD (beyond the paper): exact solves for the coefficients with
//! the basis fixed and for the basis with the coefficients fixed, on the voxel centres.

use std::time::Instant;

use ndarray::{Array2, Array3, linalg::general_mat_mul};
use prt_core::{GridField, KernelWeights, Progress, SpatialKernels};
use prt_linalg::cholesky_solve;
use rayon::prelude::*;

use crate::objective::{Preconditioner, Problem, Samples};
use crate::solver::{IterationRecord, MbdOptions, SolveReport, initialise, validate};
use crate::solver::{Stopping, relative_to};
use crate::subspace::{cholesky_in_place, cholesky_solve_in_place, linalg_error};
use crate::{MbdError, MbdModel};

/// Largest `N·L` (basis nodes × rank) for which [`solve_als`] assembles and factors the dense
/// normal equations of the basis step (a 4096² f64 matrix is 128 MiB).
pub const ALS_MAX_BASIS_UNKNOWNS: usize = 4096;

/// Levenberg-Marquardt damping of the basis step, relative to the mean diagonal of its normal
/// equations (measured on Sponza 48 × 20 × 30, L = 8: 1e-3 and 1e-2 both keep the basis
/// bounded; 1e-2 converges further in two sweeps).
const BASIS_DAMPING: f64 = 1e-2;

/// Fits a rank-L MBD by alternating least squares on the discrete loss
/// `Σ_v ‖f_v − f̂(x_v)‖² + λ/2 ‖c‖²` over the voxel centres `x_v`.
///
/// * **Coefficients given the basis**: when the coefficient kernels interpolate at the voxel
///   centres (one kernel per voxel with weight 1 there, as the hat grid of [`crate::Mbd`]), the
///   problem separates into one `L × L` ridge system per voxel, solved exactly.
/// * **Basis given the coefficients**: the normal equations
///   `Σ_v (ψ_v ⊗ c_v)(ψ_v ⊗ c_v)ᵀ vec(B) = Σ_v (ψ_v ⊗ c_v) f_vᵀ` (`N·L` unknowns, D right-hand
///   sides), assembled per basis cell with small matrix products and solved by Cholesky, damped
///   towards the current basis (Levenberg-Marquardt, 1e-2 of the mean diagonal): without it,
///   nodes seen almost only by zero voxels (a traced volume's invalid voxels) grew their basis
///   without bound, exact at the voxel centres but wrong between them (Sponza: 8.1e-2 instead
///   of 1.7e-3). The damping slows convergence on smooth fields (synthetic 32³: 5.2e-6 instead
///   of 9.1e-7 after 8 sweeps).
///
/// Each iteration never increases the discrete loss. Initialisation as in [`crate::solve`];
/// `options.max_iterations`, `tolerance`, `patience` and the progress/cancellation contract are
/// the same; there is no sampling, so the result is deterministic.
///
/// # Errors
/// As [`crate::solve`], plus [`MbdError::InvalidKernels`] if the coefficient kernels do not
/// interpolate at the voxel centres and [`MbdError::InvalidOption`] if `N·L` exceeds
/// [`ALS_MAX_BASIS_UNKNOWNS`].
pub fn solve_als<C: SpatialKernels, B: SpatialKernels>(
    field: &GridField,
    coefficient_kernels: C,
    basis_kernels: B,
    options: &MbdOptions,
    progress: &dyn Progress,
) -> Result<(MbdModel<C, B>, SolveReport), MbdError> {
    let start = Instant::now();
    validate(field, &coefficient_kernels, &basis_kernels, options)?;
    let (l, d) = (options.rank, field.dim());
    let n = basis_kernels.len();
    if n * l > ALS_MAX_BASIS_UNKNOWNS {
        return Err(MbdError::InvalidOption {
            what: "ALS basis size",
            why: format!("{n} nodes x rank {l} exceeds {ALS_MAX_BASIS_UNKNOWNS} dense unknowns"),
        });
    }
    let voxel_of_kernel = interpolating_kernels(field, &coefficient_kernels)?;
    let problem = Problem {
        field,
        coefficient_kernels: &coefficient_kernels,
        basis_kernels: &basis_kernels,
        rank: l,
        lambda: options.lambda,
        preconditioner: Preconditioner::Diagonal,
    };
    let (mut coefficients, mut basis) = initialise(&problem, options)?;
    let mut centres = Samples::draw(field, &basis_kernels, 0, 0, false, 1);
    problem.prepare(&mut centres)?;
    let energy = problem.target_energy(&centres, progress)?;
    let mut report = SolveReport {
        init_seconds: start.elapsed().as_secs_f64(),
        ..SolveReport::default()
    };
    progress.set_len(options.max_iterations as u64);
    let mut stopping = Stopping::default();
    for _ in 0..options.max_iterations {
        progress.check()?;
        let before = problem.evaluate(&centres, &coefficients, &basis, false, progress)?;
        let loss_before = before.loss();
        coefficient_step(
            field,
            &basis_kernels,
            &voxel_of_kernel,
            &basis,
            &mut coefficients,
            l,
            options.lambda,
        )?;
        basis_step(
            field,
            &basis_kernels,
            &coefficients,
            &voxel_of_kernel,
            &mut basis,
            l,
            d,
            progress,
        )?;
        let after = problem.evaluate(&centres, &coefficients, &basis, false, progress)?;
        let loss_after = after.loss();
        report.history.push(IterationRecord {
            loss_before,
            data_before: before.data_loss,
            loss_after,
            held_out: Some(relative_to(after.data_loss, energy)),
            step: 1.0,
            elapsed: start.elapsed().as_secs_f64(),
        });
        progress.inc(1);
        progress.message(&format!("ALS loss {loss_after:.6e}"));
        if stopping.should_stop(loss_before, loss_after, before.data_loss, options) {
            report.converged = true;
            break;
        }
    }
    let m = coefficient_kernels.len();
    let to_err = |e: ndarray::ShapeError| MbdError::InvalidOption {
        what: "tensor shape",
        why: e.to_string(),
    };
    let coefficients = Array2::from_shape_vec((m, l), coefficients).map_err(to_err)?;
    let basis = Array3::from_shape_vec((n, l, d), basis).map_err(to_err)?;
    Ok((
        MbdModel::new(coefficient_kernels, basis_kernels, coefficients, basis)?,
        report,
    ))
}

/// For each coefficient kernel, the voxel at whose centre it is 1 (and all others 0).
fn interpolating_kernels<C: SpatialKernels>(
    field: &GridField,
    kernels: &C,
) -> Result<Vec<usize>, MbdError> {
    let not_interpolating = |why: String| MbdError::InvalidKernels {
        which: "coefficient",
        why,
    };
    if kernels.len() != field.num_voxels() {
        return Err(not_interpolating(format!(
            "ALS needs one kernel per voxel ({} vs {})",
            kernels.len(),
            field.num_voxels()
        )));
    }
    let mut voxel_of_kernel = vec![usize::MAX; kernels.len()];
    let mut w = KernelWeights::default();
    for v in 0..field.num_voxels() {
        kernels.eval(field.centre_of(v), &mut w)?;
        // Tolerances well above f32 rounding of the hat weights at voxel centres far from the
        // origin (a 32 × 31 × 32 grid over the Cornell box's bounds leaves weights ~3e-6 off).
        let hits: Vec<(u32, f32)> = w.iter().filter(|&(_, x)| x > 1e-4).collect();
        match hits.as_slice() {
            [(k, x)] if (x - 1.0).abs() < 1e-3 && voxel_of_kernel[*k as usize] == usize::MAX => {
                voxel_of_kernel[*k as usize] = v
            }
            _ => {
                return Err(not_interpolating(format!(
                    "kernels do not interpolate at voxel {v}"
                )));
            }
        }
    }
    Ok(voxel_of_kernel)
}

/// `c_v = (b_v b_vᵀ + λ/2 I)⁻¹ b_v f_v` for every voxel.
fn coefficient_step<B: SpatialKernels>(
    field: &GridField,
    basis_kernels: &B,
    voxel_of_kernel: &[usize],
    basis: &[f32],
    coefficients: &mut [f32],
    l: usize,
    lambda: f32,
) -> Result<(), MbdError> {
    let d = field.dim();
    let half_lambda = (lambda as f64 * 0.5).max(1e-12);
    coefficients
        .par_chunks_mut(l)
        .zip(voxel_of_kernel.par_iter())
        .try_for_each_init(
            || {
                (
                    KernelWeights::default(),
                    vec![0.0f32; l * d],
                    vec![0.0f64; l * l],
                    vec![0.0f64; l],
                )
            },
            |(psi, b, a, rhs), (out, &v)| -> Result<(), MbdError> {
                basis_kernels.eval(field.centre_of(v), psi)?;
                b.fill(0.0);
                for (node, w) in psi.iter() {
                    for (o, &x) in b
                        .iter_mut()
                        .zip(&basis[node as usize * l * d..(node as usize + 1) * l * d])
                    {
                        *o += w * x;
                    }
                }
                let f = field.voxel(v);
                for i in 0..l {
                    let bi = &b[i * d..(i + 1) * d];
                    rhs[i] = bi.iter().zip(f).map(|(&x, &y)| x as f64 * y as f64).sum();
                    for j in 0..=i {
                        let g: f64 = bi
                            .iter()
                            .zip(&b[j * d..(j + 1) * d])
                            .map(|(&x, &y)| x as f64 * y as f64)
                            .sum();
                        a[i * l + j] = g;
                        a[j * l + i] = g;
                    }
                    a[i * l + i] += half_lambda;
                }
                if cholesky_in_place(a, l) {
                    cholesky_solve_in_place(a, rhs, l, 1);
                    out.iter_mut()
                        .zip(rhs.iter())
                        .for_each(|(o, &x)| *o = x as f32);
                }
                Ok(())
            },
        )
}

/// One chunk's share of the basis normal equations: its nodes, `PᵀP` and `PᵀF`.
type CellSystem = (Vec<u32>, Array2<f32>, Array2<f32>);

/// Solves the basis normal equations with the coefficients fixed.
fn basis_step<B: SpatialKernels>(
    field: &GridField,
    basis_kernels: &B,
    coefficients: &[f32],
    voxel_of_kernel: &[usize],
    basis: &mut [f32],
    l: usize,
    d: usize,
    progress: &dyn Progress,
) -> Result<(), MbdError> {
    let n = basis_kernels.len();
    let nl = n * l;
    // Coefficients by voxel.
    let mut c_of_voxel = vec![0.0f32; field.num_voxels() * l];
    for (k, &v) in voxel_of_kernel.iter().enumerate() {
        c_of_voxel[v * l..(v + 1) * l].copy_from_slice(&coefficients[k * l..(k + 1) * l]);
    }
    let mut a = Array2::<f64>::zeros((nl, nl));
    let mut rhs = Array2::<f64>::zeros((nl, d));
    let voxels: Vec<usize> = (0..field.num_voxels()).collect();
    for chunk in voxels.chunks(4096) {
        progress.check()?;
        let parts: Vec<Result<CellSystem, MbdError>> = chunk
            .par_chunks(256)
            .map(|vs| {
                let mut w = KernelWeights::default();
                let mut rows: Vec<(Vec<u32>, Vec<f32>)> = Vec::with_capacity(vs.len());
                for &v in vs {
                    basis_kernels.eval(field.centre_of(v), &mut w)?;
                    rows.push((w.indices.clone(), w.weights.clone()));
                }
                let mut nodes: Vec<u32> = rows.iter().flat_map(|r| r.0.iter().copied()).collect();
                nodes.sort_unstable();
                nodes.dedup();
                let nb = nodes.len();
                let mut p = Array2::<f32>::zeros((vs.len(), nb * l));
                let mut f = Array2::<f32>::zeros((vs.len(), d));
                for (s, (&v, (idx, wts))) in vs.iter().zip(&rows).enumerate() {
                    for (&i, &wi) in idx.iter().zip(wts) {
                        let j = nodes.binary_search(&i).unwrap_or(0);
                        for li in 0..l {
                            p[[s, j * l + li]] += wi * c_of_voxel[v * l + li];
                        }
                    }
                    f.row_mut(s).assign(&ndarray::aview1(field.voxel(v)));
                }
                let mut ata = Array2::<f32>::zeros((nb * l, nb * l));
                general_mat_mul(1.0, &p.t(), &p, 0.0, &mut ata);
                let mut atf = Array2::<f32>::zeros((nb * l, d));
                general_mat_mul(1.0, &p.t(), &f, 0.0, &mut atf);
                Ok((nodes, ata, atf))
            })
            .collect();
        for part in parts {
            let (nodes, ata, atf) = part?;
            let global = |j: usize| nodes[j / l] as usize * l + j % l;
            for (j, row) in ata.rows().into_iter().enumerate() {
                let gj = global(j);
                for (k, &x) in row.iter().enumerate() {
                    a[[gj, global(k)]] += x as f64;
                }
                for (r, &x) in rhs.row_mut(gj).iter_mut().zip(atf.row(j).iter()) {
                    *r += x as f64;
                }
            }
        }
    }
    let trace: f64 = a.diag().sum();
    if trace <= 0.0 {
        return Ok(());
    }
    // Levenberg-Marquardt damping towards the current basis, the same for every unknown: a node
    // whose voxels are nearly all zero (a traced volume's invalid voxels) has almost no
    // curvature, and the undamped solve let its basis grow without bound there (exact at the
    // voxel centres, wrong between them: Sponza ended 5.5x above its start).
    // The damped solve still never increases the loss (the current basis stays feasible at no
    // penalty).
    let damping = BASIS_DAMPING * trace / nl as f64;
    for i in 0..nl {
        a[[i, i]] += damping;
        for (r, &b) in rhs.row_mut(i).iter_mut().zip(&basis[i * d..(i + 1) * d]) {
            *r += damping * b as f64;
        }
    }
    // The f32 cell products make a rank-deficient system (e.g. right after the global-PCA start,
    // where every node holds the same basis) slightly indefinite: a relative ridge, grown until
    // the factorisation succeeds, keeps it solvable without visibly biasing the fit.
    let mut ridge = 1e-6 * trace / nl as f64;
    let solution = loop {
        match cholesky_solve(a.view(), rhs.view(), ridge) {
            Ok(x) => break x,
            Err(prt_linalg::LinalgError::NotPositiveDefinite { .. }) if ridge < 1e-2 * trace => {
                ridge *= 100.0
            }
            Err(e) => return Err(linalg_error("ALS basis step", e)),
        }
    };
    for (b, &x) in basis.iter_mut().zip(solution.iter()) {
        *b = x as f32;
    }
    Ok(())
}
