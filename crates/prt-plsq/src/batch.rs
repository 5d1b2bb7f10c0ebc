//! Many independent progressive encoders (one per lightmap texel or probe) in a
//! structure-of-arrays layout, updated in parallel.
//!
//! Encoders are grouped in blocks of [`LANES`]; inside a block every array is
//! `[basis function][channel][lane]`, so the update of one sample per encoder is a sequence of
//! lane-wide vector operations, the layout a GPU compute shader would use with one thread per
//! encoder. Blocks are independent, so results do not depend on the thread count.
use glam::Vec3;
use prt_core::SphericalBasis;
use rayon::prelude::*;

use prt_sphere::SgBasis;

use crate::PlsqError;
use crate::encoder::{Denominator, EncoderConfig, Precision, Sweep, Update, true_square_means};
use crate::fast::exp_nonpositive;

/// Spherical Gaussian lobes in structure-of-arrays form, for lane-wide evaluation.
#[derive(Debug, Clone)]
struct SgLanes {
    px: Vec<f32>,
    py: Vec<f32>,
    pz: Vec<f32>,
    lambda: Vec<f32>,
}

/// Encoders per block (the SIMD/GPU lane width of the layout).
pub const LANES: usize = 16;

/// A batch of independent progressive encoders sharing one basis and configuration.
#[derive(Debug, Clone)]
pub struct BatchEncoder<'b, B: SphericalBasis + ?Sized> {
    basis: &'b B,
    channels: usize,
    config: EncoderConfig,
    count: usize,
    true_means: Vec<f32>,
    coeffs: Vec<f32>,
    integrals: Vec<f32>,
    weights: Vec<f32>,
    sg: Option<SgLanes>,
}

impl<'b> BatchEncoder<'b, SgBasis> {
    /// `count` encoders into a set of spherical Gaussians, with the basis evaluated lane-wide
    /// by a vectorised `exp` (the fast path; the same results as [`BatchEncoder::new`] to `exp`
    /// rounding).
    pub fn new_sg(
        basis: &'b SgBasis,
        channels: usize,
        count: usize,
        config: EncoderConfig,
    ) -> Result<Self, PlsqError> {
        let mut enc = Self::new(basis, channels, count, config)?;
        let axes = basis.axes();
        enc.sg = Some(SgLanes {
            px: axes.iter().map(|a| a.x).collect(),
            py: axes.iter().map(|a| a.y).collect(),
            pz: axes.iter().map(|a| a.z).collect(),
            lambda: basis.sharpness().to_vec(),
        });
        Ok(enc)
    }
}

impl<'b, B: SphericalBasis + ?Sized> BatchEncoder<'b, B> {
    /// `count` encoders of `channels` channels into `basis`.
    pub fn new(
        basis: &'b B,
        channels: usize,
        count: usize,
        config: EncoderConfig,
    ) -> Result<Self, PlsqError> {
        // Validate through the single encoder (same rules).
        crate::ProgressiveEncoder::new(basis, channels, config)?;
        if config.precision != Precision::F32 {
            return Err(PlsqError::invalid(
                "precision",
                "the batch encoder stores f32 only",
            ));
        }
        let k = basis.len();
        let blocks = count.div_ceil(LANES);
        Ok(Self {
            basis,
            channels,
            config,
            count,
            true_means: true_square_means(basis)?,
            coeffs: vec![0.0; blocks * k * channels * LANES],
            integrals: vec![0.0; blocks * k * LANES],
            weights: vec![0.0; blocks * LANES],
            sg: None,
        })
    }

    /// Number of encoders.
    pub fn len(&self) -> usize {
        self.count
    }

    /// Whether the batch holds no encoder.
    pub fn is_empty(&self) -> bool {
        self.count == 0
    }

    /// The coefficients of encoder `e` (`len` rows of `channels`), or `None` out of range.
    pub fn coefficients(&self, e: usize) -> Option<Vec<f32>> {
        if e >= self.count {
            return None;
        }
        let (k, ch) = (self.basis.len(), self.channels);
        let (block, lane) = (e / LANES, e % LANES);
        let base = block * k * ch * LANES;
        Some(
            (0..k * ch)
                .map(|ic| self.coeffs[base + ic * LANES + lane])
                .collect(),
        )
    }

    /// Total weight of encoder `e`.
    pub fn total_weight(&self, e: usize) -> Option<f32> {
        (e < self.count).then(|| self.weights[e])
    }

    /// Adds one sample to every encoder: `dirs[e]`, `values[e·channels..]`, weight `weights[e]`
    /// (1 when `None`; a zero weight leaves that encoder untouched). All input is validated
    /// before any state changes. The same as [`Self::add_sample_runs`] with one sample per
    /// encoder.
    pub fn add_samples(
        &mut self,
        dirs: &[Vec3],
        values: &[f32],
        weights: Option<&[f32]>,
    ) -> Result<(), PlsqError> {
        self.add_sample_runs(1, dirs, values, weights)
    }

