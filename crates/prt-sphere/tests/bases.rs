//! Laws of the SG, ambient cube/dice bases, sampling and environment maps.
use glam::{DVec3, Vec3};
use ndarray::Array2;
use proptest::prelude::*;
use prt_core::SphericalBasis;
use prt_sphere::sampling::{
    cosine_hemisphere, halton_sphere, radical_inverse, sobol_sphere, sphere_quadrature,
    stratified_sphere,
};
use prt_sphere::{
    AmbientCube, AmbientDiceBezier, AmbientDiceSrbf, CubeMap, LatLongMap, SgBasis, SgLobe,
    SphereError, envmap, quadrature_gram, sg_inner_product, sg_integral,
};

fn cholesky(g: &Array2<f64>) -> Option<Array2<f64>> {
    let n = g.nrows();
    let mut l = Array2::<f64>::zeros((n, n));
    for i in 0..n {
        for j in 0..=i {
            let mut s = g[[i, j]];
            for k in 0..j {
                s -= l[[i, k]] * l[[j, k]];
            }
            if i == j {
                if s <= 0.0 {
                    return None;
                }
                l[[i, i]] = s.sqrt();
            } else {
                l[[i, j]] = s / l[[j, j]];
            }
        }
    }
    Some(l)
}

fn solve_spd(g: &Array2<f64>, b: &[f64]) -> Vec<f64> {
    let l = cholesky(g).expect("SPD");
    let n = b.len();
    let mut y = vec![0.0; n];
    for i in 0..n {
        y[i] = (b[i] - (0..i).map(|k| l[[i, k]] * y[k]).sum::<f64>()) / l[[i, i]];
    }
    let mut x = vec![0.0; n];
    for i in (0..n).rev() {
        x[i] = (y[i] - (i + 1..n).map(|k| l[[k, i]] * x[k]).sum::<f64>()) / l[[i, i]];
    }
    x
}

fn assert_symmetric_pd(g: &Array2<f64>) {
    for i in 0..g.nrows() {
        for j in 0..g.ncols() {
            assert!((g[[i, j]] - g[[j, i]]).abs() <= 1e-12 * g[[i, i]].abs().max(1.0));
        }
    }
    assert!(cholesky(g).is_some(), "Gram is not positive definite");
}

/// Reconstruction of a function in the span: LS through the exact Gram and quadrature moments.
fn reconstructs_span(basis: &dyn SphericalBasis, coeffs: &[f64], n_quad: usize, tol: f64) {
    let k = basis.len();
    let (dirs, weights) = sphere_quadrature(n_quad);
    let mut b = vec![0.0f32; k];
    let mut moments = vec![0.0f64; k];
    for (d, w) in dirs.iter().zip(&weights) {
        basis.eval(*d, &mut b);
        let f: f64 = (0..k).map(|i| coeffs[i] * b[i] as f64).sum();
        for i in 0..k {
            moments[i] += w * f * b[i] as f64;
        }
    }
    let x = solve_spd(&basis.gram(), &moments);
    for i in 0..k {
        assert!(
            (x[i] - coeffs[i]).abs() < tol,
            "{}: coefficient {i}: {} vs {}",
            basis.name(),
            x[i],
            coeffs[i]
        );
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(24))]

    #[test]
    fn sg_inner_product_matches_quadrature(
        a in prop::array::uniform3(-1.0f64..1.0),
        b in prop::array::uniform3(-1.0f64..1.0),
        l1 in 0.01f64..40.0,
        l2 in 0.01f64..40.0,
    ) {
        let (p1, p2) = (DVec3::from_array(a), DVec3::from_array(b));
        prop_assume!(p1.length() > 0.1 && p2.length() > 0.1);
        let (p1, p2) = (p1.normalize(), p2.normalize());
        let (dirs, weights) = sphere_quadrature(160);
        let q: f64 = dirs
            .iter()
            .zip(&weights)
            .map(|(d, w)| {
                let d = d.as_dvec3();
                w * (l1 * (p1.dot(d) - 1.0)).exp() * (l2 * (p2.dot(d) - 1.0)).exp()
            })
            .sum();
        let exact = sg_inner_product(p1, l1, p2, l2);
        prop_assert!((q - exact).abs() < 1e-6 * exact.max(1e-3), "{q} vs {exact}");
        prop_assert!((exact - sg_inner_product(p2, l2, p1, l1)).abs() <= 1e-15 * exact);
    }

    #[test]
    fn uv_direction_round_trip(u in 0.0f64..1.0, v in 0.001f64..0.999) {
        let d = envmap::uv_to_direction(u, v);
        let (u2, v2) = envmap::direction_to_uv(d);
        let du = (u - u2).abs().min(1.0 - (u - u2).abs());
        prop_assert!(du < 1e-5 && (v - v2).abs() < 1e-5, "({u},{v}) -> ({u2},{v2})");
    }

    #[test]
    fn cube_face_selection_round_trip(face in 0usize..6, s in 0usize..16, t in 0usize..16) {
        let d = envmap::cube_texel_direction(face, s, t, 16);
        let (f2, s2, t2) = envmap::direction_to_cube(d);
        prop_assert_eq!(f2, face);
        prop_assert!(((s2 * 16.0).floor() as usize, (t2 * 16.0).floor() as usize) == (s, t));
    }
}

