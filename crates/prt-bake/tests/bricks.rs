//! The MBD container's coefficient volume in bricks: read back, the model equals the dense one
//! on every live node and at every valid voxel centre; the rule keeps small or mostly valid
//! grids dense; node liveness follows the validity.

mod common;

use common::scratch;

use ndarray::{Array2, Array3};
use proptest::prelude::*;
use prt_bake::container::read_container;
use prt_bake::container::{
    CoefficientLayout, ContainerContents, LayoutConfig, node_liveness, write_container_with,
};
use prt_core::{Aabb, FieldModel, glam::Vec3};
use prt_kernels::HatGrid;
use prt_mbd::MbdModel;
use prt_texture::container::ArrayLayout;
use prt_texture::{Encoding, Limits};

const BOX: Aabb = Aabb {
    min: Vec3::new(-1.0, 0.0, -0.5),
    max: Vec3::new(2.0, 2.0, 1.5),
};

/// A rank-3 model of dimension 5 with a coefficient node per voxel of `grid`.
fn model(grid: [usize; 3], seed: u64) -> MbdModel<HatGrid, HatGrid> {
    let mut state = seed | 1;
    let mut next = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 40) as f32 / (1u64 << 24) as f32 * 2.0 - 1.0
    };
    let nodes = grid.iter().product();
    let coefficients = Array2::from_shape_fn((nodes, 3), |_| next());
    let basis = Array3::from_shape_fn((8, 3, 5), |_| next());
    MbdModel::new(
        HatGrid::new(grid, BOX).unwrap(),
        HatGrid::new([2, 2, 2], BOX).unwrap(),
        coefficients,
        basis,
    )
    .unwrap()
}

/// Valid voxels inside a ball around a corner of the grid.
fn ball(grid: [usize; 3], radius: f64) -> Vec<bool> {
    (0..grid.iter().product())
        .map(|v| {
            let p = [v % grid[0], v / grid[0] % grid[1], v / (grid[0] * grid[1])];
            p.iter().map(|&i| (i as f64).powi(2)).sum::<f64>() < radius * radius
        })
        .collect()
}

fn write_read(
    grid: [usize; 3],
    valid: &[bool],
    model: &MbdModel<HatGrid, HatGrid>,
    layout: CoefficientLayout,
    brick_size: u32,
) -> (prt_bake::container::MbdContainer, ArrayLayout) {
    let folder = scratch("bricks");
    let contents = ContainerContents {
        model,
        grid,
        valid,
        scene: "test",
        lambda: 1e-4,
        encoding: Encoding::F16,
    };
    let config = LayoutConfig {
        layout,
        brick_size,
        live_nodes: None,
    };
    let report = write_container_with(&folder, &contents, &config).unwrap();
    let back = read_container(&folder, &Limits::small()).unwrap();
    let _ = std::fs::remove_dir_all(&folder);
    (back, report.manifest.arrays[0].layout)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(12))]

    #[test]
    fn bricks_equal_dense_on_live_nodes_and_valid_voxels(
        grid in prop::array::uniform3(2usize..14),
        radius in 1.0f64..12.0,
        brick_size in 1u32..6,
        seed in any::<u64>(),
    ) {
        let model = model(grid, seed);
        let valid = ball(grid, radius);
        let (dense, dense_layout) = write_read(grid, &valid, &model, CoefficientLayout::Dense, 4);
        let (bricks, bricks_layout) =
            write_read(grid, &valid, &model, CoefficientLayout::Bricks, brick_size);
        prop_assert_eq!(dense_layout, ArrayLayout::Volume);
        prop_assert_eq!(bricks_layout, ArrayLayout::Bricks);
        let kernels = model.coefficient_kernels();
        let (mut a, mut b) = (vec![0.0; 5], vec![0.0; 5]);
        for (v, _) in valid.iter().enumerate().filter(|(_, ok)| **ok) {
            // Live node = valid voxel here (a node per voxel): stored bit for bit.
            prop_assert_eq!(bricks.model.coefficients().row(v), dense.model.coefficients().row(v));
            let node = [v % grid[0], v / grid[0] % grid[1], v / (grid[0] * grid[1])];
            let x = kernels.node_position(node).unwrap();
            bricks.model.eval(x, &mut a).unwrap();
            dense.model.eval(x, &mut b).unwrap();
            for (p, q) in a.iter().zip(&b) {
                // Neighbours of a node centre weigh 0 up to f32 rounding of the position.
                prop_assert!((p - q).abs() <= 1e-5 * (1.0 + q.abs()), "{p} vs {q} at voxel {v}");
            }
        }
    }
}

#[test]
fn the_rule_keeps_mostly_valid_grids_dense_and_bricks_sparse_ones() {
    let grid = [24, 16, 24];
    let model = model(grid, 7);
    let all = vec![true; grid.iter().product()];
    let (_, layout) = write_read(grid, &all, &model, CoefficientLayout::Auto, 4);
    assert_eq!(layout, ArrayLayout::Volume);
    let (_, layout) = write_read(grid, &ball(grid, 6.0), &model, CoefficientLayout::Auto, 4);
    assert_eq!(layout, ArrayLayout::Bricks);
}

#[test]
fn node_liveness_marks_the_nodes_a_valid_voxel_centre_touches() {
    // 5 voxels over 3 nodes per axis: voxel centres at node coordinates 0, ½, 1, 1½, 2.
    let kernels = HatGrid::new([3, 1, 1], BOX).unwrap();
    let live = |valid: [bool; 5]| node_liveness(&kernels, [5, 1, 1], &valid).unwrap();
    assert_eq!(
        live([true, false, false, false, false]),
        [true, false, false]
    );
    assert_eq!(
        live([false, true, false, false, false]),
        [true, true, false]
    );
    assert_eq!(
        live([false, false, true, false, false]),
        [false, true, false]
    );
    assert_eq!(
        live([false, false, false, false, true]),
        [false, false, true]
    );
    assert!(node_liveness(&kernels, [5, 1, 1], &[true; 4]).is_err());
}
