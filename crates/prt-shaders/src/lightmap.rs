//! The lightmap shaders' math on the CPU, operation for operation in f32 (shaders/wgsl/
//! lightmap_*.wgsl and their GLSL twins): what `prt render --lightmap` draws with, and what the
//! tests hold against prt-sphere and numerical integration. Directions are in the texel's
//! tangent frame ([`tangent_frame`]) unless said otherwise.

use std::f32::consts::PI;

use glam::{Mat3, Vec3};

/// Coefficients the SH shaders read: bands 0..2.
pub const SH_COEFFICIENTS: usize = 9;

/// `lm_tangent_frame`: columns (tangent, normal, bitangent), glam's `any_orthonormal_pair`
/// (Duff et al. 2017) with the sign bit of `normal.z` (−0.0 counts as negative).
pub fn tangent_frame(normal: Vec3) -> Mat3 {
    let sign = if normal.z.is_sign_negative() {
        -1.0
    } else {
        1.0
    };
    let a = -1.0 / (sign + normal.z);
    let b = normal.x * normal.y * a;
    let tangent = Vec3::new(
        1.0 + sign * normal.x * normal.x * a,
        sign * b,
        -sign * normal.x,
    );
    let bitangent = Vec3::new(b, sign + normal.y * normal.y * a, -normal.y);
    Mat3::from_cols(tangent, normal, bitangent)
}

/// `lm_to_tangent`: a world direction in `frame`'s coordinates.
pub fn to_tangent(frame: Mat3, d: Vec3) -> Vec3 {
    Vec3::new(
        d.dot(frame.x_axis),
        d.dot(frame.y_axis),
        d.dot(frame.z_axis),
    )
}

/// `lm_sg_integral`: `∫ exp(λ (p·v − 1)) dv = 2π (1 − e^{−2λ}) / λ` (the shader's f32 form of
/// `prt_sphere::sg_integral`).
fn sg_integral(lambda: f32) -> f32 {
    let l = lambda.max(1e-4);
    2.0 * PI * (1.0 - (-2.0 * l).exp()) / l
}

/// `lm_sg_inner_product`: `∫ G₁ G₂` of two unit-amplitude SGs (the shader's f32 form of
/// `prt_sphere::sg_inner_product`).
fn sg_inner_product(p1: Vec3, l1: f32, p2: Vec3, l2: f32) -> f32 {
    let r = (l1 * p1 + l2 * p2).length().max(1e-4);
    2.0 * PI * (r - l1 - l2).exp() * (1.0 - (-2.0 * r).exp()) / r
}

/// `lm_sg_irradiance_unit`: irradiance of a unit-amplitude SG at normal `n` — the exact
/// Legendre series through band 4 up to λ = 22, Hill's fit above.
pub fn sg_irradiance_unit(p: Vec3, lambda: f32, n: Vec3) -> f32 {
    let mu = p.dot(n).clamp(-1.0, 1.0);
    let l = lambda.max(1e-4);
    if l <= 22.0 {
        let e2 = (-2.0 * l).exp();
        let g1 = (1.0 + e2) / (1.0 - e2) - 1.0 / l;
        let g2 = 1.0 - 3.0 * g1 / l;
        let g3 = g1 - 5.0 * g2 / l;
        let g4 = if l >= 0.5 { g2 - 7.0 * g3 / l } else { 0.0 };
        let mu2 = mu * mu;
        let p2 = 0.5 * (3.0 * mu2 - 1.0);
        let p4 = (35.0 * mu2 * mu2 - 30.0 * mu2 + 3.0) / 8.0;
        let series = 0.25 + 0.5 * g1 * mu + 0.3125 * g2 * p2 - 0.09375 * g4 * p4;
        return (series * sg_integral(l)).max(0.0);
    }
    let c0 = 0.36f32;
    let c1 = 1.0 / (4.0 * c0);
    let eml = (-l).exp();
    let em2l = eml * eml;
    let rl = 1.0 / l;
    let scale = 1.0 + 2.0 * em2l - rl;
    let bias = (eml - em2l) * rl - em2l;
    let x = (1.0 - scale).max(0.0).sqrt();
    let x0 = c0 * mu;
    let x1 = c1 * x;
    let s = x0 + x1;
    let y = if x0.abs() <= x1 && x > 0.0 {
        s * s / x
    } else {
        mu.clamp(0.0, 1.0)
    };
    ((scale * y + bias) * sg_integral(l)).max(0.0)
}

/// `lm_alpha2`: GGX α² of a perceptual roughness (α = roughness², at least 10⁻³).
pub fn alpha2(roughness: f32) -> f32 {
    let a = (roughness * roughness).max(1e-3);
    a * a
}

/// `lm_ggx_warped_sg`: the GGX NDF as an SG warped to the reflection of `v`: (axis, sharpness);
/// its amplitude is `1 / (π α²)`.
pub fn ggx_warped_sg(n: Vec3, v: Vec3, a2: f32) -> (Vec3, f32) {
    let axis = -v + 2.0 * n.dot(v) * n;
    (axis, 2.0 / a2 / (4.0 * n.dot(v).max(1e-4)))
}

