//! Property tests of prt-core's laws: trilinear sampling, metrics, oracle and progress contracts.

use glam::Vec3;
use ndarray::Array2;
use proptest::prelude::*;
use prt_core::{
    Aabb, AtomicProgress, CoreError, DenseOracle, GridField, MatrixOracle, NoProgress, Progress,
    metrics,
};

fn arb_dims() -> impl Strategy<Value = [usize; 3]> {
    [1usize..6, 1usize..6, 1usize..6]
}

fn arb_box() -> impl Strategy<Value = Aabb> {
    (
        prop::array::uniform3(-10.0f32..10.0),
        prop::array::uniform3(0.1f32..20.0),
    )
        .prop_map(|(min, size)| {
            let min = Vec3::from(min);
            Aabb::new(min, min + Vec3::from(size))
        })
}

/// An affine map R³ → R^dim.
#[derive(Debug, Clone)]
struct Affine {
    offset: Vec<f32>,
    gradient: Vec<[f32; 3]>,
}

impl Affine {
    fn eval(&self, p: Vec3, out: &mut [f32]) {
        for (k, o) in out.iter_mut().enumerate() {
            let g = self.gradient[k];
            *o = self.offset[k] + g[0] * p.x + g[1] * p.y + g[2] * p.z;
        }
    }
}

