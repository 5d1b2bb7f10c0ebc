// prt filterable MBD layout: shared definitions (see docs/formats.md, "Filterable layout").
// Needs `const RANK: u32` (the MBD rank L) declared before this file.

// A hat grid stored as a tiled 3D texture: every channel group (4 values) is a tile of
// `nodes` texels, tiles laid out x first, then y, then z.
struct MbdGrid {
    domain_min: vec4<f32>, // xyz: the grid's first node
    inv_size: vec4<f32>,   // xyz: 1 / (domain_max - domain_min); 0 on single-node axes
    nodes: vec4<f32>,      // xyz: nodes per axis
    tiles: vec4<f32>,      // xyz: tiles per axis; the texture is nodes * tiles texels
}

// A hat grid stored in bricks (docs/formats.md, "Brick layout"): bricks of `size` cells, each
// (size + 1)^3 texels of an atlas (its last layer an apron copying the next brick's first
// nodes), one atlas per channel group stacked along z; an rgba8unorm indirection texture of one
// texel per brick holds (atlas brick xyz, live) / 255.
struct MbdBricks {
    grid: vec4<f32>,  // xyz: bricks per axis; w: cells per brick edge (size)
    atlas: vec4<f32>, // xyz: atlas bricks per axis (one group); the texture is atlas * (size + 1) texels, z times the groups
}

// Coefficient groups: L coefficients, four per texel.
const MBD_COEFFICIENT_GROUPS: u32 = (RANK + 3u) / 4u;
// Texels per lit basis vector: 27 values (SH9 RGB) in 7 texels, the 28th is 0.
const MBD_LIT_GROUPS: u32 = 7u;

// Position inside any tile, in texels: node i sits at texel centre i + 0.5. Clamping to the
// grid's box keeps the filter footprint inside the tile (no blending with the next tile).
fn mbd_local(grid: MbdGrid, x: vec3<f32>) -> vec3<f32> {
    let t = clamp((x - grid.domain_min.xyz) * grid.inv_size.xyz, vec3<f32>(0.0), vec3<f32>(1.0));
    return t * (grid.nodes.xyz - 1.0) + 0.5;
}

// The tile of channel group g.
fn mbd_tile(grid: MbdGrid, g: u32) -> vec3<u32> {
    let tx = u32(grid.tiles.x);
    let ty = u32(grid.tiles.y);
    return vec3<u32>(g % tx, (g / tx) % ty, g / (tx * ty));
}

// Normalised texture coordinates of `local` (from mbd_local) in the tile of group g.
fn mbd_tile_uvw(grid: MbdGrid, local: vec3<f32>, g: u32) -> vec3<f32> {
    let tile = vec3<f32>(mbd_tile(grid, g));
    return (tile * grid.nodes.xyz + local) / (grid.nodes.xyz * grid.tiles.xyz);
}

// Value k of a 28-slot array packed as 7 vec4s.
fn mbd_component(v: array<vec4<f32>, 7>, k: u32) -> f32 {
    var copy = v;
    return copy[k / 4u][k % 4u];
}

// Real SH of order 3 at unit direction n (prt's convention: +Y up, Condon-Shortley phase).
fn mbd_sh9(n: vec3<f32>) -> array<f32, 9> {
    return array<f32, 9>(
        0.28209479177387814,
        -0.4886025119029199 * n.x,
        0.4886025119029199 * n.y,
        -0.4886025119029199 * n.z,
        1.0925484305920792 * n.x * n.z,
        -1.0925484305920792 * n.x * n.y,
        0.94617469575756 * n.y * n.y - 0.31539156525252,
        -1.0925484305920792 * n.y * n.z,
        0.5462742152960396 * (n.z * n.z - n.x * n.x),
    );
}

// Irradiance E(n) = integral of L(w) max(0, n.w) dw, RGB, from incident radiance as SH9 per
// channel (value c*9 + i of `sh`), by the clamped-cosine zonal convolution (pi, 2pi/3, pi/4).
fn mbd_irradiance(sh: array<vec4<f32>, 7>, normal: vec3<f32>) -> vec3<f32> {
    var y = mbd_sh9(normalize(normal));
    var a = array<f32, 9>(
        3.14159265, 2.09439510, 2.09439510, 2.09439510,
        0.78539816, 0.78539816, 0.78539816, 0.78539816, 0.78539816,
    );
    var e = vec3<f32>(0.0);
    for (var i = 0u; i < 9u; i++) {
        let w = a[i] * y[i];
        e += w * vec3<f32>(mbd_component(sh, i), mbd_component(sh, 9u + i), mbd_component(sh, 18u + i));
    }
    return e;
}
