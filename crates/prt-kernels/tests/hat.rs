//! Laws and extremes of the hat grid.

use glam::Vec3;
use proptest::prelude::*;
use prt_core::{Aabb, CoreError, KernelWeights, SpatialKernels};
use prt_kernels::{HatGrid, KernelError};

/// A box with corners in [-100, 100] and every extent at least 0.01.
fn domain() -> impl Strategy<Value = Aabb> {
    (
        prop::array::uniform3(-100.0f32..100.0),
        prop::array::uniform3(0.01f32..50.0),
    )
        .prop_map(|(min, size)| {
            let min = Vec3::from_array(min);
            Aabb::new(min, min + Vec3::from_array(size))
        })
}

/// A grid with 1..=6 nodes per axis (1 = constant along that axis) and a point given in
/// local coordinates `[-0.5, 1.5]³`, so that a quarter of the points fall outside the domain.
fn grid_and_point() -> impl Strategy<Value = (HatGrid, Vec3)> {
    (
        prop::array::uniform3(1usize..=6),
        domain(),
        prop::array::uniform3(-0.5f32..1.5),
    )
        .prop_map(|(nodes, domain, local)| {
            let grid = HatGrid::new(nodes, domain).unwrap();
            let p = domain.min + Vec3::from_array(local) * domain.size();
            (grid, p)
        })
}

/// Affine function with the given coefficients.
fn affine(c: [f32; 4], p: Vec3) -> f64 {
    c[0] as f64 + c[1] as f64 * p.x as f64 + c[2] as f64 * p.y as f64 + c[3] as f64 * p.z as f64
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    #[test]
    fn partition_of_unity_non_negative_bounded((grid, p) in grid_and_point()) {
        let mut w = KernelWeights::default();
        grid.eval(p, &mut w).unwrap();
        prop_assert!(!w.is_empty());
        prop_assert!(w.len() <= grid.max_support());
        prop_assert!((w.sum() - 1.0).abs() < 1e-5, "sum {}", w.sum());
        for (i, wi) in w.iter() {
            prop_assert!(wi > 0.0 && wi <= 1.0 + 1e-6);
            prop_assert!((i as usize) < grid.len());
        }
        let mut sorted = w.indices.clone();
        sorted.sort_unstable();
        sorted.dedup();
        prop_assert_eq!(sorted.len(), w.len(), "duplicate indices");
    }

    /// Σ w_i f(node_i) = f(clamp(x)) for affine f: linear precision of the hats. Along
    /// single-node axes the family is constant, so f must not depend on them.
    #[test]
    fn reproduces_affine_functions((grid, p) in grid_and_point(), c in prop::array::uniform4(-3.0f32..3.0)) {
        let mut c = c;
        for k in 0..3 {
            if grid.nodes()[k] == 1 {
                c[k + 1] = 0.0;
            }
        }
        let mut w = KernelWeights::default();
        grid.eval(p, &mut w).unwrap();
        let got: f64 = w.iter().map(|(i, wi)| wi as f64 * affine(c, grid.centre(i as usize).unwrap())).sum();
        let want = affine(c, grid.domain().clamp(p));
        // f32 weights and node positions: relative error ~1e-6 of the magnitudes involved.
        let scale = 1.0 + c.iter().map(|v| v.abs() as f64).sum::<f64>() * 200.0;
        prop_assert!((got - want).abs() < 2e-6 * scale, "got {got}, want {want}");
    }

    /// Kernel i is non-zero only inside the cells around its node (compact support), and the
    /// trait's non-zero weights are exactly the non-zero weights of `eval_local`.
    #[test]
    fn compact_support_and_local_agree((grid, p) in grid_and_point()) {
        let local = grid.eval_local(p).unwrap();
        let mut w = KernelWeights::default();
        grid.eval(p, &mut w).unwrap();
        let nonzero: Vec<(u32, f32)> = local
            .indices()
            .iter()
            .copied()
            .zip(local.weights().iter().copied())
            .filter(|&(_, wi)| wi > 0.0)
            .collect();
        prop_assert_eq!(nonzero, w.iter().collect::<Vec<_>>());
        let q = grid.domain().clamp(p);
        let spacing = grid.domain().size() / (Vec3::from_array(grid.nodes().map(|n| n as f32)) - 1.0).max(Vec3::ONE);
        for (i, _) in w.iter() {
            let node = grid.centre(i as usize).unwrap();
            for k in 0..3 {
                if grid.nodes()[k] >= 2 {
                    prop_assert!((q[k] - node[k]).abs() <= spacing[k] * (1.0 + 1e-4));
                }
            }
        }
        prop_assert_eq!(grid.support_cell(p), grid.cell_index(local.cell()));
        let corners = grid.cell_corners(local.cell()).unwrap();
        prop_assert_eq!(corners.indices(), local.indices());
    }

    /// Node index ↔ coordinates ↔ position round trip, and a point on a node gives that node
    /// weight 1.
    #[test]
    fn node_round_trip(nodes in prop::array::uniform3(1usize..=7), d in domain(), pick in prop::array::uniform3(0usize..7)) {
        let grid = HatGrid::new(nodes, d).unwrap();
        let node = [0, 1, 2].map(|k| pick[k] % nodes[k]);
        let index = grid.node_index(node).unwrap();
        prop_assert_eq!(grid.node_coords(index as usize), Some(node));
        let p = grid.node_position(node).unwrap();
        let local = grid.eval_local(p).unwrap();
        let at = local.indices().iter().position(|&i| i == index).unwrap();
        // A node position is rounded to f32: relative to the node spacing, that rounding can
        // move the point by a few ulps of its magnitude, which lowers the node's weight by as
        // much (a 0.01-wide box at x = 81 puts one ulp at 0.5% of the spacing).
        let slack = (0..3)
            .filter(|&k| nodes[k] > 1)
            .map(|k| {
                let spacing = (d.max[k] - d.min[k]) / (nodes[k] - 1) as f32;
                4.0 * f32::EPSILON * d.min[k].abs().max(d.max[k].abs()) / spacing
            })
            .sum::<f32>();
        prop_assert!(local.weights()[at] > 1.0 - 1e-5 - slack, "weight {} (slack {slack})", local.weights()[at]);
    }
}

