//! Laws of the progressive encoder, the batch encoder and the references.
use glam::Vec3;
use proptest::prelude::*;
use prt_core::{AtomicProgress, NoProgress, SphericalBasis};
use prt_plsq::{
    BatchEncoder, Denominator, EncoderConfig, PlsqError, Precision, ProgressiveEncoder,
    SampleOutcome, Sweep, Update, reference,
};
use prt_sphere::sampling::{halton_sphere, sobol_sphere};
use prt_sphere::{SgBasis, ShBasis};

/// A smooth RGB test signal: a sky gradient plus a warm lobe.
fn signal(d: Vec3) -> [f32; 3] {
    let sun = (8.0 * (d.dot(Vec3::new(0.6, 0.64, 0.48)) - 1.0)).exp();
    [
        0.2 + 0.5 * d.y.max(0.0) + 3.0 * sun,
        0.3 + 0.3 * d.y + sun,
        0.5 + 0.1 * d.x,
    ]
}

fn samples(n: usize) -> (Vec<Vec3>, Vec<f32>) {
    let dirs = halton_sphere(n);
    let values = dirs.iter().flat_map(|d| signal(*d)).collect();
    (dirs, values)
}

fn fit_rmse(
    basis: &dyn SphericalBasis,
    coeffs: &[f32],
    channels: usize,
    dirs: &[Vec3],
    values: &[f32],
) -> f64 {
    let mut b = vec![0.0f32; basis.len()];
    let mut sum = 0.0f64;
    for (s, d) in dirs.iter().enumerate() {
        basis.eval(*d, &mut b);
        for c in 0..channels {
            let f: f32 = (0..basis.len())
                .map(|i| b[i] * coeffs[i * channels + c])
                .sum();
            sum += ((f - values[s * channels + c]) as f64).powi(2);
        }
    }
    (sum / (dirs.len() * channels) as f64).sqrt()
}

fn run(
    basis: &dyn SphericalBasis,
    cfg: EncoderConfig,
    dirs: &[Vec3],
    values: &[f32],
    ch: usize,
) -> Vec<f32> {
    let mut enc = ProgressiveEncoder::new(basis, ch, cfg).unwrap();
    enc.add_samples(dirs, values, None, &NoProgress).unwrap();
    enc.coefficients().to_vec()
}

#[test]
fn progressive_variants_approach_least_squares() {
    let basis = SgBasis::spiral(12, 6.0).unwrap();
    let (dirs, values) = samples(20000);
    let ls = reference::least_squares_samples(&basis, &dirs, &values, 3).unwrap();
    let ls_err = fit_rmse(&basis, &ls, 3, &dirs, &values);
    let naive = reference::naive_projection(
        &basis,
        &dirs,
        &values,
        3,
        reference::probulator_sg_naive_scale(6.0, 12),
    )
    .unwrap();
    let naive_err = fit_rmse(&basis, &naive, 3, &dirs, &values);
    assert!(naive_err > 1.2 * ls_err, "naive {naive_err} vs LS {ls_err}");
    // Gauss-Seidel sweeps and the running average come within 3% of LS; Jacobi residual steps
    // with overlapping lobes stay measurably above it (but far below naive projection).
    for (name, cfg, factor) in [
        ("paper", EncoderConfig::paper(), 1.03),
        (
            "running average",
            EncoderConfig::probulator_running_average(),
            1.03,
        ),
        (
            "accel 3",
            EncoderConfig {
                update: Update::Residual { acceleration: 3.0 },
                ..EncoderConfig::paper()
            },
            1.03,
        ),
        (
            "jacobi exact",
            EncoderConfig {
                sweep: Sweep::Jacobi,
                denominator: Denominator::Exact,
                ..EncoderConfig::paper()
            },
            1.15,
        ),
    ] {
        let c = run(&basis, cfg, &dirs, &values, 3);
        let err = fit_rmse(&basis, &c, 3, &dirs, &values);
        assert!(err < factor * ls_err, "{name}: {err} vs LS {ls_err}");
        assert!(err < naive_err, "{name}: {err} vs naive {naive_err}");
    }
    // LS through the exact Gram is close to LS over the samples on 20000 Halton points.
    let lg = reference::least_squares_gram(&basis, &dirs, &values, 3).unwrap();
    assert!(fit_rmse(&basis, &lg, 3, &dirs, &values) < 1.01 * ls_err);
}