    /// Adds a run of `per_encoder` samples to every encoder (a pass of `per_encoder` samples per
    /// lightmap texel or probe), encoder-major: sample `k` of encoder `e` is `dirs[e·per_encoder
    /// + k]`, its values `values[(e·per_encoder + k)·channels..]`, its weight
    /// `weights[e·per_encoder + k]` (1 when `None`; 0 skips that sample). Each encoder takes its
    /// samples in order `k = 0, 1, ..`, so the result is bit-identical to `per_encoder` calls
    /// of [`Self::add_samples`], one per `k`; but the work is split over blocks of [`LANES`]
    /// encoders and a block applies all its samples while its state is in cache, which is what
    /// lets a second core help (one-sample rounds over a large batch are memory-bound). Blocks
    /// are fixed, so the result does not depend on the thread count. All input is validated
    /// before any state changes; `per_encoder == 0` is a no-op.
    pub fn add_sample_runs(
        &mut self,
        per_encoder: usize,
        dirs: &[Vec3],
        values: &[f32],
        weights: Option<&[f32]>,
    ) -> Result<(), PlsqError> {
        let (n, ch, k) = (self.count, self.channels, self.basis.len());
        let samples = n.checked_mul(per_encoder).ok_or_else(|| {
            PlsqError::invalid(
                "samples per encoder",
                format!("{n} × {per_encoder} overflows"),
            )
        })?;
        if dirs.len() != samples {
            return Err(PlsqError::LengthMismatch {
                what: "sample directions",
                expected: samples,
                got: dirs.len(),
            });
        }
        if values.len() != samples * ch {
            return Err(PlsqError::LengthMismatch {
                what: "sample values",
                expected: samples * ch,
                got: values.len(),
            });
        }
        PlsqError::check_finite("sample value", values)?;
        for (i, d) in dirs.iter().enumerate() {
            if !d.is_finite() {
                return Err(PlsqError::NonFinite {
                    what: "sample direction",
                    index: i,
                });
            }
        }
        if let Some(w) = weights {
            if w.len() != samples {
                return Err(PlsqError::LengthMismatch {
                    what: "sample weights",
                    expected: samples,
                    got: w.len(),
                });
            }
            PlsqError::check_finite("sample weight", w)?;
            if let Some(i) = w.iter().position(|&x| x < 0.0) {
                return Err(PlsqError::invalid(
                    "sample weight",
                    format!("weight {i} is negative"),
                ));
            }
        }
        if per_encoder == 0 {
            return Ok(());
        }
        let basis = self.basis;
        let cfg = self.config;
        let true_means = &self.true_means;
        let sg = self.sg.as_ref();
        self.coeffs
            .par_chunks_mut(k * ch * LANES)
            .zip(self.integrals.par_chunks_mut(k * LANES))
            .zip(self.weights.par_chunks_mut(LANES))
            .enumerate()
            .for_each_init(
                || Scratch::new(k, ch),
                |scratch, (block, ((coeffs, integrals), wsum))| {
                    let first = block * LANES;
                    let lanes = LANES.min(n - first);
                    for run in 0..per_encoder {
                        // Sample `run` of each encoder of the block.
                        let at = |l: usize| (first + l) * per_encoder + run;
                        let mut w = [0.0f32; LANES];
                        let mut block_dirs = [Vec3::ZERO; LANES];
                        for l in 0..lanes {
                            w[l] = weights.map_or(1.0, |ws| ws[at(l)]);
                            block_dirs[l] = dirs[at(l)];
                        }
                        scratch.values.fill(0.0);
                        for l in 0..lanes {
                            for c in 0..ch {
                                scratch.values[c * LANES + l] = values[at(l) * ch + c];
                            }
                        }
                        // The sample itself, then (hemisphere mode) its mirror with no value.
                        let mirrored = cfg.hemisphere.then(|| block_dirs.map(|d| -d));
                        let passes = std::iter::once((&block_dirs, true))
                            .chain(mirrored.as_ref().map(|m| (m, false)));
                        for (pass_dirs, with_values) in passes {
                            let block = Block {
                                coeffs: &mut *coeffs,
                                integrals: &mut *integrals,
                                wsum: &mut *wsum,
                            };
                            let lanes_in = Lanes {
                                dirs: pass_dirs,
                                w: &w,
                                count: lanes,
                                with_values,
                            };
                            update_block(basis, sg, &cfg, true_means, block, scratch, lanes_in);
                        }
                    }
                },
            );
        Ok(())
    }
}

struct Scratch {
    eval: Vec<f32>,
    b: Vec<f32>,
    delta: Vec<f32>,
    values: Vec<f32>,
}

impl Scratch {
    fn new(k: usize, ch: usize) -> Self {
        Self {
            eval: vec![0.0; k],
            b: vec![0.0; k * LANES],
            delta: vec![0.0; ch * LANES],
            values: vec![0.0; ch * LANES],
        }
    }
}

