//! The container written a block at a time (`ContainerWriter`, the validity summarised and
//! written a block at a time too) is the container `write_container_with` writes, byte for
//! byte, whatever the blocks and their order; a block outside the grid, a node written twice
//! and a node never written are errors.

mod common;

use common::{ENCODINGS, scratch};
use std::collections::BTreeMap;
use std::path::Path;

use ndarray::{Array2, Array3};
use proptest::prelude::*;
use prt_bake::container::{
    CoefficientLayout, ContainerContents, ContainerParts, ContainerWriter, LayoutConfig,
    ValiditySummary, write_container_with,
};
use prt_core::{Aabb, glam::Vec3};
use prt_kernels::HatGrid;
use prt_mbd::MbdModel;
use prt_texture::{Encoding, RangeFit};

const BOX: Aabb = Aabb {
    min: Vec3::new(-1.0, 0.0, -0.5),
    max: Vec3::new(1.0, 2.0, 0.5),
};

/// Every file of `folder` by name.
fn files(folder: &Path) -> BTreeMap<String, Vec<u8>> {
    std::fs::read_dir(folder)
        .expect("container folder")
        .map(|entry| {
            let path = entry.expect("entry").path();
            let name = path.file_name().unwrap().to_string_lossy().into_owned();
            (name, std::fs::read(&path).expect("file"))
        })
        .collect()
}

/// The boxes of a grid of `dims` cut at `cuts` (per axis, positions inside the axis).
fn boxes(dims: [usize; 3], cuts: [Vec<usize>; 3]) -> Vec<([usize; 3], [usize; 3])> {
    let spans = |a: usize| {
        let mut at: Vec<usize> = cuts[a].iter().map(|&c| c % dims[a]).collect();
        at.extend([0, dims[a]]);
        at.sort_unstable();
        at.dedup();
        at.windows(2)
            .map(|w| (w[0], w[1] - w[0]))
            .collect::<Vec<_>>()
    };
    let (xs, ys, zs) = (spans(0), spans(1), spans(2));
    let mut out = Vec::new();
    for &(z, sz) in &zs {
        for &(y, sy) in &ys {
            for &(x, sx) in &xs {
                out.push(([x, y, z], [sx, sy, sz]));
            }
        }
    }
    out
}

/// The coefficients of the box at `min` of `size`, x fastest.
fn block(
    coefficients: &Array2<f32>,
    dims: [usize; 3],
    min: [usize; 3],
    size: [usize; 3],
) -> Vec<f32> {
    let mut out = Vec::new();
    for v in box_voxels(dims, min, size) {
        out.extend(coefficients.row(v));
    }
    out
}

/// The validity of the box at `min` of `size`, x fastest.
fn valid_block(valid: &[bool], dims: [usize; 3], min: [usize; 3], size: [usize; 3]) -> Vec<bool> {
    box_voxels(dims, min, size).map(|v| valid[v]).collect()
}

/// The voxels of the box at `min` of `size` in a grid of `dims`, x fastest.
fn box_voxels(dims: [usize; 3], min: [usize; 3], size: [usize; 3]) -> impl Iterator<Item = usize> {
    (min[2]..min[2] + size[2]).flat_map(move |z| {
        (min[1]..min[1] + size[1]).flat_map(move |y| {
            (min[0]..min[0] + size[0]).map(move |x| x + dims[0] * (y + dims[1] * z))
        })
    })
}

const LAYOUTS: [CoefficientLayout; 3] = [
    CoefficientLayout::Auto,
    CoefficientLayout::Dense,
    CoefficientLayout::Bricks,
];

