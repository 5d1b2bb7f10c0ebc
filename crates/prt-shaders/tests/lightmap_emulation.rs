//! The lightmap shaders' math (`prt_shaders::lightmap`, the CPU mirror of lightmap_*.wgsl and
//! *.glsl) against (i) prt-sphere and prt-lightmap's own evaluation of the bases and (ii)
//! brute-force quadrature of the reconstructed radiance against the clamped cosine (diffuse)
//! and a GGX BRDF (specular). Tolerances sit just above the errors measured here (printed with
//! `--nocapture`).

use std::f64::consts::PI;

use glam::{DVec3, Mat3, Vec3};
use proptest::prelude::*;
use prt_lightmap::LightmapBasis;
use prt_shaders::lightmap::{self as lm, SH_COEFFICIENTS};
use prt_sphere::{SgLobe, ShRotation, eval_sh_f64};

/// A small xorshift stream in [0, 1).
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> f32 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 40) as f32 / (1u64 << 24) as f32
    }

    fn unit(&mut self) -> Vec3 {
        let y = 2.0 * self.next() - 1.0;
        let phi = std::f32::consts::TAU * self.next();
        let r = (1.0 - y * y).max(0.0).sqrt();
        Vec3::new(r * phi.cos(), y, r * phi.sin())
    }

    /// A unit direction with y >= `min_y`.
    fn upper(&mut self, min_y: f32) -> Vec3 {
        let y = min_y + (1.0 - min_y) * self.next();
        let phi = std::f32::consts::TAU * self.next();
        let r = (1.0 - y * y).max(0.0).sqrt();
        Vec3::new(r * phi.cos(), y, r * phi.sin())
    }

    fn colour(&mut self) -> Vec3 {
        Vec3::new(self.next(), self.next(), self.next())
    }
}

/// `∫ f(ω) dω` over the sphere by the midpoint rule in (θ, φ) about `pole`, fine near the pole
/// (where the specular lobe is).
fn integrate(pole: DVec3, rings: usize, sectors: usize, f: impl Fn(DVec3) -> DVec3) -> DVec3 {
    let pole = pole.normalize();
    let (a, b) = pole.any_orthonormal_pair();
    let (dt, dp) = (PI / rings as f64, 2.0 * PI / sectors as f64);
    let mut sum = DVec3::ZERO;
    for i in 0..rings {
        let theta = (i as f64 + 0.5) * dt;
        let (s, c) = theta.sin_cos();
        for k in 0..sectors {
            let phi = (k as f64 + 0.5) * dp;
            let w = a * (s * phi.cos()) + b * (s * phi.sin()) + pole * c;
            sum += f(w) * (s * dt * dp);
        }
    }
    sum
}

/// GGX BRDF times the cosine, f64: D(h) V1(l) V1(v) F(l·h) (n·l) with α = roughness².
fn ggx_times_cosine(n: DVec3, v: DVec3, l: DVec3, roughness: f64, f0: DVec3) -> DVec3 {
    let (nl, nv) = (n.dot(l), n.dot(v));
    if nl <= 0.0 || nv <= 0.0 {
        return DVec3::ZERO;
    }
    let a2 = (roughness * roughness).powi(2);
    let h = (l + v).normalize();
    let nh = n.dot(h);
    let d = a2 / (PI * (nh * nh * (a2 - 1.0) + 1.0).powi(2));
    let v1 = |x: f64| 1.0 / (x + (a2 + (1.0 - a2) * x * x).sqrt());
    let fresnel = f0 + (DVec3::ONE - f0) * (1.0 - l.dot(h).clamp(0.0, 1.0)).powi(5);
    fresnel * (d * v1(nl) * v1(nv) * nl)
}

fn sg_radiance(axes: &[Vec3], sharpness: f32, c: &[Vec3], w: DVec3) -> DVec3 {
    axes.iter().zip(c).fold(DVec3::ZERO, |s, (p, c)| {
        s + c.as_dvec3() * (f64::from(sharpness) * (p.as_dvec3().dot(w) - 1.0)).exp()
    })
}

