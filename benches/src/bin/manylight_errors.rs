//! Where the error of row-column sampling comes from, with the sun as an exact column (as in
//! `manylight_scene … exact-sun`): the error image is split into one term per cluster,
//! `e_k = w_k c_rep − Σ_{j∈C_k} c_j`, by evaluating every member of every cluster seen by the rows
//! (the unseen lights' exact sum is the rest of the reference). Besides the realised `‖e_k‖`, the
//! expected squared error of each seen cluster given the rows and the clustering,
//! `Σ_j ‖c_j‖² / p_j − ‖Σ_j c_j‖²`, is computed for the paper's `p_j ∝ ‖ρ_j‖`; for the unseen
//! lights (one uniform draw among `N`) it is estimated from a sample of their columns.
//!
//! `cargo run --release -p prt-benches --bin manylight_errors -- SCENE WIDTH VPLS CLAMP ROWS/COLS [SEEDS] [FIRST_SEED] [UNSEEN_PROBE] [GROUPS]`
//!
//! `GROUPS` (default 1, `UnseenLights::Sample`): the unseen lights are cut into this many groups
//! (`UnseenLights::Groups`); their expected error is then estimated as `N²/k · mean ‖c_j‖² −
//! ‖S‖²/k` (equal groups, equal shares).
//!
//! All norms are printed relative to `‖reference‖`. Costs about the seen lights' columns (a few
//! thousand) per seed on top of the run itself.

use prt_benches::manylight::{Args, Reference, SweepScene};
use prt_core::metrics::relative_frobenius_error;
use prt_core::{MatrixOracle, NoProgress};
use prt_manylight::{RowColumnConfig, UnseenLights, row_column_sampling};

/// Mixture weights λ of the uniform draw in the representatives' probability whose expected
/// error is reported (0: the paper's `p ∝ ‖ρ_j‖`; 1: uniform).
const MIXTURES: [f64; 5] = [0.0, 0.05, 0.2, 0.5, 1.0];

fn norm2(v: &[f64]) -> f64 {
    v.iter().map(|x| x * x).sum()
}

/// The kind of light `j` of the sampled oracle (the sun is not in it).
fn kind(j: usize, vpls: &[prt_trace::Vpl]) -> String {
    match vpls.get(j) {
        Some(v) => format!("bounce {}", v.bounce),
        None => "sky".to_string(),
    }
}

