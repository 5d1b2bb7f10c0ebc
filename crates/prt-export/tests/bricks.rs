//! Exports from a container whose coefficient volume is in bricks: the engine formats stay dense
//! 3D textures, lit from the model `read_container` decodes, and equal the dense container's
//! on every valid voxel and every voxel dilation fills.

use std::path::PathBuf;

use ndarray::{Array2, Array3};
use prt_bake::container::{
    CoefficientLayout, ContainerContents, LayoutConfig, write_container_with,
};
use prt_bake::container::{MbdContainer, read_container};
use prt_core::{Aabb, NoProgress, glam::Vec3};
use prt_export::{DilateConfig, dilate};
use prt_kernels::HatGrid;
use prt_mbd::MbdModel;
use prt_sphere::Sky;
use prt_texture::container::ArrayLayout;
use prt_texture::{Encoding, Limits};

fn written(layout: CoefficientLayout, tag: &str) -> MbdContainer {
    let grid = [14, 9, 11];
    let nodes: usize = grid.iter().product();
    let domain = Aabb::new(Vec3::ZERO, Vec3::new(2.6, 1.6, 2.0));
    let mut state = 0x2545_F491_4F6C_DD1Du64;
    let mut next = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 40) as f32 / (1u64 << 24) as f32 - 0.5
    };
    let coefficients = Array2::from_shape_fn((nodes, 3), |_| next());
    let basis = Array3::from_shape_fn((8, 3, 324), |_| 0.2 * next());
    let model = MbdModel::new(
        HatGrid::new(grid, domain).unwrap(),
        HatGrid::new([2, 2, 2], domain).unwrap(),
        coefficients,
        basis,
    )
    .unwrap();
    // Valid voxels in a slab at the bottom, a fifth of the grid.
    let valid: Vec<bool> = (0..nodes).map(|v| v / grid[0] % grid[1] < 2).collect();
    let folder: PathBuf =
        std::env::temp_dir().join(format!("prt-export-bricks-{}-{tag}", std::process::id()));
    let _ = std::fs::remove_dir_all(&folder);
    let contents = ContainerContents {
        model: &model,
        grid,
        valid: &valid,
        scene: "test",
        lambda: 0.0,
        encoding: Encoding::F16,
    };
    let config = LayoutConfig {
        layout,
        ..LayoutConfig::default()
    };
    write_container_with(&folder, &contents, &config).unwrap();
    let container = read_container(&folder, &Limits::small()).unwrap();
    let _ = std::fs::remove_dir_all(&folder);
    container
}

#[test]
fn exports_from_bricks_equal_those_from_the_dense_volume_where_they_are_known() {
    let dense = written(CoefficientLayout::Dense, "dense");
    let bricks = written(CoefficientLayout::Bricks, "bricks");
    let layout = |c: &MbdContainer| c.manifest.arrays[0].layout;
    assert_eq!(layout(&dense), ArrayLayout::Volume);
    assert_eq!(layout(&bricks), ArrayLayout::Bricks);
    let sky = Sky::default();
    let lit = |c: &MbdContainer| {
        let volume = c.light(&sky, &NoProgress).unwrap();
        dilate(&volume, &DilateConfig::default()).unwrap()
    };
    let (dense, bricks) = (lit(&dense), lit(&bricks));
    assert_eq!(dense.filled, bricks.filled);
    assert!(dense.filled > 0);
    // Known: valid, or filled by dilation (the invalid voxels next to a valid one).
    let grid = dense.volume.dims;
    let known = |v: usize| {
        let p = [v % grid[0], v / grid[0] % grid[1], v / (grid[0] * grid[1])];
        p[1] < 3
    };
    let mut compared = 0;
    for v in (0..dense.volume.voxels()).filter(|&v| known(v)) {
        compared += 1;
        let (a, b) = (&dense.volume.radiance[v], &bricks.volume.radiance[v]);
        for (ca, cb) in a.iter().zip(b) {
            for (x, y) in ca.iter().zip(cb) {
                assert!(
                    (x - y).abs() <= 1e-5 * (1.0 + x.abs()),
                    "voxel {v}: {x} vs {y}"
                );
            }
        }
    }
    assert_eq!(compared, 3 * grid[0] * grid[2]);
}
