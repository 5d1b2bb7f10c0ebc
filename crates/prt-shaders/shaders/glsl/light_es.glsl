// WebGL2 (GLSL ES 3.00) declarations of what light.glsl reads and writes.
uniform MbdGrid u_mbd_basis; // the raw basis atlas: 81 tiles per basis vector
uniform MbdGrid u_mbd_lit; // the lit atlas being written: 7 tiles per basis vector
uniform vec4 u_mbd_sky[7];   // sky SH per channel, value c*9 + j
uniform int u_mbd_slice;     // the z slice of the lit atlas this draw writes
uniform highp sampler3D u_mbd_basis_texture;
// Dequantisation of raw basis group g: texel (g, 0) is the scale, (g, 1) the bias (RGBA32F).
uniform highp sampler2D u_mbd_basis_ranges;
out vec4 mbd_lit;
#define MBD_FETCH3D(t, p) texelFetch(t, p, 0)
#define MBD_FETCH2D(t, p) texelFetch(t, p, 0)
