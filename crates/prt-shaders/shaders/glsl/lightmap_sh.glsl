// SH lightmap texels (`prt lightmap --basis sh:N`); the same math as
// shaders/wgsl/lightmap_sh.wgsl (bands 0..2: 9 coefficients, zeros past sh:1 and sh:2's).
// Needs lightmap_common.glsl. Every direction below is in the texel's tangent frame.

// sum_i g_band(i) c_i Y_i(d) (prt's SH convention: +Y up, Condon-Shortley phase).
vec3 lm_sh_eval_scaled(vec3 coefficients[9], vec3 d, vec3 g) {
    float y[9];
    y[0] = 0.28209479177387814;
    y[1] = -0.4886025119029199 * d.x;
    y[2] = 0.4886025119029199 * d.y;
    y[3] = -0.4886025119029199 * d.z;
    y[4] = 1.0925484305920792 * d.x * d.z;
    y[5] = -1.0925484305920792 * d.x * d.y;
    y[6] = 0.94617469575756 * d.y * d.y - 0.31539156525252;
    y[7] = -1.0925484305920792 * d.y * d.z;
    y[8] = 0.5462742152960396 * (d.z * d.z - d.x * d.x);
    vec3 out_value = vec3(0.0);
    for (int i = 0; i < 9; i++) {
        float band = i == 0 ? g.x : (i < 4 ? g.y : g.z);
        out_value += band * y[i] * coefficients[i];
    }
    return out_value;
}

// Diffuse irradiance E(n): Ramamoorthi and Hanrahan's clamped-cosine convolution.
vec3 lm_sh_diffuse(vec3 coefficients[9], vec3 n) {
    return lm_sh_eval_scaled(coefficients, n, vec3(LM_PI, 2.0 * LM_PI / 3.0, 0.25 * LM_PI));
}

// Specular exit radiance towards v: the radiance convolved exactly with the warped NDF lobe
// (band l times i_l / i_0 of its sharpness), the rest of the BRDF at its axis.
vec3 lm_sh_specular(vec3 coefficients[9], vec3 n, vec3 v, float roughness, vec3 f0) {
    float a2 = lm_alpha2(roughness);
    vec4 lobe = lm_ggx_warped_sg(n, v, a2);
    float lambda = lobe.w;
    float e2 = exp(-2.0 * lambda);
    float g1 = (1.0 + e2) / (1.0 - e2) - 1.0 / lambda;
    float g2 = 1.0 - 3.0 * g1 / lambda;
    vec3 convolved = lm_sh_eval_scaled(coefficients, lobe.xyz, vec3(1.0, g1, g2));
    vec3 s = convolved * lm_sg_integral(lambda) * lm_ggx_sg_amplitude(a2);
    return max(s * lm_ggx_rest(n, v, lobe.xyz, a2, f0), vec3(0.0));
}
