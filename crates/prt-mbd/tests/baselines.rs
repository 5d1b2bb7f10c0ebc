//! The PCA-family baselines, the evaluation and the seam metric.

use prt_core::{Aabb, Compressor, CoreError, FieldModel, GridField, NoProgress, resample_to_grid};
use prt_mbd::*;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

/// A field whose voxels lie in subspace `pick(v)` (of `subspaces`, each of dimension `rank`).
fn piecewise_subspace_field(
    dims: [usize; 3],
    dim: usize,
    rank: usize,
    subspaces: usize,
    pick: impl Fn([usize; 3]) -> usize,
) -> GridField {
    let mut rng = Pcg64Mcg::seed_from_u64(9);
    let bases: Vec<f32> = (0..subspaces * rank * dim)
        .map(|_| rng.random::<f32>() - 0.5)
        .collect();
    let mut field = GridField::new(dims, Aabb::UNIT, dim).unwrap();
    for v in 0..field.num_voxels() {
        let s = pick(field.coords(v));
        let out = field.voxel_mut(v);
        for l in 0..rank {
            let c = rng.random::<f32>() * 2.0 - 1.0;
            for d in 0..dim {
                out[d] += c * bases[(s * rank + l) * dim + d];
            }
        }
    }
    field
}

fn rel(model: &dyn FieldModel, field: &GridField) -> f64 {
    evaluate(model, field, &EvalOptions::default())
        .unwrap()
        .relative_mse
}

#[test]
fn global_pca_is_exact_on_a_global_rank_l_field_and_counts_its_storage() {
    let field = piecewise_subspace_field([5, 4, 3], 8, 3, 1, |_| 0);
    let model = GlobalPca { rank: 3 }.compress(&field, &NoProgress).unwrap();
    assert!(rel(&model, &field) < 1e-10);
    assert_eq!(model.stored_scalars(), 3 * 8 + 60 * 3);
    // Rank D reproduces anything.
    let noise = SyntheticField {
        dims: [4, 4, 4],
        dim: 5,
        harmonics: 4,
        seed: 2,
    }
    .build(Aabb::UNIT)
    .unwrap();
    let full = GlobalPca { rank: 5 }.compress(&noise, &NoProgress).unwrap();
    assert!(rel(&full, &noise) < 1e-10);
}

#[test]
fn block_pca_is_exact_when_each_block_has_its_own_subspace() {
    let field = piecewise_subspace_field([6, 4, 4], 7, 2, 8, |c| {
        (c[0] / 3) + 2 * (c[1] / 2) + 4 * (c[2] / 2)
    });
    let bpca = BlockPca {
        rank: 2,
        blocks: [2, 2, 2],
        window: 1.0,
    }
    .compress(&field, &NoProgress)
    .unwrap();
    assert!(rel(&bpca, &field) < 1e-10, "{}", rel(&bpca, &field));
    assert_eq!(bpca.stored_scalars(), 8 * 2 * 7 + 96 * 2);
    // The window mixes neighbouring subspaces into each fit: no longer exact.
    let wbpca = BlockPca {
        rank: 2,
        blocks: [2, 2, 2],
        window: 2.0,
    }
    .compress(&field, &NoProgress)
    .unwrap();
    assert!(rel(&wbpca, &field) > 1e-3);
    assert_eq!(wbpca.name(), "WBPCA rank 2");
}

#[test]
fn clustered_pca_separates_interleaved_subspaces() {
    // A checkerboard of two subspaces: no spatial block structure helps, clustering does.
    let field = piecewise_subspace_field([6, 6, 6], 9, 2, 2, |c| (c[0] + c[1] + c[2]) % 2);
    let cpca = ClusteredPca::new(2, 2)
        .compress(&field, &NoProgress)
        .unwrap();
    assert!(rel(&cpca, &field) < 1e-8, "{}", rel(&cpca, &field));
    let bpca = BlockPca {
        rank: 2,
        blocks: [2, 1, 1],
        window: 1.0,
    }
    .compress(&field, &NoProgress)
    .unwrap();
    assert!(rel(&bpca, &field) > 1e-2);
}

#[test]
fn vector_quantisation_is_exact_with_one_codeword_per_distinct_value() {
    let field = GridField::from_fn([5, 5, 2], Aabb::UNIT, 3, |p, out| {
        let k = ((p.x * 3.0) as usize).min(2) as f32;
        out.copy_from_slice(&[k, 1.0 - k, 2.0 * k]);
    })
    .unwrap();
    let vq = KMeansVq {
        codewords: 3,
        iterations: 20,
        seed: 1,
    }
    .compress(&field, &NoProgress)
    .unwrap();
    assert!(rel(&vq, &field) < 1e-12);
    assert_eq!(vq.stored_scalars(), 3 * 3 + 50);
}

