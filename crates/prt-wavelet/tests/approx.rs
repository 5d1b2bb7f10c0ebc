//! Laws of NWA, BI and PBI: NWA is the exact top-k, updates are consistent with the
//! approximation they produce, the exhaustive strategy is optimal for the frame objective,
//! static lighting is an exact fixed point, and the extremes behave as documented.

use proptest::prelude::*;
use prt_wavelet::{
    Approximator, BandMode, BandStrategy, CubemapLayout, FrameUpdate, Policy, WaveletError,
    Weighting,
};

const STRATEGIES: [BandStrategy; 3] = [
    BandStrategy::Exhaustive,
    BandStrategy::L1Test,
    BandStrategy::Dealer,
];

fn all_policies() -> Vec<Policy> {
    let mut p = vec![Policy::NonIncremental, Policy::Incremental];
    p.extend(STRATEGIES.map(Policy::PerBand));
    p
}

/// Weighted L1 of `target − approx`, scores summed over channels (the documented objective).
fn objective(target: &[f32], approx: &[f32], weights: &[f32]) -> f64 {
    let n = weights.len();
    (0..n)
        .map(|i| {
            let s: f32 = (0..target.len() / n)
                .map(|c| (target[c * n + i] - approx[c * n + i]).abs())
                .sum();
            (weights[i] * s) as f64
        })
        .sum()
}

/// Replays an update on the previous approximation, as the relighting engine does.
fn replay(prev: &[f32], update: &FrameUpdate, bands: &[u8], channels: usize) -> Vec<f32> {
    let n = bands.len();
    let mut out = prev.to_vec();
    for i in 0..n {
        if update.modes[bands[i] as usize] == BandMode::Replace {
            for c in 0..channels {
                out[c * n + i] = 0.0;
            }
        }
    }
    for (t, term) in update.terms.iter().enumerate() {
        for c in 0..channels {
            out[c * n + term.index as usize] += update.values[t * channels + c];
        }
    }
    out
}

#[derive(Debug, Clone)]
struct Case {
    bands: Vec<u8>,
    weights: Vec<f32>,
    channels: usize,
    frames: Vec<Vec<f32>>,
    terms: usize,
}

