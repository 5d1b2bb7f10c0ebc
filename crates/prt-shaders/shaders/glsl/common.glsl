// prt filterable MBD layout: shared definitions (see docs/formats.md, "Filterable layout").
// Common to GLSL ES 3.00 (WebGL2) and GLSL 4.50; needs `#define RANK` (the MBD rank L).

// A hat grid stored as a tiled 3D texture: every channel group (4 values) is a tile of
// `nodes` texels, tiles laid out x first, then y, then z.
struct MbdGrid {
    vec4 domain_min; // xyz: the grid's first node
    vec4 inv_size;   // xyz: 1 / (domain_max - domain_min); 0 on single-node axes
    vec4 nodes;      // xyz: nodes per axis
    vec4 tiles;      // xyz: tiles per axis; the texture is nodes * tiles texels
};

// A hat grid stored in bricks (docs/formats.md, "Brick layout"): bricks of `size` cells, each
// (size + 1)^3 texels of an atlas (its last layer an apron copying the next brick's first
// nodes), one atlas per channel group stacked along z; an RGBA8 indirection texture of one texel
// per brick holds (atlas brick xyz, live) / 255.
struct MbdBricks {
    vec4 grid;  // xyz: bricks per axis; w: cells per brick edge (size)
    vec4 atlas; // xyz: atlas bricks per axis (one group); the texture is atlas * (size + 1) texels, z times the groups
};

// Coefficient groups: L coefficients, four per texel.
#define MBD_COEFFICIENT_GROUPS ((RANK + 3) / 4)
// Texels per lit basis vector: 27 values (SH9 RGB) in 7 texels, the 28th is 0.
#define MBD_LIT_GROUPS 7

// Position inside any tile, in texels: node i sits at texel centre i + 0.5. Clamping to the
// grid's box keeps the filter footprint inside the tile (no blending with the next tile).
vec3 mbd_local(MbdGrid grid, vec3 x) {
    vec3 t = clamp((x - grid.domain_min.xyz) * grid.inv_size.xyz, vec3(0.0), vec3(1.0));
    return t * (grid.nodes.xyz - 1.0) + 0.5;
}

// The tile of channel group g.
ivec3 mbd_tile(MbdGrid grid, int g) {
    int tx = int(grid.tiles.x);
    int ty = int(grid.tiles.y);
    return ivec3(g % tx, (g / tx) % ty, g / (tx * ty));
}

// Normalised texture coordinates of `local` (from mbd_local) in the tile of group g.
vec3 mbd_tile_uvw(MbdGrid grid, vec3 local, int g) {
    vec3 tile = vec3(mbd_tile(grid, g));
    return (tile * grid.nodes.xyz + local) / (grid.nodes.xyz * grid.tiles.xyz);
}

// Value k of a 28-slot array packed as 7 vec4s.
float mbd_component(vec4 v[7], int k) {
    return v[k / 4][k % 4];
}

// Irradiance E(n) = integral of L(w) max(0, n.w) dw, RGB, from incident radiance as SH9 per
// channel (value c*9 + i of `sh`), by the clamped-cosine zonal convolution (pi, 2pi/3, pi/4).
// SH of order 3 in prt's convention: +Y up, Condon-Shortley phase.
vec3 mbd_irradiance(vec4 sh[7], vec3 normal) {
    vec3 n = normalize(normal);
    float y[9];
    y[0] = 0.28209479177387814;
    y[1] = -0.4886025119029199 * n.x;
    y[2] = 0.4886025119029199 * n.y;
    y[3] = -0.4886025119029199 * n.z;
    y[4] = 1.0925484305920792 * n.x * n.z;
    y[5] = -1.0925484305920792 * n.x * n.y;
    y[6] = 0.94617469575756 * n.y * n.y - 0.31539156525252;
    y[7] = -1.0925484305920792 * n.y * n.z;
    y[8] = 0.5462742152960396 * (n.z * n.z - n.x * n.x);
    vec3 e = vec3(0.0);
    for (int i = 0; i < 9; i++) {
        float a = i == 0 ? 3.14159265 : (i < 4 ? 2.09439510 : 0.78539816);
        float w = a * y[i];
        e += w * vec3(mbd_component(sh, i), mbd_component(sh, 9 + i), mbd_component(sh, 18 + i));
    }
    return e;
}
