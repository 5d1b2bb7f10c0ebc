// WebGL2 (GLSL ES 3.00) declarations of what reconstruct.glsl reads.
uniform MbdGrid u_mbd_coefficients;
uniform MbdGrid u_mbd_lit;
// Dequantisation of the coefficient texels: value = bias + scale * texel (per channel).
uniform vec4 u_mbd_coefficient_scale[MBD_COEFFICIENT_GROUPS];
uniform vec4 u_mbd_coefficient_bias[MBD_COEFFICIENT_GROUPS];
// Both with LINEAR filtering, no mipmaps, CLAMP_TO_EDGE.
uniform highp sampler3D u_mbd_coefficient_texture;
uniform highp sampler3D u_mbd_lit_texture;
#define MBD_SAMPLE3D(t, uvw) textureLod(t, uvw, 0.0)
