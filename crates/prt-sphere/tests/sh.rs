//! Laws of the spherical harmonics: conventions, orthonormality up to l = 100, rotation and
//! zonal convolution.
use glam::{DVec3, Mat3, Quat, Vec3};
use proptest::prelude::*;
use prt_core::SphericalBasis;
use prt_sphere::sampling::{sphere_quadrature, sphere_quadrature_f64};
use prt_sphere::sh::{
    clamped_cosine_coefficient, eval_expansion, irradiance_from_radiance, project_samples,
};
use prt_sphere::{ShBasis, ShRotation, eval_sh, eval_sh_f64, sh_index, sh_len};

/// Textbook real SH (Condon-Shortley phase) through θ, φ measured from the textbook z axis,
/// which is prt's +Y; textbook x is prt's z and textbook y is prt's x.
fn textbook(l: usize, m: isize, d: DVec3) -> f64 {
    let (xt, yt, zt) = (d.z, d.x, d.y);
    let theta = zt.clamp(-1.0, 1.0).acos();
    let phi = yt.atan2(xt);
    let am = m.unsigned_abs();
    // Associated Legendre with the Condon-Shortley phase, by the textbook recurrence.
    let x = theta.cos();
    let s = theta.sin();
    let mut pmm = 1.0;
    for k in 1..=am {
        pmm *= -((2 * k - 1) as f64) * s;
    }
    let plm = if l == am {
        pmm
    } else {
        let mut p0 = pmm;
        let mut p1 = x * (2 * am + 1) as f64 * pmm;
        for ll in (am + 2)..=l {
            let p2 = ((2 * ll - 1) as f64 * x * p1 - (ll + am - 1) as f64 * p0) / (ll - am) as f64;
            p0 = p1;
            p1 = p2;
        }
        p1
    };
    let fact = |n: usize| (1..=n).map(|k| k as f64).product::<f64>();
    let k =
        ((2 * l + 1) as f64 / (4.0 * std::f64::consts::PI) * fact(l - am) / fact(l + am)).sqrt();
    match m.signum() {
        0 => k * plm,
        1 => std::f64::consts::SQRT_2 * k * plm * (am as f64 * phi).cos(),
        _ => std::f64::consts::SQRT_2 * k * plm * (am as f64 * phi).sin(),
    }
}

fn unit(v: [f64; 3]) -> Option<DVec3> {
    let d = DVec3::from_array(v);
    (d.length() > 1e-3).then(|| d.normalize())
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn explicit_recurrence_and_textbook_agree(v in prop::array::uniform3(-1.0f64..1.0)) {
        let Some(d) = unit(v) else { return Ok(()) };
        let order = 8;
        let mut rec = vec![0.0f64; sh_len(order)];
        eval_sh_f64(order, d, &mut rec);
        let mut fast = vec![0.0f32; 25];
        eval_sh(5, d.as_vec3(), &mut fast);
        for l in 0..order {
            for m in -(l as isize)..=(l as isize) {
                let i = sh_index(l, m);
                let t = textbook(l, m, d);
                prop_assert!((rec[i] - t).abs() < 1e-12, "recurrence ({l},{m}): {} vs {t}", rec[i]);
                if i < 25 {
                    prop_assert!((fast[i] as f64 - t).abs() < 2e-6, "explicit ({l},{m}): {} vs {t}", fast[i]);
                }
            }
        }
    }

    #[test]
    fn rotation_matches_reprojection(
        axis in prop::array::uniform3(-1.0f32..1.0),
        angle in -3.0f32..3.0,
        coeffs in prop::collection::vec(-1.0f32..1.0, 36),
    ) {
        let Some(a) = unit(axis.map(|x| x as f64)) else { return Ok(()) };
        let r = Mat3::from_quat(Quat::from_axis_angle(a.as_vec3(), angle));
        let order = 6;
        let mut rotated = coeffs.clone();
        ShRotation::new(order, r).unwrap().apply(&mut rotated, 1).unwrap();
        // Re-project g(ω) = f(r⁻¹ ω) with a quadrature exact for degree 2·5.
        let (dirs, weights) = sphere_quadrature(12);
        let inv = r.transpose();
        let mut y = vec![0.0f32; 36];
        let mut reproj = vec![0.0f64; 36];
        let mut g = [0.0f32];
        for (d, w) in dirs.iter().zip(&weights) {
            eval_expansion(&coeffs, 1, inv * *d, &mut g).unwrap();
            eval_sh(order, *d, &mut y);
            for i in 0..36 {
                reproj[i] += w * (g[0] * y[i]) as f64;
            }
        }
        for i in 0..36 {
            prop_assert!((rotated[i] as f64 - reproj[i]).abs() < 2e-4, "coefficient {i}: {} vs {}", rotated[i], reproj[i]);
        }
    }
}

#[test]
fn band_polynomials_match_the_documented_table() {
    let d = Vec3::new(0.48, 0.6, 0.64);
    let mut y = [0.0f32; 9];
    eval_sh(3, d, &mut y);
    let (x, yy, z) = (d.x, d.y, d.z);
    let expected = [
        0.282095,
        -0.488603 * x,
        0.488603 * yy,
        -0.488603 * z,
        1.092548 * x * z,
        -1.092548 * x * yy,
        0.315392 * (3.0 * yy * yy - 1.0),
        -1.092548 * yy * z,
        0.546274 * (z * z - x * x),
    ];
    for i in 0..9 {
        assert!(
            (y[i] - expected[i]).abs() < 2e-6,
            "{i}: {} vs {}",
            y[i],
            expected[i]
        );
    }
}