fn sh_radiance(c: &[Vec3; SH_COEFFICIENTS], w: DVec3) -> DVec3 {
    let mut y = [0.0; SH_COEFFICIENTS];
    eval_sh_f64(3, w, &mut y);
    y.iter()
        .zip(c)
        .fold(DVec3::ZERO, |s, (y, c)| s + c.as_dvec3() * *y)
}

fn max_rel(got: Vec3, want: DVec3, scale: f64) -> f64 {
    (got.as_dvec3() - want).abs().max_element() / scale
}

fn lobes(n: usize) -> (Vec<Vec3>, f32) {
    LightmapBasis::sg_lobes(n)
}

/// The tangent frame is glam's `any_orthonormal_pair`, bit for bit, the sign of −0.0 included.
#[test]
fn the_tangent_frame_is_the_bakes() {
    let mut rng = Rng(7);
    let mut normals: Vec<Vec3> = (0..1000).map(|_| rng.unit()).collect();
    normals.extend([
        Vec3::new(0.0, 1.0, -0.0),
        Vec3::new(0.0, 1.0, 0.0),
        Vec3::new(0.0, -1.0, -0.0),
        Vec3::new(1.0, 0.0, 0.0),
    ]);
    for n in normals {
        let frame = lm::tangent_frame(n);
        let (t, b) = n.any_orthonormal_pair();
        assert_eq!((frame.x_axis, frame.y_axis, frame.z_axis), (t, n, b), "{n}");
        let d = Vec3::new(0.3, -0.5, 0.8).normalize();
        let local = lm::to_tangent(frame, d);
        assert!((local - Vec3::new(d.dot(t), d.dot(n), d.dot(b))).length() < 1e-6);
    }
}

/// `∫ exp(λ (cos θ − 1)) max(0, n·ω) dω` for `μ = p·n`, f64: the azimuthal integral of
/// `max(0, a + b cos φ)` in closed form, then the midpoint rule over θ (from the lobe's axis).
fn sg_irradiance_reference(lambda: f64, mu: f64) -> f64 {
    let steps = 8192;
    let st = (1.0 - mu * mu).max(0.0).sqrt();
    (0..steps)
        .map(|i| {
            let theta = (i as f64 + 0.5) * PI / steps as f64;
            let (s, c) = theta.sin_cos();
            let (a, b) = (mu * c, st * s);
            let ring = if a >= b {
                2.0 * PI * a
            } else if a <= -b {
                0.0
            } else {
                let phi = (-a / b).acos();
                2.0 * (a * phi + b * phi.sin())
            };
            (lambda * (c - 1.0)).exp() * ring * s * PI / steps as f64
        })
        .sum()
}

/// SG diffuse (truncated series or Hill's fit) against quadrature for the lobe sets
/// `prt lightmap --basis sg:N` writes, and against prt-sphere's `SgLobe::irradiance` (its exact
/// series) up to λ = 16; errors relative to the lobe's peak irradiance (at its own axis).
#[test]
fn sg_diffuse_matches_the_exact_irradiance() {
    println!("lobes  sharpness  max |shader − exact| / peak");
    for (n, tolerance) in [
        (1, 1e-5),
        (2, 1e-5),
        (4, 2e-4),
        (9, 3e-3),
        (16, 8e-3),
        (32, 0.017),
        (64, 0.013),
    ] {
        let (_, lambda) = lobes(n);
        let peak = sg_irradiance_reference(f64::from(lambda), 1.0);
        let mut worst = 0.0f64;
        for k in 0..=100 {
            let mu = -1.0 + k as f64 / 50.0;
            let normal = Vec3::new((1.0 - mu * mu).max(0.0).sqrt() as f32, mu as f32, 0.0);
            let got = f64::from(lm::sg_irradiance_unit(Vec3::Y, lambda, normal));
            worst = worst.max((got - sg_irradiance_reference(f64::from(lambda), mu)).abs() / peak);
            if lambda <= 16.0 {
                let sphere = SgLobe {
                    axis: Vec3::Y,
                    sharpness: lambda,
                    amplitude: Vec3::ONE,
                }
                .irradiance(normal);
                worst = worst.max((got - f64::from(sphere.x)).abs() / peak);
            }
        }
        println!("{n:5}  {lambda:9.3}  {worst:.2e}");
        assert!(worst < tolerance, "{n} lobes: {worst}");
    }
    // Quadrature of the whole texel: radiance from random amplitudes against the clamped cosine.
    let (axes, lambda) = lobes(9);
    let mut rng = Rng(3);
    for _ in 0..4 {
        let c: Vec<Vec3> = axes.iter().map(|_| rng.colour()).collect();
        let normal = rng.upper(0.2);
        let want = integrate(normal.as_dvec3(), 256, 256, |w| {
            sg_radiance(&axes, lambda, &c, w) * normal.as_dvec3().dot(w).max(0.0)
        });
        let got = lm::sg_diffuse(&axes, lambda, &c, normal);
        let err = max_rel(got, want, want.max_element());
        println!("sg:9 texel at normal {normal:.2}: relative error {err:.4}");
        assert!(err < 3e-3, "{got} vs {want}");
    }
}