fn case() -> impl Strategy<Value = Case> {
    (4usize..80, 1usize..=3, 1u8..=5, 0usize..20, 2usize..6).prop_flat_map(
        |(n, channels, band_count, terms, frames)| {
            (
                prop::collection::vec(0..band_count, n),
                prop::collection::vec(0.0f32..4.0, n),
                // Sparse-ish frames with repeated values so that ties and zeros occur.
                prop::collection::vec(
                    prop::collection::vec(
                        prop_oneof![Just(0.0f32), Just(1.0f32), -8.0f32..8.0],
                        n * channels,
                    ),
                    frames,
                ),
            )
                .prop_map(move |(mut bands, weights, frames)| {
                    // Every band from 0 to the largest must exist for the band count to be what we set.
                    for (i, b) in bands.iter_mut().enumerate().take(band_count as usize) {
                        *b = i as u8;
                    }
                    Case {
                        bands,
                        weights,
                        channels,
                        frames,
                        terms,
                    }
                })
        },
    )
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn nwa_is_the_weighted_top_k(c in case()) {
        let n = c.bands.len();
        let mut nwa = Approximator::new(c.bands.clone(), c.weights.clone(), c.channels, c.terms, Policy::NonIncremental).unwrap();
        for frame in &c.frames {
            let update = nwa.step(frame).unwrap().clone();
            let score = |i: usize| c.weights[i] * (0..c.channels).map(|ch| frame[ch * n + i].abs()).sum::<f32>();
            let mut order: Vec<usize> = (0..n).filter(|&i| score(i) > 0.0).collect();
            order.sort_by(|&a, &b| score(b).total_cmp(&score(a)).then(a.cmp(&b)));
            order.truncate(c.terms);
            order.sort_unstable();
            let chosen: Vec<usize> = update.terms.iter().map(|t| t.index as usize).collect();
            prop_assert_eq!(&chosen, &order);
            for i in 0..n {
                for ch in 0..c.channels {
                    let expect = if order.contains(&i) { frame[ch * n + i] } else { 0.0 };
                    prop_assert_eq!(nwa.approximation()[ch * n + i], expect);
                }
            }
        }
    }

    #[test]
    fn updates_replay_to_the_approximation_and_report_the_objective(c in case()) {
        for policy in all_policies() {
            let mut a = Approximator::new(c.bands.clone(), c.weights.clone(), c.channels, c.terms, policy).unwrap();
            let mut prev = a.approximation().to_vec();
            for frame in &c.frames {
                let update = a.step(frame).unwrap().clone();
                prop_assert!(update.terms.len() <= c.terms);
                // Deltas are rounded once in f32 (`(L − L̃) + L̃` may differ from `L` by an ulp).
                let replayed = replay(&prev, &update, &c.bands, c.channels);
                for ((r, x), p) in replayed.iter().zip(a.approximation()).zip(&prev) {
                    prop_assert!((r - x).abs() <= 2.0 * f32::EPSILON * (x.abs() + p.abs()), "{} vs {}", r, x);
                }
                let obj = objective(frame, a.approximation(), &c.weights);
                prop_assert!((update.residual - obj).abs() <= 1e-4 * (1.0 + obj), "{:?}: {} vs {}", policy, update.residual, obj);
                prev = a.approximation().to_vec();
            }
        }
    }

    #[test]
    fn exhaustive_is_optimal_for_the_frame_objective(c in case()) {
        // Every policy starts from the same state (the previous frame as the approximation) and
        // sees the same target; the exhaustive search must leave no more out than any of them.
        let (target, earlier) = c.frames.split_last().unwrap();
        let state = earlier.last().unwrap();
        let mut results = Vec::new();
        for policy in all_policies() {
            let mut a = Approximator::new(c.bands.clone(), c.weights.clone(), c.channels, c.terms, policy).unwrap();
            a.set_approximation(state).unwrap();
            results.push((policy, a.step(target).unwrap().residual));
        }
        let best = results.iter().find(|r| r.0 == Policy::PerBand(BandStrategy::Exhaustive)).unwrap().1;
        for (policy, r) in results {
            prop_assert!(best <= r * (1.0 + 1e-6) + 1e-6, "{:?} beat exhaustive: {} < {}", policy, r, best);
        }
    }

    #[test]
    fn exhaustive_matches_the_enumeration_of_every_mode_assignment(c in case()) {
        // The reference the thesis describes: for each of the 2^bands assignments, score every
        // coefficient in its band's mode and drop the k best; the least left out is the optimum.
        let n = c.bands.len();
        let band_count = *c.bands.iter().max().unwrap() as usize + 1;
        let (target, earlier) = c.frames.split_last().unwrap();
        let state = earlier.last().unwrap();
        let score = |i: usize, replace: bool| -> f32 {
            let s: f32 = (0..c.channels)
                .map(|ch| {
                    let j = ch * n + i;
                    if replace { target[j].abs() } else { (target[j] - state[j]).abs() }
                })
                .sum();
            c.weights[i] * s
        };
        let mut optimum = f64::INFINITY;
        for mask in 0..1u32 << band_count {
            let mut scores: Vec<f32> = (0..n).map(|i| score(i, mask & (1 << c.bands[i]) != 0)).collect();
            let total: f64 = scores.iter().map(|&s| s as f64).sum();
            scores.sort_by(|a, b| b.total_cmp(a));
            let kept: f64 = scores.iter().take(c.terms).map(|&s| s as f64).sum();
            optimum = optimum.min(total - kept);
        }
        let mut a = Approximator::new(c.bands.clone(), c.weights.clone(), c.channels, c.terms, Policy::PerBand(BandStrategy::Exhaustive)).unwrap();
        a.set_approximation(state).unwrap();
        let residual = a.step(target).unwrap().residual;
        prop_assert!((residual - optimum).abs() <= 1e-6 * (1.0 + optimum), "{} vs enumeration {}", residual, optimum);
    }

    #[test]
    fn exhaustive_over_many_bands_is_no_worse_than_any_other_policy(
        frames in prop::collection::vec(prop::collection::vec(prop_oneof![Just(0.0f32), -4.0f32..4.0], 6 * 16 * 16), 3),
        terms in 1usize..40,
    ) {
        // Level × face × quadrant bands of 16 × 16 faces: 6 × (2 + 4 × 3) = 84 bands, far past
        // what enumerating 2^bands assignments could check.
        let layout = CubemapLayout::new(16).unwrap();
        let bands = layout.level_face_tile_bands(2).unwrap();
        let weights = layout.area_weights().to_vec();
        let (target, earlier) = frames.split_last().unwrap();
        let make = |policy| Approximator::new(bands.clone(), weights.clone(), 1, terms, policy).unwrap();
        // A state with history: the exhaustive PBI after the earlier frames.
        let mut warm = make(Policy::PerBand(BandStrategy::Exhaustive));
        for f in earlier {
            warm.step(f).unwrap();
        }
        let state = warm.approximation().to_vec();
        let best = warm.step(target).unwrap().residual;
        for policy in all_policies() {
            let mut a = make(policy);
            a.set_approximation(&state).unwrap();
            let r = a.step(target).unwrap().residual;
            prop_assert!(best <= r * (1.0 + 1e-6) + 1e-6, "{:?} beat exhaustive: {} < {}", policy, r, best);
        }
    }

    #[test]
    fn static_lighting_is_an_exact_fixed_point(c in case()) {
        let n = c.bands.len();
        let target = c.frames.last().unwrap();
        let nonzero = (0..n).filter(|&i| c.weights[i] > 0.0 && (0..c.channels).any(|ch| target[ch * n + i] != 0.0)).count();
        let terms = c.terms.max(1);
        for policy in all_policies().into_iter().filter(|p| *p != Policy::NonIncremental) {
            let mut a = Approximator::new(c.bands.clone(), c.weights.clone(), c.channels, terms, policy).unwrap();
            for f in &c.frames[..c.frames.len() - 1] {
                a.step(f).unwrap();
            }
            // Incremental bands re-use what is right; a replaced band may restart, so allow the
            // documented bound ⌈nnz / k⌉ plus one frame per band for the switch to incremental.
            let bound = nonzero.div_ceil(terms) + 1 + a.band_count();
            for _ in 0..bound {
                a.step(target).unwrap();
            }
            let converged = a.step(target).unwrap().clone();
            prop_assert_eq!(converged.residual, 0.0, "{:?}", policy);
            for i in 0..n {
                if c.weights[i] > 0.0 {
                    for ch in 0..c.channels {
                        prop_assert_eq!(a.approximation()[ch * n + i], target[ch * n + i]);
                    }
                }
            }
            prop_assert!(converged.terms.is_empty());
        }
    }
}

