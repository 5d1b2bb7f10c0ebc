//! `WallAware` / `wall_aware_basis`: hat basis kernels cut back at walls.

use glam::Vec3;
use proptest::prelude::*;
use prt_core::{
    Aabb, CoreError, FieldModel, GridField, KernelWeights, NoProgress, SpatialKernels,
    resample_to_grid,
};
use prt_kernels::HatGrid;
use prt_mbd::*;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

mod common;
use common::dense;

fn bounds() -> Aabb {
    Aabb::new(Vec3::new(-1.0, 0.5, 2.0), Vec3::new(2.0, 1.5, 2.8))
}

/// A random mask with about `invalid` of the voxels invalid and at least one valid.
fn random_mask(n: usize, invalid: f64, seed: u64) -> Vec<bool> {
    let mut rng = Pcg64Mcg::seed_from_u64(seed);
    let mut valid: Vec<bool> = (0..n).map(|_| rng.random::<f64>() >= invalid).collect();
    valid[rng.random_range(0..n)] = true;
    valid
}

/// The family over a hat grid spanning the field's whole box (nodes on its faces), whose node
/// positions the wall tests below are laid out around.
fn whole_box_family(
    field: &GridField,
    valid: &[bool],
    nodes: [usize; 3],
    options: &WallOptions,
) -> WallAware<HatGrid> {
    let hat = HatGrid::new(nodes, field.bounds()).unwrap();
    WallAware::from_hat(hat, field.dims(), field.bounds(), valid, options).unwrap()
}

fn zero_field(dims: [usize; 3]) -> GridField {
    GridField::new(dims, bounds(), 1).unwrap()
}

