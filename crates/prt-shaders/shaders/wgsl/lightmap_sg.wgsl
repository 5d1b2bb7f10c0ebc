// SG lightmap texels (`prt lightmap --basis sg:N`): incident radiance
// L(w) = sum_i c_i exp(lambda (p_i.w - 1)) in the texel's tangent frame, RGB amplitudes c_i.
// Needs lightmap_common.wgsl and, before it, the lobes of the manifest's `sg` entry:
//   const LM_SG_LOBES: u32;                              // N
//   const LM_SG_SHARPNESS: f32;                          // lambda, shared by every lobe
//   const LM_SG_AXES: array<vec3<f32>, LM_SG_LOBES>;     // p_i, tangent frame
// Every direction below is in the texel's tangent frame (lm_to_tangent).

// Diffuse irradiance E(n) = integral of L(w) max(0, n.w) dw: Hill's fitted cosine convolution
// per lobe (lm_sg_irradiance_unit). Divide by pi and multiply by the albedo for the exit radiance.
fn lm_sg_diffuse(coefficients: array<vec3<f32>, LM_SG_LOBES>, n: vec3<f32>) -> vec3<f32> {
    var c = coefficients;
    var axes = LM_SG_AXES;
    var e = vec3<f32>(0.0);
    for (var i = 0u; i < LM_SG_LOBES; i++) {
        e += c[i] * lm_sg_irradiance_unit(axes[i], LM_SG_SHARPNESS, n);
    }
    return e;
}

// Specular exit radiance towards v of a GGX microfacet BRDF (perceptual roughness, Schlick
// Fresnel from f0), as in Roughton's Figure 2 (SG lightmaps for indirect specular) after Neubelt
// and Pettineo: each light lobe times the warped NDF lobe (lm_sg_inner_product), the rest of the
// BRDF and the cosine evaluated at the warped lobe's axis.
fn lm_sg_specular(
    coefficients: array<vec3<f32>, LM_SG_LOBES>,
    n: vec3<f32>,
    v: vec3<f32>,
    roughness: f32,
    f0: vec3<f32>,
) -> vec3<f32> {
    var c = coefficients;
    var axes = LM_SG_AXES;
    let a2 = lm_alpha2(roughness);
    let lobe = lm_ggx_warped_sg(n, v, a2);
    var s = vec3<f32>(0.0);
    for (var i = 0u; i < LM_SG_LOBES; i++) {
        s += c[i] * lm_sg_inner_product(axes[i], LM_SG_SHARPNESS, lobe.xyz, lobe.w);
    }
    return max(s * lm_ggx_sg_amplitude(a2) * lm_ggx_rest(n, v, lobe.xyz, a2, f0), vec3<f32>(0.0));
}
