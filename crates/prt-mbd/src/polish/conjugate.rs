//! The polish's iteration: preconditioned nonlinear conjugate gradients on the reduced loss.

use super::*;

/// Longest step of the conjugate-gradient line search, in multiples of the step that is optimal
/// with the basis held fixed.
pub(super) const MAX_STRETCH: f64 = 32.0;
/// Iterations whose mean decrease the conjugate gradients' stopping rule judges.
pub(super) const STOP_WINDOW: usize = 3;

/// Preconditioned nonlinear conjugate gradients (Polak–Ribière, restarted when β < 0 or the
/// direction does not descend) on the reduced loss `g(c) = min_B E(c, B)`, whose every
/// evaluation solves the basis exactly (variable projection). Its gradient is the coefficient
/// step's residual at that basis, and the coefficient step itself is the gradient
/// preconditioned by the coefficient system — the nonlinear preconditioning of conjugate
/// gradients by alternating least squares of De Sterck (2012, "A nonlinearly preconditioned
/// conjugate gradient algorithm for rank-R canonical tensor approximation"). The line search
/// starts from the step that is optimal with the basis fixed (which lowers `g`, since
/// `g ≤ E(·, B)`), stretched by the previous iteration's ratio, and tries the vertex of the
/// parabola through `g(0)`, `g'(0)` and that trial when it lies elsewhere.
pub(super) struct Conjugate<'q, 'a> {
    pub(super) quadrature: &'q Systems<'a>,
    pub(super) field: &'q GridField,
    pub(super) rank: usize,
    pub(super) options: &'q PolishOptions,
    pub(super) energy: f64,
    pub(super) start: Instant,
    pub(super) progress: &'q dyn Progress,
}

impl Conjugate<'_, '_> {
    pub(super) fn exact(&self, quadratic: f64, c: &[f64]) -> ExactLoss {
        exact_from(quadratic, c, self.options.lambda, self.energy)
    }

    /// `g(c)` and the basis attaining it.
    pub(super) fn reduced(
        &self,
        c: &[f64],
        scratch: &mut Vec<f64>,
    ) -> Result<(ExactLoss, Array2<f64>), MbdError> {
        let system =
            self.quadrature
                .basis_system(self.field, c, self.rank, scratch, self.progress)?;
        let b = system.solve()?;
        let loss = self.exact(system.quadratic(&b) + ridge(c, self.options.lambda), c);
        Ok((loss, b))
    }

    pub(super) fn record(
        &self,
        report: &mut PolishReport,
        step: PolishStep,
        loss: ExactLoss,
        accepted: bool,
        cg_iterations: usize,
    ) {
        report.history.push(PolishRecord {
            step,
            loss,
            accepted,
            cg_iterations,
            elapsed: self.start.elapsed().as_secs_f64(),
        });
    }