fn arb_affine(dim: usize) -> impl Strategy<Value = Affine> {
    (
        prop::collection::vec(-5.0f32..5.0, dim),
        prop::collection::vec(prop::array::uniform3(-3.0f32..3.0), dim),
    )
        .prop_map(|(offset, gradient)| Affine { offset, gradient })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(96))]

    /// Inside the box of voxel centres, trilinear interpolation of an affine field is exact
    /// (along an axis with a single voxel, the field must be constant along that axis).
    #[test]
    fn trilinear_reproduces_affine_fields(
        dims in [2usize..6, 2usize..6, 2usize..6],
        bounds in arb_box(),
        affine in arb_affine(3),
        t in prop::array::uniform3(0.0f32..=1.0),
    ) {
        let field = GridField::from_fn(dims, bounds, 3, |p, out| affine.eval(p, out)).unwrap();
        let lo = field.voxel_centre(0, 0, 0);
        let hi = field.voxel_centre(dims[0] - 1, dims[1] - 1, dims[2] - 1);
        let p = lo + (hi - lo) * Vec3::from(t);
        let mut got = [0.0f32; 3];
        let mut want = [0.0f32; 3];
        field.sample(p, &mut got).unwrap();
        affine.eval(p, &mut want);
        for k in 0..3 {
            let scale = 1.0 + want[k].abs() + 30.0 * bounds.size().max_element();
            prop_assert!((got[k] - want[k]).abs() <= 2e-5 * scale, "{got:?} vs {want:?}");
        }
    }

    /// At a voxel centre, sampling returns that voxel's value.
    #[test]
    fn voxel_centres_return_voxel_values(
        dims in arb_dims(),
        bounds in arb_box(),
        seed in any::<u64>(),
    ) {
        let mut state = seed;
        let mut next = move || {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((state >> 40) as f32) / (1u64 << 24) as f32 - 0.5
        };
        let field = GridField::from_fn(dims, bounds, 2, |_, out| {
            out[0] = next();
            out[1] = 1e3 * next();
        })
        .unwrap();
        let mut got = [0.0f32; 2];
        for v in 0..field.num_voxels() {
            field.sample(field.centre_of(v), &mut got).unwrap();
            let want = field.voxel(v);
            prop_assert!((got[0] - want[0]).abs() <= 1e-4, "voxel {v}: {got:?} vs {want:?}");
            prop_assert!((got[1] - want[1]).abs() <= 1e-1, "voxel {v}: {got:?} vs {want:?}");
        }
    }

    /// Trilinear weights are a partition of unity with non-negative entries, everywhere
    /// (including far outside the box, where sampling clamps).
    #[test]
    fn trilinear_weights_partition_unity(
        dims in arb_dims(),
        bounds in arb_box(),
        p in prop::array::uniform3(-100.0f32..100.0),
    ) {
        let field = GridField::new(dims, bounds, 1).unwrap();
        let w = field.trilinear_weights(Vec3::from(p)).unwrap();
        let sum: f32 = w.weights.iter().sum();
        prop_assert!((sum - 1.0).abs() < 1e-5);
        prop_assert!(w.weights.iter().all(|&x| x >= 0.0));
        prop_assert!(w.indices.iter().all(|&i| i < field.num_voxels()));
    }

    /// Outside the box, sampling equals sampling at the clamped point of the voxel-centre box.
    #[test]
    fn sampling_clamps_outside(
        dims in arb_dims(),
        affine in arb_affine(1),
        p in prop::array::uniform3(-50.0f32..50.0),
    ) {
        let field = GridField::from_fn(dims, Aabb::UNIT, 1, |q, out| affine.eval(q, out)).unwrap();
        let lo = field.voxel_centre(0, 0, 0);
        let hi = field.voxel_centre(dims[0] - 1, dims[1] - 1, dims[2] - 1);
        let p = Vec3::from(p);
        let (mut a, mut b) = ([0.0f32], [0.0f32]);
        field.sample(p, &mut a).unwrap();
        field.sample(p.clamp(lo, hi), &mut b).unwrap();
        prop_assert!((a[0] - b[0]).abs() < 1e-4);
    }

    /// Metrics agree with direct f64 computation.
    #[test]
    fn metrics_agree_with_direct_computation(
        pairs in prop::collection::vec((-1e3f32..1e3, -1e3f32..1e3, 0.0f32..10.0), 1..64),
    ) {
        let a: Vec<f32> = pairs.iter().map(|p| p.0).collect();
        let b: Vec<f32> = pairs.iter().map(|p| p.1).collect();
        let w: Vec<f32> = pairs.iter().map(|p| p.2).collect();
        let n = a.len() as f64;
        let se: f64 = a.iter().zip(&b).map(|(&x, &y)| (x as f64 - y as f64).powi(2)).sum();
        let e: f64 = b.iter().map(|&y| (y as f64).powi(2)).sum();
        let l1: f64 = a.iter().zip(&b).zip(&w).map(|((&x, &y), &w)| w as f64 * (x as f64 - y as f64).abs()).sum();
        let ws: f64 = w.iter().map(|&w| w as f64).sum();
        let close = |x: f64, y: f64| (x - y).abs() <= 1e-12 * (1.0 + y.abs());
        prop_assert!(close(metrics::rmse(&a, &b).unwrap(), (se / n).sqrt()));
        prop_assert!(close(metrics::frobenius_error(&a, &b).unwrap(), se.sqrt()));
        if e > 0.0 {
            prop_assert!(close(metrics::relative_mse(&a, &b).unwrap(), se / e));
            prop_assert!(close(metrics::relative_frobenius_error(&a, &b).unwrap(), (se / e).sqrt()));
        }
        if ws > 0.0 {
            prop_assert!(close(metrics::area_weighted_l1(&a, &b, &w).unwrap(), l1 / ws));
        }
        prop_assert_eq!(metrics::rmse(&b, &b).unwrap(), 0.0);
    }

    /// The dense oracle's rows and columns are the matrix's, and it counts every element.
    #[test]
    fn dense_oracle_rows_and_columns(rows in 1usize..8, cols in 1usize..8, channels in 1usize..4) {
        let data = Array2::from_shape_fn((rows, cols * channels), |(i, j)| (i * 100 + j) as f32);
        let oracle = DenseOracle::new(data.clone(), channels).unwrap();
        let mut row = vec![0.0; cols * channels];
        let mut col = vec![0.0; rows * channels];
        for i in 0..rows {
            oracle.eval_row(i, &mut row).unwrap();
            prop_assert_eq!(row.clone(), data.row(i).to_vec());
        }
        for j in 0..cols {
            oracle.eval_col(j, &mut col).unwrap();
            for i in 0..rows {
                for c in 0..channels {
                    prop_assert_eq!(col[i * channels + c], data[[i, j * channels + c]]);
                }
            }
        }
        prop_assert_eq!(oracle.elements_evaluated(), 2 * (rows * cols) as u64);
    }
}

#[test]
fn single_voxel_field_is_constant_everywhere() {
    let field = GridField::from_fn([1, 1, 1], Aabb::UNIT, 2, |_, out| {
        out.copy_from_slice(&[3.0, -1.0])
    })
    .unwrap();
    let mut v = [0.0; 2];
    for p in [Vec3::ZERO, Vec3::ONE, Vec3::splat(-1e30), Vec3::splat(1e30)] {
        field.sample(p, &mut v).unwrap();
        assert_eq!(v, [3.0, -1.0]);
    }
}

#[test]
fn huge_dynamic_range_is_interpolated_without_loss() {
    // Values from 1e-6 to 1e6 side by side: interpolation is a convex combination, so the
    // result stays within the endpoints and is exact at the centres.
    let field = GridField::from_fn([2, 1, 1], Aabb::UNIT, 1, |p, out| {
        out[0] = if p.x < 0.5 { 1e-6 } else { 1e6 };
    })
    .unwrap();
    let mut v = [0.0];
    field.sample(field.voxel_centre(0, 0, 0), &mut v).unwrap();
    assert_eq!(v[0], 1e-6);
    field.sample(Vec3::new(0.5, 0.5, 0.5), &mut v).unwrap();
    assert!((v[0] - 0.5e6).abs() <= 0.5e6 * 1e-6);
}

