//! Non-linear wavelet approximation (NWA), basic incremental (BI) and per-band incremental (PBI)
//! updates of a lighting coefficient vector, after Overbeck, Ben-Artzi, Ramamoorthi and Grinspun,
//! "Exploiting Temporal Coherence for Incremental All-Frequency Relighting" (EGSR 2006) and
//! Overbeck's thesis "Exploiting Temporal Coherence for Pre-computation Based Rendering".
//!
//! Every frame, `k` terms (coefficient indices, all channels of each) are chosen from a
//! candidate vector, where a *band* (wavelet level) is either
//! - **incremental**: candidates are the residual `L − L̃`; chosen terms are added (`L̃ᵢ ← Lᵢ`),
//!   everything else in the band keeps its previous value; or
//! - **non-incremental** (replace): candidates are `L` itself; the band of `L̃` is cleared and
//!   only the chosen terms are set.
//!
//! NWA is every band non-incremental (the `k` largest coefficients of `L`), BI every band
//! incremental (`Δ = Approx_k(L − L̃)`, `L̃ += Δ`), and PBI chooses per band each frame with one
//! of three strategies ([`BandStrategy`]). The score of a candidate is `wᵢ Σ_c |xᵢ,c|` with
//! selection weights `w` (unweighted, area-weighted or transport-weighted); the frame's
//! objective is the weighted L1 norm of what is left out, which for area weights bounds the
//! area-weighted L1 lighting error (see [`crate::CubemapLayout`]).
//!
//! Selection is a single pass with a `k`-bounded heap per band and mode (no sort of the
//! candidates; linear in practice, `O(n log k)` at worst), then a `k`-way merge. Ties break towards the lower index, so results
//! are deterministic. Candidates of score 0 are never chosen, so a static lighting converges to
//! `L̃ = L` exactly (assignment, not accumulation) after at most `⌈nnz / k⌉` frames and then stays
//! there with no terms spent (coefficients of selection weight 0 are never chosen).

use std::cmp::Reverse;
use std::collections::BinaryHeap;

use crate::WaveletError;
use crate::cubemap::CubemapLayout;

/// How one band is updated in a frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BandMode {
    /// Candidates are the residual `L − L̃`; the rest of the band keeps its value.
    Incremental,
    /// Candidates are `L`; the band is cleared and only the chosen terms are set.
    Replace,
}

/// How PBI decides each band's mode.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BandStrategy {
    /// Try all `2^bands` assignments and keep the one whose `k` best terms leave the least
    /// weighted L1 out (optimal for that objective; cost `2^bands × k × bands` per frame).
    Exhaustive,
    /// Incremental exactly when the band's weighted L1 residual `‖L_b − L̃_b‖` is no larger than
    /// its weighted L1 norm `‖L_b‖` (the thesis' simple per-band test); then the `k` best terms.
    L1Test,
    /// Deal the `k` terms one at a time to the band whose error drops most by one more term,
    /// the error of a band holding `n` terms being the better of its two modes; each band then
    /// takes its dealt number of terms in its better mode. (Our greedy reading of the thesis'
    /// dealer; unlike [`BandStrategy::Exhaustive`] it scales to many bands, e.g.
    /// [`crate::CubemapLayout::level_face_bands`].)
    Dealer,
}

/// Which approximation runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Policy {
    /// NWA: the `k` largest coefficients of each frame, no memory.
    NonIncremental,
    /// BI: `L̃ += Approx_k(L − L̃)`.
    Incremental,
    /// PBI with the given strategy.
    PerBand(BandStrategy),
}

/// The selection weights `wᵢ`.
#[derive(Debug, Clone, PartialEq)]
pub enum Weighting {
    /// `wᵢ = 1`.
    Unweighted,
    /// The cube-map layout's area weights (L1 norms of the basis functions on the sphere).
    Area,
    /// Caller-given weights, e.g. the transport matrix's column norms (Ng et al.'s transport
    /// weighting); one per coefficient, finite and non-negative.
    Transport(Vec<f32>),
}