    pub(super) fn run(
        &self,
        c: &mut Vec<f64>,
        b: &mut Array2<f64>,
        loss: &mut ExactLoss,
        basis_system: BasisSystem,
        mut blocks: Vec<f64>,
        report: &mut PolishReport,
    ) -> Result<(), MbdError> {
        let options = self.options;
        let lambda = options.lambda;
        // The gradient needs the basis that solves the basis system.
        let after = basis_system.step(b)?;
        drop(basis_system);
        if let Some(after) = after {
            *loss = self.exact(after + ridge(c, lambda), c);
        }
        self.record(report, PolishStep::Basis, *loss, after.is_some(), 0);
        // (gradient, preconditioned gradient, direction) of the previous iteration.
        let mut previous: Option<(Vec<f64>, Vec<f64>, Vec<f64>)> = None;
        // The last accepted step in multiples of the step optimal with the basis fixed.
        let mut previous_stretch = 1.0;
        // The loss at the start of every iteration, for the stopping rule.
        let mut window: Vec<ExactLoss> = Vec::new();
        for _ in 0..options.iterations {
            self.progress.check()?;
            let sweep_start = *loss;
            let system = self.quadrature.coefficient_system(
                self.field,
                b.as_slice().unwrap_or(&[]),
                self.rank,
                lambda,
                std::mem::take(&mut blocks),
                self.progress,
            )?;
            // Half the gradient of g: `A c − r` at the optimal basis (envelope theorem); the
            // alternating step is `−A⁻¹` of it, the preconditioned gradient.
            let residual = system.residual(c);
            let gradient: Vec<f64> = residual.iter().map(|&r| -r).collect();
            let (alternating, cg_iterations) = system.solve(c, residual, options, self.progress)?;
            let preconditioned: Vec<f64> =
                c.iter().zip(&alternating).map(|(&x, &y)| x - y).collect();
            let mut direction: Vec<f64> = preconditioned.iter().map(|&x| -x).collect();
            if let Some((g0, p0, d0)) = &previous {
                // Polak–Ribière with restarts (β ≥ 0, descent kept).
                let beta = (dot(&gradient, &preconditioned) - dot(&gradient, p0)) / dot(g0, p0);
                if beta > 0.0 && beta.is_finite() {
                    let mixed: Vec<f64> = direction
                        .iter()
                        .zip(d0)
                        .map(|(&d, &e)| d + beta * e)
                        .collect();
                    if dot(&gradient, &mixed) < 0.0 {
                        direction = mixed;
                    }
                }
            }
            let slope = dot(&gradient, &direction);
            let mut ad = vec![0.0; c.len()];
            system.apply(&direction, &mut ad);
            let curvature = dot(&direction, &ad);
            blocks = system.into_blocks();
            if !(slope < 0.0 && curvature > 0.0) {
                self.record(
                    report,
                    PolishStep::Coefficients,
                    *loss,
                    false,
                    cg_iterations,
                );
                report.converged = true;
                break;
            }
            // The step optimal with the basis fixed lowers g (g ≤ E(·, B)), but g is flatter
            // along the coupled valley (on Sponza the best step is 8–10 times longer): try the
            // previous iteration's multiple of it, then the minimum of the parabola through
            // g(0), g'(0) and that trial when it lies elsewhere; if neither lowers g, the step
            // with the basis fixed.
            let point = |alpha: f64| -> Vec<f64> {
                c.iter()
                    .zip(&direction)
                    .map(|(&x, &d)| round_f32(x + alpha * d))
                    .collect()
            };
            let fixed = -slope / curvature;
            let start_loss = *loss;
            let phi0 = start_loss.loss();
            let mut best: Option<(f64, Vec<f64>, Array2<f64>, ExactLoss)> = None;
            let try_step = |stretch: f64,
                            best: &mut Option<(f64, Vec<f64>, Array2<f64>, ExactLoss)>,
                            report: &mut PolishReport,
                            blocks: &mut Vec<f64>|
             -> Result<f64, MbdError> {
                let trial = point(fixed * stretch);
                let (trial_loss, trial_b) = self.reduced(&trial, blocks)?;
                let better = trial_loss.loss() < best.as_ref().map_or(phi0, |x| x.3.loss());
                if better {
                    *best = Some((stretch, trial, trial_b, trial_loss));
                }
                let kept = best.as_ref().map_or(start_loss, |x| x.3);
                self.record(report, PolishStep::LineSearch, kept, better, 0);
                Ok(trial_loss.loss())
            };
            let first = previous_stretch;
            let phi1 = try_step(first, &mut best, report, &mut blocks)?;
            // g(s) ≈ φ0 + 2 slope·fixed·s + κ s²; κ from the trial.
            let kappa = (phi1 - phi0 - 2.0 * slope * fixed * first) / (first * first);
            let vertex = if kappa > 0.0 {
                (-slope * fixed / kappa).min(MAX_STRETCH)
            } else {
                MAX_STRETCH
            };
            if !(0.7 * first..=1.4 * first).contains(&vertex) {
                try_step(vertex, &mut best, report, &mut blocks)?;
            }
            if best.is_none() && first != 1.0 && vertex != 1.0 {
                try_step(1.0, &mut best, report, &mut blocks)?;
            }
            let moved = best.is_some();
            if let Some((stretch, c_new, b_new, loss_new)) = best {
                (*c, *b, *loss) = (c_new, b_new, loss_new);
                previous = Some((gradient, preconditioned, direction));
                previous_stretch = stretch.max(1.0);
            } else {
                previous = None;
                previous_stretch = 1.0;
            }
            self.record(
                report,
                PolishStep::Coefficients,
                *loss,
                moved,
                cg_iterations,
            );
            self.progress.inc(1);
            self.progress
                .message(&format!("polish relative MSE {:.4e}", loss.relative_mse()));
            // The progress of one iteration varies with its line search (on Sponza 72 one
            // iteration in 24 gained 0.05 % between iterations gaining 0.25 %), so the rule
            // looks at the mean of the last few.
            window.push(sweep_start);
            let oldest = window[window.len().saturating_sub(STOP_WINDOW)];
            let mean_decrease = (oldest.loss() - loss.loss()) / STOP_WINDOW as f64;
            if !moved
                || (options.tolerance > 0.0
                    && window.len() >= STOP_WINDOW
                    && mean_decrease <= options.tolerance * oldest.data)
            {
                report.converged = true;
                break;
            }
        }
        Ok(())
    }
}