/// The samples of one block: a direction and weight per lane, `count` lanes in use, values in
/// the scratch buffer (or zero for hemisphere mirror samples).
struct Lanes<'a> {
    dirs: &'a [Vec3; LANES],
    w: &'a [f32; LANES],
    count: usize,
    with_values: bool,
}

struct Block<'a> {
    coeffs: &'a mut [f32],
    integrals: &'a mut [f32],
    wsum: &'a mut [f32],
}

/// One sample per lane; the same arithmetic as `ProgressiveEncoder::apply`, lane-wide.
fn update_block<B: SphericalBasis + ?Sized>(
    basis: &B,
    sg: Option<&SgLanes>,
    cfg: &EncoderConfig,
    true_means: &[f32],
    block: Block<'_>,
    scratch: &mut Scratch,
    lanes_in: Lanes<'_>,
) {
    let Lanes {
        dirs,
        w,
        count: lanes,
        with_values,
    } = lanes_in;
    let k = basis.len();
    let ch = scratch.delta.len() / LANES;
    let Block {
        coeffs,
        integrals,
        wsum,
    } = block;
    let mut share = [0.0f32; LANES];
    for l in 0..LANES {
        if l < lanes && w[l] > 0.0 {
            wsum[l] += w[l];
            share[l] = w[l] / wsum[l];
        }
    }
    if let Some(sg) = sg {
        let dx: [f32; LANES] = std::array::from_fn(|l| dirs[l].x);
        let dy: [f32; LANES] = std::array::from_fn(|l| dirs[l].y);
        let dz: [f32; LANES] = std::array::from_fn(|l| dirs[l].z);
        let live: [f32; LANES] = std::array::from_fn(|l| if l < lanes { 1.0 } else { 0.0 });
        for i in 0..k {
            let b = &mut scratch.b[i * LANES..(i + 1) * LANES];
            let (px, py, pz, lambda) = (sg.px[i], sg.py[i], sg.pz[i], sg.lambda[i]);
            for l in 0..LANES {
                b[l] = live[l]
                    * exp_nonpositive(lambda * (px * dx[l] + py * dy[l] + pz * dz[l] - 1.0));
            }
        }
    } else {
        for l in 0..lanes {
            basis.eval(dirs[l], &mut scratch.eval);
            for i in 0..k {
                scratch.b[i * LANES + l] = scratch.eval[i];
            }
        }
        for l in lanes..LANES {
            for i in 0..k {
                scratch.b[i * LANES + l] = 0.0;
            }
        }
    }
    let delta = &mut scratch.delta;
    if with_values {
        delta.copy_from_slice(&scratch.values);
    } else {
        delta.fill(0.0);
    }
    for i in 0..k {
        let b = &scratch.b[i * LANES..(i + 1) * LANES];
        for c in 0..ch {
            let co = &coeffs[(i * ch + c) * LANES..(i * ch + c + 1) * LANES];
            let d = &mut delta[c * LANES..(c + 1) * LANES];
            for l in 0..LANES {
                d[l] -= b[l] * co[l];
            }
        }
    }
    for i in 0..k {
        let b: [f32; LANES] = std::array::from_fn(|l| scratch.b[i * LANES + l]);
        // Lanes whose basis value is 0 (or whose weight is 0) skip the update, as in the paper.
        let s: [f32; LANES] = std::array::from_fn(|l| if b[l] != 0.0 { share[l] } else { 0.0 });
        let est = &mut integrals[i * LANES..(i + 1) * LANES];
        let mut denom = [1.0f32; LANES];
        for l in 0..LANES {
            est[l] += (b[l] * b[l] - est[l]) * s[l];
            denom[l] = match cfg.denominator {
                Denominator::Clamped { floor } => est[l].max(floor * true_means[i]),
                Denominator::LerpFromOne => s[l] + (1.0 - s[l]) * est[l],
                Denominator::Exact => true_means[i],
            };
            if denom[l] == 0.0 {
                denom[l] = 1.0;
            }
        }
        for c in 0..ch {
            let co = &mut coeffs[(i * ch + c) * LANES..(i * ch + c + 1) * LANES];
            let d = &mut delta[c * LANES..(c + 1) * LANES];
            for l in 0..LANES {
                let old = co[l];
                let step = s[l] * b[l] / denom[l];
                let mut new = match cfg.update {
                    Update::Residual { acceleration } => old + acceleration * step * d[l],
                    Update::RunningAverage => {
                        old + (b[l] * (d[l] + old * b[l]) / denom[l] - old) * s[l]
                    }
                };
                if cfg.non_negative {
                    new = new.max(0.0);
                }
                co[l] = new;
                if cfg.sweep == Sweep::GaussSeidel {
                    match cfg.update {
                        Update::Residual { .. } => d[l] *= 1.0 - step * b[l],
                        Update::RunningAverage => d[l] -= (new - old) * b[l],
                    }
                }
            }
        }
    }
}