fn main() {
    let args = Args::from_env();
    let scene_name = args.text(0).unwrap_or("sponza");
    let width: usize = args.parsed(1, 256);
    let target: usize = args.parsed(2, 100_000);
    let clamp: f32 = args.parsed(3, 1.58);
    let (rows, cols) = args.budget(4, (400, 1300));
    let seeds: u64 = args.parsed(5, 3);
    let first_seed: u64 = args.parsed(6, 7);
    let probe: usize = args.parsed(7, 500);
    let groups: usize = args.parsed(8, 1);
    let Some(setup) = SweepScene::load(scene_name, width, target) else {
        return;
    };
    let directional = setup.sun_sky();
    let vpls = &setup.vpls;
    let Reference {
        image: reference,
        sun,
        ..
    } = setup.reference(&directional, clamp);
    let n = reference.len() / 3;
    let mut col = vec![0.0f32; 3 * n];
    let ref_norm = reference
        .iter()
        .map(|&v| v as f64 * v as f64)
        .sum::<f64>()
        .sqrt();
    let sampled = setup.oracle(clamp, &directional[1..]);
    let m = sampled.cols();
    // The sampled lights' exact image: reference minus the sun.
    let rest: Vec<f64> = reference
        .iter()
        .zip(&sun)
        .map(|(&r, &s)| r as f64 - s as f64)
        .collect();
    println!(
        "{scene_name} {width}², {m} sampled lights (sun exact), clamp {clamp}, {rows}/{cols}: \
         ‖sampled lights' image‖ / ‖ref‖ = {:.4}",
        norm2(&rest).sqrt() / ref_norm
    );
    let rel = |x: f64| 100.0 * x.max(0.0).sqrt() / ref_norm;

    for seed in first_seed..first_seed + seeds {
        let config = RowColumnConfig::new(rows, cols)
            .with_seed(seed)
            .with_unseen(UnseenLights::Groups(groups.max(1)));
        let estimate = row_column_sampling(&sampled, &config, &NoProgress).expect("estimate");
        let image: Vec<f32> = estimate
            .image
            .iter()
            .zip(&sun)
            .map(|(a, b)| a + b)
            .collect();
        let error = relative_frobenius_error(&image, &reference).expect("same size");
        // Reduced norms of this run's rows.
        let reduced =
            prt_manylight::ReducedMatrix::sample(&sampled, estimate.rows.clone(), &NoProgress)
                .expect("rows");
        let a = reduced.norms();
        let mut seen_sum = vec![0.0f64; 3 * n];
        let mut unseen_estimate = vec![0.0f64; 3 * n];
        // (‖e_k‖², E‖e_k‖², ‖S_k‖, cluster, rep kind) of every seen cluster.
        let mut terms: Vec<(f64, f64, f64, usize, String)> = Vec::new();
        let mut unseen_members: Vec<u32> = Vec::new();
        let mut sum = vec![0.0f64; 3 * n];
        let mut mixture_expected = [0.0f64; MIXTURES.len()];
        for (k, (members, rep)) in estimate
            .clustering
            .clusters()
            .iter()
            .zip(&estimate.representatives)
            .enumerate()
        {
            let total: f64 = members.iter().map(|&j| a[j as usize]).sum();
            if total == 0.0 {
                sampled.eval_col(rep.column, &mut col).expect("column");
                for (u, &c) in unseen_estimate.iter_mut().zip(&col) {
                    *u += rep.weight * c as f64;
                }
                unseen_members.extend_from_slice(members);
                continue;
            }
            sum.fill(0.0);
            let mut inverse_p = 0.0;
            let mut member_c2 = Vec::with_capacity(members.len());
            let mut rep_column = Vec::new();
            for &j in members {
                sampled.eval_col(j as usize, &mut col).expect("column");
                let c2: f64 = col.iter().map(|&v| v as f64 * v as f64).sum();
                member_c2.push((a[j as usize] / total, c2));
                if a[j as usize] > 0.0 {
                    inverse_p += c2 * total / a[j as usize];
                }
                for (s, &v) in sum.iter_mut().zip(&col) {
                    *s += v as f64;
                }
                if j as usize == rep.column {
                    rep_column = col.clone();
                }
            }
            let s2 = norm2(&sum);
            let e2: f64 = sum
                .iter()
                .zip(&rep_column)
                .map(|(s, &c)| (rep.weight * c as f64 - s).powi(2))
                .sum();
            for (t, s) in seen_sum.iter_mut().zip(&sum) {
                *t += s;
            }
            // Expected ‖e_k‖² with the defensive mixture p_j = (1 − λ) a_j / Σa + λ / |C|.
            let size = members.len() as f64;
            for (x, &lambda) in mixture_expected.iter_mut().zip(&MIXTURES) {
                let inverse: f64 = member_c2
                    .iter()
                    .map(|&(q, c2)| c2 / ((1.0 - lambda) * q + lambda / size))
                    .sum();
                *x += inverse - s2;
            }
            terms.push((e2, inverse_p - s2, s2.sqrt(), k, kind(rep.column, vpls)));
        }
        // The unseen lights' exact sum is what the seen clusters leave of the sampled image.
        let unseen_exact: Vec<f64> = rest.iter().zip(&seen_sum).map(|(r, s)| r - s).collect();
        let unseen_e2: f64 = unseen_estimate
            .iter()
            .zip(&unseen_exact)
            .map(|(u, x)| (u - x).powi(2))
            .sum();
        // E‖e‖² of one uniform draw among N unseen lights: N Σ‖c_j‖² − ‖S‖², Σ‖c_j‖² from a
        // probe of evenly spaced members.
        let count = unseen_members.len();
        let step = (count / probe.max(1)).max(1);
        let (mut probe_sq, mut probed, mut lit) = (0.0f64, 0usize, 0usize);
        for &j in unseen_members.iter().step_by(step) {
            sampled.eval_col(j as usize, &mut col).expect("column");
            let c2: f64 = col.iter().map(|&v| v as f64 * v as f64).sum();
            probe_sq += c2;
            probed += 1;
            lit += usize::from(c2 > 0.0);
        }
        let k = groups.clamp(1, count.max(1)) as f64;
        let unseen_expected = (count as f64 * count as f64 * probe_sq / probed.max(1) as f64
            - norm2(&unseen_exact))
            / k;
        let seen_e2: f64 = terms.iter().map(|t| t.0).sum();
        let seen_expected: f64 = terms.iter().map(|t| t.1).sum();
        println!(
            "\nseed {seed}: error {:.2}% | seen clusters: {} realised √Σ‖e_k‖² {:.2}% expected \
             {:.2}% | unseen: {count} lights ({lit} of {probed} probed light a pixel), ‖exact \
             sum‖ {:.2}%, realised {:.2}%, expected {:.2}%",
            100.0 * error,
            terms.len(),
            rel(seen_e2),
            rel(seen_expected),
            rel(norm2(&unseen_exact)),
            rel(unseen_e2),
            rel(unseen_expected),
        );
        for (lambda, x) in MIXTURES.iter().zip(mixture_expected) {
            println!(
                "  seen clusters, expected with p = (1 − {lambda}) ‖ρ_j‖/Σ‖ρ‖ + {lambda}/|C|: {:.2}%",
                rel(x)
            );
        }
        let mut by_kind: std::collections::BTreeMap<String, (f64, f64, usize)> = Default::default();
        for t in &terms {
            let e = by_kind.entry(t.4.clone()).or_default();
            e.0 += t.0;
            e.1 += t.1;
            e.2 += 1;
        }
        for (k, (e2, ex, c)) in &by_kind {
            println!(
                "  clusters with a {k} representative: {c}, realised {:.2}%, expected {:.2}%",
                rel(*e2),
                rel(*ex)
            );
        }
        let mut by_size = [(0.0f64, 0.0f64, 0usize); 5];
        for t in &terms {
            let size = estimate.clustering.clusters()[t.3].len();
            let bin = match size {
                1 => 0,
                2..=4 => 1,
                5..=16 => 2,
                17..=128 => 3,
                _ => 4,
            };
            by_size[bin].0 += t.0;
            by_size[bin].1 += t.1;
            by_size[bin].2 += 1;
        }
        for (label, (e2, ex, c)) in ["1", "2-4", "5-16", "17-128", ">128"].iter().zip(by_size) {
            println!(
                "  clusters of {label} lights: {c}, realised {:.2}%, expected {:.2}%",
                rel(e2),
                rel(ex)
            );
        }
        terms.sort_by(|x, y| y.1.total_cmp(&x.1));
        for t in terms.iter().take(8) {
            let members = &estimate.clustering.clusters()[t.3];
            let rep = estimate.representatives[t.3];
            let sky = members
                .iter()
                .filter(|&&j| j as usize >= vpls.len())
                .count();
            println!(
                "  cluster {}: {} lights ({sky} sky), rep {} weight {:.1}, ‖S_k‖ {:.2}%, \
                 expected {:.2}%, realised {:.2}%",
                t.3,
                members.len(),
                t.4,
                rep.weight,
                100.0 * t.2 / ref_norm,
                rel(t.1),
                rel(t.0)
            );
        }
    }
}
