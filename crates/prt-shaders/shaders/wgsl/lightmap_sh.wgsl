// SH lightmap texels (`prt lightmap --basis sh:N`): incident radiance as real SH in the texel's
// tangent frame (prt's convention: +Y up, Condon-Shortley phase, orthonormal), RGB per function.
// Bands 0..2 are read (9 coefficients; zeros past the texel's N^2 for sh:1 and sh:2, and the
// first 9 of sh:4 and up, whose higher bands add at most a few percent to the irradiance).
// Needs lightmap_common.wgsl. Every direction below is in the texel's tangent frame.

fn lm_sh9(n: vec3<f32>) -> array<f32, 9> {
    return array<f32, 9>(
        0.28209479177387814,
        -0.4886025119029199 * n.x,
        0.4886025119029199 * n.y,
        -0.4886025119029199 * n.z,
        1.0925484305920792 * n.x * n.z,
        -1.0925484305920792 * n.x * n.y,
        0.94617469575756 * n.y * n.y - 0.31539156525252,
        -1.0925484305920792 * n.y * n.z,
        0.5462742152960396 * (n.z * n.z - n.x * n.x),
    );
}

// sum_i g_band(i) c_i Y_i(d): the expansion at d, band l scaled by g[l].
fn lm_sh_eval_scaled(coefficients: array<vec3<f32>, 9>, d: vec3<f32>, g: vec3<f32>) -> vec3<f32> {
    var c = coefficients;
    var y = lm_sh9(d);
    var out = vec3<f32>(0.0);
    for (var i = 0u; i < 9u; i++) {
        let band = select(select(2u, 1u, i < 4u), 0u, i == 0u);
        out += g[band] * y[i] * c[i];
    }
    return out;
}

// Diffuse irradiance E(n): the clamped-cosine convolution of Ramamoorthi and Hanrahan, "An
// Efficient Representation for Irradiance Environment Maps" (SIGGRAPH 2001): band l times
// A_l = pi, 2 pi / 3, pi / 4.
fn lm_sh_diffuse(coefficients: array<vec3<f32>, 9>, n: vec3<f32>) -> vec3<f32> {
    return lm_sh_eval_scaled(coefficients, n, vec3<f32>(LM_PI, 2.0 * LM_PI / 3.0, 0.25 * LM_PI));
}

// Specular exit radiance towards v (GGX, perceptual roughness, Schlick Fresnel from f0): the
// radiance convolved with the warped NDF lobe of lm_ggx_warped_sg, then the rest of the BRDF
// at its axis, as lm_sg_specular does. The convolution of an SH expansion with a zonal SG of
// sharpness lambda is exact (Funk-Hecke): band l times (integral of the SG) i_l(lambda) /
// i_0(lambda), with i_1/i_0 = coth(lambda) - 1/lambda and i_2/i_0 = 1 - 3 (i_1/i_0) / lambda
// (modified spherical Bessel functions), so the only approximation is the lobe's SG fit.
fn lm_sh_specular(
    coefficients: array<vec3<f32>, 9>,
    n: vec3<f32>,
    v: vec3<f32>,
    roughness: f32,
    f0: vec3<f32>,
) -> vec3<f32> {
    let a2 = lm_alpha2(roughness);
    let lobe = lm_ggx_warped_sg(n, v, a2);
    let lambda = lobe.w;
    let e2 = exp(-2.0 * lambda);
    let g1 = (1.0 + e2) / (1.0 - e2) - 1.0 / lambda;
    let g2 = 1.0 - 3.0 * g1 / lambda;
    let convolved = lm_sh_eval_scaled(coefficients, lobe.xyz, vec3<f32>(1.0, g1, g2));
    let s = convolved * lm_sg_integral(lambda) * lm_ggx_sg_amplitude(a2);
    return max(s * lm_ggx_rest(n, v, lobe.xyz, a2, f0), vec3<f32>(0.0));
}