#[test]
fn bi_converges_in_ceil_nnz_over_k_frames() {
    let n = 100;
    let target: Vec<f32> = (0..n)
        .map(|i| {
            if i % 3 == 0 {
                0.0
            } else {
                (i as f32).sin() * 1e3
            }
        })
        .collect();
    let nnz = target.iter().filter(|v| **v != 0.0).count();
    let mut bi = Approximator::new(vec![0; n], vec![1.0; n], 1, 10, Policy::Incremental).unwrap();
    for frame in 0..nnz.div_ceil(10) {
        let u = bi.step(&target).unwrap();
        assert_eq!(u.terms.len(), 10.min(nnz - 10 * frame));
        if frame + 1 < nnz.div_ceil(10) {
            assert!(u.residual > 0.0);
        }
    }
    assert_eq!(bi.approximation(), &target[..]);
}

#[test]
fn extremes() {
    let layout = CubemapLayout::new(4).unwrap();
    let n = layout.len();
    // Zero lighting: no terms, zero residual.
    for policy in all_policies() {
        let mut a = Approximator::for_cubemap(&layout, 2, Weighting::Area, 7, policy).unwrap();
        let u = a.step(&vec![0.0; 2 * n]).unwrap();
        assert!(u.terms.is_empty() && u.residual == 0.0);
    }
    // k = 0: nothing changes; k >= n: exact in one frame, even over 12 decades of range.
    let wide: Vec<f32> = (0..n)
        .map(|i| 10f32.powi((i % 13) as i32 - 6) * if i % 2 == 0 { 1.0 } else { -1.0 })
        .collect();
    let mut none =
        Approximator::for_cubemap(&layout, 1, Weighting::Unweighted, 0, Policy::Incremental)
            .unwrap();
    assert!(none.step(&wide).unwrap().terms.is_empty());
    assert!(none.approximation().iter().all(|&v| v == 0.0));
    for policy in all_policies() {
        let mut all = Approximator::for_cubemap(&layout, 1, Weighting::Area, n, policy).unwrap();
        all.step(&wide).unwrap();
        assert_eq!(all.approximation(), &wide[..]);
    }
    // A single non-zero coefficient is the only term chosen.
    let mut single = vec![0.0f32; n];
    single[37] = -2.5;
    let mut a = Approximator::for_cubemap(
        &layout,
        1,
        Weighting::Area,
        5,
        Policy::PerBand(BandStrategy::Dealer),
    )
    .unwrap();
    let u = a.step(&single).unwrap();
    assert_eq!(u.terms.len(), 1);
    assert_eq!(u.terms[0].index, 37);
    assert_eq!(u.terms[0].band as usize, layout.bands()[37] as usize);
}