#[test]
fn corners_edges_and_faces_of_the_domain() {
    let grid = HatGrid::new(
        [3, 4, 5],
        Aabb::new(Vec3::new(-1.0, 0.0, 2.0), Vec3::new(1.0, 3.0, 6.0)),
    )
    .unwrap();
    let mut w = KernelWeights::default();
    // The 8 corners of the domain are nodes: one kernel each, weight exactly 1.
    for c in 0..8 {
        let d = grid.domain();
        let p = Vec3::new(
            if c & 1 == 1 { d.max.x } else { d.min.x },
            if c & 2 == 2 { d.max.y } else { d.min.y },
            if c & 4 == 4 { d.max.z } else { d.min.z },
        );
        grid.eval(p, &mut w).unwrap();
        let node = [(c & 1) * 2, (c >> 1 & 1) * 3, (c >> 2 & 1) * 4];
        assert_eq!(
            w.indices,
            vec![grid.node_index(node).unwrap()],
            "corner {c}"
        );
        assert_eq!(w.weights, vec![1.0]);
    }
    // The midpoint of an edge between two nodes along x: two kernels of weight 1/2.
    grid.eval(Vec3::new(-0.5, 0.0, 2.0), &mut w).unwrap();
    assert_eq!(w.indices, vec![0, 1]);
    assert_eq!(w.weights, vec![0.5, 0.5]);
    // The centre of a face cell: 4 kernels of 1/4.
    grid.eval(Vec3::new(-0.5, 0.5, 2.0), &mut w).unwrap();
    assert_eq!(w.len(), 4);
    assert!(w.weights.iter().all(|&x| x == 0.25));
    // The upper face belongs to the last cell.
    assert_eq!(grid.cell_of(Vec3::new(1.0, 3.0, 6.0)).unwrap(), [1, 2, 3]);
    assert_eq!(
        grid.support_cell(Vec3::new(1.0, 3.0, 6.0)),
        Some(grid.num_support_cells() - 1)
    );
}

