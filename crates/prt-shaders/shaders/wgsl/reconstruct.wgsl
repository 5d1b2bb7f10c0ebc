// prt filterable MBD layout: per-pixel reconstruction of incident radiance (SH9 RGB),
// f(x) = sum_l c_l(x) b_l(x), from the coefficient volume and the lit basis volume, both
// hardware-filtered (trilinear, clamp-to-edge). Needs common.wgsl and the coefficient layout's
// mbd_coefficient_site / mbd_coefficient_texel (coefficients_dense.wgsl or
// coefficients_bricks.wgsl).

struct MbdReconstruction {
    coefficients: MbdGrid,
    lit: MbdGrid,
    // Dequantisation of the coefficient texels: value = bias + scale * texel (per channel).
    coefficient_scale: array<vec4<f32>, MBD_COEFFICIENT_GROUPS>,
    coefficient_bias: array<vec4<f32>, MBD_COEFFICIENT_GROUPS>,
    // The bricks of a coefficient volume in the bricks layout (unused when dense).
    bricks: MbdBricks,
}

@group(0) @binding(0) var<uniform> mbd: MbdReconstruction;
@group(0) @binding(1) var mbd_coefficient_texture: texture_3d<f32>;
@group(0) @binding(2) var mbd_lit_texture: texture_3d<f32>;
@group(0) @binding(3) var mbd_linear_clamp: sampler;

// Incident radiance at world position x: SH9 per channel, value c*9 + i (28th value 0).
fn mbd_incident_radiance(x: vec3<f32>) -> array<vec4<f32>, 7> {
    let site = mbd_coefficient_site(x);
    let lit_local = mbd_local(mbd.lit, x);
    var out: array<vec4<f32>, 7>;
    for (var g = 0u; g < MBD_COEFFICIENT_GROUPS; g++) {
        let texel = mbd_coefficient_texel(site, g);
        // site.w = 0 in an empty brick: no coefficients there.
        let c = site.w * (mbd.coefficient_bias[g] + mbd.coefficient_scale[g] * texel);
        for (var k = 0u; k < 4u; k++) {
            let l = 4u * g + k;
            if (l < RANK) {
                for (var r = 0u; r < MBD_LIT_GROUPS; r++) {
                    let at = mbd_tile_uvw(mbd.lit, lit_local, MBD_LIT_GROUPS * l + r);
                    out[r] += c[k] * textureSampleLevel(mbd_lit_texture, mbd_linear_clamp, at, 0.0);
                }
            }
        }
    }
    return out;
}
