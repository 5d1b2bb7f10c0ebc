//! Laws and extremes of the Shepard kernels, checked against a brute-force evaluation.

use glam::Vec3;
use proptest::prelude::*;
use prt_core::{Aabb, CoreError, KernelWeights, SpatialKernels};
use prt_kernels::{KernelError, Shepard, wendland_c2};

/// The weights by definition, over all kernels, in f64: (index, w) for every covering kernel.
fn brute_force(centres: &[Vec3], radii: &[f32], x: Vec3) -> Vec<(u32, f64)> {
    let phis: Vec<(u32, f64)> = centres
        .iter()
        .zip(radii)
        .enumerate()
        .filter_map(|(i, (&c, &r))| {
            let d = (x.as_dvec3() - c.as_dvec3()).length();
            let phi = wendland_c2(d / r as f64);
            (phi > 0.0).then_some((i as u32, phi))
        })
        .collect();
    let sum: f64 = phis.iter().map(|p| p.1).sum();
    phis.into_iter().map(|(i, p)| (i, p / sum)).collect()
}

fn kernels() -> impl Strategy<Value = (Vec<Vec3>, Vec<f32>)> {
    (1usize..60).prop_flat_map(|n| {
        (
            prop::collection::vec(
                prop::array::uniform3(0.0f32..10.0).prop_map(Vec3::from_array),
                n,
            ),
            prop::collection::vec(0.3f32..4.0, n),
        )
    })
}

/// Compares a Shepard evaluation with the brute force: same covering set (except kernels whose
/// f32 weight rounds to 0), same weights.
fn check_against_brute_force(
    s: &Shepard,
    centres: &[Vec3],
    radii: &[f32],
    x: Vec3,
) -> Result<(), TestCaseError> {
    let mut w = KernelWeights::default();
    let want = brute_force(centres, radii, x);
    match s.eval(x, &mut w) {
        Err(CoreError::Uncovered { point }) => {
            prop_assert_eq!(point, x.to_array());
            prop_assert!(
                want.is_empty(),
                "uncovered, but brute force finds {:?}",
                want
            );
        }
        Err(e) => prop_assert!(false, "unexpected error {e}"),
        Ok(()) => {
            let want: Vec<(u32, f64)> = want.into_iter().filter(|p| p.1 as f32 > 0.0).collect();
            prop_assert_eq!(w.len(), want.len());
            prop_assert!(w.len() <= s.max_support());
            prop_assert!((w.sum() - 1.0).abs() < 1e-5, "sum {}", w.sum());
            for ((i, wi), (j, wj)) in w.iter().zip(&want) {
                prop_assert_eq!(i, *j);
                prop_assert!(wi > 0.0 && wi <= 1.0);
                prop_assert!((wi as f64 - wj).abs() < 1e-6 * (1.0 + wj));
                // Compact support: only kernels whose ball holds x.
                prop_assert!(x.distance(centres[i as usize]) < radii[i as usize] * (1.0 + 1e-6));
            }
        }
    }
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(128))]

    /// Partition of unity, non-negativity, compact support, the support bound and the covering
    /// test, at random points of the domain and just outside it.
    #[test]
    fn matches_brute_force((centres, radii) in kernels(), locals in prop::collection::vec(prop::array::uniform3(-0.1f32..1.1), 20)) {
        let s = Shepard::new(centres.clone(), radii.clone()).unwrap();
        let d = s.domain();
        for local in locals {
            let x = d.min + Vec3::from_array(local) * d.size();
            check_against_brute_force(&s, &centres, &radii, x)?;
        }
        // Every centre is covered, by its own kernel at least.
        let mut w = KernelWeights::default();
        for (i, &c) in centres.iter().enumerate() {
            s.eval(c, &mut w).unwrap();
            prop_assert!(w.indices.contains(&(i as u32)));
        }
    }

    /// Wildly mixed radii (1e-3 .. 1e3): the bucket grid stays within its budget and queries
    /// still find every covering kernel.
    #[test]
    fn mixed_radii((centres, _) in kernels(), exps in prop::collection::vec(-3i32..=3, 60), locals in prop::collection::vec(prop::array::uniform3(0.0f32..1.0), 20)) {
        let radii: Vec<f32> = centres.iter().zip(&exps).map(|(_, &e)| 10f32.powi(e)).collect();
        let s = Shepard::new(centres.clone(), radii.clone()).unwrap();
        prop_assert!(s.bucket_dims().iter().product::<usize>() <= 32 * centres.len() + 4096);
        let d = s.domain();
        for local in locals {
            check_against_brute_force(&s, &centres, &radii, d.min + Vec3::from_array(local) * d.size())?;
        }
        for &c in &centres {
            check_against_brute_force(&s, &centres, &radii, c)?;
        }
    }
}

