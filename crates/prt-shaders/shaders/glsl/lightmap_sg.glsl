// SG lightmap texels (`prt lightmap --basis sg:N`); the same math as
// shaders/wgsl/lightmap_sg.wgsl. Needs lightmap_common.glsl and, before it:
//   #define LM_SG_LOBES N
//   const float LM_SG_SHARPNESS = lambda;
//   const vec3 LM_SG_AXES[LM_SG_LOBES] = vec3[](...);   // tangent frame
// Every direction below is in the texel's tangent frame (lm_to_tangent).

// Diffuse irradiance E(n) (Hill's fitted cosine convolution per lobe).
vec3 lm_sg_diffuse(vec3 coefficients[LM_SG_LOBES], vec3 n) {
    vec3 e = vec3(0.0);
    for (int i = 0; i < LM_SG_LOBES; i++) {
        e += coefficients[i] * lm_sg_irradiance_unit(LM_SG_AXES[i], LM_SG_SHARPNESS, n);
    }
    return e;
}

// Specular exit radiance towards v (GGX, perceptual roughness, Schlick Fresnel from f0): each
// light lobe times the warped NDF lobe, the rest of the BRDF at the warped axis.
vec3 lm_sg_specular(vec3 coefficients[LM_SG_LOBES], vec3 n, vec3 v, float roughness, vec3 f0) {
    float a2 = lm_alpha2(roughness);
    vec4 lobe = lm_ggx_warped_sg(n, v, a2);
    vec3 s = vec3(0.0);
    for (int i = 0; i < LM_SG_LOBES; i++) {
        s += coefficients[i] * lm_sg_inner_product(LM_SG_AXES[i], LM_SG_SHARPNESS, lobe.xyz, lobe.w);
    }
    return max(s * lm_ggx_sg_amplitude(a2) * lm_ggx_rest(n, v, lobe.xyz, a2, f0), vec3(0.0));
}