#[test]
fn points_outside_are_clamped_to_the_box() {
    let grid = HatGrid::new([4, 4, 4], Aabb::UNIT).unwrap();
    let (mut inside, mut outside) = (KernelWeights::default(), KernelWeights::default());
    for (p, q) in [
        (Vec3::new(-5.0, 0.5, 0.5), Vec3::new(0.0, 0.5, 0.5)),
        (Vec3::new(0.3, 7.0, -2.0), Vec3::new(0.3, 1.0, 0.0)),
        (Vec3::splat(1e30), Vec3::ONE),
        (Vec3::splat(-f32::MAX), Vec3::ZERO),
    ] {
        grid.eval(p, &mut outside).unwrap();
        grid.eval(q, &mut inside).unwrap();
        assert_eq!(outside, inside, "{p} vs {q}");
    }
}

#[test]
fn non_finite_point_is_a_typed_error_naming_the_axis() {
    let grid = HatGrid::new([2, 2, 2], Aabb::UNIT).unwrap();
    let mut w = KernelWeights::default();
    assert_eq!(
        grid.eval(Vec3::new(0.5, f32::NAN, 0.5), &mut w),
        Err(CoreError::NonFinite {
            what: "query point",
            index: 1
        })
    );
    assert_eq!(
        grid.eval_local(Vec3::new(0.5, 0.5, f32::INFINITY))
            .unwrap_err(),
        CoreError::NonFinite {
            what: "query point",
            index: 2
        }
    );
    assert_eq!(grid.support_cell(Vec3::NAN), None);
}

#[test]
fn two_nodes_per_axis_is_plain_trilinear() {
    let grid = HatGrid::new([2, 2, 2], Aabb::UNIT).unwrap();
    assert_eq!(
        (grid.len(), grid.max_support(), grid.num_support_cells()),
        (8, 8, 1)
    );
    let p = Vec3::new(0.2, 0.3, 0.9);
    let local = grid.eval_local(p).unwrap();
    assert_eq!(local.indices(), &[0, 1, 2, 3, 4, 5, 6, 7]);
    for c in 0..8 {
        let f = |k: usize, t: f32| if c >> k & 1 == 1 { t } else { 1.0 - t };
        let want = f(0, p.x) * f(1, p.y) * f(2, p.z);
        assert!((local.weights()[c] - want).abs() < 1e-6, "corner {c}");
    }
}

#[test]
fn one_and_two_dimensional_grids() {
    let d = Aabb::new(Vec3::ZERO, Vec3::new(4.0, 10.0, 2.0));
    let line = HatGrid::line_x(5, d).unwrap();
    assert_eq!(
        (line.len(), line.max_support(), line.active_axes()),
        (5, 2, 1)
    );
    let mut w = KernelWeights::default();
    line.eval(Vec3::new(2.5, 7.0, 0.3), &mut w).unwrap();
    assert_eq!(w.indices, vec![2, 3]);
    assert_eq!(w.weights, vec![0.5, 0.5]);
    // The single node of a constant axis sits at the domain's centre.
    assert_eq!(line.centre(4), Some(Vec3::new(4.0, 5.0, 1.0)));

    let plane = HatGrid::plane_xz(5, 3, d).unwrap();
    assert_eq!(
        (plane.len(), plane.max_support(), plane.num_support_cells()),
        (15, 4, 8)
    );
    // Constant along y: the weights do not depend on it.
    let mut w2 = KernelWeights::default();
    plane.eval(Vec3::new(2.5, 0.0, 0.5), &mut w).unwrap();
    plane.eval(Vec3::new(2.5, 9.0, 0.5), &mut w2).unwrap();
    assert_eq!(w, w2);
    // Node (i, k) has index i + nx * k.
    assert_eq!(w.indices, vec![2, 3, 7, 8]);
    assert_eq!(
        plane.cell_corners([2, 0, 0]).unwrap().indices(),
        &[2, 3, 7, 8]
    );

    let point = HatGrid::new([1, 1, 1], d).unwrap();
    point.eval(Vec3::new(-3.0, 1.0, 1.0), &mut w).unwrap();
    assert_eq!(
        (w.indices.as_slice(), w.weights.as_slice()),
        (&[0u32][..], &[1.0f32][..])
    );
}