#[test]
fn function_in_the_span_is_recovered() {
    let basis = SgBasis::spiral(6, 3.0).unwrap();
    let truth = [0.5f32, 1.0, 0.25, 2.0, 0.0, 1.5];
    let dirs = sobol_sphere(20000, 3);
    let mut b = [0.0f32; 6];
    let values: Vec<f32> = dirs
        .iter()
        .map(|d| {
            basis.eval(*d, &mut b);
            b.iter().zip(&truth).map(|(x, y)| x * y).sum()
        })
        .collect();
    let ls = reference::least_squares_samples(&basis, &dirs, &values, 1).unwrap();
    let nn = reference::nnls_samples(&basis, &dirs, &values, 1).unwrap();
    for i in 0..6 {
        assert!(
            (ls[i] - truth[i]).abs() < 1e-3,
            "LS {i}: {} vs {}",
            ls[i],
            truth[i]
        );
        assert!((nn[i] - truth[i]).abs() < 1e-3, "NNLS {i}");
    }
    let c = run(&basis, EncoderConfig::paper(), &dirs, &values, 1);
    for i in 0..6 {
        assert!(
            (c[i] - truth[i]).abs() < 0.02,
            "progressive {i}: {} vs {}",
            c[i],
            truth[i]
        );
    }
}

