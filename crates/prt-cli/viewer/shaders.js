// The viewer's own GLSL (prt-shaders' comes from the server, /shaders/*.glsl).

// Lit SH9 RGB (27 values) is 7 vec4 per node: prt-shaders' MBD_LIT_GROUPS.
export const LIT_GROUPS = 7;

// One triangle over the whole viewport, from gl_VertexID alone (no vertex buffer).
export const FULLSCREEN_VS = `#version 300 es
void main() {
  vec2 p = vec2(float((gl_VertexID & 1) << 2) - 1.0, float((gl_VertexID & 2) << 1) - 1.0);
  gl_Position = vec4(p, 0.0, 1.0);
}`;

// The voxel pass: for one voxel per fragment, its 7 texels of the voxel atlas (tiles along z,
// tile r = slices r·nz .. (r+1)·nz), written through 7 draw buffers at once.
export const VOXEL_MAIN = `
uniform ivec3 u_voxels;
uniform int u_voxel_slice;
uniform highp sampler3D u_validity;
uniform vec2 u_validity_range; // scale, bias
layout(location = 0) out vec4 o_0;
layout(location = 1) out vec4 o_1;
layout(location = 2) out vec4 o_2;
layout(location = 3) out vec4 o_3;
layout(location = 4) out vec4 o_4;
layout(location = 5) out vec4 o_5;
layout(location = 6) out vec4 o_6;
void voxel_values(ivec3 voxel, out vec4 v[${LIT_GROUPS}]);
void main() {
  ivec3 voxel = ivec3(ivec2(gl_FragCoord.xy), u_voxel_slice);
  float stored = u_validity_range.y + u_validity_range.x * texelFetch(u_validity, voxel, 0).r;
  vec4 v[${LIT_GROUPS}];
  for (int r = 0; r < ${LIT_GROUPS}; r++) v[r] = vec4(0.0);
  if (stored > 0.5) {
    voxel_values(voxel, v);
    // Slot 28 (always 0 in a lit texel) carries the validity, so filtering gives its weight.
    v[${LIT_GROUPS - 1}].w = 1.0;
  }
  o_0 = v[0]; o_1 = v[1]; o_2 = v[2]; o_3 = v[3]; o_4 = v[4]; o_5 = v[5]; o_6 = v[6];
}
`;

// MBD: Σ c_l b̃_l at the voxel centre (prt-shaders' reconstruction).
export const MBD_VOXEL = `
uniform vec3 u_node_step;
void voxel_values(ivec3 voxel, out vec4 v[MBD_LIT_GROUPS]) {
  mbd_incident_radiance(u_mbd_coefficients.domain_min.xyz + vec3(voxel) * u_node_step, v);
}
`;

// Kept volumes: the voxel's lit texels.
export const KEPT_VOXEL = `
uniform highp sampler3D u_lit_voxels;
void voxel_values(ivec3 voxel, out vec4 v[MBD_LIT_GROUPS]) {
  for (int r = 0; r < MBD_LIT_GROUPS; r++) {
    v[r] = texelFetch(u_lit_voxels, ivec3(voxel.x + r * u_voxels.x, voxel.y, voxel.z), 0);
  }
}
`;

// The scene's triangles with their materials, per vertex (flat across each triangle).
export const SCENE_VS = `#version 300 es
uniform mat4 u_view_proj;
in vec3 a_position;
in vec3 a_normal;
in vec3 a_albedo;
in vec3 a_emission;
in float a_double_sided;
out vec3 v_position;
flat out vec3 v_normal;
flat out vec3 v_albedo;
flat out vec3 v_emission;
flat out float v_double_sided;
void main() {
  v_position = a_position;
  v_normal = a_normal;
  v_albedo = a_albedo;
  v_emission = a_emission;
  v_double_sided = a_double_sided;
  gl_Position = u_view_proj * vec4(a_position, 1.0);
}`;

