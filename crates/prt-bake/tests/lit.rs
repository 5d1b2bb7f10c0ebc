//! A bake folder's volumes lit by a sky: the container lit basis vector by basis vector equals
//! its model lit at each voxel centre, and the folder lights every volume the one way.

mod common;

use common::scratch;

use ndarray::{Array2, Array3};
use proptest::prelude::*;
use prt_bake::BakeFolder;
use prt_bake::container::{ContainerContents, read_container, write_container};
use prt_core::{Aabb, AtomicProgress, FieldModel, NoProgress, glam::Vec3};
use prt_kernels::HatGrid;
use prt_mbd::MbdModel;
use prt_sphere::Sky;
use prt_texture::{Encoding, Limits};
use prt_trace::TRANSFER_DIM;
use prt_trace::lit::incident_radiance;

/// The baked grid: the coefficient hats sit on its voxel centres.
const GRID: [usize; 3] = [4, 3, 2];
const CENTRES: Aabb = Aabb {
    min: Vec3::new(-1.0, 0.0, -0.5),
    max: Vec3::new(1.0, 2.0, 0.5),
};

/// A rank-`rank` 324-D model (coefficients on the grid's voxel centres, basis on 2³ nodes),
/// its values drawn from `seed`, written as an f32 container into `folder/mbd`.
fn write_folder(folder: &BakeFolder, rank: usize, seed: u64) {
    let mut state = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
    let mut next = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 40) as f32 / (1u64 << 24) as f32 * 2.0 - 1.0
    };
    let nodes: usize = GRID.iter().product();
    let model = MbdModel::new(
        HatGrid::new(GRID, CENTRES).expect("coefficient kernels"),
        HatGrid::new([2, 2, 2], CENTRES).expect("basis kernels"),
        Array2::from_shape_fn((nodes, rank), |_| next()),
        Array3::from_shape_fn((8, rank, TRANSFER_DIM), |_| 0.1 * next()),
    )
    .expect("model");
    let valid: Vec<bool> = (0..nodes).map(|v| v % 5 != 0).collect();
    let contents = ContainerContents {
        model: &model,
        grid: GRID,
        valid: &valid,
        scene: "test",
        lambda: 1e-4,
        encoding: Encoding::F32,
    };
    write_container(&folder.container_dir(), &contents).expect("write");
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(8))]

    #[test]
    fn lighting_the_basis_once_equals_lighting_the_model_at_each_voxel(
        seed in any::<u64>(),
        rank in 1usize..4,
        rgb in prop::array::uniform3(0.1f32..2.0),
        degrees in 0.0f32..360.0,
    ) {
        let folder = BakeFolder::new(scratch("lit"));
        write_folder(&folder, rank, seed);
        let sky = Sky::constant(rgb).rotated_about_y(degrees);
        let lit = folder
            .lit_volume(BakeFolder::CONTAINER, &sky, &Limits::small(), &NoProgress)
            .expect("lit");
        let container = read_container(&folder.container_dir(), &Limits::small()).expect("read");
        prop_assert_eq!(&lit, &container.light(&sky, &NoProgress).expect("lit"));
        prop_assert_eq!(lit.dims, GRID);
        prop_assert_eq!(&lit.valid, &container.valid);
        // The voxel centres are the coefficient nodes: the box is half a voxel wider.
        let centre_box = lit.centre_box();
        prop_assert!((centre_box.min - CENTRES.min).abs().max_element() < 1e-5);
        prop_assert!((centre_box.max - CENTRES.max).abs().max_element() < 1e-5);
        // Both sums are of a few hundred f32 products (f64 against f32 accumulation).
        let mut t = vec![0.0; TRANSFER_DIM];
        for v in 0..lit.voxels() {
            container.model.eval(lit.voxel_centre(v), &mut t).expect("eval");
            let direct = incident_radiance(&t, &sky);
            for (a, b) in lit.radiance[v].as_flattened().iter().zip(direct.as_flattened()) {
                prop_assert!((a - b).abs() <= 1e-5 * (1.0 + b.abs()), "voxel {}: {} vs {}", v, a, b);
            }
        }
        let _ = std::fs::remove_dir_all(folder.root());
    }
}

#[test]
fn lighting_is_refused_for_unknown_volumes_and_stops_when_cancelled() {
    let folder = BakeFolder::new(scratch("lit-errors"));
    write_folder(&folder, 2, 7);
    let sky = Sky::default();
    let limits = Limits::small();
    let unknown = folder
        .lit_volume("bpca", &sky, &limits, &NoProgress)
        .expect_err("no kept volumes");
    assert!(unknown.to_string().contains("kept volumes"), "{unknown}");
    let cancelled = AtomicProgress::new();
    cancelled.cancel();
    let stopped = folder
        .lit_volume(BakeFolder::CONTAINER, &sky, &limits, &cancelled)
        .expect_err("cancelled");
    assert!(
        stopped
            .to_string()
            .contains("cannot light the `mbd` volume"),
        "{stopped}"
    );
    let _ = std::fs::remove_dir_all(folder.root());
}
