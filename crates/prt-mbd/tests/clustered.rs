//! `LabelKernels` and `Basis::Clusters`: MBD on clustered PCA's clusters.

use glam::Vec3;
use proptest::prelude::*;
use prt_core::{
    Aabb, Compressor, FieldModel, GridField, KernelWeights, NoProgress, SpatialKernels,
};
use prt_mbd::expert::{LabelKernels, fit_on_clusters};
use prt_mbd::*;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

mod common;
use common::dense;

fn bounds() -> Aabb {
    Aabb::new(Vec3::new(-1.0, 0.5, 2.0), Vec3::new(2.0, 1.5, 2.8))
}

fn random_labels(n: usize, len: usize, seed: u64) -> Vec<u32> {
    let mut rng = Pcg64Mcg::seed_from_u64(seed);
    (0..n).map(|_| rng.random_range(0..len as u32)).collect()
}

/// [`Mbd`] of rank `rank` on `count` clusters with the default smoothing and solver.
fn clustered(rank: usize, count: usize) -> Mbd {
    Mbd::new(
        rank,
        Basis::Clusters {
            count,
            smoothing: LabelSmoothing::default(),
        },
    )
}

fn point(bounds: Aabb, u: [f32; 3]) -> Vec3 {
    bounds.min + bounds.size() * Vec3::from(u)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(24))]

    /// A non-negative partition of unity everywhere, continuous (a small step moves the weights
    /// by at most the step times the largest weight gradient of trilinear interpolation), and
    /// never more kernels at a point than `max_support`.
    #[test]
    fn label_kernels_are_a_continuous_partition_of_unity(
        dims in [1usize..6, 1usize..6, 1usize..6],
        len in 1usize..6,
        radius in 0usize..3,
        falloff in 0.1f32..=1.0,
        with_mask in any::<bool>(),
        seed in 0u64..1000,
        u in [0.0f32..1.0, 0.0f32..1.0, 0.0f32..1.0],
    ) {
        let n = dims.iter().product();
        let labels = random_labels(n, len, seed);
        let valid: Vec<bool> = (0..n).map(|v| !(v as u64 + seed).is_multiple_of(3)).collect();
        let kernels = LabelKernels::new(
            dims,
            bounds(),
            &labels,
            len,
            with_mask.then_some(valid.as_slice()),
            &LabelSmoothing { radius, falloff },
        )
        .unwrap();
        let x = point(bounds(), u);
        let w = dense(&kernels, x);
        prop_assert!(w.iter().all(|&wi| wi >= 0.0));
        prop_assert!((w.iter().sum::<f64>() - 1.0).abs() < 1e-5);
        prop_assert!(w.iter().filter(|&&wi| wi > 0.0).count() <= kernels.max_support());
        // Trilinear interpolation of values in [0, 1]: |∂w/∂x_k| ≤ voxels per unit length.
        let h = 1e-3f32;
        let step = Vec3::splat(h) * bounds().size();
        let near = dense(&kernels, x + step);
        let largest = w.iter().zip(&near).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
        prop_assert!(largest <= 3.0 * f64::from(h) * dims.iter().max().copied().unwrap() as f64 + 1e-5,
            "weights jump by {largest} over a step of {h} of the box");
    }
}

/// Radius 0 at a voxel centre is the indicator of the voxel's label; with one label every
/// weight is that kernel's.
#[test]
fn sharp_labels_are_indicators_at_voxel_centres() {
    let dims = [4, 3, 5];
    let field = GridField::new(dims, bounds(), 1).unwrap();
    let labels = random_labels(60, 4, 7);
    let sharp = LabelSmoothing {
        radius: 0,
        falloff: 0.5,
    };
    let kernels = LabelKernels::new(dims, bounds(), &labels, 4, None, &sharp).unwrap();
    for v in 0..60 {
        let w = dense(&kernels, field.centre_of(v));
        for (k, &wk) in w.iter().enumerate() {
            let expected = if k == labels[v] as usize { 1.0 } else { 0.0 };
            assert!((wk - expected).abs() < 1e-5, "voxel {v}, kernel {k}: {wk}");
        }
    }
    let one = LabelKernels::new(dims, bounds(), &[0; 60], 1, None, &Default::default()).unwrap();
    assert_eq!(one.max_support(), 1);
    let w = dense(&one, Vec3::new(0.3, 0.9, 2.1));
    assert!(w.len() == 1 && (w[0] - 1.0).abs() < 1e-6, "{w:?}");
}

