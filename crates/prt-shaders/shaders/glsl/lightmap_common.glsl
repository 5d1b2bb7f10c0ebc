// prt lightmap texels (`prt lightmap --basis sg:N | sh:N`, docs/formats.md "Lightmap folder"):
// the texel's tangent frame, spherical Gaussians and the GGX terms shared by lightmap_sg.glsl
// and lightmap_sh.glsl. The same math as shaders/wgsl/lightmap_common.wgsl (sources there).
//
// A texel stores incident radiance in its tangent frame: +Y the surface's (winding) normal, X
// and Z the orthonormal pair of Duff et al., "Building an Orthonormal Basis, Revisited" (JCGT
// 6(1), 2017), exactly as glam's Vec3::any_orthonormal_pair builds it on the CPU.

const float LM_PI = 3.14159265;

// The texel's tangent frame for its unit normal: columns (tangent, normal, bitangent); the sign
// is n.z's sign bit, as Rust's f32::signum reads it (-0.0 gives -1).
mat3 lm_tangent_frame(vec3 normal) {
    float sign_z = (floatBitsToUint(normal.z) >> 31u) == 1u ? -1.0 : 1.0;
    float a = -1.0 / (sign_z + normal.z);
    float b = normal.x * normal.y * a;
    vec3 tangent = vec3(1.0 + sign_z * normal.x * normal.x * a, sign_z * b, -sign_z * normal.x);
    vec3 bitangent = vec3(b, sign_z + normal.y * normal.y * a, -normal.y);
    return mat3(tangent, normal, bitangent);
}

// A world direction in the tangent frame of lm_tangent_frame(texel_normal).
vec3 lm_to_tangent(mat3 frame, vec3 d) {
    return d * frame;
}

// Integral over the sphere of exp(lambda (p.v - 1)).
float lm_sg_integral(float lambda) {
    float l = max(lambda, 1e-4);
    return 2.0 * LM_PI * (1.0 - exp(-2.0 * l)) / l;
}

// Integral over the sphere of the product of two unit-amplitude SGs.
float lm_sg_inner_product(vec3 p1, float l1, vec3 p2, float l2) {
    float r = max(length(l1 * p1 + l2 * p2), 1e-4);
    return 2.0 * LM_PI * exp(r - l1 - l2) * (1.0 - exp(-2.0 * r)) / r;
}

// Irradiance of a unit-amplitude SG at unit normal n: the exact Legendre series through band 4
// up to lambda = 22, Hill's fitted approximation above (see lightmap_common.wgsl).
float lm_sg_irradiance_unit(vec3 p, float lambda, vec3 n) {
    float mu = clamp(dot(p, n), -1.0, 1.0);
    float l = max(lambda, 1e-4);
    if (l <= 22.0) {
        float e2 = exp(-2.0 * l);
        float g1 = (1.0 + e2) / (1.0 - e2) - 1.0 / l;
        float g2 = 1.0 - 3.0 * g1 / l;
        float g3 = g1 - 5.0 * g2 / l;
        float g4 = l >= 0.5 ? g2 - 7.0 * g3 / l : 0.0;
        float mu2 = mu * mu;
        float p2 = 0.5 * (3.0 * mu2 - 1.0);
        float p4 = (35.0 * mu2 * mu2 - 30.0 * mu2 + 3.0) / 8.0;
        float series = 0.25 + 0.5 * g1 * mu + 0.3125 * g2 * p2 - 0.09375 * g4 * p4;
        return max(series * lm_sg_integral(l), 0.0);
    }
    float c0 = 0.36;
    float c1 = 1.0 / (4.0 * c0);
    float eml = exp(-l);
    float em2l = eml * eml;
    float rl = 1.0 / l;
    float scale = 1.0 + 2.0 * em2l - rl;
    float bias = (eml - em2l) * rl - em2l;
    float x = sqrt(max(1.0 - scale, 0.0));
    float x0 = c0 * mu;
    float x1 = c1 * x;
    float s = x0 + x1;
    float y = clamp(mu, 0.0, 1.0);
    if (abs(x0) <= x1 && x > 0.0) {
        y = s * s / x;
    }
    return max((scale * y + bias) * lm_sg_integral(l), 0.0);
}

// The GGX lobe as one SG warped into the domain of incident directions: (axis, sharpness).
vec4 lm_ggx_warped_sg(vec3 n, vec3 v, float a2) {
    vec3 axis = reflect(-v, n);
    float sharpness = 2.0 / a2 / (4.0 * max(dot(n, v), 1e-4));
    return vec4(axis, sharpness);
}

float lm_ggx_sg_amplitude(float a2) {
    return 1.0 / (LM_PI * a2);
}

// The separable Smith-GGX visibility G1(x) / (2 n.x) of one direction.
float lm_ggx_v1(float a2, float n_dot_x) {
    return 1.0 / (n_dot_x + sqrt(a2 + (1.0 - a2) * n_dot_x * n_dot_x));
}

// V1(l) V1(v) F(l.h) (n.l) at the warped lobe's axis l, Schlick's Fresnel from f0.
vec3 lm_ggx_rest(vec3 n, vec3 v, vec3 l, float a2, vec3 f0) {
    float n_dot_l = clamp(dot(n, l), 0.0, 1.0);
    float n_dot_v = clamp(dot(n, v), 0.0, 1.0);
    vec3 h = normalize(l + v);
    vec3 fresnel = f0 + (vec3(1.0) - f0) * pow(1.0 - clamp(dot(l, h), 0.0, 1.0), 5.0);
    return lm_ggx_v1(a2, n_dot_l) * lm_ggx_v1(a2, n_dot_v) * fresnel * n_dot_l;
}

// GGX alpha squared of a perceptual roughness, kept off 0.
float lm_alpha2(float roughness) {
    float a = max(roughness * roughness, 1e-3);
    return a * a;
}