/// One chosen term of a frame: a coefficient and what to do with it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Term {
    /// Coefficient index within a channel plane.
    pub index: u32,
    /// Its band.
    pub band: u8,
}

/// What a frame changed, in the form the relighting engine consumes (Overbeck's figure 6.1):
/// per band the mode, and the chosen terms with their values — the delta `Lᵢ − L̃ᵢ` for
/// incremental bands and the new value `Lᵢ` for replaced bands.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FrameUpdate {
    /// Mode of every band this frame.
    pub modes: Vec<BandMode>,
    /// Chosen terms, sorted by index.
    pub terms: Vec<Term>,
    /// `values[t * channels + c]`: delta or new value of term `t`, channel `c`.
    pub values: Vec<f32>,
    /// The objective after the update: the weighted L1 norm of `L − L̃` for the wavelet
    /// [`Approximator`]; for [`crate::ShApproximator`] the summed L2 change of the bands left stale.
    pub residual: f64,
}

impl FrameUpdate {
    /// Number of terms chosen in each band.
    pub fn terms_per_band(&self) -> Vec<usize> {
        let mut counts = vec![0; self.modes.len()];
        for t in &self.terms {
            counts[t.band as usize] += 1;
        }
        counts
    }
}

/// A candidate list of one band in one mode: the best `k` (score, index) pairs, best first,
/// and the total score of the band.
#[derive(Debug, Clone, Default)]
struct Candidates {
    best: Vec<(f32, u32)>,
    total: f64,
    /// `prefix[n]` = sum of the `n` best scores.
    prefix: Vec<f64>,
}

/// NWA / BI / PBI over a coefficient vector of `channels` planes.
#[derive(Debug, Clone)]
pub struct Approximator {
    channels: usize,
    terms: usize,
    policy: Policy,
    band_members: Vec<Vec<u32>>,
    bands: Vec<u8>,
    weights: Vec<f32>,
    approx: Vec<f32>,
    inc_scores: Vec<f32>,
    rep_scores: Vec<f32>,
    update: FrameUpdate,
}

impl Approximator {
    /// A general approximator: `bands[i]` is the band of coefficient `i` (bands numbered from
    /// 0, every band between 0 and the largest present), `weights[i]` its selection weight,
    /// `channels` planes of `bands.len()` coefficients, `terms` = `k` per frame.
    pub fn new(
        bands: Vec<u8>,
        weights: Vec<f32>,
        channels: usize,
        terms: usize,
        policy: Policy,
    ) -> Result<Self, WaveletError> {
        WaveletError::check_len("selection weights", bands.len(), weights.len())?;
        WaveletError::check_finite("selection weights", &weights)?;
        if let Some(i) = weights.iter().position(|&w| w < 0.0) {
            return Err(WaveletError::Invalid {
                what: "selection weights",
                why: format!("weight {i} is negative"),
            });
        }
        if channels == 0 || bands.is_empty() {
            return Err(WaveletError::Invalid {
                what: "approximator",
                why: "needs at least one channel and one coefficient".into(),
            });
        }
        let band_count = bands.iter().map(|&b| b as usize + 1).max().unwrap_or(1);
        if let (Policy::PerBand(BandStrategy::Exhaustive), true) = (policy, band_count > 20) {
            return Err(WaveletError::Invalid {
                what: "policy",
                why: format!(
                    "exhaustive search over {band_count} bands (2^{band_count} assignments)"
                ),
            });
        }
        let mut band_members = vec![Vec::new(); band_count];
        for (i, &b) in bands.iter().enumerate() {
            band_members[b as usize].push(i as u32);
        }
        let n = bands.len();
        Ok(Self {
            channels,
            terms,
            policy,
            band_members,
            bands,
            weights,
            approx: vec![0.0; n * channels],
            inc_scores: vec![0.0; n],
            rep_scores: vec![0.0; n],
            update: FrameUpdate::default(),
        })
    }

