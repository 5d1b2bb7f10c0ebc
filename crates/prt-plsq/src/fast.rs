//! The progressive encoder specialised for spherical Gaussians: lobes in structure-of-arrays
//! form, a vectorisable `exp`, and the Gauss-Seidel residual sweep written as a prefix
//! product so that every per-lobe loop vectorises.
//!
//! For the residual update, Gauss-Seidel multiplies the residual by `(1 − step_j B_j)` after
//! lobe `j`, so lobe `k` sees `Δ_0 Π_{j<k} (1 − step_j B_j)`: the only serial work per sample
//! is that 12-term prefix product, independent of the channel count.
use glam::Vec3;
use prt_core::{Progress, SphericalBasis};
use prt_sphere::SgBasis;

use crate::PlsqError;
use crate::encoder::{
    Denominator, EncoderConfig, Precision, SampleOutcome, Sweep, Update, true_square_means,
};

/// `e^x` for `x <= 0` in f32, to about 3e-7 relative (inputs below −87 give about 1e-38):
/// `2^n e^r` with `n = round(x log₂e)` by the magic-number trick, `r = x − n ln 2` in two parts
/// (Cody-Waite, so `r` is accurate for large `|x|`) and a degree-6 polynomial for `e^r`,
/// `|r| <= ln 2 / 2`. Branch-free, so loops over lobes vectorise.
#[inline(always)]
pub fn exp_nonpositive(x: f32) -> f32 {
    const MAGIC: f32 = 12_582_912.0; // 1.5 · 2^23
    const LN2_HI: f32 = 0.693_359_4; // ln 2 rounded to 11 bits: n · LN2_HI is exact
    const LN2_LO: f32 = -2.121_944_4e-4;
    let x = x.max(-87.0);
    let m = x * std::f32::consts::LOG2_E + MAGIC;
    let n = m - MAGIC;
    let r = (x - n * LN2_HI) - n * LN2_LO;
    let ni = (m.to_bits() as i32).wrapping_sub(MAGIC.to_bits() as i32);
    let scale = f32::from_bits(((ni + 127) as u32) << 23);
    // e^r, Taylor to degree 6 (error < 1.2e-7 for |r| <= ln 2 / 2).
    let p = 1.0
        + r * (1.0
            + r * (0.5
                + r * (1.0 / 6.0 + r * (1.0 / 24.0 + r * (1.0 / 120.0 + r * (1.0 / 720.0))))));
    scale * p
}

/// A progressive least-squares encoder for a set of spherical Gaussians and `C` channels, the
/// same arithmetic as [`crate::ProgressiveEncoder`] (to `exp` rounding) at several times the
/// speed. f32 state only.
#[derive(Debug, Clone)]
pub struct SgEncoder<const C: usize> {
    px: Vec<f32>,
    py: Vec<f32>,
    pz: Vec<f32>,
    lambda: Vec<f32>,
    true_means: Vec<f32>,
    config: EncoderConfig,
    coeffs: [Vec<f32>; C],
    integrals: Vec<f32>,
    total_weight: f32,
    b: Vec<f32>,
    step: Vec<f32>,
    denom: Vec<f32>,
    scale: Vec<f32>,
}

impl<const C: usize> SgEncoder<C> {
    /// An encoder for the lobes of `basis`. Errors: `C == 0`, an invalid configuration, 16-bit
    /// precision (use [`crate::ProgressiveEncoder`] for that experiment).
    pub fn new(basis: &SgBasis, config: EncoderConfig) -> Result<Self, PlsqError> {
        crate::ProgressiveEncoder::new(basis, C, config)?;
        if config.precision != Precision::F32 {
            return Err(PlsqError::invalid("precision", "SgEncoder stores f32 only"));
        }
        let k = basis.len();
        let axes = basis.axes();
        Ok(Self {
            px: axes.iter().map(|a| a.x).collect(),
            py: axes.iter().map(|a| a.y).collect(),
            pz: axes.iter().map(|a| a.z).collect(),
            lambda: basis.sharpness().to_vec(),
            true_means: true_square_means(basis)?,
            config,
            coeffs: std::array::from_fn(|_| vec![0.0; k]),
            integrals: vec![0.0; k],
            total_weight: 0.0,
            b: vec![0.0; k],
            step: vec![0.0; k],
            denom: vec![1.0; k],
            scale: vec![0.0; k],
        })
    }