#[test]
fn sg_closed_forms_at_the_extremes() {
    use std::f64::consts::PI;
    // λ → 0: a constant lobe; λ = 1e-4 is 4π (1 − λ) to first order.
    let tiny = 1e-4;
    assert!((sg_integral(tiny) - 4.0 * PI * (1.0 - tiny)).abs() < 1e-7);
    assert!((sg_integral(0.0) - 4.0 * PI).abs() < 1e-12);
    // λ = 1e4: 2π/λ, no overflow.
    assert!((sg_integral(1e4) - 2.0 * PI / 1e4).abs() < 1e-15);
    for &l in &[1e-4, 1e-2, 1.0, 6.0, 100.0, 1e4] {
        let p = DVec3::new(0.0, 0.6, 0.8);
        let self_ip = sg_inner_product(p, l, p, l);
        assert!(
            (self_ip - sg_integral(2.0 * l)).abs() <= 1e-12 * self_ip,
            "λ={l}"
        );
        let opposite = sg_inner_product(p, l, -p, l);
        assert!(opposite.is_finite() && opposite >= 0.0 && opposite <= self_ip);
        // Two nearly coincident sharp lobes: the exact value is e^{-λ θ²/2}-like, finite.
        let q = DVec3::new(0.0, 0.6 + 1e-6, 0.8).normalize();
        let near = sg_inner_product(p, l, q, l);
        assert!(near.is_finite() && near <= self_ip * (1.0 + 1e-12));
        let lobe = SgLobe {
            axis: p.as_vec3(),
            sharpness: l as f32,
            amplitude: Vec3::ONE,
        };
        for n in [p.as_vec3(), -p.as_vec3(), Vec3::X] {
            let e = lobe.irradiance(n);
            assert!(e.is_finite() && e.x >= -1e-6, "λ={l} n={n}: {e}");
        }
    }
    // A wide lobe's irradiance tends to π (uniform unit radiance).
    let wide = SgLobe {
        axis: Vec3::Y,
        sharpness: 1e-4,
        amplitude: Vec3::ONE,
    };
    assert!((wide.irradiance(Vec3::X).x as f64 - PI).abs() < 1e-3);
    // The exact series (λ <= 4) against a quadrature of ∫ G max(0, n·v).
    let (dirs, weights) = sphere_quadrature(400);
    for lambda in [0.5f32, 2.0, 6.0, 16.0] {
        let lobe = SgLobe {
            axis: Vec3::Y,
            sharpness: lambda,
            amplitude: Vec3::ONE,
        };
        for n in [Vec3::Y, Vec3::new(0.8, 0.6, 0.0), Vec3::X, -Vec3::Y] {
            let q: f64 = dirs
                .iter()
                .zip(&weights)
                .map(|(d, w)| w * lobe.eval(*d).x as f64 * n.dot(*d).max(0.0) as f64)
                .sum();
            let e = lobe.irradiance(n).x as f64;
            assert!(
                (e - q).abs() < 1e-4 * q.max(1e-2),
                "λ={lambda} n={n}: series {e} vs {q}"
            );
        }
    }
    // Hill's fit above λ = 16: within 3% of the peak irradiance.
    let lobe = SgLobe {
        axis: Vec3::Y,
        sharpness: 40.0,
        amplitude: Vec3::ONE,
    };
    let peak = lobe.irradiance(Vec3::Y).x as f64;
    for n in [Vec3::Y, Vec3::new(0.8, 0.6, 0.0), Vec3::X] {
        let q: f64 = dirs
            .iter()
            .zip(&weights)
            .map(|(d, w)| w * lobe.eval(*d).x as f64 * n.dot(*d).max(0.0) as f64)
            .sum();
        let e = lobe.irradiance(n).x as f64;
        assert!((e - q).abs() < 0.03 * peak, "n={n}: fitted {e} vs {q}");
    }
}

