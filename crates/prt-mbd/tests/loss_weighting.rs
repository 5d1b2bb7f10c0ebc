//! The loss weighting: its weights are scale-free and bounded, and undoing it is exact at the
//! voxel centres (a weighted fit is the fit of the weighted field with each voxel's
//! coefficients divided by its weight), for MBD and for the PCA baselines; weighted BPCA
//! minimises the weighted loss.

use proptest::prelude::*;
use prt_core::Compressor;
use prt_core::{FieldModel, GridField, NoProgress};
use prt_mbd::{Basis, BlockPca, ClusteredPca, LossWeighting, Mbd, MbdError, PiecewisePcaModel};

mod common;

fn mbd(weighting: Option<LossWeighting>) -> Mbd {
    let mut mbd = Mbd::new(2, Basis::HatGrid { nodes: [2, 3, 2] });
    mbd.solver.max_iterations = 4;
    mbd.loss_weighting = weighting;
    mbd
}

/// A field whose voxel magnitudes span several orders (a sunlit corner and a dark one).
fn field(seed: u64) -> GridField {
    common::scaled_noise_field([5, 4, 3], seed, |p| 10f32.powf(3.0 * p.x - 1.5))
}

fn centre(field: &GridField, v: usize) -> prt_core::glam::Vec3 {
    let dims = field.dims();
    let c = [
        v % dims[0],
        (v / dims[0]) % dims[1],
        v / (dims[0] * dims[1]),
    ];
    field.bounds().min
        + prt_core::glam::Vec3::from_array(c.map(|i| i as f32 + 0.5)) * field.voxel_size()
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(12))]

    #[test]
    fn weights_are_scale_free_and_bounded(
        seed in 0u64..1000, exponent in 0.0f32..2.0, floor in 0.01f32..1.0, scale in 1e-3f32..1e3,
    ) {
        let weighting = LossWeighting { exponent, floor };
        let f = field(seed);
        let mut scaled = f.clone();
        scaled.data_mut().iter_mut().for_each(|x| *x *= scale);
        let (a, b) = (weighting.weights(&f, None).unwrap(), weighting.weights(&scaled, None).unwrap());
        for (x, y) in a.iter().zip(&b) {
            prop_assert!((x - y).abs() <= 1e-3 * x.abs(), "{x} vs {y}");
            // No voxel weighs more than the floor allows.
            prop_assert!(*x > 0.0 && *x <= floor.powf(-exponent) * 1.0001);
        }
    }

    /// At every voxel centre the weighted fit reconstructs the weighted field's fit divided by
    /// the voxel's weight.
    #[test]
    fn undoing_the_weighting_is_exact_at_voxel_centres(
        seed in 0u64..1000, exponent in 0.0f32..1.5,
        mask in prop::collection::vec(prop::bool::weighted(0.8), 60),
    ) {
        prop_assume!(mask.contains(&true));
        let f = field(seed);
        let weighting = LossWeighting { exponent, floor: 0.05 };
        let weights = weighting.weights(&f, Some(&mask)).unwrap();
        let mut weighted = f.clone();
        for (v, &w) in weights.iter().enumerate() {
            weighted.voxel_mut(v).iter_mut().for_each(|x| *x *= w);
        }
        let direct = mbd(Some(weighting)).fit_masked(&f, &mask, &NoProgress).unwrap().model;
        let plain = mbd(None).fit_masked(&weighted, &mask, &NoProgress).unwrap().model;
        prop_assert_eq!(direct.basis(), plain.basis());
        let (mut a, mut b) = (vec![0.0; 7], vec![0.0; 7]);
        for v in 0..f.num_voxels() {
            let x = centre(&f, v);
            direct.eval(x, &mut a).unwrap();
            plain.eval(x, &mut b).unwrap();
            for (p, q) in a.iter().zip(&b) {
                let want = q / weights[v];
                prop_assert!((p - want).abs() <= 1e-4 * (1.0 + want.abs()), "voxel {v}: {p} vs {want}");
            }
        }
    }
}