#[test]
fn non_negative_and_hemisphere_modes() {
    let basis = SgBasis::spiral(12, 6.0).unwrap();
    // A signal with a dark band that pulls unconstrained LS negative.
    let dirs = halton_sphere(8000);
    let values: Vec<f32> = dirs
        .iter()
        .map(|d| {
            if d.z.abs() < 0.2 {
                0.0
            } else {
                5.0 * d.z.abs()
            }
        })
        .collect();
    let cfg = EncoderConfig {
        non_negative: true,
        ..EncoderConfig::paper()
    };
    let c = run(&basis, cfg, &dirs, &values, 1);
    assert!(c.iter().all(|&x| x >= 0.0));
    let nn = reference::nnls_samples(&basis, &dirs, &values, 1).unwrap();
    assert!(nn.iter().all(|&x| x >= 0.0));
    // Hemisphere mode: only upper-hemisphere samples, the fit must vanish below.
    let up: Vec<Vec3> = dirs
        .iter()
        .map(|d| Vec3::new(d.x, d.y.abs(), d.z))
        .collect();
    let vals: Vec<f32> = up.iter().map(|d| 1.0 + d.y).collect();
    let cfg = EncoderConfig {
        hemisphere: true,
        ..EncoderConfig::paper()
    };
    let mut enc = ProgressiveEncoder::new(&basis, 1, cfg).unwrap();
    enc.add_samples(&up, &vals, None, &NoProgress).unwrap();
    assert_eq!(enc.total_weight(), 2.0 * up.len() as f32);
    let (mut below, mut above) = ([0.0f32], [0.0f32]);
    enc.eval(-Vec3::Y, &mut below);
    enc.eval(Vec3::Y, &mut above);
    assert!(
        below[0].abs() < 0.15 && (above[0] - 2.0).abs() < 0.3,
        "below {} above {}",
        below[0],
        above[0]
    );
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(16))]

    #[test]
    fn weights_scale_invariance(scale in 0.01f32..100.0, seed in 0u32..1000) {
        // With a clamped or exact denominator only w / W matters.
        let basis = SgBasis::spiral(8, 5.0).unwrap();
        let dirs = sobol_sphere(500, seed);
        let values: Vec<f32> = dirs.iter().map(|d| signal(*d)[0]).collect();
        let w: Vec<f32> = (0..500).map(|i| 0.5 + (i % 7) as f32).collect();
        let ws: Vec<f32> = w.iter().map(|x| x * scale).collect();
        let cfg = EncoderConfig { denominator: Denominator::Clamped { floor: 1.0 }, ..EncoderConfig::paper() };
        let mut a = ProgressiveEncoder::new(&basis, 1, cfg).unwrap();
        a.add_samples(&dirs, &values, Some(&w), &NoProgress).unwrap();
        let mut b = ProgressiveEncoder::new(&basis, 1, cfg).unwrap();
        b.add_samples(&dirs, &values, Some(&ws), &NoProgress).unwrap();
        for (x, y) in a.coefficients().iter().zip(b.coefficients()) {
            prop_assert!((x - y).abs() <= 1e-4 * x.abs().max(1.0), "{x} vs {y}");
        }
    }

    #[test]
    fn batch_matches_single_encoders_on_any_thread_count(
        count in 1usize..40,
        accel in 1.0f32..4.0,
        gs in any::<bool>(),
        running in any::<bool>(),
        hemi in any::<bool>(),
    ) {
        let basis = SgBasis::spiral(12, 6.0).unwrap();
        let cfg = EncoderConfig {
            update: if running { Update::RunningAverage } else { Update::Residual { acceleration: accel } },
            sweep: if gs { Sweep::GaussSeidel } else { Sweep::Jacobi },
            hemisphere: hemi,
            ..EncoderConfig::paper()
        };
        let rounds = 20;
        let all = sobol_sphere(count * rounds, 11);
        let run_batch = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            pool.install(|| {
                let mut batch = BatchEncoder::new(&basis, 3, count, cfg).unwrap();
                for r in 0..rounds {
                    let dirs = &all[r * count..(r + 1) * count];
                    let values: Vec<f32> = dirs.iter().flat_map(|d| signal(*d)).collect();
                    let w: Vec<f32> = (0..count).map(|e| if (e + r) % 5 == 0 { 0.0 } else { 1.0 + (e % 3) as f32 }).collect();
                    batch.add_samples(dirs, &values, Some(&w)).unwrap();
                }
                (0..count).map(|e| batch.coefficients(e).unwrap()).collect::<Vec<_>>()
            })
        };
        let one = run_batch(1);
        let two = run_batch(2);
        prop_assert_eq!(&one, &two);
        for e in 0..count {
            let mut enc = ProgressiveEncoder::new(&basis, 3, cfg).unwrap();
            for r in 0..rounds {
                let d = all[r * count + e];
                let w = if (e + r) % 5 == 0 { 0.0 } else { 1.0 + (e % 3) as f32 };
                enc.add_sample(d, &signal(d), w).unwrap();
            }
            for (x, y) in enc.coefficients().iter().zip(&one[e]) {
                prop_assert!((x - y).abs() <= 1e-5 * x.abs().max(1.0), "encoder {e}: {x} vs {y}");
            }
        }
    }
}

#[test]
fn sixteen_bit_state_is_biased_and_f32_is_not() {
    // Constant basis; samples 1 except every 10th = 10 (mean 1.9). The fit is the weighted mean.
    let basis = ShBasis::new(1).unwrap();
    let dirs = halton_sphere(20000);
    let values: Vec<f32> = (0..dirs.len())
        .map(|i| if i % 10 == 9 { 10.0 } else { 1.0 })
        .collect();
    let y0 = 0.5 / std::f32::consts::PI.sqrt();
    let mean = |p: Precision| {
        let cfg = EncoderConfig {
            precision: p,
            denominator: Denominator::Exact,
            ..EncoderConfig::paper()
        };
        run(&basis, cfg, &dirs, &values, 1)[0] * y0
    };
    let f32_mean = mean(Precision::F32);
    let f16_mean = mean(Precision::F16);
    assert!((f32_mean - 1.9).abs() < 2e-3, "f32 {f32_mean}");
    assert!(
        (f16_mean - 1.9).abs() > 0.05,
        "f16 {f16_mean} shows no bias"
    );
}