#[test]
fn invalid_grids_are_typed_errors() {
    assert_eq!(
        HatGrid::new([3, 0, 3], Aabb::UNIT),
        Err(KernelError::NoNodes { axis: 1 })
    );
    let flat = Aabb::new(Vec3::ZERO, Vec3::new(1.0, 0.0, 1.0));
    assert_eq!(
        HatGrid::new([3, 2, 3], flat),
        Err(KernelError::DegenerateAxis { axis: 1, nodes: 2 })
    );
    // A flat domain is fine when the flat axis has a single node.
    assert!(HatGrid::plane_xz(3, 3, flat).is_ok());
    let nan = Aabb {
        min: Vec3::new(0.0, f32::NAN, 0.0),
        max: Vec3::ONE,
    };
    assert!(matches!(
        HatGrid::new([2, 2, 2], nan),
        Err(KernelError::InvalidDomain { .. })
    ));
    let inverted = Aabb {
        min: Vec3::ONE,
        max: Vec3::ZERO,
    };
    assert!(matches!(
        HatGrid::new([2, 2, 2], inverted),
        Err(KernelError::InvalidDomain { .. })
    ));
    assert!(matches!(
        HatGrid::new([usize::MAX, 2, 2], Aabb::UNIT),
        Err(KernelError::TooManyKernels { .. })
    ));
    assert!(matches!(
        HatGrid::new([70_000, 70_000, 1], Aabb::UNIT),
        Err(KernelError::TooManyKernels { .. })
    ));
}

#[test]
fn huge_grids_index_exactly() {
    // 65536 × 65535 = 2^32 - 2^16 nodes: the largest indices still fit u32.
    let d = Aabb::new(Vec3::ZERO, Vec3::new(65535.0, 1.0, 65534.0));
    let grid = HatGrid::plane_xz(65536, 65535, d).unwrap();
    assert_eq!(grid.len(), 65536 * 65535);
    let local = grid.eval_local(d.max).unwrap();
    let last = (grid.len() - 1) as u32;
    let at = local.indices().iter().position(|&i| i == last).unwrap();
    assert_eq!(local.weights()[at], 1.0);
    // Halfway between nodes 40000 and 40001 of x, on node 60000 of z: the f64 cell coordinate
    // keeps the fraction exact although x has 16 significant bits of integer part.
    let local = grid.eval_local(Vec3::new(40000.5, 0.0, 60000.0)).unwrap();
    assert_eq!(local.cell(), [40000, 0, 60000]);
    let lo = grid.node_index([40000, 0, 60000]).unwrap();
    let mut pairs: Vec<(u32, f32)> = local
        .indices()
        .iter()
        .copied()
        .zip(local.weights().iter().copied())
        .filter(|&(_, w)| w > 0.0)
        .collect();
    pairs.sort_by_key(|p| p.0);
    assert_eq!(pairs, vec![(lo, 0.5), (lo + 1, 0.5)]);
    // Extreme but finite domain corners: the f64 extent does not overflow.
    let wide = Aabb::new(Vec3::splat(-f32::MAX), Vec3::splat(f32::MAX));
    let grid = HatGrid::new([3, 3, 3], wide).unwrap();
    let mut w = KernelWeights::default();
    grid.eval(Vec3::ZERO, &mut w).unwrap();
    assert_eq!(w.indices, vec![13]);
    assert_eq!(w.weights, vec![1.0]);
}
