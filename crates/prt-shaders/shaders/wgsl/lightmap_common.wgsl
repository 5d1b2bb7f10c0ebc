// prt lightmap texels (`prt lightmap --basis sg:N | sh:N`, docs/formats.md "Lightmap folder"):
// the texel's tangent frame, spherical Gaussians and the GGX terms shared by lightmap_sg.wgsl
// and lightmap_sh.wgsl. Needs nothing before it.
//
// A texel stores incident radiance in its tangent frame: +Y the surface's (winding) normal, X
// and Z the orthonormal pair of Duff et al., "Building an Orthonormal Basis, Revisited" (JCGT
// 6(1), 2017), exactly as glam's Vec3::any_orthonormal_pair builds it on the CPU.

const LM_PI: f32 = 3.14159265;

// The texel's tangent frame for its unit normal: columns (tangent, normal, bitangent). The sign
// is the sign bit of n.z, as Rust's f32::signum reads it (-0.0 gives -1): a floor's normal
// (0, 1, -0.0) must give the frame the bake used.
fn lm_tangent_frame(normal: vec3<f32>) -> mat3x3<f32> {
    let sign = select(1.0, -1.0, (bitcast<u32>(normal.z) >> 31u) == 1u);
    let a = -1.0 / (sign + normal.z);
    let b = normal.x * normal.y * a;
    let tangent = vec3<f32>(1.0 + sign * normal.x * normal.x * a, sign * b, -sign * normal.x);
    let bitangent = vec3<f32>(b, sign + normal.y * normal.y * a, -normal.y);
    return mat3x3<f32>(tangent, normal, bitangent);
}

// A world direction in the tangent frame of lm_tangent_frame(texel_normal).
fn lm_to_tangent(frame: mat3x3<f32>, d: vec3<f32>) -> vec3<f32> {
    return d * frame;
}

// Integral over the sphere of exp(lambda (p.v - 1)): 2 pi (1 - e^(-2 lambda)) / lambda.
fn lm_sg_integral(lambda: f32) -> f32 {
    let l = max(lambda, 1e-4);
    return 2.0 * LM_PI * (1.0 - exp(-2.0 * l)) / l;
}

// Integral over the sphere of the product of two unit-amplitude SGs: 2 pi e^(r - l1 - l2)
// (1 - e^(-2r)) / r with r = |l1 p1 + l2 p2| (Wang et al. 2009; Pettineo, "SG Series" part 2).
fn lm_sg_inner_product(p1: vec3<f32>, l1: f32, p2: vec3<f32>, l2: f32) -> f32 {
    let r = max(length(l1 * p1 + l2 * p2), 1e-4);
    return 2.0 * LM_PI * exp(r - l1 - l2) * (1.0 - exp(-2.0 * r)) / r;
}