#[test]
fn bad_input_and_extremes() {
    let basis = SgBasis::spiral(12, 6.0).unwrap();
    let mut enc = ProgressiveEncoder::new(&basis, 3, EncoderConfig::paper()).unwrap();
    assert_eq!(
        enc.add_sample(Vec3::Y, &[1.0, 2.0, 3.0], 0.0).unwrap(),
        SampleOutcome::ZeroWeight
    );
    assert!(enc.coefficients().iter().all(|&c| c == 0.0) && enc.total_weight() == 0.0);
    assert_eq!(
        enc.add_sample(Vec3::Y, &[1.0, f32::NAN, 3.0], 1.0),
        Err(PlsqError::NonFinite {
            what: "sample value",
            index: 1
        })
    );
    assert!(enc.add_sample(Vec3::Y, &[1.0, 2.0], 1.0).is_err());
    assert!(enc.add_sample(Vec3::Y, &[1.0, 2.0, 3.0], -1.0).is_err());
    let dirs = halton_sphere(10);
    let mut values = vec![1.0f32; 30];
    values[22] = f32::INFINITY;
    assert_eq!(
        enc.add_samples(&dirs, &values, None, &NoProgress),
        Err(PlsqError::NonFinite {
            what: "sample value",
            index: 22
        })
    );
    assert!(ProgressiveEncoder::new(&basis, 0, EncoderConfig::paper()).is_err());
    let bad = EncoderConfig {
        update: Update::Residual {
            acceleration: f32::NAN,
        },
        ..EncoderConfig::paper()
    };
    assert!(ProgressiveEncoder::new(&basis, 1, bad).is_err());
    // A single sample with α = 1 and Gauss-Seidel interpolates it exactly.
    let mut one = ProgressiveEncoder::new(
        &basis,
        1,
        EncoderConfig {
            denominator: Denominator::Clamped { floor: 0.0 },
            ..EncoderConfig::paper()
        },
    )
    .unwrap();
    let d = Vec3::new(0.3, 0.4, 0.866).normalize();
    one.add_sample(d, &[7.0], 1.0).unwrap();
    let mut v = [0.0f32];
    one.eval(d, &mut v);
    assert!((v[0] - 7.0).abs() < 1e-3, "{}", v[0]);
    // HDR values up to 1e6 stay finite.
    let big: Vec<f32> = dirs
        .iter()
        .map(|d| if d.y > 0.9 { 1e6 } else { 1e-6 })
        .collect();
    let c = run(&basis, EncoderConfig::paper(), &dirs, &big, 1);
    assert!(c.iter().all(|x| x.is_finite()));
    // References: no samples is a typed error; duplicated lobes make a singular system.
    assert_eq!(
        reference::least_squares_samples(&basis, &[], &[], 1),
        Err(PlsqError::ZeroTotalWeight)
    );
    let dup = SgBasis::new(vec![Vec3::Y, Vec3::Y], vec![4.0, 4.0], "dup").unwrap();
    let (dirs, values) = (halton_sphere(200), vec![1.0f32; 200]);
    assert!(matches!(
        reference::least_squares_samples(&dup, &dirs, &values, 1),
        Err(PlsqError::Singular { .. })
    ));
    assert!(matches!(
        reference::least_squares_gram(&dup, &dirs, &values, 1),
        Err(PlsqError::Singular { .. })
    ));
    // Batch rejects bad input before touching any state.
    let mut batch = BatchEncoder::new(&basis, 1, 3, EncoderConfig::paper()).unwrap();
    assert!(
        batch
            .add_samples(&dirs[..3], &[1.0, f32::NAN, 1.0], None)
            .is_err()
    );
    assert!(batch.add_samples(&dirs[..2], &[1.0, 1.0], None).is_err());
    assert_eq!(batch.total_weight(0), Some(0.0));
    assert_eq!(batch.coefficients(3), None);
}