fn dims_strategy() -> impl Strategy<Value = [usize; 3]> {
    [1usize..7, 1usize..7, 1usize..7]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(24))]

    /// At random points of (and slightly beyond) the box, for random masks: non-negative
    /// weights summing to one, kernel indices in range, at most `max_support` of them.
    #[test]
    fn partition_of_unity_and_non_negative(
        dims in dims_strategy(),
        nodes in [2usize..5, 2usize..5, 2usize..5],
        invalid in 0.0f64..0.9,
        seed in 0u64..1000,
    ) {
        let field = zero_field(dims);
        let valid = random_mask(field.num_voxels(), invalid, seed);
        let basis = wall_aware_basis(&field, &valid, nodes, &WallOptions::default()).unwrap();
        prop_assert_eq!(basis.len(), nodes.iter().product::<usize>());
        let mut rng = Pcg64Mcg::seed_from_u64(seed ^ 7);
        let b = bounds();
        let mut w = KernelWeights::default();
        for _ in 0..64 {
            let t = Vec3::new(rng.random(), rng.random(), rng.random()) * 1.1 - 0.05;
            basis.eval(b.min + t * b.size(), &mut w).unwrap();
            prop_assert!(!w.is_empty() && w.len() <= basis.max_support());
            prop_assert!(w.weights.iter().all(|&x| x >= 0.0));
            prop_assert!(w.indices.iter().all(|&i| (i as usize) < basis.len()));
            prop_assert!((w.sum() - 1.0).abs() < 1e-5, "sum {}", w.sum());
        }
    }

    /// The weights are continuous: on either side of a voxel-centre plane (where the blended
    /// voxels change) and of a basis-node plane they agree to within the step times the
    /// largest slope (one unit of weight per voxel).
    #[test]
    fn weights_are_continuous_across_cell_boundaries(
        dims in [2usize..7, 2usize..7, 2usize..7],
        nodes in [2usize..5, 2usize..5, 2usize..5],
        invalid in 0.0f64..0.7,
        seed in 0u64..1000,
        axis in 0usize..3,
    ) {
        let field = zero_field(dims);
        let valid = random_mask(field.num_voxels(), invalid, seed);
        let basis = wall_aware_basis(&field, &valid, nodes, &WallOptions::default()).unwrap();
        let b = bounds();
        let voxel = field.voxel_size();
        let mut rng = Pcg64Mcg::seed_from_u64(seed ^ 11);
        let step = 1e-4 * voxel[axis];
        for i in 0..dims[axis] {
            let mut x = b.min + Vec3::new(rng.random(), rng.random(), rng.random()) * b.size();
            // A voxel-centre plane, then the node plane nearest it.
            for plane in [
                b.min[axis] + (i as f32 + 0.5) * voxel[axis],
                b.min[axis] + (i as f32 / dims[axis] as f32 * (nodes[axis] - 1) as f32).round()
                    / (nodes[axis] - 1) as f32 * b.size()[axis],
            ] {
                x[axis] = plane;
                let (mut lo, mut hi) = (x, x);
                lo[axis] -= step;
                hi[axis] += step;
                let (wl, wh) = (dense(&basis, lo), dense(&basis, hi));
                let jump = wl.iter().zip(&wh).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
                prop_assert!(jump < 1e-3, "jump {jump} at {x:?} (axis {axis})");
            }
        }
    }

    /// With every voxel valid the family is the hat grid at every voxel centre.
    #[test]
    fn all_valid_is_the_hat_grid_at_voxel_centres(
        dims in dims_strategy(),
        nodes in [2usize..5, 2usize..5, 2usize..5],
    ) {
        let field = zero_field(dims);
        let valid = vec![true; field.num_voxels()];
        let basis = whole_box_family(&field, &valid, nodes, &WallOptions::default());
        prop_assert_eq!(basis.fallbacks(), 0);
        let hat = HatGrid::new(nodes, field.bounds()).unwrap();
        for v in 0..field.num_voxels() {
            let x = field.centre_of(v);
            for (a, b) in dense(&basis, x).iter().zip(dense(&hat, x)) {
                prop_assert!((a - b).abs() < 1e-6);
            }
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(16))]

    /// The support cells batch well: with basis nodes at least one voxel apart, the kernels
    /// non-zero anywhere in one cell are at most 27 (3 node planes per axis), for `Mbd`'s hat
    /// (over the box of the voxel centres) and a hat over the field's box (`from_hat`), and the
    /// latter is a partition of unity too.
    #[test]
    fn support_cells_share_few_kernels(
        dims in [2usize..9, 2usize..9, 2usize..9],
        nodes in [2usize..5, 2usize..5, 2usize..5],
        invalid in 0.0f64..0.6,
        seed in 0u64..1000,
    ) {
        let nodes = [0, 1, 2].map(|k| nodes[k].min(dims[k]));
        let field = zero_field(dims);
        let valid = random_mask(field.num_voxels(), invalid, seed);
        let options = WallOptions::default();
        let whole_box = HatGrid::new(nodes, field.bounds()).unwrap();
        let families = [
            wall_aware_basis(&field, &valid, nodes, &options).unwrap(),
            WallAware::from_hat(whole_box, dims, field.bounds(), &valid, &options).unwrap(),
        ];
        let b = bounds();
        let mut rng = Pcg64Mcg::seed_from_u64(seed);
        let mut w = KernelWeights::default();
        for basis in &families {
            let cells = basis.num_support_cells();
            prop_assert!(cells > 0);
            let mut union: Vec<Vec<u32>> = vec![Vec::new(); cells];
            for _ in 0..400 {
                let x = b.min + Vec3::new(rng.random(), rng.random(), rng.random()) * b.size();
                let cell = basis.support_cell(x).unwrap();
                prop_assert!(cell < cells);
                basis.eval(x, &mut w).unwrap();
                prop_assert!((w.sum() - 1.0).abs() < 1e-5);
                for &i in &w.indices {
                    if !union[cell].contains(&i) {
                        union[cell].push(i);
                    }
                }
            }
            prop_assert!(union.iter().all(|u| u.len() <= 27));
        }
    }
}

/// Where the hat grid's node planes pass through voxel centres (5 and 9 voxels, 3 nodes), the
/// hat is trilinear inside every voxel-centre cell, so with every voxel valid the family equals
/// it everywhere inside the box of voxel centres.
#[test]
fn all_valid_equals_the_hat_grid_between_voxel_centres_too() {
    let field = zero_field([5, 9, 5]);
    let valid = vec![true; field.num_voxels()];
    let basis = wall_aware_basis(&field, &valid, [3, 3, 3], &WallOptions::default()).unwrap();
    let hat = HatGrid::new([3, 3, 3], basis_box(&field)).unwrap();
    let inner = voxel_centre_box(&field);
    let mut rng = Pcg64Mcg::seed_from_u64(3);
    for _ in 0..500 {
        let x = inner.min + Vec3::new(rng.random(), rng.random(), rng.random()) * inner.size();
        for (a, b) in dense(&basis, x).iter().zip(dense(&hat, x)) {
            assert!((a - b).abs() < 1e-5, "{a} vs {b} at {x:?}");
        }
    }
}

