// WebGL2 (GLSL ES 3.00) declarations of what coefficients_bricks.glsl reads.
uniform MbdBricks u_mbd_bricks;
// RGBA8, read with texelFetch (NEAREST).
uniform highp sampler3D u_mbd_coefficient_indirection;
#define MBD_FETCH_INDIRECTION(t, p) texelFetch(t, p, 0)