#[test]
fn sg_bases_gram_spd_and_reconstruct_their_span() {
    for basis in [
        SgBasis::spiral(12, 6.0).unwrap(),
        SgBasis::fibonacci(9, 4.0).unwrap(),
        SgBasis::icosahedral(8.0).unwrap(),
    ] {
        let g = basis.gram();
        assert_symmetric_pd(&g);
        let coeffs: Vec<f64> = (0..basis.len())
            .map(|i| (i as f64 * 0.7).sin() + 0.2)
            .collect();
        reconstructs_span(&basis, &coeffs, 96, 1e-5);
    }
    assert!(SgBasis::spiral(0, 6.0).is_err());
    assert_eq!(
        SgBasis::new(vec![Vec3::Y], vec![f32::NAN], "x"),
        Err(SphereError::NonFinite {
            what: "lobe sharpness",
            index: 0
        })
    );
    assert!(SgBasis::new(vec![Vec3::Y * 2.0], vec![1.0], "x").is_err());
    // Probulator's spiral for n = 12 (conventions.md): z from 11/12 to -11/12.
    let axes = prt_sphere::spiral_axes(12);
    assert!((axes[0].z - 11.0 / 12.0).abs() < 1e-6 && (axes[11].z + 11.0 / 12.0).abs() < 1e-6);
    assert!(axes.iter().all(|a| (a.length() - 1.0).abs() < 1e-6));
}

#[test]
fn ambient_cube_and_dice() {
    let cube = AmbientCube;
    let g = cube.gram();
    assert_symmetric_pd(&g);
    let q = quadrature_gram(&cube, 64);
    for i in 0..6 {
        for j in 0..6 {
            // The lobes have a kink on a coordinate plane: the quadrature is not exact there.
            assert!(
                (g[[i, j]] - q[[i, j]]).abs() < 1e-6,
                "({i},{j}) {} vs {}",
                g[[i, j]],
                q[[i, j]]
            );
        }
    }
    let mut b = [0.0f32; 6];
    for d in halton_sphere(50) {
        cube.eval(d, &mut b);
        assert!(
            (b.iter().sum::<f32>() - 1.0).abs() < 1e-5,
            "partition of unity"
        );
    }
    reconstructs_span(&cube, &[1.0, 0.5, -0.25, 2.0, 0.0, 3.0], 64, 1e-6);
    let dice = AmbientDiceSrbf;
    let g = dice.gram();
    assert_symmetric_pd(&g);
    let mut w = [0.0f32; 12];
    dice.eval(Vec3::new(0.3, -0.5, 0.81).normalize(), &mut w);
    assert_eq!(
        w.iter().filter(|&&x| x != 0.0).count(),
        6,
        "one lobe of each pair"
    );
    reconstructs_span(
        &dice,
        &(0..12).map(|i| i as f64 * 0.1 - 0.3).collect::<Vec<_>>(),
        256,
        2e-3,
    );
}