    /// An approximator for cube-map Haar coefficients (bands = wavelet levels).
    pub fn for_cubemap(
        layout: &CubemapLayout,
        channels: usize,
        weighting: Weighting,
        terms: usize,
        policy: Policy,
    ) -> Result<Self, WaveletError> {
        let weights = match weighting {
            Weighting::Unweighted => vec![1.0; layout.len()],
            Weighting::Area => layout.area_weights().to_vec(),
            Weighting::Transport(w) => w,
        };
        Self::new(layout.bands().to_vec(), weights, channels, terms, policy)
    }

    /// The current approximation `L̃` (planar, like the input).
    pub fn approximation(&self) -> &[f32] {
        &self.approx
    }

    /// Number of bands.
    pub fn band_count(&self) -> usize {
        self.band_members.len()
    }

    /// Terms per frame.
    pub fn terms(&self) -> usize {
        self.terms
    }

    /// Sets the approximation `L̃` (for example to resume from a stored state). Errors on a
    /// length mismatch or a non-finite value.
    pub fn set_approximation(&mut self, values: &[f32]) -> Result<(), WaveletError> {
        WaveletError::check_len("approximation", self.approx.len(), values.len())?;
        WaveletError::check_finite("approximation", values)?;
        self.approx.copy_from_slice(values);
        Ok(())
    }

    /// Forgets the approximation (back to `L̃ = 0`).
    pub fn reset(&mut self) {
        self.approx.fill(0.0);
    }

    /// Advances one frame towards `target` (planar coefficients, `channels × len`) and returns
    /// what changed. Errors on a length mismatch or a non-finite coefficient.
    pub fn step(&mut self, target: &[f32]) -> Result<&FrameUpdate, WaveletError> {
        let n = self.bands.len();
        WaveletError::check_len("lighting coefficients", n * self.channels, target.len())?;
        WaveletError::check_finite("lighting coefficients", target)?;
        self.score(target);
        let band_count = self.band_count();
        let k = self.terms;
        let (inc, rep) = self.candidates(k);
        let (modes, counts) = match self.policy {
            Policy::NonIncremental => (vec![BandMode::Replace; band_count], None),
            Policy::Incremental => (vec![BandMode::Incremental; band_count], None),
            Policy::PerBand(BandStrategy::L1Test) => (
                (0..band_count)
                    .map(|b| {
                        if inc[b].total <= rep[b].total {
                            BandMode::Incremental
                        } else {
                            BandMode::Replace
                        }
                    })
                    .collect(),
                None,
            ),
            Policy::PerBand(BandStrategy::Exhaustive) => (exhaustive(&inc, &rep, k), None),
            Policy::PerBand(BandStrategy::Dealer) => {
                let (modes, counts) = deal(&inc, &rep, k);
                (modes, Some(counts))
            }
        };
        let lists: Vec<&Candidates> = modes
            .iter()
            .enumerate()
            .map(|(b, m)| {
                if *m == BandMode::Incremental {
                    &inc[b]
                } else {
                    &rep[b]
                }
            })
            .collect();
        let chosen = match counts {
            Some(counts) => lists
                .iter()
                .zip(&counts)
                .flat_map(|(l, &c)| l.best[..c].iter().map(|p| p.1))
                .collect(),
            None => merge_best(&lists, k),
        };
        let residual: f64 = lists.iter().map(|l| l.total).sum::<f64>() - {
            let mut chosen_score = 0.0f64;
            for &i in &chosen {
                let b = self.bands[i as usize] as usize;
                chosen_score += if modes[b] == BandMode::Incremental {
                    self.inc_scores[i as usize] as f64
                } else {
                    self.rep_scores[i as usize] as f64
                };
            }
            chosen_score
        };
        self.apply(target, modes, chosen, residual.max(0.0));
        Ok(&self.update)
    }

    fn score(&mut self, target: &[f32]) {
        let n = self.bands.len();
        self.inc_scores.fill(0.0);
        self.rep_scores.fill(0.0);
        // Channel planes are contiguous: accumulate plane by plane so the loops vectorise.
        for (t, a) in target.chunks_exact(n).zip(self.approx.chunks_exact(n)) {
            for i in 0..n {
                self.inc_scores[i] += (t[i] - a[i]).abs();
                self.rep_scores[i] += t[i].abs();
            }
        }
        for i in 0..n {
            self.inc_scores[i] *= self.weights[i];
            self.rep_scores[i] *= self.weights[i];
        }
    }

