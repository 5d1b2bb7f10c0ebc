//! A masked fit sees the valid voxels only.

use proptest::prelude::*;
use prt_core::{Aabb, GridField, NoProgress};
use prt_mbd::{Basis, Mbd, MbdError, SyntheticField};

fn mbd() -> Mbd {
    let mut mbd = Mbd::new(2, Basis::HatGrid { nodes: [2, 3, 2] });
    mbd.solver.max_iterations = 4;
    mbd
}

fn field() -> GridField {
    SyntheticField::new([6, 5, 4], 6)
        .build(Aabb::UNIT)
        .expect("synthetic field")
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(12))]
    /// Whatever the invalid voxels hold, the fit is the same, bit for bit; coefficient kernels
    /// no valid voxel's sample reaches (none within one voxel) stay exactly zero.
    #[test]
    fn changing_invalid_voxels_does_not_change_the_fit(
        mask in prop::collection::vec(prop::bool::weighted(0.6), 120),
        junk in -50f32..50.0,
    ) {
        prop_assume!(mask.contains(&true));
        let field = field();
        let mut other = field.clone();
        for (v, mut row) in other.data_mut().outer_iter_mut().enumerate() {
            if !mask[v] {
                row.iter_mut().enumerate().for_each(|(k, x)| *x = junk + k as f32);
            }
        }
        let a = mbd().fit_masked(&field, &mask, &NoProgress).expect("fit");
        let b = mbd().fit_masked(&other, &mask, &NoProgress).expect("fit");
        prop_assert_eq!(a.model.coefficients(), b.model.coefficients());
        prop_assert_eq!(a.model.basis(), b.model.basis());
        let dims = field.dims();
        for m in 0..field.num_voxels() {
            let c = [m % dims[0], (m / dims[0]) % dims[1], m / (dims[0] * dims[1])];
            let near_valid = (0..field.num_voxels()).any(|v| {
                let d = [v % dims[0], (v / dims[0]) % dims[1], v / (dims[0] * dims[1])];
                mask[v] && (0..3).all(|k| c[k].abs_diff(d[k]) <= 1)
            });
            if !near_valid {
                prop_assert!(a.model.coefficients().row(m).iter().all(|&x| x == 0.0), "kernel {}", m);
            }
        }
    }
}

#[test]
fn a_masked_fit_refuses_what_it_cannot_do() {
    let field = field();
    let mask = vec![true; field.num_voxels()];
    assert!(matches!(
        mbd().fit_masked(&field, &mask[1..], &NoProgress),
        Err(MbdError::ShapeMismatch { .. })
    ));
    assert!(matches!(
        mbd().fit_masked(&field, &vec![false; field.num_voxels()], &NoProgress),
        Err(MbdError::InvalidOption { .. })
    ));
    let mut polished = mbd();
    polished.polish = Some(Default::default());
    assert!(polished.fit_masked(&field, &mask, &NoProgress).is_err());
}

#[test]
fn the_masked_fit_is_close_to_the_full_fit_where_every_voxel_is_valid() {
    let field = field();
    let full = mbd().fit(&field, &NoProgress).expect("fit");
    let masked = mbd()
        .fit_masked(&field, &vec![true; field.num_voxels()], &NoProgress)
        .expect("fit");
    let diff = (full.model.basis() - masked.model.basis())
        .iter()
        .fold(0f32, |m, &x| m.max(x.abs()));
    assert!(diff < 1e-3, "{diff}");
}

#[test]
fn masked_clustered_pca_ignores_invalid_voxels() {
    let field = field();
    let mask: Vec<bool> = (0..field.num_voxels()).map(|v| v % 3 != 0).collect();
    let mut other = field.clone();
    for (v, mut row) in other.data_mut().outer_iter_mut().enumerate() {
        if !mask[v] {
            row.fill(7.0);
        }
    }
    let cpca = prt_mbd::ClusteredPca::new(2, 4);
    let a = cpca
        .compress_masked(&field, &mask, &NoProgress)
        .expect("cpca");
    let b = cpca
        .compress_masked(&other, &mask, &NoProgress)
        .expect("cpca");
    assert_eq!(a.bases(), b.bases());
    assert_eq!(a.coefficients(), b.coefficients());
    for v in (0..mask.len()).filter(|&v| !mask[v]) {
        assert!(a.coefficients().row(v).iter().all(|&c| c == 0.0));
    }
}
