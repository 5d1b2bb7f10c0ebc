//! The sparse bake traces exactly what the dense bake traces, on the voxels it keeps.

use proptest::prelude::*;
use prt_core::NoProgress;
use prt_trace::bricks::{BrickMap, BrickOptions};
use prt_trace::{BakeOptions, Scene, TransferBaker};

/// The Cornell box in a grid reaching past its walls: the outside sees back faces (invalid), so
/// whole bricks are dropped; 11 voxels per axis cut the upper bricks short.
fn options() -> BakeOptions {
    let scene_box = Scene::cornell_box()
        .bounds()
        .expect("the box has triangles");
    let grown = scene_box.expand(0.6 * scene_box.size().max_element());
    BakeOptions {
        resolution: [11, 10, 11],
        bounds: Some(grown),
        rays_per_voxel: 48,
        probe_rays: 24,
        cache_rays: 8,
        seed: 3,
        ..BakeOptions::default()
    }
}

#[test]
fn the_sparse_bake_equals_the_dense_one_bit_for_bit_on_the_kept_voxels() {
    sparse_equals_dense(options());
}

/// With adaptive sampling and the denoiser too: the filter reads the same valid neighbours.
#[test]
fn the_denoised_sparse_bake_equals_the_denoised_dense_one() {
    sparse_equals_dense(BakeOptions {
        adaptive: Some(prt_trace::AdaptiveSampling {
            target_error: 0.1,
            min_rays: 24,
        }),
        denoise: Some(prt_trace::DenoiseOptions::default()),
        ..options()
    });
}

fn sparse_equals_dense(options: BakeOptions) {
    let scene = Scene::cornell_box();
    let baker = TransferBaker::new(&scene, options).expect("valid options");
    let dense = baker.bake(&NoProgress).expect("dense bake");
    let sparse = baker
        .bake_bricks(&BrickOptions::default(), &NoProgress)
        .expect("sparse bake");
    assert_eq!(
        sparse.valid, dense.valid,
        "validity is the probe's, in both"
    );
    let stored = sparse.bricks.kept_bricks();
    assert!(
        stored > 0 && stored < sparse.bricks.bricks(),
        "some bricks dropped, some kept: {stored} of {}",
        sparse.bricks.bricks()
    );
    assert_eq!(sparse.brick_stats.traced_voxels, dense.stats.valid_voxels());
    let back = sparse.to_dense().expect("dense copy");
    for v in 0..dense.field.num_voxels() {
        let (a, b) = (dense.field.voxel(v), back.field.voxel(v));
        assert!(
            a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits()),
            "voxel {v} (valid {})",
            dense.valid[v]
        );
    }
}

#[test]
fn a_distance_limit_drops_bricks_far_from_geometry() {
    let scene = Scene::cornell_box();
    let baker = TransferBaker::new(&scene, options()).expect("valid options");
    let all = baker
        .bake_bricks(&BrickOptions::default(), &NoProgress)
        .expect("sparse bake");
    let near = BrickOptions {
        max_distance: Some(0.05 * scene.bounds().expect("box").size().max_element()),
        ..BrickOptions::default()
    };
    let some = baker.bake_bricks(&near, &NoProgress).expect("sparse bake");
    assert!(some.bricks.kept_bricks() < all.bricks.kept_bricks());
    assert!(some.brick_stats.dropped_valid_voxels > 0);
    // What is kept is what the full sparse bake has there.
    for v in (0..some.valid.len()).filter(|&v| some.valid[v]) {
        assert_eq!(some.voxel(v), all.voxel(v), "voxel {v}");
    }
    assert!(
        baker
            .bake_bricks(
                &BrickOptions {
                    edge: 0,
                    ..BrickOptions::default()
                },
                &NoProgress
            )
            .is_err()
    );
}

proptest! {
    /// Every voxel of a kept brick has its own row, inside the stored data; no other voxel has one.
    #[test]
    fn brick_rows_are_a_bijection_onto_the_kept_bricks(
        dims in prop::array::uniform3(1usize..10),
        edge in 1usize..5,
        mask in prop::collection::vec(any::<bool>(), 1000),
    ) {
        let voxels: usize = dims.iter().product();
        let keep = &mask[..voxels];
        let map = BrickMap::from_voxels(dims, edge, keep);
        let mut seen = vec![false; map.stored_voxels()];
        for v in 0..voxels {
            match map.row(v) {
                Some(r) => {
                    prop_assert!(!seen[r]);
                    seen[r] = true;
                    let b = map.brick_of(v);
                    prop_assert_eq!(map.voxel_in_brick(b, r % edge.pow(3)), Some(v));
                }
                None => prop_assert!(!keep[v]),
            }
            if keep[v] {
                prop_assert!(map.row(v).is_some());
            }
        }
    }
}
