//! The progressive least-squares encoder (Roughton, "Progressive Least-Squares Encoding for
//! Linear Bases", JCGT 9(1), 2020).
use glam::Vec3;
use prt_core::{Progress, SphericalBasis};

use crate::PlsqError;

/// How each sample moves the coefficients.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Update {
    /// The paper's residual step: `b_i += α w B_i Δ / (W I_i)` with `Δ = f(s) − Σ_j b_j B_j(s)`.
    /// `acceleration` is α (1 = plain progressive least squares; the paper uses up to 5).
    Residual {
        /// The step multiplier α (> 0).
        acceleration: f32,
    },
    /// The "running average" of Roughton's 2018 blog post and Probulator: `b_i` is the
    /// weighted running mean of the per-sample estimates `B_i (f − Σ_{k≠i} b_k B_k) / I_i`, i.e.
    /// `b_i += (w/W) (B_i (Δ + b_i B_i) / I_i − b_i)`.
    RunningAverage,
}

/// The denominator `I_i`, the per-basis estimate of `∫ B_i² / 4π`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Denominator {
    /// The Monte Carlo estimate (updated in lockstep with the coefficients) clamped from below
    /// to `floor` times the true integral (Probulator's "running average" uses 0.75; the blog
    /// recommends 1).
    Clamped {
        /// Fraction of the true integral used as the lower bound.
        floor: f32,
    },
    /// The Monte Carlo estimate blended from 1: `I = s + (1 − s) Î` with `s = w / W` the
    /// sample's share (so the first sample divides by 1, and `I → Î` as samples accumulate),
    /// which damps the first steps when `Î` rests on a handful of samples. This is the form of
    /// Roughton's reference code (troughton/Probulator, `ExperimentSGRunningAverage`).
    LerpFromOne,
    /// The true integral only (no per-basis state needed; slightly higher error).
    Exact,
}

/// In which order the basis functions see the residual of a sample.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Sweep {
    /// Every basis function sees the residual of the coefficients before the sample.
    Jacobi,
    /// Each basis function sees the residual after the updates of the previous ones. For the
    /// residual update `Δ *= 1 − (w/W) B_i² / I_i` (the unaccelerated, unclamped step, as in
    /// Roughton's reference code); for the running average `Δ −= (b_i' − b_i) B_i`.
    GaussSeidel,
}

/// Storage precision of the encoder state.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Precision {
    /// f32 state (the paper: 32 bits suffice).
    F32,
    /// Coefficients, integrals and total weight rounded to IEEE half after every sample, to
    /// show the paper's claim that 16-bit state biases the result (the total weight stops
    /// growing at 2048 samples, so late samples get too large a share). Not for production.
    F16,
}

/// Configuration of a [`ProgressiveEncoder`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EncoderConfig {
    /// The update rule.
    pub update: Update,
    /// The denominator.
    pub denominator: Denominator,
    /// Jacobi or Gauss-Seidel.
    pub sweep: Sweep,
    /// Clamp every coefficient to `>= 0` after its update (a projected, non-negative solve).
    pub non_negative: bool,
    /// Hemisphere mode: every sample is followed by a zero-valued sample of the same weight in
    /// the opposite direction, so that a hemispherical signal is fitted as a function that
    /// vanishes below the horizon.
    pub hemisphere: bool,
    /// State precision.
    pub precision: Precision,
}

impl EncoderConfig {
    /// The paper's recommendation: residual update, α = 1, lerped denominator, Gauss-Seidel.
    pub fn paper() -> Self {
        Self {
            update: Update::Residual { acceleration: 1.0 },
            denominator: Denominator::LerpFromOne,
            sweep: Sweep::GaussSeidel,
            non_negative: false,
            hemisphere: false,
            precision: Precision::F32,
        }
    }

    /// Probulator's `ExperimentSGRunningAverage`: running average, MC integral clamped to 0.75
    /// of the true one, Jacobi.
    pub fn probulator_running_average() -> Self {
        Self {
            update: Update::RunningAverage,
            denominator: Denominator::Clamped { floor: 0.75 },
            sweep: Sweep::Jacobi,
            non_negative: false,
            hemisphere: false,
            precision: Precision::F32,
        }
    }