#[test]
fn orthonormal_at_band_100_in_f64_and_f32_and_finite_at_poles() {
    let order = 101;
    let n = sh_len(order);
    // Band 100 entirely, every 7th function of band 99, and the constant.
    let mut subset: Vec<usize> = (sh_index(100, -100)..=sh_index(100, 100)).collect();
    subset.extend((sh_index(99, -99)..=sh_index(99, 99)).step_by(7));
    subset.push(0);
    let k = subset.len();
    let (dirs, weights) = sphere_quadrature_f64(101);
    let mut g64 = vec![0.0f64; k * k];
    let mut g32 = vec![0.0f64; k * k];
    let mut y = vec![0.0f64; n];
    let mut s64 = vec![0.0f64; k];
    let mut s32 = vec![0.0f64; k];
    for (d, w) in dirs.iter().zip(&weights) {
        eval_sh_f64(order, *d, &mut y);
        for (a, &i) in subset.iter().enumerate() {
            s64[a] = y[i];
            s32[a] = (y[i] as f32) as f64;
        }
        for a in 0..k {
            for b in a..k {
                g64[a * k + b] += w * s64[a] * s64[b];
                g32[a * k + b] += w * s32[a] * s32[b];
            }
        }
    }
    let (mut e64, mut e32) = (0.0f64, 0.0f64);
    for a in 0..k {
        for b in a..k {
            let id = if a == b { 1.0 } else { 0.0 };
            e64 = e64.max((g64[a * k + b] - id).abs());
            e32 = e32.max((g32[a * k + b] - id).abs());
        }
    }
    assert!(e64 < 1e-10, "f64 orthonormality error {e64}");
    assert!(e32 < 1e-4, "f32 orthonormality error {e32}");
    let mut yf = vec![0.0f32; n];
    for d in [Vec3::Y, -Vec3::Y, Vec3::new(1e-20, 1.0, 0.0)] {
        eval_sh(order, d, &mut yf);
        assert!(yf.iter().all(|v| v.is_finite()), "non-finite SH at {d}");
        // At the pole only m = 0 survives: Y_l^0(+Y) = sqrt((2l+1)/4π).
        // P_100 is even, so the value is the same at -Y.
        let expected = (201.0f64 / (4.0 * std::f64::consts::PI)).sqrt();
        assert!((yf[sh_index(100, 0)] as f64 - expected).abs() < 1e-4 * expected);
    }
}

#[test]
fn basis_properties_and_bad_order() {
    assert!(ShBasis::new(0).is_err());
    let b = ShBasis::new(4).unwrap();
    assert_eq!(b.len(), 16);
    assert!(b.is_orthonormal());
    assert_eq!(b.gram(), ndarray::Array2::<f64>::eye(16));
    // The order-5 explicit path and the order-6 recurrence share bands 0..4.
    let d = Vec3::new(-0.3, 0.2, 0.9).normalize();
    let (mut a, mut c) = (vec![0.0f32; 25], vec![0.0f32; 36]);
    eval_sh(5, d, &mut a);
    eval_sh(6, d, &mut c);
    for i in 0..25 {
        assert!((a[i] - c[i]).abs() < 2e-6);
    }
}

#[test]
fn clamped_cosine_kernel_values_and_irradiance() {
    use std::f64::consts::PI;
    assert!((clamped_cosine_coefficient(0) - PI).abs() < 1e-15);
    assert!((clamped_cosine_coefficient(1) - 2.0 * PI / 3.0).abs() < 1e-15);
    assert!((clamped_cosine_coefficient(2) - PI / 4.0).abs() < 1e-15);
    assert_eq!(clamped_cosine_coefficient(3), 0.0);
    assert!((clamped_cosine_coefficient(4) + PI / 24.0).abs() < 1e-15);
    assert!(clamped_cosine_coefficient(200).is_finite());
    // A radiance in bands 0..2: irradiance SH must equal the quadrature of ∫ L max(0, n·ω).
    let coeffs: Vec<f32> = (0..9).map(|i| 0.3 + 0.1 * (i as f32).sin()).collect();
    let mut irr = coeffs.clone();
    irradiance_from_radiance(&mut irr, 1).unwrap();
    let (dirs, weights) = sphere_quadrature(200);
    for n in [
        Vec3::Y,
        Vec3::new(0.6, -0.0, 0.8),
        Vec3::new(-0.36, 0.48, -0.8),
    ] {
        let mut e = 0.0f64;
        let mut l = [0.0f32];
        for (d, w) in dirs.iter().zip(&weights) {
            eval_expansion(&coeffs, 1, *d, &mut l).unwrap();
            e += w * l[0] as f64 * n.dot(*d).max(0.0) as f64;
        }
        let mut got = [0.0f32];
        eval_expansion(&irr, 1, n, &mut got).unwrap();
        assert!(
            (got[0] as f64 - e).abs() < 1e-3 * e.abs().max(1.0),
            "{n}: {} vs {e}",
            got[0]
        );
    }
}

#[test]
fn sample_projection_is_unbiased_for_a_constant_and_rejects_nan() {
    let dirs = prt_sphere::sampling::halton_sphere(4096);
    let vals = vec![2.0f32; dirs.len()];
    let c = project_samples(3, &dirs, &vals, 1).unwrap();
    let exact = 2.0 * (4.0 * std::f64::consts::PI).sqrt();
    assert!((c[0] as f64 - exact).abs() < 1e-4 * exact);
    for ci in &c[1..] {
        assert!(ci.abs() < 0.02, "{ci}");
    }
    let mut bad = vals.clone();
    bad[17] = f32::NAN;
    assert_eq!(
        project_samples(3, &dirs, &bad, 1),
        Err(prt_sphere::SphereError::NonFinite {
            what: "sample value",
            index: 17
        })
    );
    assert!(
        project_samples(3, &[], &[], 1)
            .unwrap()
            .iter()
            .all(|&v| v == 0.0)
    );
}
