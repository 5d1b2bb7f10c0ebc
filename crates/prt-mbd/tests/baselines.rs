//! The PCA-family baselines, the evaluation and the error seams.

use prt_core::{Aabb, Compressor, CoreError, FieldModel, GridField, NoProgress, resample_to_grid};
use prt_mbd::expert::{kernel_labels, nonzero_voxels};
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

/// The error seams with the default options.
fn seams(field: &GridField, recon: &GridField, labels: &[u32]) -> Result<ErrorSeams, MbdError> {
    error_seams(field, recon, labels, &SeamOptions::default())
}

/// Rank 2 on a 3³ hat grid, 16 iterations.
fn short_mbd() -> Mbd {
    let mut mbd = Mbd::new(2, Basis::HatGrid { nodes: [3, 3, 3] });
    mbd.solver.max_iterations = 16;
    mbd
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
        loss_weighting: None,
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
        loss_weighting: None,
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
        loss_weighting: None,
    }
    .compress(&field, &NoProgress)
    .unwrap();
    assert!(rel(&bpca, &field) > 1e-2);
}

/// CPCA with its own labels given reproduces its fit; the true checkerboard labels are exact,
/// labels that ignore it are not; a label per voxel is required.
#[test]
fn clustered_pca_with_given_labels_fits_those_clusters() {
    let field = piecewise_subspace_field([6, 6, 6], 9, 2, 2, |c| (c[0] + c[1] + c[2]) % 2);
    let cpca = ClusteredPca::new(2, 3)
        .compress(&field, &NoProgress)
        .unwrap();
    let again = ClusteredPca::with_labels(&field, cpca.labels().to_vec(), 2, &NoProgress).unwrap();
    let gap = again
        .reconstruct()
        .unwrap()
        .data()
        .iter()
        .zip(cpca.reconstruct().unwrap().data().iter())
        .map(|(a, b)| (a - b).abs())
        .fold(0.0f32, f32::max);
    assert!(gap < 1e-5, "{gap}");
    let checkerboard: Vec<u32> = (0..216)
        .map(|v| ((v % 6 + (v / 6) % 6 + v / 36) % 2) as u32)
        .collect();
    let exact = ClusteredPca::with_labels(&field, checkerboard, 2, &NoProgress).unwrap();
    assert!(rel(&exact, &field) < 1e-8, "{}", rel(&exact, &field));
    let halves: Vec<u32> = (0..216).map(|v| u32::from(v % 6 >= 3)).collect();
    let wrong = ClusteredPca::with_labels(&field, halves, 2, &NoProgress).unwrap();
    assert!(rel(&wrong, &field) > 1e-2, "{}", rel(&wrong, &field));
    assert!(matches!(
        ClusteredPca::with_labels(&field, vec![0; 215], 2, &NoProgress),
        Err(MbdError::ShapeMismatch { what: "labels", .. })
    ));
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
        loss_weighting: None,
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
        loss_weighting: None,
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
fn error_seams_are_large_for_bpca_and_small_for_mbd() {
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
        loss_weighting: None,
    }
    .compress(&field, &NoProgress)
    .unwrap();
    let bpca_seam = seams(&field, &bpca.reconstruct().unwrap(), bpca.labels()).unwrap();
    let model = short_mbd().fit(&field, &NoProgress).unwrap().model;
    let recon = resample_to_grid(&model, field.dims(), field.bounds()).unwrap();
    let labels = kernel_labels(model.basis_kernels(), &field).unwrap();
    let mbd_seam = seams(&field, &recon, &labels).unwrap();
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
fn error_seams_extremes() {
    let field = SyntheticField {
        dims: [4, 4, 4],
        dim: 3,
        harmonics: 1,
        seed: 1,
    }
    .build(Aabb::UNIT)
    .unwrap();
    // A perfect reconstruction has no jumps; a single cluster has no boundary.
    let s = seams(&field, &field, &[0; 64]).unwrap();
    assert_eq!((s.boundary, s.interior), (0.0, 0.0));
    assert!(seams(&field, &field, &[0; 63]).is_err());
    // A zero field with a non-zero reconstruction still shows its (unnormalised) jumps.
    let zero = GridField::new([4, 4, 4], Aabb::UNIT, 3).unwrap();
    let labels: Vec<u32> = (0..64).map(|v| (v % 4 >= 2) as u32).collect();
    let s = seams(&zero, &field, &labels).unwrap();
    assert!(s.boundary > 0.0 && s.boundary.is_finite());
}

/// `field` plus independent uniform noise of RMS `rms` per component (seeded), like the Monte
/// Carlo noise of a traced volume.
fn with_noise(field: &GridField, rms: f32, seed: u64) -> GridField {
    let mut rng = Pcg64Mcg::seed_from_u64(seed);
    let mut noisy = field.clone();
    // Uniform on [-a, a] has RMS a / √3.
    let a = rms * 3f32.sqrt();
    noisy
        .data_mut()
        .iter_mut()
        .for_each(|x| *x += a * (2.0 * rng.random::<f32>() - 1.0));
    noisy
}

#[test]
fn denoised_seam_ratio_separates_bpca_from_mbd_on_a_noisy_field() {
    let clean = SyntheticField {
        dims: [16, 16, 16],
        dim: 16,
        harmonics: 2,
        seed: 5,
    }
    .build(Aabb::UNIT)
    .unwrap();
    let rms = (clean.data().iter().map(|&x| x * x).sum::<f32>() / clean.data().len() as f32).sqrt();
    let field = with_noise(&clean, 0.05 * rms, 3);
    let bpca = BlockPca {
        rank: 2,
        blocks: [3, 3, 3],
        window: 1.0,
        loss_weighting: None,
    }
    .compress(&field, &NoProgress)
    .unwrap();
    let model = short_mbd().fit(&field, &NoProgress).unwrap().model;
    let recon = resample_to_grid(&model, field.dims(), field.bounds()).unwrap();
    let labels = kernel_labels(model.basis_kernels(), &field).unwrap();
    let denoised = SeamOptions::denoised();
    let bpca_recon = bpca.reconstruct().unwrap();
    let bpca_raw = seams(&field, &bpca_recon, bpca.labels()).unwrap();
    let bpca_seam = error_seams(&field, &bpca_recon, bpca.labels(), &denoised).unwrap();
    let mbd_raw = seams(&field, &recon, &labels).unwrap();
    let mbd_seam = error_seams(&field, &recon, &labels, &denoised).unwrap();
    // The noise sits in every error and pulls the raw ratios towards 1; the blur removes it, so
    // BPCA's steps stand out and MBD's boundaries look like its interior.
    assert!(
        bpca_seam.ratio() > 1.5 * bpca_raw.ratio(),
        "BPCA raw {bpca_raw:?}, denoised {bpca_seam:?}"
    );
    assert!(bpca_seam.ratio() > 2.0, "{bpca_seam:?}");
    assert!(mbd_seam.ratio() < 1.3, "{mbd_seam:?}");
    assert!(
        mbd_seam.ratio() < 0.5 * bpca_seam.ratio(),
        "MBD {mbd_seam:?} (raw {mbd_raw:?}) vs BPCA {bpca_seam:?}"
    );
}

#[test]
fn denoising_the_reference_neither_creates_nor_hides_a_boundary() {
    let dims = [12, 12, 12];
    // A constant reference: the normalised blur leaves it exactly as it is, edges included.
    let field = GridField::from_fn(dims, Aabb::UNIT, 2, |_, out| {
        out[0] = 1.0;
        out[1] = 0.5;
    })
    .unwrap();
    // Labels: x < 0.5 and x ≥ 0.5.
    let labels: Vec<u32> = (0..field.num_voxels())
        .map(|v| (field.coords(v)[0] >= 6) as u32)
        .collect();
    let denoised = SeamOptions::denoised();
    // A smooth error (a ramp in x): boundaries look exactly like the interior.
    let ramp = GridField::from_fn(dims, Aabb::UNIT, 2, |p, out| {
        out[0] = 1.0 + 0.1 * p.x;
        out[1] = 0.5;
    })
    .unwrap();
    for options in [SeamOptions::default(), denoised] {
        let s = error_seams(&field, &ramp, &labels, &options).unwrap();
        assert!((s.ratio() - 1.0).abs() < 1e-4, "{s:?}");
    }
    // A step of the error at the boundary: no interior jump, the full step across it.
    let step = GridField::from_fn(dims, Aabb::UNIT, 2, |p, out| {
        out[0] = 1.0 + if p.x >= 0.5 { 0.1 } else { 0.0 };
        out[1] = 0.5;
    })
    .unwrap();
    let step_height = 0.1 / 1.25f64.sqrt();
    for options in [SeamOptions::default(), denoised] {
        let s = error_seams(&field, &step, &labels, &options).unwrap();
        assert_eq!(s.interior, 0.0);
        assert_eq!(s.ratio(), f64::INFINITY);
        assert!(
            (s.boundary - step_height).abs() < 1e-5 * step_height,
            "{s:?} vs {step_height}"
        );
    }
    // With noise on the reference, the raw metric sees the noise everywhere; denoised, the step
    // stands out again.
    let noisy = with_noise(&field, 0.05, 7);
    let raw = seams(&noisy, &step, &labels).unwrap();
    let clean = error_seams(&noisy, &step, &labels, &denoised).unwrap();
    assert!(raw.ratio() < 2.0, "{raw:?}");
    assert!(clean.ratio() > 3.0 * raw.ratio(), "{clean:?} vs {raw:?}");
}

#[test]
fn error_seams_skip_excluded_voxels_and_reject_bad_options() {
    let field = SyntheticField {
        dims: [8, 8, 8],
        dim: 3,
        harmonics: 1,
        seed: 2,
    }
    .build(Aabb::UNIT)
    .unwrap();
    let labels: Vec<u32> = (0..512).map(|v| (field.coords(v)[0] >= 4) as u32).collect();
    let valid: Vec<bool> = (0..512).map(|v| field.coords(v)[1] < 5).collect();
    let recon = with_noise(&field, 0.05, 1);
    // Garbage in the excluded voxels (of the field and the reconstruction) changes nothing.
    let (mut field_garbage, mut recon_garbage) = (field.clone(), recon.clone());
    for v in (0..512).filter(|&v| !valid[v]) {
        field_garbage.voxel_mut(v).fill(1e6);
        recon_garbage.voxel_mut(v).fill(-1e6);
    }
    for sigma in [0.0, 1.0] {
        let options = SeamOptions {
            denoise_sigma: sigma,
            valid: Some(&valid),
        };
        let s = error_seams(&field, &recon, &labels, &options).unwrap();
        let g = error_seams(&field_garbage, &recon_garbage, &labels, &options).unwrap();
        assert!(s.boundary > 0.0 && s.interior > 0.0, "{s:?}");
        assert!(
            (s.boundary - g.boundary).abs() <= 1e-9 * s.boundary,
            "{s:?} vs {g:?}"
        );
        assert!(
            (s.interior - g.interior).abs() <= 1e-9 * s.interior,
            "{s:?} vs {g:?}"
        );
    }
    for sigma in [-1.0, f64::NAN, f64::INFINITY] {
        let bad = SeamOptions {
            denoise_sigma: sigma,
            valid: None,
        };
        assert!(matches!(
            error_seams(&field, &recon, &labels, &bad),
            Err(MbdError::InvalidOption { .. })
        ));
    }
    let short = vec![true; 511];
    let bad = SeamOptions {
        denoise_sigma: 0.0,
        valid: Some(&short),
    };
    assert!(error_seams(&field, &recon, &labels, &bad).is_err());
}

#[test]
fn blocks_of_zero_voxels_are_handled() {
    // Like a traced volume whose voxels inside geometry are invalid (zero transfer): whole
    // blocks are zero. Both branches of the subspace fit: more voxels than D, and fewer.
    for dim in [4, 324] {
        let mut field = SyntheticField {
            dims: [12, 12, 12],
            dim,
            harmonics: 2,
            seed: 3,
        }
        .build(Aabb::UNIT)
        .unwrap();
        for v in 0..field.num_voxels() {
            if field.coords(v)[0] < 6 {
                field.voxel_mut(v).fill(0.0);
            }
        }
        let bpca = BlockPca {
            rank: 2,
            blocks: [2, 2, 2],
            window: 1.0,
            loss_weighting: None,
        }
        .compress(&field, &NoProgress)
        .unwrap();
        let bpca_recon = bpca.reconstruct().unwrap();
        for v in (0..field.num_voxels()).filter(|&v| field.coords(v)[0] < 6) {
            assert!(bpca_recon.voxel(v).iter().all(|&x| x == 0.0));
        }
        let e = rel(&bpca, &field);
        assert!(e.is_finite() && e < 0.5, "D = {dim}: {e}");
        let mut mbd = Mbd::new(2, Basis::HatGrid { nodes: [3, 3, 3] });
        mbd.solver.max_iterations = 4;
        let mbd = mbd.fit(&field, &NoProgress).unwrap().model;
        assert!(rel(&mbd, &field).is_finite());
    }
}

#[test]
fn nonzero_voxels_marks_voxels_with_any_non_zero_value() {
    let field = GridField::from_fn([3, 1, 1], Aabb::UNIT, 2, |x, out| {
        out[0] = 0.0;
        out[1] = if x.x < 0.5 { -1e-30 } else { 0.0 };
    })
    .unwrap();
    assert_eq!(nonzero_voxels(&field), vec![true, false, false]);
}