#[test]
fn exhaustive_finds_a_replacement_that_pays_off_only_after_two_terms() {
    // Band 0: two fresh coefficients (5.5, kept right by incremental updates but worth 11 to a
    // replacement) and ten stale ones (1 each, left over from the previous frame). Incremental
    // leaves 10, 9, 8 with 0, 1, 2 terms; replacing leaves 11, 5.5, 0. Band 1 leaves 5.1, 0.1.
    // With k = 2 the dealer's one-term gains (4.5 for band 0, 5 for band 1) send a term to
    // band 1 and leave 5.5 + 0.1; the optimum replaces band 0 with both terms and leaves 5.1.
    let mut bands = vec![0u8; 12];
    bands.extend([1, 1]);
    let mut state = vec![5.5f32, 5.5];
    state.extend([1.0; 10]);
    state.extend([0.0, 0.0]);
    let mut target = vec![5.5f32, 5.5];
    target.extend([0.0; 10]);
    target.extend([5.0, 0.1]);
    let residual = |strategy| {
        let mut a = Approximator::new(
            bands.clone(),
            vec![1.0; 14],
            1,
            2,
            Policy::PerBand(strategy),
        )
        .unwrap();
        a.set_approximation(&state).unwrap();
        let u = a.step(&target).unwrap();
        (u.residual, u.modes.clone())
    };
    let (optimum, modes) = residual(BandStrategy::Exhaustive);
    assert!((optimum - 5.1).abs() < 1e-5, "{optimum}");
    assert_eq!(modes, [BandMode::Replace, BandMode::Incremental]);
    let (dealt, _) = residual(BandStrategy::Dealer);
    assert!((dealt - 5.6).abs() < 1e-5, "{dealt}");
}

#[test]
fn bad_input_is_a_typed_error() {
    let mut a =
        Approximator::new(vec![0, 1, 1, 0], vec![1.0; 4], 1, 2, Policy::Incremental).unwrap();
    assert!(matches!(
        a.step(&[0.0; 3]),
        Err(WaveletError::LengthMismatch {
            expected: 4,
            got: 3,
            ..
        })
    ));
    assert_eq!(
        a.step(&[0.0, 1.0, f32::NAN, 0.0]),
        Err(WaveletError::NonFinite {
            what: "lighting coefficients",
            index: 2
        })
    );
    assert!(matches!(
        Approximator::new(vec![0; 3], vec![1.0, -1.0, 1.0], 1, 1, Policy::Incremental),
        Err(WaveletError::Invalid { .. })
    ));
    assert!(matches!(
        Approximator::new(vec![0; 3], vec![1.0; 2], 1, 1, Policy::Incremental),
        Err(WaveletError::LengthMismatch { .. })
    ));
    assert!(matches!(
        Approximator::new(vec![0; 3], vec![1.0; 3], 0, 1, Policy::Incremental),
        Err(WaveletError::Invalid { .. })
    ));
}
