// prt filterable MBD layout: the lighting pass, run when the sky changes, as a fragment pass
// (WebGL2 has no compute): draw one full-viewport quad per z slice of the lit volume (an
// rgba16f 3D texture attached with framebufferTextureLayer, viewport = its width x height,
// u_mbd_slice = the slice). Each fragment writes one lit texel: group 7l + r holds values
// 4r .. 4r+3 of b_{n,l}[c*9 + i] = sum_j (D_ij + T^c_ij) s^c_j. Needs common.glsl and the
// declarations of u_mbd_*, mbd_lit, MBD_FETCH3D and MBD_FETCH2D (light_es.glsl).

// Raw basis value d (0..323) of vector l at node `node`, dequantised.
float mbd_raw(ivec3 node, int l, int d) {
    int g = 81 * l + d / 4;
    ivec3 origin = mbd_tile(u_mbd_basis, g) * ivec3(u_mbd_basis.nodes.xyz);
    vec4 texel = MBD_FETCH3D(u_mbd_basis_texture, origin + node);
    vec4 scale = MBD_FETCH2D(u_mbd_basis_ranges, ivec2(g, 0));
    vec4 bias = MBD_FETCH2D(u_mbd_basis_ranges, ivec2(g, 1));
    return (bias + scale * texel)[d % 4];
}

// Lit value k (0..27) of vector l at node `node`: row i of the direct block plus row i of
// channel c's indirect block, dotted with channel c's sky.
float mbd_lit_value(ivec3 node, int l, int k) {
    if (k >= 27) {
        return 0.0;
    }
    int c = k / 9;
    int i = k % 9;
    float sum = 0.0;
    for (int j = 0; j < 9; j++) {
        float d = mbd_raw(node, l, 9 * i + j);
        float t = mbd_raw(node, l, 81 * (c + 1) + 9 * i + j);
        sum += (d + t) * mbd_component(u_mbd_sky, 9 * c + j);
    }
    return sum;
}

// The lit texel at `texel` of the lit atlas.
vec4 mbd_light_texel(ivec3 texel) {
    ivec3 nodes = ivec3(u_mbd_lit.nodes.xyz);
    ivec3 tiles = ivec3(u_mbd_lit.tiles.xyz);
    ivec3 tile = texel / nodes;
    ivec3 node = texel - tile * nodes;
    int group = tile.x + tiles.x * (tile.y + tiles.y * tile.z);
    int l = group / MBD_LIT_GROUPS;
    int r = group - l * MBD_LIT_GROUPS;
    if (l >= RANK) {
        return vec4(0.0);
    }
    return vec4(
        mbd_lit_value(node, l, 4 * r),
        mbd_lit_value(node, l, 4 * r + 1),
        mbd_lit_value(node, l, 4 * r + 2),
        mbd_lit_value(node, l, 4 * r + 3));
}

void main() {
    mbd_lit = mbd_light_texel(ivec3(ivec2(gl_FragCoord.xy), u_mbd_slice));
}