// Shading (appended to prt-shaders' common.glsl): the voxel atlas sampled at the surface point
// moved half a voxel along the normal facing the eye, divided by the filtered validity.
export const SCENE_FS = `
uniform MbdGrid u_volume;
uniform highp sampler3D u_volume_texture;
uniform MbdGrid u_reference;
uniform highp sampler3D u_reference_texture;
uniform vec3 u_eye;
uniform vec3 u_offset;
uniform float u_diff_scale; // 0: the method's radiance; > 0: |method − reference| · scale
in vec3 v_position;
flat in vec3 v_normal;
flat in vec3 v_albedo;
flat in vec3 v_emission;
flat in float v_double_sided;
out vec4 o_radiance;

bool irradiance_at(MbdGrid g, highp sampler3D t, vec3 p, vec3 n, out vec3 e) {
  vec3 local = mbd_local(g, p);
  vec4 sh[MBD_LIT_GROUPS];
  for (int r = 0; r < MBD_LIT_GROUPS; r++) {
    sh[r] = textureLod(t, mbd_tile_uvw(g, local, r), 0.0);
  }
  float weight = sh[MBD_LIT_GROUPS - 1].w;
  e = vec3(0.0);
  if (weight <= 1e-4) return false;
  for (int r = 0; r < MBD_LIT_GROUPS; r++) sh[r] /= weight;
  e = mbd_irradiance(sh, n);
  return true;
}

void main() {
  vec3 n = normalize(v_normal);
  bool front = dot(n, u_eye - v_position) > 0.0;
  bool visible = front || v_double_sided > 0.5;
  vec3 facing = front ? n : -n;
  vec3 p = v_position + facing * u_offset;
  vec3 albedo = visible ? v_albedo : vec3(0.0);
  vec3 emission = visible ? v_emission : vec3(0.0);
  vec3 e;
  irradiance_at(u_volume, u_volume_texture, p, facing, e);
  vec3 radiance;
  if (u_diff_scale > 0.0) {
    vec3 e_reference;
    irradiance_at(u_reference, u_reference_texture, p, facing, e_reference);
    radiance = u_diff_scale * albedo / 3.14159265 * abs(e - e_reference);
  } else {
    radiance = emission + albedo / 3.14159265 * e;
  }
  o_radiance = vec4(radiance, 1.0);
}
`;

// Misses show the sky's radiance along the pixel's ray (alpha 0: not counted by auto exposure).
export const SKY_FS = `
uniform vec4 u_sky[MBD_LIT_GROUPS];
uniform vec3 u_forward;
uniform vec3 u_right;
uniform vec3 u_up;
uniform vec2 u_tan; // tan(yfov/2) · aspect, tan(yfov/2)
uniform vec2 u_resolution;
uniform float u_show;
out vec4 o_radiance;
void main() {
  vec2 s = gl_FragCoord.xy / u_resolution * 2.0 - 1.0;
  vec3 d = normalize(u_forward + u_right * s.x * u_tan.x + u_up * s.y * u_tan.y);
  float y[9];
  y[0] = 0.28209479177387814;
  y[1] = -0.4886025119029199 * d.x;
  y[2] = 0.4886025119029199 * d.y;
  y[3] = -0.4886025119029199 * d.z;
  y[4] = 1.0925484305920792 * d.x * d.z;
  y[5] = -1.0925484305920792 * d.x * d.y;
  y[6] = 0.94617469575756 * d.y * d.y - 0.31539156525252;
  y[7] = -1.0925484305920792 * d.y * d.z;
  y[8] = 0.5462742152960396 * (d.z * d.z - d.x * d.x);
  vec3 l = vec3(0.0);
  for (int j = 0; j < 9; j++) {
    l += y[j] * vec3(mbd_component(u_sky, j), mbd_component(u_sky, 9 + j), mbd_component(u_sky, 18 + j));
  }
  o_radiance = vec4(u_show * l, 0.0);
}
`;

// prt-render's tone map: srgb(aces(exposure · radiance)).
export const TONEMAP_FS = `#version 300 es
precision highp float;
uniform highp sampler2D u_hdr;
uniform float u_exposure;
out vec4 o_color;
float display(float v) {
  float x = max(v * u_exposure, 0.0);
  float c = clamp((x * (2.51 * x + 0.03)) / (x * (2.43 * x + 0.59) + 0.14), 0.0, 1.0);
  return c <= 0.0031308 ? 12.92 * c : 1.055 * pow(c, 1.0 / 2.4) - 0.055;
}
void main() {
  vec3 v = texelFetch(u_hdr, ivec2(gl_FragCoord.xy), 0).rgb;
  o_color = vec4(display(v.r), display(v.g), display(v.b), 1.0);
}`;