#[test]
fn wendland_c2_shape() {
    assert_eq!(wendland_c2(0.0), 1.0);
    assert_eq!(wendland_c2(1.0), 0.0);
    assert_eq!(wendland_c2(1.5), 0.0);
    assert_eq!(wendland_c2(-0.1), 0.0);
    assert_eq!(wendland_c2(f64::NAN), 0.0);
    // (1 - t)^4 (4t + 1) at t = 1/2: 1/16 * 3.
    assert_eq!(wendland_c2(0.5), 3.0 / 16.0);
    let ts: Vec<f64> = (0..=1000).map(|i| i as f64 / 1000.0).collect();
    assert!(
        ts.windows(2).all(|t| wendland_c2(t[1]) < wendland_c2(t[0])),
        "strictly decreasing"
    );
    // C2 at the edge of the support: value, slope and curvature all vanish as (1-t)^2 or faster.
    let e = 1e-3;
    assert!(wendland_c2(1.0 - e) < 5.0 * e.powi(4) * 1.01);
}

#[test]
fn a_single_kernel_is_one_inside_and_uncovered_outside() {
    let s = Shepard::with_radius(vec![Vec3::new(1.0, 2.0, 3.0)], 0.5).unwrap();
    assert_eq!((s.len(), s.max_support()), (1, 1));
    assert_eq!(
        s.domain(),
        Aabb::new(Vec3::new(0.5, 1.5, 2.5), Vec3::new(1.5, 2.5, 3.5))
    );
    let mut w = KernelWeights::default();
    s.eval(Vec3::new(1.2, 2.1, 2.9), &mut w).unwrap();
    assert_eq!(
        (w.indices.as_slice(), w.weights.as_slice()),
        (&[0u32][..], &[1.0f32][..])
    );
    // On the sphere of radius R the kernel is 0: a box corner, or a point at distance exactly R.
    for x in [
        Vec3::new(1.5, 2.0, 3.0),
        Vec3::new(0.5, 1.5, 2.5),
        Vec3::new(1.0, 2.0, 3.5),
    ] {
        assert_eq!(
            s.eval(x, &mut w),
            Err(CoreError::Uncovered {
                point: x.to_array()
            }),
            "{x}"
        );
        assert!(w.is_empty());
    }
    // Outside the domain, far away.
    let far = Vec3::new(-1e30, 0.0, 0.0);
    assert_eq!(
        s.eval(far, &mut w),
        Err(CoreError::Uncovered {
            point: far.to_array()
        })
    );
}

#[test]
fn two_kernels_meet_symmetrically() {
    let s = Shepard::with_radius(vec![Vec3::ZERO, Vec3::new(1.0, 0.0, 0.0)], 1.0).unwrap();
    let mut w = KernelWeights::default();
    s.eval(Vec3::new(0.5, 0.2, -0.1), &mut w).unwrap();
    assert_eq!(w.indices, vec![0, 1]);
    assert_eq!(w.weights, vec![0.5, 0.5]);
    // On a centre, the other kernel is exactly zero there (distance = R): weight 1 alone.
    s.eval(Vec3::ZERO, &mut w).unwrap();
    assert_eq!(
        (w.indices.as_slice(), w.weights.as_slice()),
        (&[0u32][..], &[1.0f32][..])
    );
    assert_eq!(s.centre(1), Some(Vec3::X));
    assert_eq!(s.centre(2), None);
}

#[test]
fn a_gap_between_balls_is_uncovered_inside_the_domain() {
    let s = Shepard::with_radius(vec![Vec3::ZERO, Vec3::new(10.0, 0.0, 0.0)], 1.0).unwrap();
    let x = Vec3::new(5.0, 0.0, 0.0);
    assert!(s.domain().contains(x));
    let mut w = KernelWeights::default();
    assert_eq!(
        s.eval(x, &mut w),
        Err(CoreError::Uncovered {
            point: [5.0, 0.0, 0.0]
        })
    );
}