// Irradiance of a unit-amplitude SG (axis p, sharpness lambda) at unit normal n,
// E = integral of exp(lambda (p.w - 1)) max(0, n.w) dw. Both functions are zonal, so E is the
// Legendre series sum_l (2l + 1) / (4 pi) A_l (integral of the SG) (i_l / i_0)(lambda)
// P_l(p.n) (Funk-Hecke; A_l the clamped cosine's pi, 2pi/3, pi/4, 0, -pi/24 of Ramamoorthi and
// Hanrahan 2001, i_l the modified spherical Bessel functions, whose ratios follow from
// i_1 / i_0 = coth(lambda) - 1/lambda and i_(l+1) = i_(l-1) - (2l + 1) / lambda i_l). Up to
// lambda = 22 it is summed through band 4 (error under 1.5% of the lobe's peak irradiance,
// measured against prt-sphere's full series); above, Hill's fitted approximation (S. Hill, in
// M. Pettineo, "SG Series Part 3: Diffuse Lighting From an SG Light Source", 2016), also under
// 1.5% there and better as the lobe sharpens (the truncated series rings). `prt lightmap`'s
// lobes have lambda = N ln 2: 0.69 for sg:1, 6.2 for sg:9, 44 for sg:64.
fn lm_sg_irradiance_unit(p: vec3<f32>, lambda: f32, n: vec3<f32>) -> f32 {
    let mu = clamp(dot(p, n), -1.0, 1.0);
    let l = max(lambda, 1e-4);
    if (l <= 22.0) {
        let e2 = exp(-2.0 * l);
        let g1 = (1.0 + e2) / (1.0 - e2) - 1.0 / l;
        let g2 = 1.0 - 3.0 * g1 / l;
        let g3 = g1 - 5.0 * g2 / l;
        // Below lambda 0.5, band 4 is under 1e-4 of band 0 and its recurrence cancels.
        let g4 = select(0.0, g2 - 7.0 * g3 / l, l >= 0.5);
        let mu2 = mu * mu;
        let p2 = 0.5 * (3.0 * mu2 - 1.0);
        let p4 = (35.0 * mu2 * mu2 - 30.0 * mu2 + 3.0) / 8.0;
        let series = 0.25 + 0.5 * g1 * mu + 0.3125 * g2 * p2 - 0.09375 * g4 * p4;
        return max(series * lm_sg_integral(l), 0.0);
    }
    let c0 = 0.36;
    let c1 = 1.0 / (4.0 * c0);
    let eml = exp(-l);
    let em2l = eml * eml;
    let rl = 1.0 / l;
    let scale = 1.0 + 2.0 * em2l - rl;
    let bias = (eml - em2l) * rl - em2l;
    let x = sqrt(max(1.0 - scale, 0.0));
    let x0 = c0 * mu;
    let x1 = c1 * x;
    let s = x0 + x1;
    var y = clamp(mu, 0.0, 1.0);
    if (abs(x0) <= x1 && x > 0.0) {
        y = s * s / x;
    }
    return max((scale * y + bias) * lm_sg_integral(l), 0.0);
}

// The GGX lobe as one SG, warped into the domain of incident directions (Neubelt and Pettineo,
// "Crafting a Next-Gen Material Pipeline for The Order: 1886", SIGGRAPH 2013 course; Pettineo,
// "SG Series Part 4: Specular Lighting From an SG Light Source", 2016): the NDF D(h) ~ SG(n,
// 2/a^2, 1/(pi a^2)), then axis reflect(-v, n) and sharpness / (4 |n.v|). Returns
// (axis, sharpness) in xyz and w; the amplitude is lm_ggx_sg_amplitude(a2).
fn lm_ggx_warped_sg(n: vec3<f32>, v: vec3<f32>, a2: f32) -> vec4<f32> {
    let axis = reflect(-v, n);
    let sharpness = 2.0 / a2 / (4.0 * max(dot(n, v), 1e-4));
    return vec4<f32>(axis, sharpness);
}

fn lm_ggx_sg_amplitude(a2: f32) -> f32 {
    return 1.0 / (LM_PI * a2);
}

// The separable Smith-GGX visibility G1(x) / (2 n.x) of one direction.
fn lm_ggx_v1(a2: f32, n_dot_x: f32) -> f32 {
    return 1.0 / (n_dot_x + sqrt(a2 + (1.0 - a2) * n_dot_x * n_dot_x));
}

// Everything of the specular BRDF but the NDF, times the cosine, at the warped lobe's axis l:
// V1(l) V1(v) F(l.h) (n.l), with Schlick's Fresnel from f0. The GGX alpha is roughness^2
// (glTF's perceptual roughness).
fn lm_ggx_rest(n: vec3<f32>, v: vec3<f32>, l: vec3<f32>, a2: f32, f0: vec3<f32>) -> vec3<f32> {
    let n_dot_l = clamp(dot(n, l), 0.0, 1.0);
    let n_dot_v = clamp(dot(n, v), 0.0, 1.0);
    let h = normalize(l + v);
    let fresnel = f0 + (vec3<f32>(1.0) - f0) * pow(1.0 - clamp(dot(l, h), 0.0, 1.0), 5.0);
    return lm_ggx_v1(a2, n_dot_l) * lm_ggx_v1(a2, n_dot_v) * fresnel * n_dot_l;
}

// GGX alpha squared of a perceptual roughness, kept off 0 (a mirror has no SG).
fn lm_alpha2(roughness: f32) -> f32 {
    let a = max(roughness * roughness, 1e-3);
    return a * a;
}