#[test]
fn cancellation_is_honoured() {
    let basis = SgBasis::spiral(12, 6.0).unwrap();
    let (dirs, values) = samples(20000);
    let progress = AtomicProgress::cancel_after(4096);
    let mut enc = ProgressiveEncoder::new(&basis, 3, EncoderConfig::paper()).unwrap();
    assert_eq!(
        enc.add_samples(&dirs, &values, None, &progress),
        Err(PlsqError::Cancelled)
    );
    assert_eq!(enc.total_weight(), 4096.0);
}

#[test]
fn fast_sg_encoder_matches_the_generic_one() {
    use prt_plsq::{SgEncoder, exp_nonpositive};
    for x in [0.0f32, -1e-7, -0.3, -1.0, -6.0, -12.0, -50.0, -86.0] {
        let e = x.exp();
        assert!((exp_nonpositive(x) - e).abs() <= 3e-7 * e, "exp({x})");
    }
    assert!(exp_nonpositive(-1e4) >= 0.0 && exp_nonpositive(-1e4) < 1e-37);
    let basis = SgBasis::spiral(12, 6.0).unwrap();
    let (dirs, values) = samples(3000);
    for cfg in [
        EncoderConfig::paper(),
        EncoderConfig::probulator_running_average(),
        EncoderConfig {
            update: Update::Residual { acceleration: 3.0 },
            non_negative: true,
            ..EncoderConfig::paper()
        },
        EncoderConfig {
            sweep: Sweep::Jacobi,
            denominator: Denominator::Exact,
            ..EncoderConfig::paper()
        },
        EncoderConfig {
            sweep: Sweep::GaussSeidel,
            ..EncoderConfig::probulator_running_average()
        },
        EncoderConfig {
            hemisphere: true,
            ..EncoderConfig::paper()
        },
    ] {
        let generic = run(&basis, cfg, &dirs, &values, 3);
        let mut fast = SgEncoder::<3>::new(&basis, cfg).unwrap();
        fast.add_samples(&dirs, &values, None, &NoProgress).unwrap();
        for (a, b) in generic.iter().zip(fast.coefficients()) {
            assert!(
                (a - b).abs() <= 1e-3 * a.abs().max(1.0),
                "{cfg:?}: {a} vs {b}"
            );
        }
    }
    let mut fast = SgEncoder::<3>::new(&basis, EncoderConfig::paper()).unwrap();
    let mut bad = values.clone();
    bad[7000] = f32::NAN;
    assert_eq!(
        fast.add_samples(&dirs, &bad, None, &NoProgress),
        Err(PlsqError::NonFinite {
            what: "sample value",
            index: 7000
        })
    );
    assert_eq!(
        fast.total_weight(),
        0.0,
        "validation happens before the chunk is applied"
    );
    assert_eq!(
        fast.add_sample(Vec3::Y, [1.0; 3], 0.0).unwrap(),
        SampleOutcome::ZeroWeight
    );
    assert!(
        SgEncoder::<3>::new(
            &basis,
            EncoderConfig {
                precision: Precision::F16,
                ..EncoderConfig::paper()
            }
        )
        .is_err()
    );
}

#[test]
fn batch_sg_fast_path_matches_the_generic_batch() {
    let basis = SgBasis::spiral(12, 6.0).unwrap();
    let count = 37;
    let cfg = EncoderConfig {
        hemisphere: true,
        ..EncoderConfig::paper()
    };
    let mut generic = BatchEncoder::new(&basis, 3, count, cfg).unwrap();
    let mut fast = BatchEncoder::new_sg(&basis, 3, count, cfg).unwrap();
    let all = sobol_sphere(count * 30, 5);
    for r in 0..30 {
        let dirs = &all[r * count..(r + 1) * count];
        let values: Vec<f32> = dirs.iter().flat_map(|d| signal(*d)).collect();
        generic.add_samples(dirs, &values, None).unwrap();
        fast.add_samples(dirs, &values, None).unwrap();
    }
    for e in 0..count {
        for (a, b) in generic
            .coefficients(e)
            .unwrap()
            .iter()
            .zip(fast.coefficients(e).unwrap())
        {
            assert!(
                (a - b).abs() <= 1e-4 * a.abs().max(1.0),
                "encoder {e}: {a} vs {b}"
            );
        }
    }
}

