// prt filterable MBD layout: the coefficient volume in bricks (layout `bricks`): one
// indirection fetch per pixel, then the filtered atlas fetches. Needs common.wgsl and
// reconstruct.wgsl.

// The indirection: rgba8unorm, one texel per brick, (atlas brick xyz, live) / 255.
@group(0) @binding(4) var mbd_coefficient_indirection: texture_3d<f32>;

// Where the coefficients of x are: xyz its position in one group's brick atlas (texels), w = 1 in
// a stored brick, 0 in an empty one. The brick holding the cell of x holds all eight of the
// cell's nodes (the apron), so the trilinear footprint never leaves it.
fn mbd_coefficient_site(x: vec3<f32>) -> vec4<f32> {
    let p = mbd_local(mbd.coefficients, x) - 0.5;
    let size = mbd.bricks.grid.w;
    let brick = min(floor(p / size), mbd.bricks.grid.xyz - 1.0);
    let entry = textureLoad(mbd_coefficient_indirection, vec3<i32>(brick), 0);
    let at = floor(entry.xyz * 255.0 + 0.5);
    return vec4<f32>(at * (size + 1.0) + (p - brick * size) + 0.5, entry.w);
}

// The filtered texel of channel group g at `site`: group g's atlas is the g-th along z.
fn mbd_coefficient_texel(site: vec4<f32>, g: u32) -> vec4<f32> {
    let texels = mbd.bricks.atlas.xyz * (mbd.bricks.grid.w + 1.0);
    let uvw = (site.xyz + vec3<f32>(0.0, 0.0, f32(g) * texels.z))
        / (texels * vec3<f32>(1.0, 1.0, f32(MBD_COEFFICIENT_GROUPS)));
    return textureSampleLevel(mbd_coefficient_texture, mbd_linear_clamp, uvw, 0.0);
}
