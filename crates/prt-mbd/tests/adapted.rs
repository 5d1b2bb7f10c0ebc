//! `scene_adapted_basis`: Shepard basis kernels at weighted k-means centres of the valid voxels.

use glam::Vec3;
use proptest::prelude::*;
use prt_core::{Compressor, CoreError, GridField, KernelWeights, NoProgress, SpatialKernels};
use prt_mbd::*;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

mod common;

/// The floor-and-column scene over a non-cubic box, 5-vectors, 30× stronger for x ≥ 6.
fn scene(seed: u64) -> (GridField, Vec<bool>) {
    common::floor_and_column_scene(
        Vec3::new(-1.0, 0.0, 2.0),
        Vec3::new(2.0, 1.5, 3.0),
        5,
        30.0,
        seed,
    )
}

fn options(placement: Placement, seed: u64) -> AdaptedBasisOptions {
    AdaptedBasisOptions {
        placement,
        seed,
        ..AdaptedBasisOptions::default()
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(8))]

    /// Every point of the field's box (corners, random points) is covered, with weights that
    /// sum to one; every centre is the centre of a valid voxel, no two the same.
    #[test]
    fn covers_the_box_with_centres_at_valid_voxels(
        seed in 0u64..1000,
        nodes in 1usize..40,
        pick in 0usize..3,
        neighbours in 1usize..10,
    ) {
        let (field, valid) = scene(seed);
        let placement = [Placement::Uniform, Placement::Energy, Placement::Variation][pick];
        let basis = scene_adapted_basis(
            &field,
            &valid,
            nodes,
            &AdaptedBasisOptions { neighbours, ..options(placement, seed) },
        )
        .unwrap();
        prop_assert_eq!(basis.len(), nodes);
        let mut centres: Vec<[u32; 3]> = Vec::new();
        for &c in basis.centres() {
            let v = (0..field.num_voxels())
                .find(|&v| field.centre_of(v) == c)
                .expect("a centre is a voxel centre");
            prop_assert!(valid[v]);
            centres.push(c.to_array().map(f32::to_bits));
        }
        centres.sort_unstable();
        centres.dedup();
        prop_assert_eq!(centres.len(), nodes);
        let b = field.bounds();
        let mut rng = Pcg64Mcg::seed_from_u64(seed + 1);
        let mut w = KernelWeights::default();
        for i in 0..500 {
            let t = if i < 8 {
                Vec3::new((i & 1) as f32, ((i >> 1) & 1) as f32, (i >> 2) as f32)
            } else {
                Vec3::new(rng.random(), rng.random(), rng.random())
            };
            let x = b.min + t * b.size();
            basis.eval(x, &mut w).unwrap();
            prop_assert!((w.sum() - 1.0).abs() < 1e-5, "x {:?}: sum {}", x, w.sum());
        }
    }
}

#[test]
fn same_seed_same_kernels_other_seed_other_kernels() {
    let (field, valid) = scene(3);
    for placement in [Placement::Uniform, Placement::Energy, Placement::Variation] {
        let a = scene_adapted_basis(&field, &valid, 20, &options(placement, 5)).unwrap();
        let b = scene_adapted_basis(&field, &valid, 20, &options(placement, 5)).unwrap();
        assert_eq!(a, b);
        let c = scene_adapted_basis(&field, &valid, 20, &options(placement, 6)).unwrap();
        assert_ne!(a.centres(), c.centres(), "{placement:?}");
    }
    // As many nodes as valid voxels: one kernel at every valid voxel.
    let count = valid.iter().filter(|&&v| v).count();
    let all = scene_adapted_basis(&field, &valid, count, &options(Placement::Energy, 0)).unwrap();
    assert_eq!(all.len(), count);
}

/// The energy weighting draws centres to the strong half (x ≥ 6 voxels, 30× the field) more
/// than the uniform placement, which follows the valid voxels' positions only.
#[test]
fn energy_placement_follows_the_field_strength() {
    let (field, valid) = scene(1);
    let split = field.bounds().min.x + 6.0 * field.voxel_size().x;
    let strong = |placement| {
        let basis = scene_adapted_basis(&field, &valid, 24, &options(placement, 2)).unwrap();
        basis.centres().iter().filter(|c| c.x > split).count()
    };
    let (uniform, energy) = (strong(Placement::Uniform), strong(Placement::Energy));
    assert!(
        energy >= uniform + 4,
        "uniform {uniform} of 24, energy {energy}"
    );
}

#[test]
fn mbd_with_adapted_basis_fits_and_beats_global_pca() {
    let (field, valid) = scene(4);
    let basis = scene_adapted_basis(&field, &valid, 12, &options(Placement::Energy, 0)).unwrap();
    let mbd = Mbd {
        basis_nodes: [2, 2, 2],
        options: MbdOptions {
            rank: 1,
            max_iterations: 24,
            ..MbdOptions::default()
        },
    };
    let (coefficients, _) = mbd.kernels(&field).unwrap();
    let (model, report) = solve(&field, coefficients, basis, &mbd.options, &NoProgress).unwrap();
    assert!(report.history.iter().all(|r| r.loss_after <= r.loss_before));
    let ours = evaluate(&model, &field, &EvalOptions::default()).unwrap();
    let pca = GlobalPca { rank: 1 }.compress(&field, &NoProgress).unwrap();
    let pca = evaluate(&pca, &field, &EvalOptions::default()).unwrap();
    assert!(
        ours.relative_mse < 0.5 * pca.relative_mse,
        "MBD {} vs PCA {}",
        ours.relative_mse,
        pca.relative_mse
    );
}

#[test]
fn bad_input_is_a_typed_error() {
    let (field, valid) = scene(0);
    let o = AdaptedBasisOptions::default();
    assert!(matches!(
        scene_adapted_basis(&field, &valid[1..], 4, &o),
        Err(MbdError::ShapeMismatch { .. })
    ));
    let count = valid.iter().filter(|&&v| v).count();
    for nodes in [0, count + 1] {
        assert!(matches!(
            scene_adapted_basis(&field, &valid, nodes, &o),
            Err(MbdError::InvalidOption { what: "nodes", .. })
        ));
    }
    assert!(matches!(
        scene_adapted_basis(&field, &vec![false; valid.len()], 1, &o),
        Err(MbdError::InvalidOption { what: "nodes", .. })
    ));
    let zero_neighbours = AdaptedBasisOptions {
        neighbours: 0,
        ..AdaptedBasisOptions::default()
    };
    assert!(matches!(
        scene_adapted_basis(&field, &valid, 4, &zero_neighbours),
        Err(MbdError::InvalidOption {
            what: "neighbours",
            ..
        })
    ));
    let mut bad = field.clone();
    bad.data_mut()[[7, 2]] = f32::NAN;
    assert!(matches!(
        scene_adapted_basis(&bad, &valid, 4, &o),
        Err(MbdError::Core(CoreError::NonFinite { .. }))
    ));
}

/// A zero field (all weights zero) falls back to uniform weights: the same kernels as the
/// uniform placement.
#[test]
fn zero_field_places_like_uniform() {
    let (field, valid) = scene(2);
    let zero = GridField::from_fn(field.dims(), field.bounds(), 5, |_, out| out.fill(0.0)).unwrap();
    let energy = scene_adapted_basis(&zero, &valid, 10, &options(Placement::Energy, 1)).unwrap();
    let uniform = scene_adapted_basis(&zero, &valid, 10, &options(Placement::Uniform, 1)).unwrap();
    assert_eq!(energy, uniform);
}