/// The shader's irradiance at the texel's normal is the irradiance the bake stores (its cosine
/// integral of the fit) for a real lightmap of the Cornell box: within Hill's error for SG,
/// float rounding for SH of order ≤ 3, and bands 3–4's missing terms for sh:5 (4.0–4.5e-2 of
/// the largest irradiance measured, depending on the bake's samples).
#[test]
fn the_shaders_reproduce_a_bakes_irradiance() {
    use prt_lightmap::{LightmapConfig, UnwrapConfig, bake_lightmap, unwrap_charts};
    let scene = prt_trace::Scene::cornell_box();
    let atlas = unwrap_charts(
        scene.triangles(),
        &UnwrapConfig {
            texels_per_metre: 3.0,
            ..Default::default()
        },
    )
    .unwrap();
    println!("basis  max |shader − bake| / max irradiance");
    for (label, tolerance) in [
        ("sg:9", 1e-3),
        ("sh:2", 6e-5),
        ("sh:3", 6e-5),
        ("sh:5", 0.06),
    ] {
        let basis = LightmapBasis::parse(label).unwrap();
        let config = LightmapConfig {
            basis,
            samples: 16,
            pass_samples: 16,
            ..Default::default()
        };
        let bake =
            bake_lightmap(&scene, &atlas, &config, &prt_core::NoProgress, &mut |_| {}).unwrap();
        let map = &bake.lightmap;
        let texels = (map.width * map.height) as usize;
        let peak = map.irradiance.iter().fold(0.0f32, |m, &v| m.max(v));
        let mut worst = 0.0f32;
        for t in (0..texels).filter(|&t| map.covered[t]) {
            let c: Vec<Vec3> = map
                .coefficients
                .iter()
                .map(|layer| Vec3::from_slice(&layer[3 * t..3 * t + 3]))
                .collect();
            let got = match basis {
                LightmapBasis::Sg { lobes: n } => {
                    let (axes, lambda) = lobes(n);
                    lm::sg_diffuse(&axes, lambda, &c, Vec3::Y)
                }
                _ => {
                    let mut nine = [Vec3::ZERO; SH_COEFFICIENTS];
                    for (o, c) in nine.iter_mut().zip(&c) {
                        *o = *c;
                    }
                    lm::sh_diffuse(&nine, Vec3::Y)
                }
            };
            let want = Vec3::from_slice(&map.irradiance[3 * t..3 * t + 3]);
            worst = worst.max((got - want).abs().max_element() / peak);
        }
        println!("{label:5}  {worst:.2e}");
        assert!(worst < tolerance, "{label}: {worst}");
    }
}