#[test]
fn probulator_rmse_definition_and_frames() {
    use prt_plsq::{LatLongFrame, radiance_rmse, sample_nearest};
    use prt_sphere::{LatLongMap, ShBasis};
    // A constant map (one texel of 1e6 HDR elsewhere checks accumulation) and the SH DC term.
    let sh = ShBasis::new(1).unwrap();
    let y00 = 0.5 / std::f32::consts::PI.sqrt();
    let constant = LatLongMap::from_fn(16, 8, |_| Vec3::new(1.0, 2.0, 3.0)).unwrap();
    let exact = [1.0 / y00, 2.0 / y00, 3.0 / y00];
    for frame in [
        LatLongFrame::Conventions,
        LatLongFrame::Probulator,
        LatLongFrame::ProbulatorZUp,
    ] {
        let e = radiance_rmse(&constant, &sh, &exact, false, frame).unwrap();
        assert!(e < 1e-6, "{frame:?}: {e}");
        // Off by 1 in one channel: sqrt(1/3) whatever the frame (unweighted mean over texels).
        let off = [exact[0] + 1.0 / y00, exact[1], exact[2]];
        let e = radiance_rmse(&constant, &sh, &off, false, frame).unwrap();
        assert!((e - (1.0f64 / 3.0).sqrt()).abs() < 1e-5, "{frame:?}: {e}");
        // Clamping: a negative fit clamps to 0, so the error is the map's RMS.
        let neg = exact.map(|c| -c);
        let clamped = radiance_rmse(&constant, &sh, &neg, true, frame).unwrap();
        assert!((clamped - (14.0f64 / 3.0).sqrt()).abs() < 1e-5);
        // The frame maps are inverse rotations.
        for d in halton_sphere(50) {
            let back = frame.to_conventions(frame.from_conventions(d));
            assert!((back - d).length() < 1e-6);
            assert!((frame.from_conventions(d).length() - 1.0).abs() < 1e-5);
        }
    }
    // Unweighted by solid angle: an error only in the top row counts 1/height of the texels,
    // though that row covers far less than 1/height of the sphere.
    let (w, h) = (16, 8);
    let mut data = vec![1.0f32; w * h * 3];
    data[..w * 3].fill(1.0 + 1e6);
    let spiky = LatLongMap::new(w, h, data).unwrap();
    let e = radiance_rmse(
        &spiky,
        &sh,
        &[1.0 / y00; 3],
        false,
        LatLongFrame::Conventions,
    )
    .unwrap();
    assert!((e - 1e6 / (h as f64).sqrt()).abs() < 1e-3 * e, "{e}");
    // Probulator's frame is conventions' turned by π about +Y: the texel a Probulator
    // direction reads is the one prt finds at (−x, y, −z).
    let ramp = LatLongMap::from_fn(64, 32, |d| Vec3::splat(d.x + 2.0)).unwrap();
    let d = Vec3::new(0.8, 0.0, 0.6);
    assert_eq!(
        sample_nearest(&ramp, &[d], LatLongFrame::Probulator),
        ramp.nearest(Vec3::new(-0.8, 0.0, -0.6)).to_array().to_vec()
    );
    // Bad input: wrong length, non-finite coefficient.
    assert!(matches!(
        radiance_rmse(&constant, &sh, &[1.0; 2], false, LatLongFrame::Conventions),
        Err(PlsqError::LengthMismatch { .. })
    ));
    assert_eq!(
        radiance_rmse(
            &constant,
            &sh,
            &[1.0, f32::INFINITY, 1.0],
            false,
            LatLongFrame::Conventions
        ),
        Err(PlsqError::NonFinite {
            what: "coefficient",
            index: 1
        })
    );
}