    /// The best `k` candidates of every band in both modes, in one pass over the scores with a
    /// `k`-bounded heap per band and mode (`O(n)` comparisons when few candidates displace
    /// the heap minimum, `O(n log k)` at worst; never a full sort). NWA never looks at the
    /// residual and BI never at the lighting itself, so they skip the other mode.
    fn candidates(&self, k: usize) -> (Vec<Candidates>, Vec<Candidates>) {
        let bc = self.band_count();
        let (want_inc, want_rep) = (
            self.policy != Policy::NonIncremental,
            self.policy != Policy::Incremental,
        );
        let mut inc: Vec<TopK> = (0..bc).map(|_| TopK::new(k)).collect();
        let mut rep: Vec<TopK> = (0..bc).map(|_| TopK::new(k)).collect();
        for (i, &b) in self.bands.iter().enumerate() {
            let b = b as usize;
            if want_inc {
                inc[b].offer(self.inc_scores[i], i as u32);
            }
            if want_rep {
                rep[b].offer(self.rep_scores[i], i as u32);
            }
        }
        (
            inc.into_iter().map(TopK::finish).collect(),
            rep.into_iter().map(TopK::finish).collect(),
        )
    }

    fn apply(&mut self, target: &[f32], modes: Vec<BandMode>, mut chosen: Vec<u32>, residual: f64) {
        let n = self.bands.len();
        for (b, mode) in modes.iter().enumerate() {
            if *mode == BandMode::Replace {
                for &i in &self.band_members[b] {
                    for c in 0..self.channels {
                        self.approx[c * n + i as usize] = 0.0;
                    }
                }
            }
        }
        chosen.sort_unstable();
        let u = &mut self.update;
        u.terms.clear();
        u.values.clear();
        for &i in &chosen {
            let band = self.bands[i as usize];
            u.terms.push(Term { index: i, band });
            for c in 0..self.channels {
                let j = c * n + i as usize;
                // Replace: the band was cleared, so the "delta" is the new value itself.
                u.values.push(target[j] - self.approx[j]);
                self.approx[j] = target[j];
            }
        }
        u.modes = modes;
        u.residual = residual;
    }
}

/// The `k` best (score, index) pairs of a stream and the stream's total score.
struct TopK {
    k: usize,
    heap: BinaryHeap<Reverse<u64>>,
    total: f64,
}

impl TopK {
    fn new(k: usize) -> Self {
        Self {
            k,
            heap: BinaryHeap::with_capacity(k + 1),
            total: 0.0,
        }
    }

    #[inline]
    fn offer(&mut self, score: f32, index: u32) {
        self.total += score as f64;
        if score <= 0.0 || self.k == 0 {
            return;
        }
        let key = rank_key(score, index);
        if self.heap.len() < self.k {
            self.heap.push(Reverse(key));
        } else if let Some(mut min) = self.heap.peek_mut()
            && key > min.0
        {
            *min = Reverse(key);
        }
    }

    fn finish(self) -> Candidates {
        let mut keys: Vec<u64> = self.heap.into_iter().map(|r| r.0).collect();
        keys.sort_unstable_by(|x, y| y.cmp(x));
        let best: Vec<(f32, u32)> = keys.into_iter().map(unrank_key).collect();
        let mut prefix = Vec::with_capacity(best.len() + 1);
        prefix.push(0.0);
        for (s, _) in &best {
            prefix.push(prefix[prefix.len() - 1] + *s as f64);
        }
        Candidates {
            best,
            total: self.total,
            prefix,
        }
    }
}

/// A sort key for a positive finite score and its index: the bit patterns of non-negative f32
/// order like the values, and the inverted index makes ties prefer the lower index.
#[inline]
fn rank_key(score: f32, index: u32) -> u64 {
    ((score.to_bits() as u64) << 32) | (!index) as u64
}