/// SH diffuse against prt-sphere's Ramamoorthi–Hanrahan convolution and against quadrature.
#[test]
fn sh_diffuse_matches_the_clamped_cosine_convolution() {
    let mut rng = Rng(11);
    for _ in 0..50 {
        let c: [Vec3; SH_COEFFICIENTS] =
            std::array::from_fn(|i| (rng.colour() - 0.5) * if i == 0 { 4.0 } else { 1.0 });
        let normal = rng.unit();
        let mut flat: Vec<f32> = c.iter().flat_map(|v| v.to_array()).collect();
        prt_sphere::sh::irradiance_from_radiance(&mut flat, 3).unwrap();
        let mut want = [0.0f32; 3];
        prt_sphere::sh::eval_expansion(&flat, 3, normal, &mut want).unwrap();
        let got = lm::sh_diffuse(&c, normal);
        assert!(
            (got - Vec3::from(want)).abs().max_element() < 1e-5,
            "{got} {want:?}"
        );
    }
    let c: [Vec3; SH_COEFFICIENTS] = std::array::from_fn(|i| {
        Vec3::splat(if i == 0 { 2.0 } else { 0.3 }) * (i as f32 * 0.7).cos()
    });
    let normal = Vec3::new(0.3, 0.8, -0.2).normalize();
    let want = integrate(normal.as_dvec3(), 256, 256, |w| {
        sh_radiance(&c, w) * normal.as_dvec3().dot(w).max(0.0)
    });
    let got = lm::sh_diffuse(&c, normal);
    assert!(
        max_rel(got, want, want.abs().max_element()) < 1e-4,
        "{got} {want}"
    );
}

/// Roughness, and the largest relative errors of the SG and SH specular against quadrature
/// measured over the views of `specular_cases` (about 10% above the measured values; the SG
/// fit of the GGX lobe, with the rest of the BRDF taken at its axis, overestimates rough
/// lobes).
const SPECULAR_TOLERANCES: [(f32, f64, f64); 5] = [
    (0.3, 0.06, 0.03),
    (0.5, 0.13, 0.14),
    (0.7, 0.24, 0.24),
    (0.85, 0.35, 0.09),
    (1.0, 0.32, 0.29),
];

/// The view and roughness grid of the specular checks: views up to 60° off the normal.
fn specular_cases(rng: &mut Rng) -> Vec<(Vec3, f32)> {
    let mut cases = Vec::new();
    for roughness in SPECULAR_TOLERANCES.map(|(r, _, _)| r) {
        for _ in 0..3 {
            cases.push((rng.upper(0.5), roughness));
        }
    }
    cases
}

/// Per roughness of `SPECULAR_TOLERANCES`, the largest relative error of `shader` against
/// quadrature of `radiance` times the GGX BRDF and cosine over the views of `specular_cases`
/// (normal +Y, f0 = 0.04, a fresh radiance per case from `fill`).
fn specular_errors<R>(
    what: &str,
    seed: u64,
    mut fill: impl FnMut(&mut Rng) -> R,
    radiance: impl Fn(&R, DVec3) -> DVec3,
    shader: impl Fn(&R, Vec3, Vec3, f32, Vec3) -> Vec3,
) -> Vec<f64> {
    let mut rng = Rng(seed);
    let (n, f0) = (Vec3::Y, Vec3::splat(0.04));
    println!("{what}: roughness  n·v  shader  quadrature  relative error");
    let mut worst = vec![0.0f64; SPECULAR_TOLERANCES.len()];
    for (v, roughness) in specular_cases(&mut rng) {
        let light = fill(&mut rng);
        let got = shader(&light, n, v, roughness, f0);
        let (axis, _) = lm::ggx_warped_sg(n, v, lm::alpha2(roughness));
        let want = integrate(axis.as_dvec3(), 512, 256, |w| {
            radiance(&light, w)
                * ggx_times_cosine(
                    n.as_dvec3(),
                    v.as_dvec3(),
                    w,
                    f64::from(roughness),
                    f0.as_dvec3(),
                )
        });
        let err = max_rel(got, want, want.max_element());
        println!(
            "{roughness:9.2}  {:.2}  {:.4}  {:.4}  {err:.3}",
            v.y, got.x, want.x
        );
        let k = SPECULAR_TOLERANCES
            .iter()
            .position(|t| t.0 == roughness)
            .unwrap();
        worst[k] = worst[k].max(err);
    }
    worst
}