    fn validate(&self) -> Result<(), PlsqError> {
        if let Update::Residual { acceleration } = self.update
            && !(acceleration.is_finite() && acceleration > 0.0)
        {
            return Err(PlsqError::invalid(
                "acceleration",
                format!("{acceleration} must be finite and > 0"),
            ));
        }
        if let Denominator::Clamped { floor } = self.denominator
            && !(floor.is_finite() && floor >= 0.0)
        {
            return Err(PlsqError::invalid(
                "denominator floor",
                format!("{floor} must be finite and >= 0"),
            ));
        }
        Ok(())
    }
}

impl Default for EncoderConfig {
    fn default() -> Self {
        Self::paper()
    }
}

/// What [`ProgressiveEncoder::add_sample`] did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SampleOutcome {
    /// The sample updated the state.
    Applied,
    /// The sample had zero weight; the state is untouched.
    ZeroWeight,
}

/// `∫ B_i² / 4π` for every basis function, from the diagonal of the Gram matrix. A zero entry
/// (a basis function that vanishes everywhere) makes the basis singular: a typed error.
pub fn true_square_means<B: SphericalBasis + ?Sized>(basis: &B) -> Result<Vec<f32>, PlsqError> {
    if basis.is_empty() {
        return Err(PlsqError::invalid("basis", "has no functions"));
    }
    let g = basis.gram();
    let inv_4pi = 1.0 / (4.0 * std::f64::consts::PI);
    (0..basis.len())
        .map(|i| {
            let v = g[[i, i]] * inv_4pi;
            if v.is_finite() && v > 0.0 {
                Ok(v as f32)
            } else {
                Err(PlsqError::Singular {
                    what: "Gram matrix",
                    why: format!("diagonal entry {i} is {v}"),
                })
            }
        })
        .collect()
}

/// A progressive least-squares encoder: per sample, `O(len × channels)` work and no stored
/// samples. State is exactly the paper's: coefficients, per-basis integral estimates and the
/// total weight.
#[derive(Debug, Clone)]
pub struct ProgressiveEncoder<'b, B: SphericalBasis + ?Sized> {
    basis: &'b B,
    channels: usize,
    config: EncoderConfig,
    coeffs: Vec<f32>,
    integrals: Vec<f32>,
    total_weight: f32,
    true_means: Vec<f32>,
    eval: Vec<f32>,
    delta: Vec<f32>,
}

impl<'b, B: SphericalBasis + ?Sized> ProgressiveEncoder<'b, B> {
    /// An encoder of `channels` channels into `basis`, coefficients starting at zero.
    pub fn new(basis: &'b B, channels: usize, config: EncoderConfig) -> Result<Self, PlsqError> {
        config.validate()?;
        if channels == 0 {
            return Err(PlsqError::invalid("channel count", "must be at least 1"));
        }
        let true_means = true_square_means(basis)?;
        let k = basis.len();
        Ok(Self {
            basis,
            channels,
            config,
            coeffs: vec![0.0; k * channels],
            integrals: vec![0.0; k],
            total_weight: 0.0,
            true_means,
            eval: vec![0.0; k],
            delta: vec![0.0; channels],
        })
    }

    /// Coefficients, `len` rows of `channels` interleaved values.
    pub fn coefficients(&self) -> &[f32] {
        &self.coeffs
    }

    /// The per-basis Monte Carlo estimates of `∫ B_i² / 4π`.
    pub fn integral_estimates(&self) -> &[f32] {
        &self.integrals
    }

    /// Total sample weight so far (hemisphere-mode mirror samples included).
    pub fn total_weight(&self) -> f32 {
        self.total_weight
    }

    /// The configuration.
    pub fn config(&self) -> &EncoderConfig {
        &self.config
    }

    /// Adds one sample `value` (`channels` values) in unit direction `dir` with weight `weight`
    /// (West's weighted extension: `W += w`, steps scale by `w / W`).
    ///
    /// Errors (state untouched): non-finite value, direction or weight, negative weight, wrong
    /// value length. A zero weight returns [`SampleOutcome::ZeroWeight`].
    pub fn add_sample(
        &mut self,
        dir: Vec3,
        value: &[f32],
        weight: f32,
    ) -> Result<SampleOutcome, PlsqError> {
        if value.len() != self.channels {
            return Err(PlsqError::LengthMismatch {
                what: "sample value",
                expected: self.channels,
                got: value.len(),
            });
        }
        PlsqError::check_finite("sample value", value)?;
        PlsqError::check_finite("sample direction", &dir.to_array())?;
        if !weight.is_finite() {
            return Err(PlsqError::NonFinite {
                what: "sample weight",
                index: 0,
            });
        }
        if weight < 0.0 {
            return Err(PlsqError::invalid("sample weight", format!("{weight} < 0")));
        }
        if weight == 0.0 {
            return Ok(SampleOutcome::ZeroWeight);
        }
        self.apply(dir, Some(value), weight);
        if self.config.hemisphere {
            self.apply(-dir, None, weight);
        }
        Ok(SampleOutcome::Applied)
    }