proptest! {
    #![proptest_config(ProptestConfig { cases: 48, ..ProptestConfig::default() })]

    #[test]
    fn a_container_written_block_by_block_is_the_whole_models_container(
        dims in prop::array::uniform3(1usize..7),
        basis_nodes in prop::array::uniform3(2usize..4),
        rank in 1usize..10,
        dim in 1usize..4,
        values in prop::collection::vec(-50.0f32..50.0, 1..97),
        validity in prop::collection::vec(0u8..4, 1..50),
        encoding in prop::sample::select(ENCODINGS.to_vec()),
        layout in prop::sample::select(LAYOUTS.to_vec()),
        brick_size in 1u32..4,
        cuts in prop::array::uniform3(prop::collection::vec(0usize..7, 0..3)),
        order_seed in any::<u64>(),
    ) {
        let voxels = dims.iter().product::<usize>();
        // Invalid voxels hold zero coefficients, as the merge's partials do.
        let valid: Vec<bool> = (0..voxels).map(|v| validity[v % validity.len()] != 0).collect();
        let mut next = values.iter().copied().cycle();
        let coefficients = Array2::from_shape_fn((voxels, rank), |(v, _)| {
            let x = next.next().unwrap_or(0.0);
            if valid[v] { x } else { 0.0 }
        });
        let basis_count = basis_nodes.iter().product::<usize>();
        let basis = Array3::from_shape_fn((basis_count, rank, dim), |_| next.next().unwrap_or(0.0));
        let coefficient_kernels = HatGrid::new(dims, BOX).expect("kernels");
        let basis_kernels = HatGrid::new(basis_nodes, BOX).expect("kernels");
        let model = MbdModel::new(
            coefficient_kernels.clone(),
            basis_kernels.clone(),
            coefficients.clone(),
            basis.clone(),
        )
        .expect("model");
        let layout = LayoutConfig { layout, brick_size, live_nodes: None };
        let whole = scratch("container-writer-whole");
        let contents = ContainerContents {
            model: &model,
            grid: dims,
            valid: &valid,
            scene: "test",
            lambda: 1e-4,
            encoding,
        };
        let whole_report = write_container_with(&whole, &contents, &layout).expect("write");

        let streamed = scratch("container-writer-blocks");
        let parts = ContainerParts {
            coefficient_kernels: &coefficient_kernels,
            basis_kernels: &basis_kernels,
            basis: &basis,
            grid: dims,
            scene: "test",
            lambda: 1e-4,
            encoding,
        };
        let mut ranges = RangeFit::new(rank);
        ranges.add(coefficients.as_slice().expect("standard layout"));
        let mut blocks = boxes(dims, cuts);
        // Any order: a rotation and, by the seed's low bit, a reversal.
        let rotation = (order_seed as usize) % blocks.len();
        blocks.rotate_left(rotation);
        if order_seed & 1 == 1 {
            blocks.reverse();
        }
        let mut summary = ValiditySummary::new(&coefficient_kernels, dims, brick_size).expect("summary");
        for &(min, size) in &blocks {
            summary.add(min, size, &valid_block(&valid, dims, min, size)).expect("summary block");
        }
        prop_assert_eq!(summary.valid_voxels(), valid.iter().filter(|&&v| v).count() as u64);
        let mut writer = ContainerWriter::create(&streamed, &parts, &ranges, &summary, layout.layout)
            .expect("create");
        // The validity in the blocks' reverse order, the coefficients in theirs.
        for &(min, size) in blocks.iter().rev() {
            writer.write_validity(min, size, &valid_block(&valid, dims, min, size)).expect("validity");
        }
        for &(min, size) in &blocks {
            writer
                .write_coefficients(min, size, &block(&coefficients, dims, min, size))
                .expect("block");
        }
        let streamed_report = writer.finish().expect("finish");
        prop_assert_eq!(&streamed_report, &whole_report);
        let same = files(&whole) == files(&streamed);
        let _ = (std::fs::remove_dir_all(&whole), std::fs::remove_dir_all(&streamed));
        prop_assert!(same, "the containers' files differ");
    }
}