/// With radius 1 and falloff 1 a voxel's weights are the label shares of its 3³ neighbours,
/// counting only valid neighbours (and itself).
#[test]
fn smoothing_counts_valid_neighbours_only() {
    let dims = [3, 3, 3];
    // Label 1 on the x = 0 face, 0 elsewhere; the centre voxel (13) sees 9 of 27 with label 1.
    let labels: Vec<u32> = (0..27)
        .map(|v: usize| u32::from(v.is_multiple_of(3)))
        .collect();
    let box_filter = LabelSmoothing {
        radius: 1,
        falloff: 1.0,
    };
    let all = LabelKernels::new(dims, bounds(), &labels, 2, None, &box_filter).unwrap();
    let shares = |k: &LabelKernels| k.voxel_weights(13).collect::<Vec<_>>();
    assert_eq!(shares(&all).len(), 2);
    assert!((shares(&all)[1].1 - 9.0 / 27.0).abs() < 1e-6);
    // The x = 0 face inside geometry: it no longer spreads its label.
    let valid: Vec<bool> = (0..27).map(|v: usize| !v.is_multiple_of(3)).collect();
    let masked = LabelKernels::new(dims, bounds(), &labels, 2, Some(&valid), &box_filter).unwrap();
    assert_eq!(shares(&masked), vec![(0, 1.0)]);
    // An invalid voxel keeps its own label beside its valid neighbours'.
    let own = masked.voxel_weights(12).collect::<Vec<_>>();
    assert_eq!(own.len(), 2);
    // Itself and the 9 valid neighbours at x = 1 of its 18 in the grid.
    assert!((own[1].1 - 1.0 / 10.0).abs() < 1e-6, "{own:?}");
}

#[test]
fn label_kernels_reject_bad_input() {
    let dims = [2, 2, 2];
    let labels = [0u32; 8];
    let ok = LabelSmoothing::default();
    let err = |r: Result<LabelKernels, MbdError>| r.unwrap_err();
    assert!(matches!(
        err(LabelKernels::new(
            dims,
            bounds(),
            &labels[..7],
            1,
            None,
            &ok
        )),
        MbdError::ShapeMismatch { what: "labels", .. }
    ));
    assert!(matches!(
        err(LabelKernels::new(
            dims,
            bounds(),
            &labels,
            1,
            Some(&[true; 3]),
            &ok
        )),
        MbdError::ShapeMismatch { what: "valid", .. }
    ));
    assert!(matches!(
        err(LabelKernels::new(
            dims,
            bounds(),
            &[0, 0, 0, 0, 0, 0, 0, 2],
            2,
            None,
            &ok
        )),
        MbdError::InvalidOption { what: "labels", .. }
    ));
    assert!(matches!(
        err(LabelKernels::new(dims, bounds(), &labels, 0, None, &ok)),
        MbdError::InvalidKernels { .. }
    ));
    assert!(matches!(
        err(LabelKernels::new([0, 2, 2], bounds(), &[], 1, None, &ok)),
        MbdError::InvalidKernels { .. }
    ));
    for falloff in [0.0, -0.5, 1.5, f32::NAN] {
        let smoothing = LabelSmoothing { radius: 1, falloff };
        assert!(matches!(
            err(LabelKernels::new(
                dims,
                bounds(),
                &labels,
                1,
                None,
                &smoothing
            )),
            MbdError::InvalidOption {
                what: "falloff",
                ..
            }
        ));
    }
    let wide = LabelSmoothing {
        radius: 5,
        falloff: 0.5,
    };
    assert!(matches!(
        err(LabelKernels::new(dims, bounds(), &labels, 1, None, &wide)),
        MbdError::InvalidOption { what: "radius", .. }
    ));
    let flat = Aabb::new(Vec3::ZERO, Vec3::new(1.0, 0.0, 1.0));
    assert!(matches!(
        err(LabelKernels::new(dims, flat, &labels, 1, None, &ok)),
        MbdError::InvalidKernels { .. }
    ));
    let kernels = LabelKernels::new(dims, bounds(), &labels, 1, None, &ok).unwrap();
    let mut w = KernelWeights::default();
    assert!(kernels.eval(Vec3::new(f32::NAN, 1.0, 2.5), &mut w).is_err());
}