    /// Coefficients as `len` rows of `C` interleaved values (the layout of
    /// [`crate::ProgressiveEncoder::coefficients`]).
    pub fn coefficients(&self) -> Vec<f32> {
        let k = self.lambda.len();
        (0..k * C).map(|i| self.coeffs[i % C][i / C]).collect()
    }

    /// Total sample weight so far.
    pub fn total_weight(&self) -> f32 {
        self.total_weight
    }

    /// Adds one sample (see [`crate::ProgressiveEncoder::add_sample`]; same errors).
    pub fn add_sample(
        &mut self,
        dir: Vec3,
        value: [f32; C],
        weight: f32,
    ) -> Result<SampleOutcome, PlsqError> {
        PlsqError::check_finite("sample value", &value)?;
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
        self.apply(dir, value, weight);
        if self.config.hemisphere {
            self.apply(-dir, [0.0; C], weight);
        }
        Ok(SampleOutcome::Applied)
    }

    /// Adds a stream of samples (`C` values each, optional weights), checking `progress` every
    /// 4096 samples. Input is validated chunk by chunk before it is applied.
    pub fn add_samples(
        &mut self,
        dirs: &[Vec3],
        values: &[f32],
        weights: Option<&[f32]>,
        progress: &dyn Progress,
    ) -> Result<(), PlsqError> {
        if values.len() != dirs.len() * C {
            return Err(PlsqError::LengthMismatch {
                what: "sample values",
                expected: dirs.len() * C,
                got: values.len(),
            });
        }
        if let Some(w) = weights
            && w.len() != dirs.len()
        {
            return Err(PlsqError::LengthMismatch {
                what: "sample weights",
                expected: dirs.len(),
                got: w.len(),
            });
        }
        progress.set_len(dirs.len() as u64);
        for start in (0..dirs.len()).step_by(4096) {
            if progress.is_cancelled() {
                return Err(PlsqError::Cancelled);
            }
            let end = (start + 4096).min(dirs.len());
            PlsqError::check_finite("sample value", &values[start * C..end * C])
                .map_err(|e| offset(e, start * C))?;
            if let Some(i) = dirs[start..end].iter().position(|d| !d.is_finite()) {
                return Err(PlsqError::NonFinite {
                    what: "sample direction",
                    index: start + i,
                });
            }
            if let Some(w) = weights {
                PlsqError::check_finite("sample weight", &w[start..end])
                    .map_err(|e| offset(e, start))?;
                if let Some(i) = w[start..end].iter().position(|&x| x < 0.0) {
                    return Err(PlsqError::invalid(
                        "sample weight",
                        format!("weight {} is negative", start + i),
                    ));
                }
            }
            for s in start..end {
                let w = weights.map_or(1.0, |w| w[s]);
                if w == 0.0 {
                    continue;
                }
                let v: [f32; C] = std::array::from_fn(|c| values[s * C + c]);
                self.apply(dirs[s], v, w);
                if self.config.hemisphere {
                    self.apply(-dirs[s], [0.0; C], w);
                }
            }
            progress.inc((end - start) as u64);
        }
        Ok(())
    }

