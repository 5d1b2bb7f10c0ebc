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
    /// The best of all `2^bands` mode assignments: the one whose `k` best terms leave the least
    /// weighted L1 out (optimal for that objective). Found without enumerating them: a band
    /// holding `n` terms leaves the lesser of its two modes' errors, so the optimum is the
    /// split of `k` terms over the bands minimising the sum, a dynamic programme over bands in
    /// `O(bands × k²)` per frame (the thesis enumerates the assignments, which limits it to
    /// few bands; this scales to [`crate::CubemapLayout::level_face_tile_bands`]).
    Exhaustive,
    /// Incremental exactly when the band's weighted L1 residual `‖L_b − L̃_b‖` is no larger than
    /// its weighted L1 norm `‖L_b‖` (the thesis' simple per-band test); then the `k` best terms.
    L1Test,
    /// Deal the `k` terms one at a time to the band whose error drops most by one more term,
    /// the error of a band holding `n` terms being the better of its two modes; each band then
    /// takes its dealt number of terms in its better mode. (Our greedy reading of the thesis'
    /// dealer: `O(bands × k)` per frame, not optimal when a band's error falls slowly for its
    /// first terms, e.g. a replaced band that only pays off after several.)
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
            Policy::PerBand(BandStrategy::Exhaustive) => {
                let (modes, counts) = optimal_split(&inc, &rep, k);
                (modes, Some(counts))
            }
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

/// Weighted L1 left out of a band's candidate list when its `n` best are taken.
fn left_out(list: &Candidates, n: usize) -> f64 {
    list.total - list.prefix[n.min(list.best.len())]
}

/// The mode of a band holding `n` terms: the one leaving less out (incremental on a tie, which
/// keeps the band coherent).
fn better_mode(inc: &Candidates, rep: &Candidates, n: usize) -> BandMode {
    if left_out(inc, n) <= left_out(rep, n) {
        BandMode::Incremental
    } else {
        BandMode::Replace
    }
}

/// Modes and term counts whose `k` terms leave the least out over all `2^bands` assignments.
/// For a fixed assignment the best `k` terms are a split of `k` over the bands (each band's
/// list is sorted, so taking its best `n` is optimal), and a band holding `n` terms does best in
/// its better mode, so the optimum is `min Σ_b E_b(n_b)` subject to `Σ n_b ≤ k` with
/// `E_b(n) = min(inc_b(n), rep_b(n))`: a knapsack solved over bands in `O(bands × k²)`. Ties
/// keep fewer terms in the earlier bands.
fn optimal_split(inc: &[Candidates], rep: &[Candidates], k: usize) -> (Vec<BandMode>, Vec<usize>) {
    let bands = inc.len();
    // least[j]: the least the bands so far leave out with at most j terms; take[b][j]: the terms
    // band b holds in that optimum.
    let mut least = vec![0.0f64; k + 1];
    let mut next = vec![0.0f64; k + 1];
    let mut take = vec![0usize; bands * (k + 1)];
    let mut band_err = Vec::with_capacity(k + 1);
    for b in 0..bands {
        let available = inc[b].best.len().max(rep[b].best.len()).min(k);
        band_err.clear();
        band_err.extend((0..=available).map(|n| left_out(&inc[b], n).min(left_out(&rep[b], n))));
        for j in 0..=k {
            let (mut best, mut best_n) = (f64::INFINITY, 0);
            for (n, e) in band_err.iter().enumerate().take(j + 1) {
                let total = least[j - n] + e;
                if total < best {
                    (best, best_n) = (total, n);
                }
            }
            next[j] = best;
            take[b * (k + 1) + j] = best_n;
        }
        std::mem::swap(&mut least, &mut next);
    }
    let mut counts = vec![0usize; bands];
    let mut j = k;
    for b in (0..bands).rev() {
        counts[b] = take[b * (k + 1) + j];
        j -= counts[b];
    }
    modes_and_counts(inc, rep, counts)
}

/// Each band's better mode for its count, and the count cut to what that mode's list holds.
fn modes_and_counts(
    inc: &[Candidates],
    rep: &[Candidates],
    mut counts: Vec<usize>,
) -> (Vec<BandMode>, Vec<usize>) {
    let modes: Vec<BandMode> = (0..inc.len())
        .map(|b| better_mode(&inc[b], &rep[b], counts[b]))
        .collect();
    for (b, count) in counts.iter_mut().enumerate() {
        let list = if modes[b] == BandMode::Incremental {
            &inc[b]
        } else {
            &rep[b]
        };
        *count = (*count).min(list.best.len());
    }
    (modes, counts)
}

fn deal(inc: &[Candidates], rep: &[Candidates], k: usize) -> (Vec<BandMode>, Vec<usize>) {
    let bands = inc.len();
    let band_err = |b: usize, n: usize| left_out(&inc[b], n).min(left_out(&rep[b], n));
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
    modes_and_counts(inc, rep, counts)
}
