//! Per-band incremental updates of spherical-harmonic lighting (Overbeck's chapter 8: PBI in a
//! basis whose bands are the SH bands `l`, as used with clustered PCA).
//!
//! SH coefficients are global, so a band is refreshed as a whole (its `2l + 1` terms) or kept.
//! Each frame has a budget of `k` terms. *Tolerance-driven band filling*: a band is stale when
//! its change `‖L_l − L̃_l‖₂` exceeds `tolerance × ‖L‖₂`; stale bands are refreshed first, the
//! most changed first, as long as they fit in the budget; the remaining budget then refreshes
//! the other changed bands in the same order, so that static lighting converges to `L̃ = L`
//! exactly (after at most `⌈n² / k⌉` frames when `k >= 2n − 1`).

use crate::WaveletError;
use crate::approx::{BandMode, FrameUpdate, Term};

/// PBI for SH lighting of order `n` (`n²` coefficients per channel, flat index `l(l+1)+m`).
#[derive(Debug, Clone)]
pub struct ShApproximator {
    order: usize,
    channels: usize,
    terms: usize,
    tolerance: f32,
    approx: Vec<f32>,
    update: FrameUpdate,
}

impl ShApproximator {
    /// An approximator with budget `terms` per frame and relative `tolerance` (finite, >= 0).
    /// Bands larger than the budget can never be refreshed: `terms >= 2 order − 1` is required.
    pub fn new(
        order: usize,
        channels: usize,
        terms: usize,
        tolerance: f32,
    ) -> Result<Self, WaveletError> {
        if order == 0 || channels == 0 {
            return Err(WaveletError::Invalid {
                what: "SH approximator",
                why: "order and channels must be >= 1".into(),
            });
        }
        if terms < 2 * order - 1 {
            return Err(WaveletError::Invalid {
                what: "SH terms per frame",
                why: format!(
                    "{terms} cannot hold band {} ({} terms)",
                    order - 1,
                    2 * order - 1
                ),
            });
        }
        if !(tolerance.is_finite() && tolerance >= 0.0) {
            return Err(WaveletError::Invalid {
                what: "SH tolerance",
                why: format!("{tolerance}"),
            });
        }
        Ok(Self {
            order,
            channels,
            terms,
            tolerance,
            approx: vec![0.0; order * order * channels],
            update: FrameUpdate::default(),
        })
    }

    /// The current approximation (planar: `channels × order²`).
    pub fn approximation(&self) -> &[f32] {
        &self.approx
    }

    /// One frame towards `target`; the update lists the refreshed bands' terms with their deltas
    /// (every band is reported as [`BandMode::Incremental`]).
    pub fn step(&mut self, target: &[f32]) -> Result<&FrameUpdate, WaveletError> {
        let n2 = self.order * self.order;
        WaveletError::check_len("SH lighting", n2 * self.channels, target.len())?;
        WaveletError::check_finite("SH lighting", target)?;
        let norm: f64 = target
            .iter()
            .map(|&v| v as f64 * v as f64)
            .sum::<f64>()
            .sqrt();
        let mut change: Vec<(usize, f64)> = (0..self.order)
            .map(|l| {
                let mut e = 0.0f64;
                for c in 0..self.channels {
                    for i in l * l..(l + 1) * (l + 1) {
                        let j = c * n2 + i;
                        e += (target[j] as f64 - self.approx[j] as f64).powi(2);
                    }
                }
                (l, e.sqrt())
            })
            .filter(|&(_, e)| e > 0.0)
            .collect();
        change.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
        let threshold = self.tolerance as f64 * norm;
        let (stale, rest): (Vec<_>, Vec<_>) = change.into_iter().partition(|&(_, e)| e > threshold);
        let mut budget = self.terms;
        let u = &mut self.update;
        u.modes = vec![BandMode::Incremental; self.order];
        u.terms.clear();
        u.values.clear();
        let mut left = 0.0f64;
        for (l, e) in stale.into_iter().chain(rest) {
            let size = 2 * l + 1;
            if size > budget {
                left += e;
                continue;
            }
            budget -= size;
            for i in l * l..(l + 1) * (l + 1) {
                u.terms.push(Term {
                    index: i as u32,
                    band: l as u8,
                });
                for c in 0..self.channels {
                    let j = c * n2 + i;
                    u.values.push(target[j] - self.approx[j]);
                    self.approx[j] = target[j];
                }
            }
        }
        u.residual = left;
        Ok(&self.update)
    }
}