#[test]
fn the_validity_summary_of_a_1_km_world_is_a_flag_per_brick() {
    // 2000 × 2000 × 200 voxels, a coefficient node per voxel, bricks of 4 cells: 500 × 500 × 50
    // bricks and 24 bytes per voxel along each axis, 12.6 MB against the 800 MB of a flag per
    // voxel.
    let world = [2000, 2000, 200];
    assert_eq!(
        ValiditySummary::bytes_for(world, world, 4),
        500 * 500 * 50 + 24 * 4200
    );
    assert_eq!(
        ValiditySummary::bytes_for([usize::MAX; 3], [usize::MAX; 3], 1),
        u64::MAX
    );
}

#[test]
fn a_block_outside_twice_or_missing_is_an_error() {
    let dims = [3, 2, 2];
    let voxels = 12;
    let valid = vec![true; voxels];
    let coefficients = Array2::from_shape_fn((voxels, 2), |(v, c)| (v * 2 + c) as f32);
    let basis = Array3::from_elem((8, 2, 3), 0.5f32);
    let coefficient_kernels = HatGrid::new(dims, BOX).expect("kernels");
    let basis_kernels = HatGrid::new([2, 2, 2], BOX).expect("kernels");
    let parts = ContainerParts {
        coefficient_kernels: &coefficient_kernels,
        basis_kernels: &basis_kernels,
        basis: &basis,
        grid: dims,
        scene: "test",
        lambda: 1e-4,
        encoding: Encoding::F16,
    };
    let ranges = RangeFit::new(2);
    let folder = scratch("container-writer-errors");
    let layout = LayoutConfig::default();
    let mut summary =
        ValiditySummary::new(&coefficient_kernels, dims, layout.brick_size).expect("summary");
    let half = valid_block(&valid, dims, [0, 0, 0], [3, 2, 1]);
    summary
        .add([0, 0, 0], [3, 2, 1], &half)
        .expect("first half");
    assert!(
        summary.add([0, 0, 1], [3, 2, 2], &half).is_err(),
        "a box outside"
    );
    assert!(
        ContainerWriter::create(&folder, &parts, &ranges, &summary, layout.layout).is_err(),
        "a summary of half the voxels"
    );
    summary
        .add([0, 0, 1], [3, 2, 1], &half)
        .expect("second half");
    let mut writer =
        ContainerWriter::create(&folder, &parts, &ranges, &summary, layout.layout).expect("create");
    writer
        .write_validity([0, 0, 0], [3, 2, 1], &half)
        .expect("validity of the first plane");
    assert!(
        writer.write_validity([0, 0, 0], [3, 2, 1], &half).is_err(),
        "validity twice"
    );
    assert!(
        writer
            .write_validity([0, 0, 1], [3, 2, 1], &half[1..])
            .is_err(),
        "short validity"
    );
    let plane = block(&coefficients, dims, [0, 0, 0], [3, 2, 1]);
    assert!(
        writer
            .write_coefficients([1, 0, 0], [3, 2, 1], &plane)
            .is_err(),
        "outside"
    );
    assert!(
        writer
            .write_coefficients([0, 0, 0], [3, 2, 1], &plane[1..])
            .is_err(),
        "short"
    );
    writer
        .write_coefficients([0, 0, 0], [3, 2, 1], &plane)
        .expect("first plane");
    assert!(
        writer
            .write_coefficients([0, 0, 0], [3, 2, 1], &plane)
            .is_err(),
        "twice"
    );
    let error = writer.finish().expect_err("the second plane is missing");
    assert!(error.to_string().contains("6 of 12"), "{error}");
    // Nothing of the coefficients' file is left, and no manifest was written.
    let names: Vec<String> = files(&folder).into_keys().collect();
    assert!(
        !names
            .iter()
            .any(|n| n.starts_with("coefficients") || n == "manifest.json"),
        "{names:?}"
    );
    let _ = std::fs::remove_dir_all(&folder);
}