/// A 10 × 2 × 2 grid with a one-voxel wall at x = 5 and 3 × 2 × 2 hat nodes (x at 0, 5, 10
/// voxels): the middle nodes sit on the wall's face towards x < 5, whose valid voxels are
/// nearer, so they serve that side only; at x ≥ 6 only the nodes at x = 10 remain, although
/// the hat gives the middle nodes 0.7 at the first voxel there.
#[test]
fn a_node_does_not_reach_across_a_wall() {
    let dims = [10, 2, 2];
    let field = zero_field(dims);
    let valid: Vec<bool> = (0..field.num_voxels()).map(|v| v % 10 != 5).collect();
    let basis = whole_box_family(&field, &valid, [3, 2, 2], &WallOptions::default());
    assert_eq!(basis.fallbacks(), 0);
    let hat = HatGrid::new([3, 2, 2], field.bounds()).unwrap();
    let middle: Vec<usize> = (0..12).filter(|i| i % 3 == 1).collect();
    for v in 0..field.num_voxels() {
        let x = field.centre_of(v);
        let (w, h) = (dense(&basis, x), dense(&hat, x));
        let mid: f64 = middle.iter().map(|&i| w[i]).sum();
        let mid_hat: f64 = middle.iter().map(|&i| h[i]).sum();
        match v % 10 {
            6..=9 => {
                assert_eq!(mid, 0.0, "voxel {v}");
                assert!(mid_hat > 0.0);
            }
            // Left of the wall nothing is cut: the same weights as the hat.
            0..=4 => assert!((mid - mid_hat).abs() < 1e-6, "voxel {v}"),
            _ => {}
        }
    }
    // Between voxel centres on the far side too (the wall voxel's own weights are those of
    // the nodes reaching its valid neighbours, so the cut holds from its centre on).
    let b = field.bounds();
    for t in [0.56f32, 0.6, 0.75, 0.9, 0.99] {
        let x = Vec3::new(b.min.x + t * b.size().x, b.centre().y, b.centre().z);
        let w = dense(&basis, x);
        let mid: f64 = middle.iter().map(|&i| w[i]).sum();
        if t >= 0.65 {
            assert_eq!(mid, 0.0, "t = {t}");
        } else {
            assert!(mid < 0.9, "t = {t}");
        }
    }
}

/// Reaching around a wall with an opening: with the default (unlimited detour) a node
/// reaches the far side through the gap; with `max_detour = 1` the voxels it reaches only by a
/// long way round are cut.
#[test]
fn detour_limit_cuts_what_is_only_reached_around_a_wall() {
    let dims = [10, 6, 1];
    let field = zero_field(dims);
    // Wall at x = 6 for y < 5, open at y = 5. Hat nodes at x = 0, 5, 10 voxels, y = 0, 6.
    let valid: Vec<bool> = (0..field.num_voxels())
        .map(|v| !(v % 10 == 6 && (v / 10) % 6 < 5))
        .collect();
    let options = |max_detour| WallOptions {
        max_detour,
        ..WallOptions::default()
    };
    let open = whole_box_family(&field, &valid, [3, 2, 2], &options(f32::INFINITY));
    let strict = whole_box_family(&field, &valid, [3, 2, 2], &options(1.0));
    let support = |k: &WallAware<HatGrid>| -> usize {
        (0..field.num_voxels())
            .map(|v| k.voxel_weights(v).count())
            .sum()
    };
    assert!(support(&strict) < support(&open));
    // The middle nodes at y = 0 (indices 1 and 7, one per z node) start from voxels (4..=5, 0);
    // voxel (8, 0) is 3 steps away in a straight line and 13 around the wall.
    let v = 8;
    let low_middle = |k: &WallAware<HatGrid>| {
        k.voxel_weights(v)
            .filter(|(i, _)| *i == 1 || *i == 7)
            .count()
    };
    assert_eq!(low_middle(&open), 2);
    assert_eq!(low_middle(&strict), 0);
}