    fn apply(&mut self, dir: Vec3, value: [f32; C], weight: f32) {
        // Common lobe counts get a copy of the body with a constant trip count (fully unrolled,
        // no remainder loops); `apply_with` is inlined into each arm.
        match self.lambda.len() {
            4 => self.apply_with(4, dir, value, weight),
            6 => self.apply_with(6, dir, value, weight),
            8 => self.apply_with(8, dir, value, weight),
            9 => self.apply_with(9, dir, value, weight),
            12 => self.apply_with(12, dir, value, weight),
            16 => self.apply_with(16, dir, value, weight),
            k => self.apply_with(k, dir, value, weight),
        }
    }

    #[inline(always)]
    fn apply_with(&mut self, k: usize, dir: Vec3, value: [f32; C], weight: f32) {
        let cfg = self.config;
        self.total_weight += weight;
        let share = weight / self.total_weight;
        let (b, step, scale) = (&mut self.b[..k], &mut self.step[..k], &mut self.scale[..k]);
        let denoms = &mut self.denom[..k];
        let (px, py, pz, lambda) = (
            &self.px[..k],
            &self.py[..k],
            &self.pz[..k],
            &self.lambda[..k],
        );
        for i in 0..k {
            let d = px[i] * dir.x + py[i] * dir.y + pz[i] * dir.z;
            b[i] = exp_nonpositive(lambda[i] * (d - 1.0));
        }
        let mut delta = value;
        for c in 0..C {
            let co = &self.coeffs[c][..k];
            let mut s = 0.0;
            for i in 0..k {
                s += b[i] * co[i];
            }
            delta[c] -= s;
        }
        let (integrals, true_means) = (&mut self.integrals[..k], &self.true_means[..k]);
        let share_of = |b: f32| if b != 0.0 { share } else { 0.0 };
        for i in 0..k {
            // A lobe that evaluates to exactly 0 is skipped, as in the generic encoder.
            integrals[i] += (b[i] * b[i] - integrals[i]) * share_of(b[i]);
        }
        match cfg.denominator {
            Denominator::Clamped { floor } => {
                for i in 0..k {
                    denoms[i] = integrals[i].max(floor * true_means[i]);
                }
            }
            Denominator::LerpFromOne => {
                for i in 0..k {
                    denoms[i] = share + (1.0 - share) * integrals[i];
                }
            }
            Denominator::Exact => denoms.copy_from_slice(true_means),
        }
        for i in 0..k {
            step[i] = share_of(b[i]) * b[i] / denoms[i];
        }
        match cfg.update {
            Update::Residual { acceleration } => {
                // scale[i] = α Π_{j<i} (1 − step_j B_j) for Gauss-Seidel, α for Jacobi.
                let mut prefix = acceleration;
                for i in 0..k {
                    scale[i] = prefix;
                    if cfg.sweep == Sweep::GaussSeidel {
                        prefix *= 1.0 - step[i] * b[i];
                    }
                }
                for c in 0..C {
                    let co = &mut self.coeffs[c][..k];
                    for i in 0..k {
                        let new = co[i] + scale[i] * step[i] * delta[c];
                        co[i] = if cfg.non_negative { new.max(0.0) } else { new };
                    }
                }
            }
            Update::RunningAverage => {
                // Serial in the lobes for Gauss-Seidel (the residual depends on the clamped
                // new coefficient); Jacobi reads the residual before the sample.
                for i in 0..k {
                    if b[i] == 0.0 {
                        continue;
                    }
                    let denom = denoms[i];
                    for c in 0..C {
                        let old = self.coeffs[c][i];
                        let mut new = old + (b[i] * (delta[c] + old * b[i]) / denom - old) * share;
                        if cfg.non_negative {
                            new = new.max(0.0);
                        }
                        self.coeffs[c][i] = new;
                        if cfg.sweep == Sweep::GaussSeidel {
                            delta[c] -= (new - old) * b[i];
                        }
                    }
                }
            }
        }
    }
}

fn offset(e: PlsqError, by: usize) -> PlsqError {
    match e {
        PlsqError::NonFinite { what, index } => PlsqError::NonFinite {
            what,
            index: index + by,
        },
        other => other,
    }
}
