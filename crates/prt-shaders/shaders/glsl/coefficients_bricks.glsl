// prt filterable MBD layout: the coefficient volume in bricks (layout `bricks`): one
// indirection fetch per pixel, then the filtered atlas fetches. Needs common.glsl,
// reconstruct_es.glsl's and bricks_es.glsl's declarations (u_mbd_bricks,
// u_mbd_coefficient_indirection, MBD_FETCH_INDIRECTION).

// Where the coefficients of x are: xyz its position in one group's brick atlas (texels), w = 1 in
// a stored brick, 0 in an empty one. The brick holding the cell of x holds all eight of the
// cell's nodes (the apron), so the trilinear footprint never leaves it.
vec4 mbd_coefficient_site(vec3 x) {
    vec3 p = mbd_local(u_mbd_coefficients, x) - 0.5;
    float size = u_mbd_bricks.grid.w;
    vec3 brick = min(floor(p / size), u_mbd_bricks.grid.xyz - 1.0);
    vec4 entry = MBD_FETCH_INDIRECTION(u_mbd_coefficient_indirection, ivec3(brick));
    vec3 at = floor(entry.xyz * 255.0 + 0.5);
    return vec4(at * (size + 1.0) + (p - brick * size) + 0.5, entry.w);
}

// The filtered texel of channel group g at `site`: group g's atlas is the g-th along z.
vec4 mbd_coefficient_texel(vec4 site, int g) {
    vec3 texels = u_mbd_bricks.atlas.xyz * (u_mbd_bricks.grid.w + 1.0);
    vec3 uvw = (site.xyz + vec3(0.0, 0.0, float(g) * texels.z))
        / (texels * vec3(1.0, 1.0, float(MBD_COEFFICIENT_GROUPS)));
    return MBD_SAMPLE3D(u_mbd_coefficient_texture, uvw);
}