#[test]
fn ambient_dice_bezier() {
    let dice = AmbientDiceBezier;
    let g = dice.gram();
    assert_symmetric_pd(&g);
    assert_eq!(g, dice.gram(), "cached");
    // Interpolation at the vertices: the value function of vertex v is 1 there and every
    // other function is 0.
    let mut w = [0.0f32; 36];
    for (v, p) in AmbientDiceBezier::vertices().iter().enumerate() {
        dice.eval(p.normalize().as_vec3(), &mut w);
        for (i, x) in w.iter().enumerate() {
            let want = if i == 3 * v { 1.0 } else { 0.0 };
            assert!((x - want).abs() < 1e-5, "vertex {v}, function {i}: {x}");
        }
    }
    // Exactly 9 functions (3 vertices) are non-zero inside a triangle.
    dice.eval(Vec3::new(0.3, -0.5, 0.81).normalize(), &mut w);
    assert_eq!(w.iter().filter(|&&x| x != 0.0).count(), 9);
    // Finite everywhere, including the poles, the axes and the zero vector.
    for d in [Vec3::X, -Vec3::Y, Vec3::Z, Vec3::ZERO] {
        dice.eval(d, &mut w);
        assert!(w.iter().all(|x| x.is_finite()), "{d}");
    }
    reconstructs_span(
        &dice,
        &(0..36).map(|i| (i as f64 * 0.37).sin()).collect::<Vec<_>>(),
        256,
        2e-3,
    );
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    /// The selected triangle contains the direction (all barycentrics >= 0 to rounding).
    #[test]
    fn ambient_dice_triangle_contains_the_direction(a in prop::array::uniform3(-1.0f64..1.0)) {
        let d = DVec3::from_array(a);
        prop_assume!(d.length() > 0.05);
        let d = d.normalize();
        let tri = AmbientDiceBezier::triangles()[AmbientDiceBezier::triangle_of(d.as_vec3())];
        let v = AmbientDiceBezier::vertices();
        let m = glam::DMat3::from_cols(v[tri[0]], v[tri[1]], v[tri[2]]);
        let b = m.inverse() * d;
        prop_assert!(b.min_element() > -1e-6, "{d}: triangle {tri:?}, barycentrics {b}");
    }

    /// The reconstruction is continuous across triangle edges.
    #[test]
    fn ambient_dice_bezier_is_continuous(
        a in prop::array::uniform3(-1.0f64..1.0),
        c in prop::collection::vec(-1.0f32..1.0, 36),
    ) {
        let d = DVec3::from_array(a);
        prop_assume!(d.length() > 0.05);
        let d = d.normalize();
        // Move to the nearest point on a great circle through two vertices of d's triangle.
        let tri = AmbientDiceBezier::triangles()[AmbientDiceBezier::triangle_of(d.as_vec3())];
        let v = AmbientDiceBezier::vertices();
        let n = v[tri[0]].cross(v[tri[1]]).normalize();
        let on_edge = (d - n * n.dot(d)).normalize();
        let dice = AmbientDiceBezier;
        let f = |p: DVec3| {
            let mut w = [0.0f32; 36];
            dice.eval(p.as_vec3(), &mut w);
            w.iter().zip(&c).map(|(w, c)| (w * c) as f64).sum::<f64>()
        };
        let eps = 1e-4;
        let (inside, outside) = ((on_edge - n * eps).normalize(), (on_edge + n * eps).normalize());
        // Across 2e-4 rad a function with a slope of a few units changes by ~1e-3; a jump
        // between the two triangles' polynomials would be O(1).
        prop_assert!((f(inside) - f(outside)).abs() < 2e-3,
            "jump {} at {on_edge}", f(inside) - f(outside));
    }
}

#[test]
fn sampling_sequences() {
    assert_eq!(radical_inverse(1, 2), 0.5);
    assert_eq!(radical_inverse(3, 2), 0.75);
    assert!((radical_inverse(5, 3) - (2.0 / 3.0 + 1.0 / 9.0)).abs() < 1e-15);
    let h = halton_sphere(20000);
    assert_eq!(h.len(), 20000);
    assert!(h.iter().all(|d| (d.length() - 1.0).abs() < 1e-5));
    // First Probulator sample: index 1 → (u, v) = (1/2, 1/3): z = 0, φ = 2π/3.
    assert!(
        (h[0]
            - Vec3::new(
                (2.0f32 * std::f32::consts::PI / 3.0).cos(),
                (2.0f32 * std::f32::consts::PI / 3.0).sin(),
                0.0
            ))
        .length()
            < 1e-6
    );
    // Unbiased means: E[d] = 0 for uniform sets; E[y] = 2/3 for the cosine hemisphere.
    // Tolerances: 5 σ of the Monte Carlo estimate (Var(d_i) = 1/3, Var(y) = 1/18 for the cosine map).
    for set in [sobol_sphere(4096, 7), stratified_sphere(64, 64, 3)] {
        let mean = set.iter().fold(DVec3::ZERO, |a, d| a + d.as_dvec3()) / set.len() as f64;
        let sigma = (1.0 / 3.0 / set.len() as f64).sqrt();
        assert!(mean.abs().max_element() < 5.0 * sigma, "{mean}");
    }
    let n = 4096;
    let ys: f64 = (0..n)
        .map(|i| {
            cosine_hemisphere(
                radical_inverse(i as u64 + 1, 2),
                radical_inverse(i as u64 + 1, 3),
            )
            .y as f64
        })
        .sum::<f64>()
        / n as f64;
    assert!(
        (ys - 2.0 / 3.0).abs() < 5.0 * (1.0 / 18.0 / n as f64).sqrt(),
        "{ys}"
    );
}