/// SG specular (warped NDF lobe, rest of the BRDF at its axis) against quadrature of the SG
/// radiance (sg:9, random positive amplitudes) times the GGX BRDF and cosine.
#[test]
fn sg_specular_matches_ggx_quadrature() {
    let (axes, lambda) = lobes(9);
    let worst = specular_errors(
        "sg:9",
        5,
        |rng| axes.iter().map(|_| rng.colour() + 0.1).collect::<Vec<_>>(),
        |c, w| sg_radiance(&axes, lambda, c, w),
        |c, n, v, roughness, f0| lm::sg_specular(&axes, lambda, c, n, v, roughness, f0),
    );
    for (&(roughness, tolerance, _), worst) in SPECULAR_TOLERANCES.iter().zip(worst) {
        println!("sg:9 roughness {roughness}: worst relative error {worst:.3}");
        assert!(worst < tolerance, "roughness {roughness}: {worst}");
    }
}

/// SH specular (the radiance convolved with the same lobe) against quadrature of the SH
/// radiance times the GGX BRDF and cosine. The radiance is what a bake fits: random positive
/// SG lobes over the upper hemisphere, zero below (the hemisphere rule), projected onto bands
/// 0..2.
#[test]
fn sh_specular_matches_ggx_quadrature() {
    let (axes, lambda) = lobes(9);
    let worst = specular_errors(
        "sh:3",
        9,
        |rng| -> [Vec3; SH_COEFFICIENTS] {
            let c: Vec<Vec3> = axes.iter().map(|_| rng.colour() + 0.1).collect();
            let mut projected = [DVec3::ZERO; SH_COEFFICIENTS];
            let mut y = [0.0; SH_COEFFICIENTS];
            let (rings, sectors) = (128, 256);
            for i in 0..rings {
                let theta = (i as f64 + 0.5) * PI / rings as f64;
                let (st, ct) = theta.sin_cos();
                if ct <= 0.0 {
                    continue;
                }
                for k in 0..sectors {
                    let phi = (k as f64 + 0.5) * 2.0 * PI / sectors as f64;
                    let w = DVec3::new(st * phi.cos(), ct, st * phi.sin());
                    eval_sh_f64(3, w, &mut y);
                    let l = sg_radiance(&axes, lambda, &c, w);
                    let area = st * (PI / rings as f64) * (2.0 * PI / sectors as f64);
                    for (p, y) in projected.iter_mut().zip(&y) {
                        *p += l * (*y * area);
                    }
                }
            }
            projected.map(|p| p.as_vec3())
        },
        sh_radiance,
        lm::sh_specular,
    );
    for (&(roughness, _, tolerance), worst) in SPECULAR_TOLERANCES.iter().zip(worst) {
        println!("sh:3 roughness {roughness}: worst relative error {worst:.3}");
        assert!(worst < tolerance, "roughness {roughness}: {worst}");
    }
}