#[inline]
fn unrank_key(key: u64) -> (f32, u32) {
    (f32::from_bits((key >> 32) as u32), !(key as u32))
}

/// The `k` best candidates over several best-first lists.
fn merge_best(lists: &[&Candidates], k: usize) -> Vec<u32> {
    let mut pos = vec![0usize; lists.len()];
    let mut out = Vec::with_capacity(k);
    while out.len() < k {
        let mut pick: Option<(usize, f32, u32)> = None;
        for (l, list) in lists.iter().enumerate() {
            if let Some(&(s, i)) = list.best.get(pos[l]) {
                let better = match pick {
                    None => true,
                    Some((_, ps, pi)) => s > ps || (s == ps && i < pi),
                };
                if better {
                    pick = Some((l, s, i));
                }
            }
        }
        match pick {
            Some((l, _, i)) => {
                pos[l] += 1;
                out.push(i);
            }
            None => break,
        }
    }
    out
}

/// Sum of the `k` best scores over lists (a `k`-way merge of the prefix sums' increments).
fn best_sum(lists: &[&Candidates], k: usize) -> f64 {
    let mut pos = vec![0usize; lists.len()];
    let mut sum = 0.0;
    for _ in 0..k {
        let mut pick: Option<(usize, f32)> = None;
        for (l, list) in lists.iter().enumerate() {
            if let Some(&(s, _)) = list.best.get(pos[l])
                && pick.is_none_or(|(_, ps)| s > ps)
            {
                pick = Some((l, s));
            }
        }
        match pick {
            Some((l, s)) => {
                pos[l] += 1;
                sum += s as f64;
            }
            None => break,
        }
    }
    sum
}

fn exhaustive(inc: &[Candidates], rep: &[Candidates], k: usize) -> Vec<BandMode> {
    let bands = inc.len();
    let mut best: Option<(f64, u32)> = None;
    let mut lists: Vec<&Candidates> = Vec::with_capacity(bands);
    for mask in 0..(1u32 << bands) {
        lists.clear();
        let mut total = 0.0;
        for b in 0..bands {
            let l = if mask & (1 << b) != 0 {
                &rep[b]
            } else {
                &inc[b]
            };
            total += l.total;
            lists.push(l);
        }
        let left = total - best_sum(&lists, k);
        // Ties keep the earlier mask, i.e. prefer incremental bands (cheaper to keep coherent).
        if best.is_none_or(|(e, _)| left < e) {
            best = Some((left, mask));
        }
    }
    let mask = best.map_or(0, |b| b.1);
    (0..bands)
        .map(|b| {
            if mask & (1 << b) != 0 {
                BandMode::Replace
            } else {
                BandMode::Incremental
            }
        })
        .collect()
}

fn deal(inc: &[Candidates], rep: &[Candidates], k: usize) -> (Vec<BandMode>, Vec<usize>) {
    let bands = inc.len();
    let err = |l: &Candidates, n: usize| l.total - l.prefix[n.min(l.best.len())];
    let band_err = |b: usize, n: usize| err(&inc[b], n).min(err(&rep[b], n));
    let mut counts = vec![0usize; bands];
    for _ in 0..k {
        let mut pick: Option<(usize, f64)> = None;
        for b in 0..bands {
            let available = inc[b].best.len().max(rep[b].best.len());
            if counts[b] >= available {
                continue;
            }
            let gain = band_err(b, counts[b]) - band_err(b, counts[b] + 1);
            if pick.is_none_or(|(_, g)| gain > g) {
                pick = Some((b, gain));
            }
        }
        match pick {
            Some((b, _)) => counts[b] += 1,
            None => break,
        }
    }
    let modes: Vec<BandMode> = (0..bands)
        .map(|b| {
            if err(&inc[b], counts[b]) <= err(&rep[b], counts[b]) {
                BandMode::Incremental
            } else {
                BandMode::Replace
            }
        })
        .collect();
    for b in 0..bands {
        let list = if modes[b] == BandMode::Incremental {
            &inc[b]
        } else {
            &rep[b]
        };
        counts[b] = counts[b].min(list.best.len());
    }
    (modes, counts)
}