/// Stripes four voxels wide alternate between two directions in R^12 (a smooth positive
/// amplitude times `a` or `b`). At rank 1 a hat grid cannot alternate its basis every four
/// voxels; MBD on clusters puts `a` and `b` on the two clusters and errs only where the smoothed
/// kernels blend across a stripe boundary (1.0e-2 against the hat grid's 0.19 when written).
#[test]
fn cluster_basis_follows_stripes_the_hat_grid_cannot() {
    let (dims, dim) = ([16, 6, 6], 12);
    let mut rng = Pcg64Mcg::seed_from_u64(11);
    let directions: Vec<Vec<f32>> = (0..2)
        .map(|_| (0..dim).map(|_| rng.random::<f32>() - 0.5).collect())
        .collect();
    let field = GridField::from_fn(dims, Aabb::UNIT, dim, |x, out| {
        let stripe = (x.x * 4.0) as usize % 2;
        let amplitude = 1.0 + x.y * x.z;
        for (o, &d) in out.iter_mut().zip(&directions[stripe]) {
            *o = amplitude * d;
        }
    })
    .unwrap();
    let eval = EvalOptions::default();
    let clustered = Mbd {
        rank: 1,
        basis: Basis::Clusters {
            count: 8,
            smoothing: LabelSmoothing {
                radius: 1,
                falloff: 0.5,
            },
        },
        solver: SolverOptions {
            max_iterations: 48,
            ..SolverOptions::default()
        },
        polish: None,
        coarse_start: None,
        loss_weighting: None,
        centre_projection: false,
    };
    let fit = clustered.fit(&field, &NoProgress).unwrap();
    assert!(fit.polish.is_none());
    let (model, report) = (fit.model, fit.solve);
    assert!(report.history.iter().all(|r| r.loss_after <= r.loss_before));
    let clustered_error = evaluate(&model, &field, &eval).unwrap().relative_mse;
    let hat = Mbd {
        basis: Basis::HatGrid { nodes: [2, 2, 2] },
        ..clustered.clone()
    };
    let hat_error = evaluate(&hat.fit(&field, &NoProgress).unwrap().model, &field, &eval)
        .unwrap()
        .relative_mse;
    assert!(
        clustered_error < 0.25 * hat_error,
        "clustered {clustered_error:.3e}, hat grid {hat_error:.3e}"
    );
    // Same model through the Compressor, and the same storage as MBD's tensors.
    let compressed = clustered.compress(&field, &NoProgress).unwrap();
    assert_eq!(compressed.stored_scalars(), model.stored_scalars());
    assert_eq!(
        model.stored_scalars(),
        model.coefficients().len() + model.basis().len()
    );
}

/// Clusters of another rank, zero clusters and fitting on clusters with a hat-grid basis are
/// typed errors.
#[test]
fn cluster_basis_rejects_mismatched_clusters() {
    let field = GridField::from_fn([4, 4, 4], Aabb::UNIT, 6, |x, out| {
        out.iter_mut()
            .enumerate()
            .for_each(|(d, o)| *o = x.x + d as f32 * x.y)
    })
    .unwrap();
    let cpca = ClusteredPca::new(2, 3)
        .compress(&field, &NoProgress)
        .unwrap();
    assert!(matches!(
        fit_on_clusters(&clustered(3, 3), &field, &cpca, &NoProgress),
        Err(MbdError::ShapeMismatch {
            what: "clusters",
            ..
        })
    ));
    assert!(matches!(
        clustered(2, 0).fit(&field, &NoProgress),
        Err(MbdError::InvalidKernels { which: "basis", .. })
    ));
    let hat = Mbd::new(2, Basis::HatGrid { nodes: [2, 2, 2] });
    assert!(matches!(
        fit_on_clusters(&hat, &field, &cpca, &NoProgress),
        Err(MbdError::InvalidOption { what: "basis", .. })
    ));
    assert!(fit_on_clusters(&clustered(2, 3), &field, &cpca, &NoProgress).is_ok());
}

/// The basis-projection seam ratio: a clustered basis that switches between two directions at a
/// cluster boundary makes a seam there; the same two bases as label kernels blended over two
/// voxels move continuously and make none, while a label without a basis is a typed error.
#[test]
fn label_kernels_move_continuously_where_clusters_jump() {
    let dims = [12, 4, 4];
    let field = GridField::from_fn(dims, Aabb::UNIT, 3, |p, out| {
        out.copy_from_slice(&[1.0, 0.5 + p.x, 0.2])
    })
    .unwrap();
    let valid = vec![true; field.num_voxels()];
    let labels: Vec<u32> = (0..field.num_voxels())
        .map(|v| u32::from(field.coords(v)[0] >= 6))
        .collect();
    let bases =
        ndarray::Array3::from_shape_vec((2, 1, 3), vec![1.0, 0.0, 0.0, 0.0, 1.0, 0.0]).unwrap();
    let kernels = LabelKernels::new(
        dims,
        Aabb::UNIT,
        &labels,
        2,
        None,
        &LabelSmoothing {
            radius: 2,
            falloff: 0.5,
        },
    )
    .unwrap();
    let clustered = projection_seam_ratio(
        &field,
        &valid,
        &labels,
        &LocalBasis::Clustered {
            labels: &labels,
            bases: &bases,
        },
    )
    .unwrap();
    let moving = projection_seam_ratio(
        &field,
        &valid,
        &labels,
        &LocalBasis::Moving {
            kernels: &kernels,
            basis: &bases,
        },
    )
    .unwrap();
    assert!(clustered > 3.0, "clustered {clustered}");
    assert!(
        moving < 0.5 * clustered,
        "moving {moving} vs clustered {clustered}"
    );
    let one_basis = bases.slice(ndarray::s![..1, .., ..]).to_owned();
    assert!(matches!(
        projection_seam_ratio(
            &field,
            &valid,
            &labels,
            &LocalBasis::Clustered {
                labels: &labels,
                bases: &one_basis,
            },
        ),
        Err(MbdError::ShapeMismatch { .. })
    ));
}