/// Line of sight: around the same wall, a voxel the flood fill reaches through the opening
/// but cannot see in a straight line from the node's seeds is cut; with every voxel valid
/// nothing is.
#[test]
fn line_of_sight_cuts_what_a_node_cannot_see() {
    let dims = [10, 6, 1];
    let field = zero_field(dims);
    let valid: Vec<bool> = (0..field.num_voxels())
        .map(|v| !(v % 10 == 6 && (v / 10) % 6 < 5))
        .collect();
    let sight = WallOptions {
        line_of_sight: true,
        ..WallOptions::default()
    };
    let seen = whole_box_family(&field, &valid, [3, 2, 2], &sight);
    // Voxel (8, 0): the middle nodes at y = 0 (indices 1, 7) see it only through the wall.
    assert_eq!(
        seen.voxel_weights(8)
            .filter(|(i, _)| *i == 1 || *i == 7)
            .count(),
        0
    );
    // Their own side stays: voxel (2, 0).
    assert_eq!(
        seen.voxel_weights(2)
            .filter(|(i, _)| *i == 1 || *i == 7)
            .count(),
        2
    );
    let all = vec![true; field.num_voxels()];
    let open = whole_box_family(&field, &all, [3, 2, 2], &sight);
    let hat = HatGrid::new([3, 2, 2], field.bounds()).unwrap();
    for v in 0..field.num_voxels() {
        let x = field.centre_of(v);
        for (a, b) in dense(&open, x).iter().zip(dense(&hat, x)) {
            assert!((a - b).abs() < 1e-6);
        }
    }
}

/// One valid voxel in a 5 × 4 × 3 grid, with more basis nodes than voxels on two axes: the
/// nodes whose support holds it serve it (and the invalid voxels next to it), the weights stay
/// a partition of unity everywhere, and no valid voxel falls back.
#[test]
fn a_single_valid_voxel() {
    let field = zero_field([5, 4, 3]);
    let mut valid = vec![false; field.num_voxels()];
    let only = field.index(2, 1, 1);
    valid[only] = true;
    let nodes = [3, 6, 5];
    let basis = wall_aware_basis(&field, &valid, nodes, &WallOptions::default()).unwrap();
    assert_eq!(basis.fallbacks(), 0);
    let hat = HatGrid::new(nodes, basis_box(&field)).unwrap();
    let x = field.centre_of(only);
    for (a, b) in dense(&basis, x).iter().zip(dense(&hat, x)) {
        assert!((a - b).abs() < 1e-6);
    }
    let b = bounds();
    let mut rng = Pcg64Mcg::seed_from_u64(1);
    let mut w = KernelWeights::default();
    for _ in 0..200 {
        let p = b.min + Vec3::new(rng.random(), rng.random(), rng.random()) * b.size();
        basis.eval(p, &mut w).unwrap();
        assert!((w.sum() - 1.0).abs() < 1e-5);
        assert!(w.weights.iter().all(|&x| x >= 0.0));
    }
}

#[test]
fn typed_errors() {
    let field = zero_field([4, 3, 2]);
    let n = field.num_voxels();
    let options = WallOptions::default();
    assert!(matches!(
        wall_aware_basis(&field, &vec![true; n - 1], [2, 2, 2], &options),
        Err(MbdError::ShapeMismatch { .. })
    ));
    assert!(matches!(
        wall_aware_basis(&field, &vec![false; n], [2, 2, 2], &options),
        Err(MbdError::InvalidOption {
            what: "validity mask",
            ..
        })
    ));
    assert!(matches!(
        wall_aware_basis(&field, &vec![true; n], [2, 1, 2], &options),
        Err(MbdError::InvalidKernels { .. })
    ));
    for max_detour in [0.0, -1.0, f32::NAN] {
        assert!(matches!(
            wall_aware_basis(
                &field,
                &vec![true; n],
                [2, 2, 2],
                &WallOptions {
                    max_detour,
                    ..WallOptions::default()
                }
            ),
            Err(MbdError::InvalidOption {
                what: "max_detour",
                ..
            })
        ));
    }
    let hat = HatGrid::new([2, 2, 2], field.bounds()).unwrap();
    assert!(matches!(
        WallAware::new(hat.clone(), [0, 3, 2], field.bounds(), &[], &options),
        Err(MbdError::InvalidOption { what: "dims", .. })
    ));
    // A base that leaves voxel centres uncovered.
    let far = prt_kernels::Shepard::with_radius(vec![Vec3::splat(100.0)], 1.0).unwrap();
    assert!(matches!(
        WallAware::new(far, field.dims(), field.bounds(), &vec![true; n], &options),
        Err(MbdError::KernelsDoNotCover { .. })
    ));
    let basis = wall_aware_basis(&field, &vec![true; n], [2, 2, 2], &options).unwrap();
    let mut w = KernelWeights::default();
    assert!(matches!(
        basis.eval(Vec3::new(0.0, f32::NAN, 0.0), &mut w),
        Err(CoreError::NonFinite { index: 1, .. })
    ));
}