fn rotation(axis: Vec3, angle: f32) -> Mat3 {
    Mat3::from_axis_angle(axis.normalize(), angle)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    /// Non-negative SG amplitudes give non-negative, finite irradiance and specular.
    #[test]
    fn sg_light_is_never_negative(
        lobes_n in 1usize..=16,
        amplitudes in prop::collection::vec(0.0f32..10.0, 16),
        nx in -1.0f32..1.0, ny in -1.0f32..1.0, nz in -1.0f32..1.0,
        vx in -1.0f32..1.0, vy in 0.05f32..1.0, vz in -1.0f32..1.0,
        roughness in 0.0f32..=1.0,
    ) {
        let (axes, lambda) = lobes(lobes_n);
        let c: Vec<Vec3> = amplitudes.iter().map(|&a| Vec3::new(a, 0.5 * a, 0.0)).collect();
        let n = Vec3::new(nx, ny, nz).try_normalize().unwrap_or(Vec3::Y);
        let v = Vec3::new(vx, vy, vz).normalize();
        let e = lm::sg_diffuse(&axes, lambda, &c, n);
        prop_assert!(e.is_finite() && e.min_element() >= 0.0, "{e}");
        let s = lm::sg_specular(&axes, lambda, &c, Vec3::Y, v, roughness, Vec3::splat(0.04));
        prop_assert!(s.is_finite() && s.min_element() >= 0.0, "{s}");
    }

    /// SH irradiance and specular are rotation invariant: rotating the radiance (prt-sphere's
    /// SH rotation), the normal and the view together changes nothing.
    #[test]
    fn sh_light_is_rotation_invariant(
        seed in 1u64..u64::MAX,
        ax in -1.0f32..1.0, ay in 0.1f32..1.0, az in -1.0f32..1.0,
        angle in -3.0f32..3.0,
        roughness in 0.3f32..=1.0,
    ) {
        let mut rng = Rng(seed);
        let c: [Vec3; SH_COEFFICIENTS] = std::array::from_fn(|_| rng.colour() - 0.3);
        let n = rng.unit();
        let v = (n + rng.unit() * 0.7).normalize();
        let r = rotation(Vec3::new(ax, ay, az), angle);
        let mut flat: Vec<f32> = c.iter().flat_map(|v| v.to_array()).collect();
        ShRotation::new(3, r).unwrap().apply(&mut flat, 3).unwrap();
        let rotated: [Vec3; SH_COEFFICIENTS] =
            std::array::from_fn(|i| Vec3::from_slice(&flat[3 * i..3 * i + 3]));
        let scale = c.iter().map(|v| v.abs().max_element()).sum::<f32>();
        let e = lm::sh_diffuse(&c, n);
        let e_rotated = lm::sh_diffuse(&rotated, r * n);
        prop_assert!((e - e_rotated).abs().max_element() < 2e-5 * scale, "{e} {e_rotated}");
        let f0 = Vec3::splat(0.04);
        let s = lm::sh_specular(&c, n, v, roughness, f0);
        let s_rotated = lm::sh_specular(&rotated, r * n, r * v, roughness, f0);
        prop_assert!(
            (s - s_rotated).abs().max_element() < 1e-4 * scale.max(s.max_element()),
            "{s} {s_rotated}"
        );
    }

    /// SG specular is rotation invariant: rotating the lobes, the normal and the view together
    /// changes nothing.
    #[test]
    fn sg_specular_is_rotation_invariant(
        lobes_n in 1usize..=12,
        ax in -1.0f32..1.0, ay in 0.1f32..1.0, az in -1.0f32..1.0,
        angle in -3.0f32..3.0,
        roughness in 0.3f32..=1.0,
        vx in -1.0f32..1.0, vy in 0.1f32..1.0,
    ) {
        let (axes, lambda) = lobes(lobes_n);
        let c: Vec<Vec3> = (0..lobes_n).map(|i| Vec3::splat(1.0 + i as f32)).collect();
        let r = rotation(Vec3::new(ax, ay, az), angle);
        let rotated: Vec<Vec3> = axes.iter().map(|&p| r * p).collect();
        let v = Vec3::new(vx, vy, 0.3).normalize();
        let f0 = Vec3::splat(0.04);
        let s = lm::sg_specular(&axes, lambda, &c, Vec3::Y, v, roughness, f0);
        let s_rotated = lm::sg_specular(&rotated, lambda, &c, r * Vec3::Y, r * v, roughness, f0);
        prop_assert!((s - s_rotated).abs().max_element() <= 1e-3 * s.max_element() + 1e-6, "{s} {s_rotated}");
        let e = lm::sg_diffuse(&axes, lambda, &c, Vec3::Y);
        let e_rotated = lm::sg_diffuse(&rotated, lambda, &c, r * Vec3::Y);
        prop_assert!((e - e_rotated).abs().max_element() <= 1e-3 * e.max_element(), "{e} {e_rotated}");
    }
}