/// `Σ_v w_v² ‖f̂_v − f_v‖²` of a piecewise PCA model on `field`.
fn weighted_loss(model: &PiecewisePcaModel, field: &GridField, weights: &[f32]) -> f64 {
    let recon = model.reconstruct().unwrap();
    (0..field.num_voxels())
        .map(|v| {
            let w = f64::from(weights[v]).powi(2);
            field
                .voxel(v)
                .iter()
                .zip(recon.voxel(v))
                .map(|(&a, &b)| w * (f64::from(a) - f64::from(b)).powi(2))
                .sum::<f64>()
        })
        .sum()
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(12))]

    /// Weighted BPCA and CPCA are the paper's methods on the weighted field, each voxel's
    /// coefficients divided by its weight: their reconstruction is the weighted fit's divided back.
    #[test]
    fn weighted_baselines_undo_the_weighting_exactly(seed in 0u64..1000, exponent in 0.0f32..1.5) {
        let f = field(seed);
        let weighting = LossWeighting { exponent, floor: 0.05 };
        let weights = weighting.weights(&f, None).unwrap();
        let mut weighted = f.clone();
        for (v, &w) in weights.iter().enumerate() {
            weighted.voxel_mut(v).iter_mut().for_each(|x| *x *= w);
        }
        let bpca = |loss_weighting| BlockPca { rank: 2, blocks: [2, 2, 1], window: 1.0, loss_weighting };
        let cpca = |loss_weighting| ClusteredPca { seed, loss_weighting, ..ClusteredPca::new(2, 3) };
        let pairs = [
            (bpca(Some(weighting)).compress(&f, &NoProgress).unwrap(), bpca(None).compress(&weighted, &NoProgress).unwrap()),
            (cpca(Some(weighting)).compress(&f, &NoProgress).unwrap(), cpca(None).compress(&weighted, &NoProgress).unwrap()),
        ];
        for (direct, plain) in &pairs {
            prop_assert_eq!(direct.labels(), plain.labels());
            prop_assert_eq!(direct.bases(), plain.bases());
            let (a, b) = (direct.reconstruct().unwrap(), plain.reconstruct().unwrap());
            for v in 0..f.num_voxels() {
                for (p, q) in a.voxel(v).iter().zip(b.voxel(v)) {
                    let want = q / weights[v];
                    prop_assert!((p - want).abs() <= 1e-4 * (1.0 + want.abs()), "voxel {v}: {p} vs {want}");
                }
            }
        }
    }

    /// Each block's weighted subspace is the best rank-L subspace for the weighted loss, so
    /// weighted BPCA's weighted loss is never above the paper's BPCA's.
    #[test]
    fn weighted_bpca_minimises_the_weighted_loss(seed in 0u64..1000, exponent in 0.2f32..1.5) {
        let f = field(seed);
        let weighting = LossWeighting { exponent, floor: 0.05 };
        let weights = weighting.weights(&f, None).unwrap();
        let bpca = |loss_weighting| BlockPca { rank: 2, blocks: [2, 1, 1], window: 1.0, loss_weighting };
        let weighted = weighted_loss(&bpca(Some(weighting)).compress(&f, &NoProgress).unwrap(), &f, &weights);
        let plain = weighted_loss(&bpca(None).compress(&f, &NoProgress).unwrap(), &f, &weights);
        prop_assert!(weighted <= plain * (1.0 + 1e-4) + 1e-9, "{weighted} > {plain}");
    }
}

#[test]
fn bad_weighting_options_are_refused() {
    let f = field(1);
    for weighting in [
        LossWeighting {
            exponent: -1.0,
            floor: 0.05,
        },
        LossWeighting {
            exponent: f32::NAN,
            floor: 0.05,
        },
        LossWeighting {
            exponent: 1.0,
            floor: 0.0,
        },
        LossWeighting {
            exponent: 1.0,
            floor: 2.0,
        },
    ] {
        assert!(matches!(
            mbd(Some(weighting)).fit(&f, &NoProgress),
            Err(MbdError::InvalidOption { .. })
        ));
    }
}
