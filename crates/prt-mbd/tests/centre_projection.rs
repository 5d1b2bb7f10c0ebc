//! MBD's centre projection: it keeps the solver's basis, changes only the coefficients of the
//! fitted voxels, and leaves no voxel-centre error above the voxel's own magnitude (the
//! solver's coefficients do: dim voxels beside bright ones), weighted or not, masked or not.

use proptest::prelude::*;
use prt_core::{FieldModel, GridField, NoProgress};
use prt_mbd::{Basis, LabelSmoothing, LossWeighting, Mbd, MbdError};

mod common;

/// A sunlit half beside a closed dark one, five orders darker.
fn field(seed: u64) -> GridField {
    common::scaled_noise_field([6, 4, 3], seed, |p| if p.x < 0.5 { 1e-5 } else { 1.0 })
}

fn mbd(projection: bool, weighting: Option<LossWeighting>) -> Mbd {
    let mut mbd = Mbd::new(2, Basis::HatGrid { nodes: [2, 2, 2] });
    mbd.solver.max_iterations = 4;
    mbd.loss_weighting = weighting;
    mbd.centre_projection = projection;
    mbd
}

/// `‖f̂(x_v) − f_v‖` and `‖f_v‖` of every voxel.
fn centre_errors(model: &impl FieldModel, field: &GridField) -> Vec<(f64, f64)> {
    let mut out = vec![0.0f32; field.dim()];
    (0..field.num_voxels())
        .map(|v| {
            model.eval(field.centre_of(v), &mut out).unwrap();
            let f = field.voxel(v);
            let norm = |it: &mut dyn Iterator<Item = f64>| it.map(|x| x * x).sum::<f64>().sqrt();
            let error = norm(&mut out.iter().zip(f).map(|(&a, &b)| f64::from(a - b)));
            (error, norm(&mut f.iter().map(|&x| f64::from(x))))
        })
        .collect()
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(8))]

    #[test]
    fn no_projected_centre_error_exceeds_the_voxels_magnitude(
        seed in 0u64..1000, weighted in any::<bool>(),
        mask in prop::collection::vec(prop::bool::weighted(0.8), 72),
    ) {
        prop_assume!(mask.contains(&true));
        let f = field(seed);
        let weighting = weighted.then(LossWeighting::default);
        for valid in [None, Some(mask.as_slice())] {
            let fit = |projection| {
                let mbd = mbd(projection, weighting);
                match valid {
                    Some(valid) => mbd.fit_masked(&f, valid, &NoProgress),
                    None => mbd.fit(&f, &NoProgress),
                }
                .unwrap()
                .model
            };
            let (plain, projected) = (fit(false), fit(true));
            prop_assert_eq!(plain.basis(), projected.basis());
            for (v, (error, norm)) in centre_errors(&projected, &f).into_iter().enumerate() {
                if valid.is_some_and(|m| !m[v]) {
                    prop_assert_eq!(plain.coefficients().row(v), projected.coefficients().row(v));
                } else {
                    prop_assert!(error <= norm * (1.0 + 1e-4) + 1e-12, "voxel {v}: {error} > {norm}");
                }
            }
        }
    }
}

/// The solver's coefficients break the bound in the field's dark voxels, so the law above is
/// the projection's doing.
#[test]
fn the_solvers_coefficients_exceed_it_in_dark_voxels() {
    let f = field(1);
    let model = mbd(false, None).fit(&f, &NoProgress).unwrap().model;
    let over = centre_errors(&model, &f)
        .into_iter()
        .filter(|&(error, norm)| error > norm * 1.01)
        .count();
    assert!(over > 0, "no voxel over its magnitude");
}

#[test]
fn clustered_kernels_refuse_the_projection() {
    let f = field(2);
    let mut mbd = mbd(true, None);
    mbd.basis = Basis::Clusters {
        count: 3,
        smoothing: LabelSmoothing {
            radius: 1,
            falloff: 0.5,
        },
    };
    assert!(matches!(
        mbd.fit(&f, &NoProgress),
        Err(MbdError::InvalidOption {
            what: "centre_projection",
            ..
        })
    ));
}
