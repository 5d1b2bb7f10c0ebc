// prt filterable MBD layout: the lighting pass, run when the sky changes. Writes the lit
// basis b_{n,l}[c*9 + i] = sum_j (D_ij + T^c_ij) s^c_j (incident radiance SH9 RGB) of every
// basis node n and vector l into a tiled rgba16float volume (group 7l + r holds values
// 4r .. 4r+3). One invocation per lit texel. Needs common.wgsl.

struct MbdLight {
    basis: MbdGrid,           // the raw basis atlas: 81 tiles per basis vector
    lit: MbdGrid,           // the lit atlas being written: 7 tiles per basis vector
    sky: array<vec4<f32>, 7>, // sky SH per channel, value c*9 + j
}

@group(0) @binding(0) var<uniform> mbd_light: MbdLight;
@group(0) @binding(1) var mbd_basis_texture: texture_3d<f32>;
// Dequantisation of raw basis group g: texel (g, 0) is the scale, (g, 1) the bias (rgba32float).
@group(0) @binding(2) var mbd_basis_ranges: texture_2d<f32>;
@group(0) @binding(3) var mbd_lit_out: texture_storage_3d<rgba16float, write>;

// Raw basis value d (0..323) of vector l at node `node`, dequantised.
fn mbd_raw(node: vec3<u32>, l: u32, d: u32) -> f32 {
    let g = 81u * l + d / 4u;
    let origin = mbd_tile(mbd_light.basis, g) * vec3<u32>(mbd_light.basis.nodes.xyz);
    let texel = textureLoad(mbd_basis_texture, vec3<i32>(origin + node), 0);
    let scale = textureLoad(mbd_basis_ranges, vec2<i32>(i32(g), 0), 0);
    let bias = textureLoad(mbd_basis_ranges, vec2<i32>(i32(g), 1), 0);
    return (bias + scale * texel)[d % 4u];
}

// Lit value k (0..27) of vector l at node `node`: row i of the direct block plus row i of
// channel c's indirect block, dotted with channel c's sky.
fn mbd_lit_value(node: vec3<u32>, l: u32, k: u32) -> f32 {
    if (k >= 27u) {
        return 0.0;
    }
    let c = k / 9u;
    let i = k % 9u;
    var sum = 0.0;
    for (var j = 0u; j < 9u; j++) {
        let d = mbd_raw(node, l, 9u * i + j);
        let t = mbd_raw(node, l, 81u * (c + 1u) + 9u * i + j);
        sum += (d + t) * mbd_component(mbd_light.sky, 9u * c + j);
    }
    return sum;
}

@compute @workgroup_size(4, 4, 4)
fn mbd_light_main(@builtin(global_invocation_id) texel: vec3<u32>) {
    let nodes = vec3<u32>(mbd_light.lit.nodes.xyz);
    let tiles = vec3<u32>(mbd_light.lit.tiles.xyz);
    if (any(texel >= nodes * tiles)) {
        return;
    }
    let tile = texel / nodes;
    let node = texel % nodes;
    let group = tile.x + tiles.x * (tile.y + tiles.y * tile.z);
    let l = group / MBD_LIT_GROUPS;
    let r = group % MBD_LIT_GROUPS;
    var v = vec4<f32>(0.0);
    if (l < RANK) {
        v = vec4<f32>(
            mbd_lit_value(node, l, 4u * r),
            mbd_lit_value(node, l, 4u * r + 1u),
            mbd_lit_value(node, l, 4u * r + 2u),
            mbd_lit_value(node, l, 4u * r + 3u),
        );
    }
    textureStore(mbd_lit_out, vec3<i32>(texel), v);
}
