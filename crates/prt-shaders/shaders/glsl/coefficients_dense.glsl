// prt filterable MBD layout: the coefficient volume dense (layout `volume`, ceil(L/4) tiles
// stacked along z). Needs common.glsl and reconstruct_es.glsl's declarations.

// Where the coefficients of x are: xyz its position inside any tile (texels), w = 1.
vec4 mbd_coefficient_site(vec3 x) {
    return vec4(mbd_local(u_mbd_coefficients, x), 1.0);
}

// The filtered texel of channel group g at `site`.
vec4 mbd_coefficient_texel(vec4 site, int g) {
    return MBD_SAMPLE3D(u_mbd_coefficient_texture, mbd_tile_uvw(u_mbd_coefficients, site.xyz, g));
}