#[test]
fn baselines_reject_bad_input() {
    let field = SyntheticField {
        dims: [4, 4, 4],
        dim: 5,
        harmonics: 2,
        seed: 1,
    }
    .build(Aabb::UNIT)
    .unwrap();
    assert!(matches!(
        GlobalPca { rank: 0 }.compress(&field, &NoProgress),
        Err(MbdError::InvalidRank { .. })
    ));
    assert!(matches!(
        GlobalPca { rank: 6 }.compress(&field, &NoProgress),
        Err(MbdError::InvalidRank { .. })
    ));
    let blocks = BlockPca {
        rank: 2,
        blocks: [5, 1, 1],
        window: 1.0,
    }
    .compress(&field, &NoProgress);
    assert!(matches!(
        blocks,
        Err(MbdError::InvalidOption { what: "blocks", .. })
    ));
    let window = BlockPca {
        rank: 2,
        blocks: [2, 2, 2],
        window: 0.5,
    }
    .compress(&field, &NoProgress);
    assert!(matches!(
        window,
        Err(MbdError::InvalidOption { what: "window", .. })
    ));
    assert!(matches!(
        ClusteredPca::new(2, 0).compress(&field, &NoProgress),
        Err(MbdError::InvalidOption { .. })
    ));
    let mut nan = field.clone();
    nan.data_mut()[[3, 1]] = f32::INFINITY;
    assert_eq!(
        GlobalPca { rank: 2 }
            .compress(&nan, &NoProgress)
            .unwrap_err(),
        MbdError::Core(CoreError::NonFinite {
            what: "field data",
            index: 3 * 5 + 1
        })
    );
}

#[test]
fn evaluation_reports_per_block_operator_errors_and_rejects_bad_blocks() {
    let field = SyntheticField {
        dims: [4, 4, 4],
        dim: 6,
        harmonics: 2,
        seed: 3,
    }
    .build(Aabb::UNIT)
    .unwrap();
    let model = GlobalPca { rank: 1 }.compress(&field, &NoProgress).unwrap();
    let options = EvalOptions {
        blocks: vec![2, 4],
        ..EvalOptions::default()
    };
    let e = evaluate(&model, &field, &options).unwrap();
    assert_eq!(e.block_relative_frobenius.len(), 2);
    // The blocks' squared errors add up to the whole: min ≤ sqrt(relative MSE) ≤ max.
    let (lo, hi) = (
        e.block_relative_frobenius[0].min(e.block_relative_frobenius[1]),
        e.block_relative_frobenius[0].max(e.block_relative_frobenius[1]),
    );
    assert!(lo <= e.relative_mse.sqrt() + 1e-12 && e.relative_mse.sqrt() <= hi + 1e-12);
    assert!(e.relative_mse > 1e-4);
    let bad = EvalOptions {
        blocks: vec![2, 3],
        ..EvalOptions::default()
    };
    assert!(matches!(
        evaluate(&model, &field, &bad),
        Err(MbdError::InvalidOption { what: "blocks", .. })
    ));
}

/// On a smooth field, BPCA's error jumps at block boundaries while MBD's changes smoothly.
#[test]
fn seam_metric_is_large_for_bpca_and_small_for_mbd() {
    let field = SyntheticField {
        dims: [16, 16, 16],
        dim: 16,
        harmonics: 2,
        seed: 5,
    }
    .build(Aabb::UNIT)
    .unwrap();
    let bpca = BlockPca {
        rank: 2,
        blocks: [3, 3, 3],
        window: 1.0,
    }
    .compress(&field, &NoProgress)
    .unwrap();
    let bpca_seam = seam_metric(&field, bpca.reconstruction(), bpca.labels()).unwrap();
    let mbd = Mbd {
        basis_nodes: [3, 3, 3],
        options: MbdOptions {
            rank: 2,
            max_iterations: 16,
            ..MbdOptions::default()
        },
    };
    let (model, _) = mbd.fit(&field, &NoProgress).unwrap();
    let recon = resample_to_grid(&model, field.dims(), field.bounds()).unwrap();
    let labels = kernel_labels(model.basis_kernels(), &field).unwrap();
    let mbd_seam = seam_metric(&field, &recon, &labels).unwrap();
    assert!(
        mbd_seam.boundary < 0.25 * bpca_seam.boundary,
        "MBD {mbd_seam:?} vs BPCA {bpca_seam:?}"
    );
    // BPCA's boundary jumps dwarf its interior ones; MBD's boundaries look like its interior.
    assert!(
        bpca_seam.boundary > 2.0 * bpca_seam.interior,
        "{bpca_seam:?}"
    );
    assert!(mbd_seam.boundary < 2.0 * mbd_seam.interior, "{mbd_seam:?}");
}

#[test]
fn seam_metric_extremes() {
    let field = SyntheticField {
        dims: [4, 4, 4],
        dim: 3,
        harmonics: 1,
        seed: 1,
    }
    .build(Aabb::UNIT)
    .unwrap();
    // A perfect reconstruction has no jumps; a single cluster has no boundary.
    let s = seam_metric(&field, &field, &[0; 64]).unwrap();
    assert_eq!((s.boundary, s.interior), (0.0, 0.0));
    assert!(seam_metric(&field, &field, &[0; 63]).is_err());
    // A zero field with a non-zero reconstruction still shows its (unnormalised) jumps.
    let zero = GridField::new([4, 4, 4], Aabb::UNIT, 3).unwrap();
    let labels: Vec<u32> = (0..64).map(|v| (v % 4 >= 2) as u32).collect();
    let s = seam_metric(&zero, &field, &labels).unwrap();
    assert!(s.boundary > 0.0 && s.boundary.is_finite());
}