#[test]
fn non_finite_point_is_a_typed_error() {
    let s = Shepard::with_radius(vec![Vec3::ZERO], 1.0).unwrap();
    let mut w = KernelWeights::default();
    assert_eq!(
        s.eval(Vec3::new(0.0, 0.0, f32::NAN), &mut w),
        Err(CoreError::NonFinite {
            what: "query point",
            index: 2
        })
    );
}

#[test]
fn dense_overlap_bound_holds_and_is_computed() {
    // 1000 kernels on a 10^3 lattice of spacing 1, radius 1.5: the bound computed from the
    // buckets must not be below the largest overlap met at any query point.
    let centres: Vec<Vec3> = (0..1000)
        .map(|i| Vec3::new((i % 10) as f32, (i / 10 % 10) as f32, (i / 100) as f32))
        .collect();
    let s = Shepard::with_radius(centres.clone(), 1.5).unwrap();
    let mut w = KernelWeights::default();
    let mut most = 0;
    for i in 0..2000 {
        let x = Vec3::new(
            (i * 37 % 1000) as f32 * 0.009,
            (i * 91 % 1000) as f32 * 0.009,
            (i * 53 % 1000) as f32 * 0.009,
        );
        s.eval(x, &mut w).unwrap();
        assert!((w.sum() - 1.0).abs() < 1e-5);
        most = most.max(w.len());
    }
    assert!(
        most >= 8,
        "a point inside a unit cell is covered by at least its 8 corners"
    );
    assert!(
        s.max_support() >= most && s.max_support() <= 1000,
        "bound {}",
        s.max_support()
    );
}

#[test]
fn invalid_inputs_are_typed_errors() {
    assert_eq!(
        Shepard::new(vec![], vec![]),
        Err(KernelError::Empty {
            what: "Shepard centres"
        })
    );
    assert_eq!(
        Shepard::new(vec![Vec3::ZERO], vec![1.0, 2.0]),
        Err(KernelError::LengthMismatch {
            what: "Shepard radii",
            expected: 1,
            got: 2
        })
    );
    assert_eq!(
        Shepard::new(
            vec![Vec3::ZERO, Vec3::new(f32::NAN, 0.0, 0.0)],
            vec![1.0, 1.0]
        ),
        Err(KernelError::NonFinite {
            what: "centre",
            index: 1
        })
    );
    assert_eq!(
        Shepard::new(vec![Vec3::ZERO, Vec3::ONE], vec![1.0, f32::INFINITY]),
        Err(KernelError::NonFinite {
            what: "radius",
            index: 1
        })
    );
    assert_eq!(
        Shepard::new(vec![Vec3::ZERO, Vec3::ONE], vec![0.0, 1.0]),
        Err(KernelError::InvalidRadius {
            index: 0,
            radius: 0.0
        })
    );
    assert_eq!(
        Shepard::with_radius(vec![Vec3::ZERO], -1.0),
        Err(KernelError::InvalidRadius {
            index: 0,
            radius: -1.0
        })
    );
    // A ball reaching past f32::MAX has no finite bounding box.
    assert!(matches!(
        Shepard::with_radius(vec![Vec3::splat(3e38)], 1e38),
        Err(KernelError::InvalidDomain { .. })
    ));
}

#[test]
fn far_apart_tiny_kernels_keep_the_bucket_grid_small() {
    // Two clusters 1e6 apart with radius 1e-3: a grid at the median radius would need 1e27
    // buckets; the budget coarsens it and queries stay exact.
    let mut centres = vec![Vec3::ZERO, Vec3::splat(1e6)];
    centres.extend((0..50).map(|i| Vec3::new(i as f32 * 1e-3, 0.0, 0.0)));
    let radii = vec![1e-3; centres.len()];
    let s = Shepard::new(centres.clone(), radii.clone()).unwrap();
    assert!(s.bucket_dims().iter().product::<usize>() <= 32 * centres.len() + 4096);
    let mut w = KernelWeights::default();
    s.eval(Vec3::new(0.0105, 0.0, 0.0), &mut w).unwrap();
    assert_eq!(w.indices, vec![12, 13]);
    s.eval(Vec3::splat(1e6), &mut w).unwrap();
    assert_eq!(w.indices, vec![1]);
}