#[test]
fn latlong_maps() {
    use std::f64::consts::PI;
    let map = LatLongMap::from_fn(64, 32, |d| Vec3::new(d.y.max(0.0), 1.0, 1e6)).unwrap();
    let total: f64 = (0..32).map(|y| map.texel_solid_angle(y) * 64.0).sum();
    assert!((total - 4.0 * PI).abs() < 1e-12);
    // Texel centres look up their own texel, nearest and bilinear.
    for (x, y) in [(0, 0), (13, 7), (63, 31), (31, 16)] {
        let d = map.direction(x, y);
        assert_eq!(map.nearest(d), map.texel(x, y));
        assert!((map.bilinear(d) - map.texel(x, y)).length() < 1e-5 * 1e6);
    }
    // Top row is up: texel (0, 0) points nearly to +Y; conventions: u = 0.5 on the equator is +Z.
    assert!(map.direction(0, 0).y > 0.99);
    assert!((envmap::uv_to_direction(0.5, 0.5) - Vec3::Z).length() < 1e-6);
    // Constant map: c0 = sqrt(4π) L exactly (texel solid angles are exact), HDR 1e6 finite.
    let sh = map.project_sh(3).unwrap();
    assert!(sh.iter().all(|v| v.is_finite()));
    assert!((sh[1] as f64 - (4.0 * PI).sqrt()).abs() < 1e-5);
    assert!((sh[2] as f64 - 1e6 * (4.0 * PI).sqrt()).abs() < 1e-6 * 1e6 * (4.0 * PI).sqrt());
    // A map that is zero except one texel projects to that texel's Y(centre) Ω.
    let mut data = vec![0.0f32; 16 * 8 * 3];
    data[3 * (3 * 16 + 5)] = 7.0;
    let one = LatLongMap::new(16, 8, data).unwrap();
    let sh = one.project_sh(2).unwrap();
    let mut y = [0.0f32; 4];
    prt_sphere::eval_sh(2, one.direction(5, 3), &mut y);
    for i in 0..4 {
        let expected = 7.0 * y[i] as f64 * one.texel_solid_angle(3);
        assert!((sh[3 * i] as f64 - expected).abs() < 1e-6, "{i}");
        assert_eq!(sh[3 * i + 1], 0.0);
    }
    // Bad input.
    let mut bad = vec![0.0f32; 16 * 8 * 3];
    bad[100] = f32::INFINITY;
    assert_eq!(
        LatLongMap::new(16, 8, bad),
        Err(SphereError::NonFinite {
            what: "texel",
            index: 100
        })
    );
    assert!(LatLongMap::new(0, 8, vec![]).is_err());
    assert!(LatLongMap::new(4, 4, vec![0.0; 5]).is_err());
}

#[test]
fn cubemaps() {
    use std::f64::consts::PI;
    let cube = CubeMap::from_fn(16, |d| d).unwrap();
    let total: f64 = (0..16)
        .flat_map(|s| (0..16).map(move |t| (s, t)))
        .map(|(s, t)| 6.0 * cube.texel_solid_angle(s, t))
        .sum();
    assert!((total - 4.0 * PI).abs() < 1e-10);
    // Vulkan orientation: the centre of face 0 is +X, face 2 is +Y, face 5 is −Z; on +X, s grows toward −Z.
    assert!((envmap::cube_to_direction(0, 0.0, 0.0) - Vec3::X).length() < 1e-6);
    assert!((envmap::cube_to_direction(2, 0.0, 0.0) - Vec3::Y).length() < 1e-6);
    assert!((envmap::cube_to_direction(5, 0.0, 0.0) + Vec3::Z).length() < 1e-6);
    assert!(envmap::cube_to_direction(0, 0.9, 0.0).z < 0.0);
    assert!(envmap::cube_to_direction(0, 0.0, 0.9).y < 0.0);
    // Round trip of a smooth map through both representations.
    let ll = LatLongMap::from_fn(128, 64, |d| Vec3::new(1.0 + d.x, 1.0 + d.y * d.z, 2.0)).unwrap();
    let back = ll.to_cubemap(32).unwrap().to_latlong(128, 64).unwrap();
    let err = ll
        .data()
        .iter()
        .zip(back.data())
        .map(|(a, b)| (a - b).abs())
        .fold(0.0f32, f32::max);
    assert!(err < 0.03, "round-trip error {err}");
    assert_eq!(
        cube.nearest(Vec3::new(1.0, 0.01, -0.01)),
        cube.texel(0, 8, 7)
    );
}