#[test]
fn map_least_squares_reproduces_a_function_in_the_span() {
    use prt_plsq::LatLongFrame;
    use prt_sphere::{AmbientDiceBezier, LatLongMap, ShBasis};
    // SH order 3 on a 128×64 map: exact up to the texel quadrature.
    let sh = ShBasis::new(3).unwrap();
    let coeffs: Vec<f32> = (0..27).map(|i| ((i as f32) * 0.41).sin()).collect();
    let eval = |basis: &dyn prt_core::SphericalBasis, c: &[f32], d: Vec3| {
        let mut b = vec![0.0f32; basis.len()];
        basis.eval(d, &mut b);
        let mut out = Vec3::ZERO;
        for i in 0..basis.len() {
            out += b[i] * Vec3::from_slice(&c[3 * i..3 * i + 3]);
        }
        out
    };
    let map = LatLongMap::from_fn(128, 64, |d| eval(&sh, &coeffs, d)).unwrap();
    let fit = reference::least_squares_map(&sh, &map, LatLongFrame::Conventions).unwrap();
    for (a, b) in coeffs.iter().zip(&fit) {
        assert!((a - b).abs() < 2e-3, "{a} vs {b}");
    }
    // The Bezier dice in Probulator's frame recovers the coefficients of a map built in that
    // frame. (The icosahedron is symmetric under the frame's π turn, so a conventions-frame
    // fit reaches the same error with the coefficients permuted: the dice figures do not
    // depend on the frame.)
    let dice = AmbientDiceBezier;
    let coeffs: Vec<f32> = (0..108).map(|i| ((i as f32) * 0.7).cos()).collect();
    let frame = LatLongFrame::Probulator;
    let map = LatLongMap::from_fn(256, 128, |d| {
        eval(&dice, &coeffs, frame.from_conventions(d))
    })
    .unwrap();
    let fit = reference::least_squares_map(&dice, &map, frame).unwrap();
    let worst = coeffs
        .iter()
        .zip(&fit)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f32::max);
    assert!(worst < 0.02, "worst coefficient error {worst}");
    let rmse = prt_plsq::radiance_rmse(&map, &dice, &fit, false, frame).unwrap();
    assert!(rmse < 1e-3, "{rmse}");
}

/// Blocking reorders only independent arithmetic: one sample at a time, the whole stream at
/// once (blocks of 64) and a stream with zero weights all give the same state, bit for bit.
#[test]
fn sg_encoder_blocking_does_not_change_the_result() {
    use prt_plsq::SgEncoder;
    let basis = SgBasis::spiral(12, 6.0).unwrap();
    let (dirs, values) = samples(101);
    for cfg in [
        EncoderConfig::paper(),
        EncoderConfig::probulator_running_average(),
        EncoderConfig {
            hemisphere: true,
            non_negative: true,
            ..EncoderConfig::paper()
        },
    ] {
        let mut whole = SgEncoder::<3>::new(&basis, cfg).unwrap();
        whole
            .add_samples(&dirs, &values, None, &NoProgress)
            .unwrap();
        let mut single = SgEncoder::<3>::new(&basis, cfg).unwrap();
        for (d, v) in dirs.iter().zip(values.chunks_exact(3)) {
            single.add_sample(*d, [v[0], v[1], v[2]], 1.0).unwrap();
        }
        // Every third sample duplicated with weight 0: skipped, no state change.
        let (mut d2, mut v2, mut w2) = (Vec::new(), Vec::new(), Vec::new());
        for (s, (d, v)) in dirs.iter().zip(values.chunks_exact(3)).enumerate() {
            d2.push(*d);
            v2.extend_from_slice(v);
            w2.push(1.0);
            if s % 3 == 0 {
                d2.push(-*d);
                v2.extend_from_slice(&[9.0, 9.0, 9.0]);
                w2.push(0.0);
            }
        }
        let mut weighted = SgEncoder::<3>::new(&basis, cfg).unwrap();
        weighted
            .add_samples(&d2, &v2, Some(&w2), &NoProgress)
            .unwrap();
        assert_eq!(whole.coefficients(), single.coefficients(), "{cfg:?}");
        assert_eq!(whole.coefficients(), weighted.coefficients(), "{cfg:?}");
        assert_eq!(whole.total_weight(), weighted.total_weight());
        // Explicit unit weights (copied into the blocks in runs) equal no weights.
        let mut unit = SgEncoder::<3>::new(&basis, cfg).unwrap();
        unit.add_samples(&dirs, &values, Some(&vec![1.0; dirs.len()]), &NoProgress)
            .unwrap();
        assert_eq!(whole.coefficients(), unit.coefficients(), "{cfg:?}");
    }
}