    /// Adds a stream of samples (`dirs.len()` directions, `channels` values each, optional
    /// weights, 1 when `None`), checking `progress` for cancellation every 4096 samples.
    pub fn add_samples(
        &mut self,
        dirs: &[Vec3],
        values: &[f32],
        weights: Option<&[f32]>,
        progress: &dyn Progress,
    ) -> Result<(), PlsqError> {
        PlsqError::check_sample_lengths(dirs.len(), values, self.channels, weights)?;
        progress.set_len(dirs.len() as u64);
        for (chunk_start, chunk) in dirs.chunks(4096).enumerate().map(|(c, d)| (c * 4096, d)) {
            if progress.is_cancelled() {
                return Err(PlsqError::Cancelled);
            }
            for (k, d) in chunk.iter().enumerate() {
                let s = chunk_start + k;
                let w = weights.map_or(1.0, |w| w[s]);
                self.add_sample(*d, &values[s * self.channels..(s + 1) * self.channels], w)
                    .map_err(|e| match e {
                        PlsqError::NonFinite { what, index } => PlsqError::NonFinite {
                            what,
                            index: if what == "sample value" {
                                s * self.channels + index
                            } else {
                                s
                            },
                        },
                        other => other,
                    })?;
            }
            progress.inc(chunk.len() as u64);
        }
        Ok(())
    }

    /// Evaluates the current fit at `dir` into `out[..channels]`.
    pub fn eval(&mut self, dir: Vec3, out: &mut [f32]) {
        self.basis.eval(dir, &mut self.eval);
        let out = &mut out[..self.channels];
        out.fill(0.0);
        for (i, b) in self.eval.iter().enumerate() {
            for c in 0..self.channels {
                out[c] += b * self.coeffs[i * self.channels + c];
            }
        }
    }

    pub(crate) fn apply(&mut self, dir: Vec3, value: Option<&[f32]>, weight: f32) {
        let ch = self.channels;
        let cfg = self.config;
        let half = cfg.precision == Precision::F16;
        self.total_weight = round(self.total_weight + weight, half);
        let share = weight / self.total_weight;
        self.basis.eval(dir, &mut self.eval);
        for c in 0..ch {
            self.delta[c] = value.map_or(0.0, |v| v[c]);
        }
        for (i, b) in self.eval.iter().enumerate() {
            for c in 0..ch {
                self.delta[c] -= b * self.coeffs[i * ch + c];
            }
        }
        for i in 0..self.eval.len() {
            let b = self.eval[i];
            if b == 0.0 {
                continue;
            }
            let est = round(
                self.integrals[i] + (b * b - self.integrals[i]) * share,
                half,
            );
            self.integrals[i] = est;
            let denom = match cfg.denominator {
                Denominator::Clamped { floor } => est.max(floor * self.true_means[i]),
                Denominator::LerpFromOne => share + (1.0 - share) * est,
                Denominator::Exact => self.true_means[i],
            };
            let step = share * b / denom;
            for c in 0..ch {
                let old = self.coeffs[i * ch + c];
                let mut new = match cfg.update {
                    Update::Residual { acceleration } => old + acceleration * step * self.delta[c],
                    Update::RunningAverage => {
                        old + (b * (self.delta[c] + old * b) / denom - old) * share
                    }
                };
                if cfg.non_negative {
                    new = new.max(0.0);
                }
                let new = round(new, half);
                self.coeffs[i * ch + c] = new;
                if cfg.sweep == Sweep::GaussSeidel {
                    match cfg.update {
                        Update::Residual { .. } => self.delta[c] *= 1.0 - step * b,
                        Update::RunningAverage => self.delta[c] -= (new - old) * b,
                    }
                }
            }
        }
    }
}

#[inline]
fn round(x: f32, half: bool) -> f32 {
    if half {
        half::f16::from_f32(x).to_f32()
    } else {
        x
    }
}