/// Relative squared error of `model` at the valid voxel centres.
fn valid_centre_error(model: &dyn FieldModel, field: &GridField, valid: &[bool]) -> f64 {
    let recon = resample_to_grid(model, field.dims(), field.bounds()).unwrap();
    let (mut error, mut energy) = (0.0, 0.0);
    for v in (0..field.num_voxels()).filter(|&v| valid[v]) {
        for (&a, &b) in field.voxel(v).iter().zip(recon.voxel(v)) {
            error += (f64::from(a) - f64::from(b)).powi(2);
            energy += f64::from(a).powi(2);
        }
    }
    error / energy
}

/// Left of a one-voxel wall (x < 5 of 10) the field is rank 1 along a direction that turns
/// linearly from e1 to e2; right of it, along e3. A rank-1 hat basis cannot fit this at the
/// valid voxel centres: on each side `b(x)` is affine in x and must be parallel to the field at
/// ≥ 4 voxel centres, which forces it parallel everywhere on the side; the middle node's
/// vector would then be parallel to e2 (left) and to e3 (right), so zero, and the left side's
/// basis `(1 − s) B_0` could not turn. The wall-aware basis serves the right side by the nodes
/// at x = 10 alone, and fits the valid voxel centres exactly (the exact per-voxel solves of
/// `solve_als` show it; between the wall and its neighbours no rank-1 model is exact).
#[test]
fn different_content_on_either_side_of_a_wall_is_fitted_far_better() {
    let dims = [10, 2, 2];
    let bounds = Aabb::new(Vec3::ZERO, Vec3::new(10.0, 2.0, 2.0));
    let field = GridField::from_fn(dims, bounds, 3, |p, out| {
        let i = p.x.floor() as usize;
        out.fill(0.0);
        if i < 5 {
            let s = p.x / 5.0;
            out[0] = 1.0 - s;
            out[1] = s;
        } else if i > 5 {
            out[2] = 1.0;
        }
    })
    .unwrap();
    let valid: Vec<bool> = (0..field.num_voxels()).map(|v| v % 10 != 5).collect();
    let mbd = Mbd {
        basis_nodes: [3, 2, 2],
        options: MbdOptions {
            rank: 1,
            max_iterations: 64,
            init: Init::LocalPca,
            ..Default::default()
        },
    };
    let (coefficients, hat) = mbd.kernels(&field).unwrap();
    let (hat_model, _) =
        solve_als(&field, coefficients.clone(), hat, &mbd.options, &NoProgress).unwrap();
    let basis = wall_aware_basis(&field, &valid, mbd.basis_nodes, &WallOptions::default()).unwrap();
    let (model, _) = solve_als(&field, coefficients, basis, &mbd.options, &NoProgress).unwrap();
    let hat = valid_centre_error(&hat_model, &field, &valid);
    let walls = valid_centre_error(&model, &field, &valid);
    assert!(hat > 1e-4, "hat {hat:e}");
    assert!(walls < 1e-3 * hat, "wall-aware {walls:e}, hat {hat:e}");
}

/// A 12 × 8 × 6 scene with a floor slab, a column and scattered invalid voxels, the same smooth
/// content everywhere: the wall-aware basis is at least as good as the hat grid.
#[test]
fn mbd_with_a_wall_is_at_least_as_good_as_the_hat_grid() {
    let b = bounds();
    let (field, valid) = common::floor_and_column_scene(b.min, b.max, 6, 1.0, 5);
    let mbd = Mbd {
        basis_nodes: [3, 3, 3],
        options: MbdOptions {
            rank: 2,
            max_iterations: 64,
            ..Default::default()
        },
    };
    let eval = EvalOptions::default();
    let (hat_model, _) = mbd.fit(&field, &NoProgress).unwrap();
    let hat = evaluate(&hat_model, &field, &eval).unwrap().relative_mse;
    let basis = wall_aware_basis(&field, &valid, mbd.basis_nodes, &WallOptions::default()).unwrap();
    let (coefficients, _) = mbd.kernels(&field).unwrap();
    let (model, _) = solve(&field, coefficients, basis, &mbd.options, &NoProgress).unwrap();
    let walls = evaluate(&model, &field, &eval).unwrap().relative_mse;
    assert!(walls <= hat, "wall-aware {walls:e}, hat {hat:e}");
}
