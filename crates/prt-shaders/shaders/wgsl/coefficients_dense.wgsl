// prt filterable MBD layout: the coefficient volume dense (layout `volume`, ceil(L/4) tiles
// stacked along z). Needs common.wgsl and reconstruct.wgsl.

// Where the coefficients of x are: xyz its position inside any tile (texels), w = 1.
fn mbd_coefficient_site(x: vec3<f32>) -> vec4<f32> {
    return vec4<f32>(mbd_local(mbd.coefficients, x), 1.0);
}

// The filtered texel of channel group g at `site`.
fn mbd_coefficient_texel(site: vec4<f32>, g: u32) -> vec4<f32> {
    let uvw = mbd_tile_uvw(mbd.coefficients, site.xyz, g);
    return textureSampleLevel(mbd_coefficient_texture, mbd_linear_clamp, uvw, 0.0);
}