/// A run of samples per encoder is the same as one round per sample index, bit for bit, on
/// any thread count, for the generic and the SG fast path (with weights, zeros among them,
/// and hemisphere mirrors); lengths are checked before anything changes.
#[test]
fn batch_sample_runs_equal_rounds_on_any_thread_count() {
    let basis = SgBasis::spiral(12, 6.0).unwrap();
    let (count, per) = (37, 9);
    let all = sobol_sphere(count * per, 5);
    let values: Vec<f32> = all.iter().flat_map(|d| signal(*d)).collect();
    let weight = |e: usize, k: usize| {
        if (e + k).is_multiple_of(4) {
            0.0
        } else {
            1.0 + (k % 3) as f32
        }
    };
    let w: Vec<f32> = (0..count * per).map(|i| weight(i / per, i % per)).collect();
    for cfg in [
        EncoderConfig::paper(),
        EncoderConfig {
            hemisphere: true,
            non_negative: true,
            ..EncoderConfig::probulator_running_average()
        },
    ] {
        for fast in [false, true] {
            let make = || {
                if fast {
                    BatchEncoder::new_sg(&basis, 3, count, cfg).unwrap()
                } else {
                    BatchEncoder::new(&basis, 3, count, cfg).unwrap()
                }
            };
            let runs = |threads: usize| {
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .unwrap();
                pool.install(|| {
                    let mut batch = make();
                    batch.add_sample_runs(per, &all, &values, Some(&w)).unwrap();
                    (0..count)
                        .map(|e| batch.coefficients(e).unwrap())
                        .collect::<Vec<_>>()
                })
            };
            let one = runs(1);
            assert_eq!(one, runs(2), "{cfg:?}, fast {fast}");
            let mut rounds = make();
            for k in 0..per {
                let idx = |e: usize| e * per + k;
                let d: Vec<Vec3> = (0..count).map(|e| all[idx(e)]).collect();
                let v: Vec<f32> = (0..count)
                    .flat_map(|e| values[3 * idx(e)..3 * idx(e) + 3].to_vec())
                    .collect();
                let wk: Vec<f32> = (0..count).map(|e| w[idx(e)]).collect();
                rounds.add_samples(&d, &v, Some(&wk)).unwrap();
            }
            for e in 0..count {
                assert_eq!(rounds.coefficients(e).unwrap(), one[e], "encoder {e}");
                // A hemisphere mirror sample carries the weight of its sample.
                let mirrors = if cfg.hemisphere { 2.0 } else { 1.0 };
                let expected: f32 = mirrors * (0..per).map(|k| weight(e, k)).sum::<f32>();
                assert_eq!(rounds.total_weight(e), Some(expected));
            }
            assert!(one.iter().flatten().any(|&c| c != 0.0));
        }
    }
    let mut batch = BatchEncoder::new_sg(&basis, 3, count, EncoderConfig::paper()).unwrap();
    assert_eq!(
        batch.add_sample_runs(per, &all[1..], &values[3..], None),
        Err(PlsqError::LengthMismatch {
            what: "sample directions",
            expected: count * per,
            got: count * per - 1
        })
    );
    let mut bad = values.clone();
    bad[3 * (5 * per + 2) + 1] = f32::INFINITY;
    assert!(matches!(
        batch.add_sample_runs(per, &all, &bad, None),
        Err(PlsqError::NonFinite {
            what: "sample value",
            ..
        })
    ));
    batch.add_sample_runs(0, &[], &[], None).unwrap();
    assert_eq!(batch.total_weight(0), Some(0.0), "nothing was applied");
}