#[test]
fn non_finite_inputs_are_typed_errors() {
    let data = Array2::from_shape_vec((2, 2), vec![0.0, 1.0, f32::NAN, 2.0]).unwrap();
    assert_eq!(
        GridField::from_data([2, 1, 1], Aabb::UNIT, data),
        Err(CoreError::NonFinite {
            what: "field data",
            index: 2
        })
    );
    let field = GridField::new([2, 2, 2], Aabb::UNIT, 1).unwrap();
    let mut v = [0.0];
    assert_eq!(
        field.sample(Vec3::new(0.0, f32::INFINITY, 0.0), &mut v),
        Err(CoreError::NonFinite {
            what: "query point",
            index: 1
        })
    );
    assert!(
        GridField::from_fn([2, 1, 1], Aabb::UNIT, 1, |p, out| out[0] =
            1.0 / (p.x - 0.1))
        .is_ok()
    );
    assert_eq!(
        GridField::from_fn([1, 1, 1], Aabb::UNIT, 1, |_, out| out[0] = f32::NAN),
        Err(CoreError::NonFinite {
            what: "field data",
            index: 0
        })
    );
    assert_eq!(
        metrics::rmse(&[1.0, f32::NAN], &[1.0, 1.0]),
        Err(CoreError::NonFinite {
            what: "approximation",
            index: 1
        })
    );
    assert!(DenseOracle::new(Array2::from_elem((1, 3), f32::NEG_INFINITY), 3).is_err());
}

#[test]
fn shapes_are_checked() {
    assert_eq!(
        GridField::new([0, 1, 1], Aabb::UNIT, 1),
        Err(CoreError::Empty {
            what: "grid dimensions"
        })
    );
    assert_eq!(
        GridField::new([1, 1, 1], Aabb::UNIT, 0),
        Err(CoreError::Empty {
            what: "field vector dimension"
        })
    );
    assert!(
        GridField::new(
            [1, 1, 1],
            Aabb {
                min: Vec3::ONE,
                max: Vec3::ZERO
            },
            1
        )
        .is_err()
    );
    assert!(GridField::new([usize::MAX, 2, 2], Aabb::UNIT, 1).is_err());
    assert!(GridField::from_data([2, 2, 2], Aabb::UNIT, Array2::zeros((7, 3))).is_err());
    let field = GridField::new([2, 2, 2], Aabb::UNIT, 3).unwrap();
    assert!(field.sample(Vec3::ZERO, &mut [0.0; 2]).is_err());
    assert!(metrics::rmse(&[1.0], &[1.0, 2.0]).is_err());
    assert!(metrics::area_weighted_l1(&[1.0], &[1.0], &[-1.0]).is_err());
    let oracle = DenseOracle::new(Array2::zeros((2, 6)), 3).unwrap();
    assert!(oracle.eval_row(2, &mut [0.0; 6]).is_err());
    assert!(oracle.eval_col(0, &mut [0.0; 5]).is_err());
    assert!(DenseOracle::new(Array2::zeros((2, 5)), 3).is_err());
}

#[test]
fn relative_metrics_of_zero_reference_are_defined() {
    assert_eq!(
        metrics::relative_mse(&[0.0, 0.0], &[0.0, 0.0]).unwrap(),
        0.0
    );
    assert_eq!(
        metrics::relative_mse(&[1.0, 0.0], &[0.0, 0.0]).unwrap(),
        f64::INFINITY
    );
    assert_eq!(metrics::rmse(&[], &[]).unwrap(), 0.0);
    // Zero total weight: every term is weighted by zero, so the error is 0 (not NaN).
    assert_eq!(
        metrics::area_weighted_l1(&[1.0], &[0.0], &[0.0]).unwrap(),
        0.0
    );
}

#[test]
fn progress_cancels() {
    assert!(NoProgress.check().is_ok());
    let p = AtomicProgress::cancel_after(10);
    p.set_len(100);
    p.inc(9);
    assert!(p.check().is_ok());
    p.inc(1);
    assert_eq!(p.check(), Err(CoreError::Cancelled));
    assert_eq!(p.position(), 10);
    p.message("stage two");
    assert_eq!(p.last_message(), "stage two");
    let q = AtomicProgress::new();
    std::thread::scope(|s| {
        s.spawn(|| q.cancel());
    });
    assert!(q.is_cancelled());
}
