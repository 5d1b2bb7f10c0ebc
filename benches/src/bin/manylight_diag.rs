//! Where the error of row-column sampling comes from on a VPL scene: which columns carry the
//! heavy tail. For a random sample of VPLs it compares the reduced-column norm on the sampled
//! rows with the full-column norm; for each run it lists the representatives whose weighted
//! column carries the largest share of the image.
//!
//! With `direct`, the sun and sky's directional columns are added (as `manylight_scene` does),
//! and the worst clusters' exact error is measured by evaluating all their members.
//!
//! `cargo run --release -p prt-benches --bin manylight_diag -- SCENE WIDTH VPLS CLAMP ROWS COLS [SEEDS] [direct]`

use prt_benches::manylight::{Args, SweepScene};
use prt_core::metrics::relative_frobenius_error;
use prt_core::{MatrixOracle, NoProgress};
use prt_manylight::{ReducedMatrix, RowColumnConfig, row_column_sampling, stratified_rows};
use rand::SeedableRng;
use rand_pcg::Pcg64Mcg;

fn norm(v: &[f32]) -> f64 {
    v.iter().map(|&x| x as f64 * x as f64).sum::<f64>().sqrt()
}

fn main() {
    let args = Args::from_env();
    let scene_name = args.text(0).unwrap_or("sponza");
    let width: usize = args.parsed(1, 256);
    let target: usize = args.parsed(2, 100_000);
    let clamp: f32 = args.parsed(3, 1.58);
    let rows: usize = args.parsed(4, 100);
    let cols: usize = args.parsed(5, 200);
    let seeds: u64 = args.parsed(6, 3);
    let direct = args.text(7) == Some("direct");
    let Some(setup) = SweepScene::load(scene_name, width, target) else {
        return;
    };
    let directional = if direct { setup.sun_sky() } else { Vec::new() };
    let vpls = &setup.vpls;
    let oracle = setup.oracle(clamp, &directional);
    let (n, m) = (oracle.rows(), oracle.cols());
    let reference = setup.reference(&directional, clamp).image;
    let mut col = vec![0.0f32; 3 * n];
    let ref_norm = norm(&reference);
    let ref_sum: f64 = reference.iter().map(|&v| v as f64).sum();
    println!(
        "{scene_name} {width}² {m} VPLs clamp {clamp}: ‖ref‖ {ref_norm:.4e}, Σref {ref_sum:.4e}"
    );

    // Sampled VPLs: full column vs reduced column on `rows` stratified rows.
    let mut rng = Pcg64Mcg::seed_from_u64(99);
    let sampled_rows = stratified_rows(n, rows, &mut rng);
    let reduced = ReducedMatrix::sample(&oracle, sampled_rows, &NoProgress).expect("rows");
    let probe: Vec<usize> = (0..2000).map(|k| (k * 7919 + 13) % m).collect();
    let mut stats = Vec::new();
    for &j in &probe {
        oracle.eval_col(j, &mut col).expect("column");
        let sum: f64 = col.iter().map(|&v| v as f64).sum();
        let full = norm(&col);
        let nonzero = col.chunks(3).filter(|c| c[0] + c[1] + c[2] > 0.0).count();
        stats.push((j, sum, full, reduced.norms()[j], nonzero));
    }
    let total_sum: f64 = stats.iter().map(|s| s.1).sum();
    let zero_red: Vec<_> = stats.iter().filter(|s| s.3 == 0.0).collect();
    let zero_red_sum: f64 = zero_red.iter().map(|s| s.1).sum();
    println!(
        "probe {} VPLs: {} with zero reduced column carry {:.2}% of their image sum ({} of them non-zero)",
        probe.len(),
        zero_red.len(),
        100.0 * zero_red_sum / total_sum,
        zero_red.iter().filter(|s| s.1 > 0.0).count()
    );
    let scale = (n as f64 / rows as f64).sqrt();
    let mut ratios: Vec<(f64, usize)> = stats
        .iter()
        .filter(|s| s.2 > 0.0)
        .map(|s| (s.3 * scale / s.2, s.0))
        .collect();
    ratios.sort_by(|a, b| a.0.total_cmp(&b.0));
    let q = |p: f64| ratios[((ratios.len() - 1) as f64 * p) as usize].0;
    println!(
        "reduced·sqrt(n/rows) / full norm quantiles: 1% {:.3} 10% {:.3} 50% {:.3} 90% {:.3} 99% {:.3}",
        q(0.01),
        q(0.1),
        q(0.5),
        q(0.9),
        q(0.99)
    );
    let mut by_sum: Vec<_> = stats.clone();
    by_sum.sort_by(|a, b| b.1.total_cmp(&a.1));
    let top: f64 = by_sum.iter().take(20).map(|s| s.1).sum();
    println!(
        "top 1% of probed VPLs carry {:.1}% of the probe's image sum; pixels lit per VPL (median) {}",
        100.0 * top / total_sum,
        {
            let mut lit: Vec<usize> = stats.iter().map(|s| s.4).collect();
            lit.sort_unstable();
            lit[lit.len() / 2]
        }
    );
    for s in by_sum.iter().take(8) {
        let kind = match vpls.get(s.0) {
            Some(v) => format!("bounce {} pos {:?} n {:?}", v.bounce, v.position, v.normal),
            None => "directional".to_string(),
        };
        println!(
            "  light {} {kind} sum {:.3e} ({:.2}% of ref) full {:.3e} reduced·s {:.3e} lit px {}",
            s.0,
            s.1,
            100.0 * s.1 / ref_sum,
            s.2,
            s.3 * scale,
            s.4
        );
    }

    for seed in 0..seeds {
        let config = RowColumnConfig::new(rows, cols).with_seed(seed + 7);
        let estimate = row_column_sampling(&oracle, &config, &NoProgress).expect("estimate");
        let err = relative_frobenius_error(&estimate.image, &reference).expect("same size");
        let mut shares: Vec<(f64, usize)> = Vec::new();
        for (k, rep) in estimate.representatives.iter().enumerate() {
            oracle.eval_col(rep.column, &mut col).expect("column");
            let s: f64 = col.iter().map(|&v| v as f64).sum::<f64>() * rep.weight;
            shares.push((s / ref_sum, k));
        }
        shares.sort_by(|a, b| b.0.total_cmp(&a.0));
        println!(
            "seed {}: error {:.2}%, estimate sum / ref sum {:.3}",
            seed + 7,
            100.0 * err,
            estimate.image.iter().map(|&v| v as f64).sum::<f64>() / ref_sum
        );
        let red = ReducedMatrix::sample(&oracle, estimate.rows.clone(), &NoProgress).expect("rows");
        if direct {
            let sun = vpls.len() as u32;
            for (k, members) in estimate.clustering.clusters().iter().enumerate() {
                if members.contains(&sun) {
                    let total: f64 = members.iter().map(|&j| red.norms()[j as usize]).sum();
                    println!(
                        "  the sun's cluster {k}: {} members, Σ reduced norms {total:.3e}, sun's {:.3e}, representative {:?}",
                        members.len(),
                        red.norms()[sun as usize],
                        estimate.representatives.get(k)
                    );
                }
            }
        }
        for &(share, k) in shares.iter().take(5) {
            let rep = estimate.representatives[k];
            let members = &estimate.clustering.clusters()[k];
            let kind = match vpls.get(rep.column) {
                Some(v) => format!("bounce {} pos {:?}", v.bounce, v.position),
                None => format!("directional {}", rep.column - vpls.len()),
            };
            // The cluster's exact contribution and the error of its weighted representative.
            let cluster_error = (members.len() <= 4000).then(|| {
                let mut exact = vec![0.0f64; 3 * n];
                for &j in members {
                    oracle.eval_col(j as usize, &mut col).expect("column");
                    for (e, &c) in exact.iter_mut().zip(&col) {
                        *e += c as f64;
                    }
                }
                oracle.eval_col(rep.column, &mut col).expect("column");
                let err: f64 = exact
                    .iter()
                    .zip(&col)
                    .map(|(e, &c)| (rep.weight * c as f64 - e).powi(2))
                    .sum::<f64>()
                    .sqrt();
                let directional_members = members
                    .iter()
                    .filter(|&&j| j as usize >= vpls.len())
                    .count();
                format!(
                    "cluster error {:.2}% of ‖ref‖, {directional_members} directional members",
                    100.0 * err / ref_norm
                )
            });
            println!(
                "  rep {} share {:.1}% weight {:.1} cluster {} reduced norm {:.3e} {kind} {}",
                rep.column,
                100.0 * share,
                rep.weight,
                rep.cluster_size,
                red.norms()[rep.column],
                cluster_error.unwrap_or_default()
            );
        }
    }
}
