// prt filterable MBD layout: per-pixel reconstruction of incident radiance (SH9 RGB),
// f(x) = sum_l c_l(x) b_l(x), from the coefficient volume and the lit basis volume, both
// hardware-filtered (trilinear, clamp-to-edge). Needs common.glsl, the declarations of u_mbd_*
// and MBD_SAMPLE3D (reconstruct_es.glsl for WebGL2) and the coefficient layout's
// mbd_coefficient_site / mbd_coefficient_texel (coefficients_dense.glsl or
// coefficients_bricks.glsl).

// Incident radiance at world position x: SH9 per channel, value c*9 + i (28th value 0).
void mbd_incident_radiance(vec3 x, out vec4 sh[7]) {
    vec4 site = mbd_coefficient_site(x);
    vec3 lit_local = mbd_local(u_mbd_lit, x);
    for (int r = 0; r < MBD_LIT_GROUPS; r++) {
        sh[r] = vec4(0.0);
    }
    for (int g = 0; g < MBD_COEFFICIENT_GROUPS; g++) {
        vec4 texel = mbd_coefficient_texel(site, g);
        // site.w = 0 in an empty brick: no coefficients there.
        vec4 c = site.w * (u_mbd_coefficient_bias[g] + u_mbd_coefficient_scale[g] * texel);
        for (int k = 0; k < 4; k++) {
            int l = 4 * g + k;
            if (l < RANK) {
                for (int r = 0; r < MBD_LIT_GROUPS; r++) {
                    vec3 at = mbd_tile_uvw(u_mbd_lit, lit_local, MBD_LIT_GROUPS * l + r);
                    sh[r] += c[k] * MBD_SAMPLE3D(u_mbd_lit_texture, at);
                }
            }
        }
    }
}