/// `lm_ggx_v1`: `G1(x) / (2 n·x)`, separable Smith-GGX.
pub fn ggx_v1(a2: f32, n_dot_x: f32) -> f32 {
    1.0 / (n_dot_x + (a2 + (1.0 - a2) * n_dot_x * n_dot_x).sqrt())
}

/// `lm_ggx_rest`: `V1(l) V1(v) F(l·h) (n·l)` at direction `l`, Schlick's Fresnel from `f0`.
pub fn ggx_rest(n: Vec3, v: Vec3, l: Vec3, a2: f32, f0: Vec3) -> Vec3 {
    let n_dot_l = n.dot(l).clamp(0.0, 1.0);
    let n_dot_v = n.dot(v).clamp(0.0, 1.0);
    let h = (l + v).normalize();
    let fresnel = f0 + (Vec3::ONE - f0) * (1.0 - l.dot(h).clamp(0.0, 1.0)).powf(5.0);
    ggx_v1(a2, n_dot_l) * ggx_v1(a2, n_dot_v) * fresnel * n_dot_l
}

/// `lm_sg_diffuse`: irradiance at `n` of SG radiance (one RGB amplitude per axis, shared
/// sharpness).
pub fn sg_diffuse(axes: &[Vec3], sharpness: f32, coefficients: &[Vec3], n: Vec3) -> Vec3 {
    axes.iter()
        .zip(coefficients)
        .fold(Vec3::ZERO, |e, (&p, &c)| {
            e + c * sg_irradiance_unit(p, sharpness, n)
        })
}

/// `lm_sg_specular`: GGX specular exit radiance towards `v` of SG radiance.
pub fn sg_specular(
    axes: &[Vec3],
    sharpness: f32,
    coefficients: &[Vec3],
    n: Vec3,
    v: Vec3,
    roughness: f32,
    f0: Vec3,
) -> Vec3 {
    let a2 = alpha2(roughness);
    let (axis, lambda) = ggx_warped_sg(n, v, a2);
    let s = axes
        .iter()
        .zip(coefficients)
        .fold(Vec3::ZERO, |s, (&p, &c)| {
            s + c * sg_inner_product(p, sharpness, axis, lambda)
        });
    (s * (1.0 / (PI * a2)) * ggx_rest(n, v, axis, a2, f0)).max(Vec3::ZERO)
}

/// `lm_sh9`: the real SH of bands 0..2 at `d` (prt's convention, +Y up; the shader's
/// polynomials for what `prt_trace::sh::sh9` evaluates through prt-sphere).
fn sh9(d: Vec3) -> [f32; SH_COEFFICIENTS] {
    [
        0.282_094_8,
        -0.488_602_5 * d.x,
        0.488_602_5 * d.y,
        -0.488_602_5 * d.z,
        1.092_548_4 * d.x * d.z,
        -1.092_548_4 * d.x * d.y,
        0.946_174_7 * d.y * d.y - 0.315_391_57,
        -1.092_548_4 * d.y * d.z,
        0.546_274_2 * (d.z * d.z - d.x * d.x),
    ]
}

fn sh_eval_scaled(coefficients: &[Vec3; SH_COEFFICIENTS], d: Vec3, g: [f32; 3]) -> Vec3 {
    let y = sh9(d);
    (0..SH_COEFFICIENTS).fold(Vec3::ZERO, |out, i| {
        let band = match i {
            0 => 0,
            1..=3 => 1,
            _ => 2,
        };
        out + g[band] * y[i] * coefficients[i]
    })
}

/// `lm_sh_diffuse`: irradiance at `n` of SH radiance (Ramamoorthi and Hanrahan 2001).
pub fn sh_diffuse(coefficients: &[Vec3; SH_COEFFICIENTS], n: Vec3) -> Vec3 {
    sh_eval_scaled(coefficients, n, [PI, 2.0 * PI / 3.0, 0.25 * PI])
}

/// `lm_sh_specular`: GGX specular exit radiance towards `v` of SH radiance.
pub fn sh_specular(
    coefficients: &[Vec3; SH_COEFFICIENTS],
    n: Vec3,
    v: Vec3,
    roughness: f32,
    f0: Vec3,
) -> Vec3 {
    let a2 = alpha2(roughness);
    let (axis, lambda) = ggx_warped_sg(n, v, a2);
    let e2 = (-2.0 * lambda).exp();
    let g1 = (1.0 + e2) / (1.0 - e2) - 1.0 / lambda;
    let g2 = 1.0 - 3.0 * g1 / lambda;
    let convolved = sh_eval_scaled(coefficients, axis, [1.0, g1, g2]);
    let s = convolved * sg_integral(lambda) * (1.0 / (PI * a2));
    (s * ggx_rest(n, v, axis, a2, f0)).max(Vec3::ZERO)
}
