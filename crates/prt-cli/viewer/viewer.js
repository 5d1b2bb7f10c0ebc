// prt view: the scene of a bake folder lit by its compressed transfer volume, relit on the GPU.
//
// Per sky change: the raw basis (324-D per basis node) is relit by prt-shaders' relight pass into
// SH9 RGB per node; a voxel pass evaluates Σ_l c_l(x) b̃_l(x) with prt-shaders' reconstruction at
// every valid voxel centre (what `prt render --method mbd` samples). Kept volumes (reference,
// BPCA, CPCA) go through the same relight pass with rank 1 over the voxel grid. Each pixel then
// samples the result trilinearly over valid voxels (value·valid and valid, divided) and shows
// emission + albedo/π · E(n), tone-mapped like prt-render (exposure, ACES fit, sRGB).
'use strict';

const PARAMS = new URLSearchParams(location.search);
const CAPTURE = PARAMS.has('size');
const TRANSFER_DIM = 324;
const RELIT_GROUPS = 7;
const BASIS_GROUPS = 81;
const MIDDLE_GREY = 0.18;

// Shows `message` on the page (the first one stays: later ones are usually its consequences).
function showError(message) {
  const box = document.getElementById('error');
  if (!box.textContent) box.textContent = `prt view: ${message}`;
  document.title = 'error';
}

function fail(message) {
  showError(message);
  throw new Error(message);
}

// Errors outside main's promise chain (event handlers, the redraw loop) reach the page too.
window.addEventListener('error', (e) => showError(e.message || e));
window.addEventListener('unhandledrejection', (e) =>
  showError(e.reason && e.reason.message ? e.reason.message : e.reason));

// WebGL reports a failed call only through getError (and the console): fail on the page instead
// of drawing black.
function checkGl(gl, what) {
  const error = gl.getError();
  if (error === gl.NO_ERROR) return;
  const names = ['INVALID_ENUM', 'INVALID_VALUE', 'INVALID_OPERATION', 'OUT_OF_MEMORY',
    'INVALID_FRAMEBUFFER_OPERATION', 'CONTEXT_LOST_WEBGL'];
  const name = names.find((n) => gl[n] === error) || 'error';
  fail(`${what}: WebGL ${name} (0x${error.toString(16)}; the browser's console may say more)`);
}

async function fetchOk(url) {
  let response;
  try {
    response = await fetch(url);
  } catch (e) {
    fail(`cannot load ${url}: ${e && e.message ? e.message : e}`);
  }
  if (!response.ok) fail(`cannot load ${url}: HTTP ${response.status}`);
  return response;
}
const fetchJson = async (url) => (await fetchOk(url)).json();
const fetchText = async (url) => (await fetchOk(url)).text();
const fetchBytes = async (url) => (await fetchOk(url)).arrayBuffer();

// ---------------------------------------------------------------- scene mesh (docs/formats.md)

function parseMesh(buffer) {
  const view = new DataView(buffer);
  let at = 0;
  const need = (bytes, what) => {
    if (at + bytes > buffer.byteLength) fail(`scene.mesh is truncated in its ${what}`);
  };
  const u32 = (what) => { need(4, what); const v = view.getUint32(at, true); at += 4; return v; };
  const f32s = (n, what) => {
    need(4 * n, what);
    const out = new Float32Array(n);
    for (let i = 0; i < n; i++) out[i] = view.getFloat32(at + 4 * i, true);
    at += 4 * n;
    return out;
  };
  const skipName = (what) => {
    const len = u32(what);
    if (len === 0xffffffff) return;
    const padded = Math.ceil(len / 4) * 4;
    need(padded, what);
    at += padded;
  };
  need(8, 'magic');
  const magic = new Uint8Array(buffer, 0, 8);
  if (String.fromCharCode(...magic) !== 'PRTMESH\0') fail('scene.mesh is not a prt scene mesh');
  at = 8;
  const version = u32('header');
  if (version !== 1) fail(`scene.mesh has version ${version}; this viewer reads version 1`);
  const [vertices, triangles, materials] = [u32('header'), u32('header'), u32('header')];
  u32('header'); u32('header'); // cameras (the views come from /views.json), reserved
  if (28 * vertices + 12 * triangles > buffer.byteLength) fail('scene.mesh counts exceed its size');
  const positions = f32s(3 * vertices, 'positions');
  const normals = f32s(3 * vertices, 'normals');
  need(4 * vertices, 'vertex materials');
  const vertexMaterials = new Uint32Array(buffer.slice(at, at + 4 * vertices)); at += 4 * vertices;
  need(12 * triangles, 'indices');
  const indices = new Uint32Array(buffer.slice(at, at + 12 * triangles)); at += 12 * triangles;
  const table = [];
  for (let m = 0; m < materials; m++) {
    const albedo = f32s(3, 'materials');
    const emission = f32s(3, 'materials');
    const flags = u32('materials');
    skipName('materials');
    table.push({ albedo, emission, doubleSided: (flags & 1) ? 1 : 0 });
  }
  for (const i of indices) if (i >= vertices) fail(`scene.mesh has an index ${i} ≥ ${vertices} vertices`);
  const albedo = new Float32Array(3 * vertices);
  const emission = new Float32Array(3 * vertices);
  const doubleSided = new Float32Array(vertices);
  const lo = [Infinity, Infinity, Infinity];
  const hi = [-Infinity, -Infinity, -Infinity];
  for (let v = 0; v < vertices; v++) {
    const m = table[vertexMaterials[v]];
    if (!m) fail(`scene.mesh vertex ${v} names material ${vertexMaterials[v]} of ${materials}`);
    albedo.set(m.albedo, 3 * v);
    emission.set(m.emission, 3 * v);
    doubleSided[v] = m.doubleSided;
    for (let k = 0; k < 3; k++) {
      lo[k] = Math.min(lo[k], positions[3 * v + k]);
      hi[k] = Math.max(hi[k], positions[3 * v + k]);
    }
  }
  return { positions, normals, albedo, emission, doubleSided, indices, bounds: { lo, hi } };
}

// ---------------------------------------------------------------- KTX2 (only what prt writes)

const VK_FORMATS = {
  f32: { vk: 109, bytes: 16 }, f16: { vk: 97, bytes: 8 },
  unorm8: { vk: 37, bytes: 4 }, snorm8: { vk: 38, bytes: 4 },
  unorm16: { vk: 91, bytes: 8 }, snorm16: { vk: 92, bytes: 8 },
};
// One-channel arrays (`single_channel` in the manifest) of the encodings that have a one-channel
// format.
const VK_FORMATS_R = {
  f32: { vk: 100, bytes: 4 }, f16: { vk: 76, bytes: 2 }, unorm8: { vk: 9, bytes: 1 },
};
const KTX2_ID = [0xab, 0x4b, 0x54, 0x58, 0x20, 0x32, 0x30, 0xbb, 0x0d, 0x0a, 0x1a, 0x0a];

// The base level of a KTX2 file, checked against the expected format and size.
function parseKtx2(buffer, name, encoding, size, singleChannel) {
  const format = (singleChannel ? VK_FORMATS_R : VK_FORMATS)[encoding];
  if (!format) fail(`${name}: encoding ${encoding} is not supported by the viewer`);
  if (buffer.byteLength < 104) fail(`${name}: too short for a KTX2 file`);
  const bytes = new Uint8Array(buffer);
  if (!KTX2_ID.every((b, i) => bytes[i] === b)) fail(`${name}: not a KTX2 file`);
  const view = new DataView(buffer);
  const u32 = (at) => view.getUint32(at, true);
  const u64 = (at) => u32(at) + 2 ** 32 * u32(at + 4);
  const vk = u32(12);
  if (vk !== format.vk) fail(`${name}: vkFormat ${vk}, expected ${format.vk} for ${encoding}`);
  const dims = [u32(20), Math.max(1, u32(24)), Math.max(1, u32(28))];
  if (dims.some((d, k) => d !== size[k])) {
    fail(`${name}: ${dims.join('×')} texels, expected ${size.join('×')}`);
  }
  if (u32(32) > 1 || u32(36) !== 1 || u32(40) < 1 || u32(44) !== 0) {
    fail(`${name}: arrays, cubemaps, missing levels or supercompression are not what prt writes`);
  }
  const offset = u64(80);
  const length = u64(88);
  const expected = dims[0] * dims[1] * dims[2] * format.bytes;
  if (length !== expected || offset + length > buffer.byteLength) {
    fail(`${name}: level 0 holds ${length} bytes at ${offset}, expected ${expected} within the file`);
  }
  return buffer.slice(offset, offset + length);
}

// ---------------------------------------------------------------- containers

// A container array as a WebGL texture in its layout, with its per-group scale and bias.
function arrayTexture(gl, entry, data) {
  const groups = Math.ceil(entry.channels / 4);
  const bricks = entry.layout === 'bricks' ? entry.bricks : null;
  const tiles = entry.layout === 'volume' ? [1, 1, groups] : (bricks ? [1, 1, 1] : entry.tiles);
  if (!tiles || !['volume', 'atlas', 'bricks'].includes(entry.layout) || (entry.layout === 'bricks' && !bricks)) {
    fail(`${entry.file}: layout ${entry.layout} is not filterable; rebake with this prt`);
  }
  // A brick atlas: (size + 1)³ texels per brick, one atlas per group stacked along z.
  const size = bricks
    ? bricks.atlas.map((a, k) => a * (bricks.size + 1) * (k === 2 ? groups : 1))
    : entry.dims.map((d, k) => d * tiles[k]);
  const single = entry.single_channel === true;
  const texels = parseKtx2(data, entry.file, entry.encoding, size, single);
  const texture = gl.createTexture();
  gl.bindTexture(gl.TEXTURE_3D, texture);
  const [w, h, d] = size;
  const upload = (internal, format, type, array) =>
    gl.texImage3D(gl.TEXTURE_3D, 0, internal, w, h, d, 0, format, type, array);
  if (single) {
    switch (entry.encoding) {
      case 'f32': upload(gl.R32F, gl.RED, gl.FLOAT, new Float32Array(texels)); break;
      case 'f16': upload(gl.R16F, gl.RED, gl.HALF_FLOAT, new Uint16Array(texels)); break;
      case 'unorm8': upload(gl.R8, gl.RED, gl.UNSIGNED_BYTE, new Uint8Array(texels)); break;
    }
  } else switch (entry.encoding) {
    case 'f32': upload(gl.RGBA32F, gl.RGBA, gl.FLOAT, new Float32Array(texels)); break;
    case 'f16': upload(gl.RGBA16F, gl.RGBA, gl.HALF_FLOAT, new Uint16Array(texels)); break;
    case 'unorm8': upload(gl.RGBA8, gl.RGBA, gl.UNSIGNED_BYTE, new Uint8Array(texels)); break;
    case 'snorm8': upload(gl.RGBA8_SNORM, gl.RGBA, gl.BYTE, new Int8Array(texels)); break;
    case 'unorm16': case 'snorm16': {
      // WebGL2 has no 16-bit normalised textures: the normalised value as f32.
      const signed = entry.encoding === 'snorm16';
      const q = signed ? new Int16Array(texels) : new Uint16Array(texels);
      const t = new Float32Array(q.length);
      for (let i = 0; i < q.length; i++) t[i] = signed ? Math.max(q[i] / 32767, -1) : q[i] / 65535;
      upload(gl.RGBA32F, gl.RGBA, gl.FLOAT, t);
      break;
    }
  }
  checkGl(gl, `uploading ${entry.file} (${w}×${h}×${d} texels)`);
  const floatTexels = entry.encoding === 'f32' || entry.encoding.endsWith('16') && entry.encoding !== 'f16';
  const filter = floatTexels && !gl.getExtension('OES_texture_float_linear') ? gl.NEAREST : gl.LINEAR;
  setSampling(gl, gl.TEXTURE_3D, filter);
  const scale = new Float32Array(4 * groups);
  const bias = new Float32Array(4 * groups);
  for (let c = 0; c < 4 * groups; c++) {
    const range = entry.ranges && entry.ranges[c];
    scale[c] = c < entry.channels ? (range ? range.scale : 1) : 0;
    bias[c] = c < entry.channels && range ? range.bias : 0;
  }
  return { texture, size, tiles, groups, scale, bias, linear: filter === gl.LINEAR, bricks };
}

// The indirection of a brick-layout array: RGBA8 unorm, one texel per brick, read with texelFetch.
async function indirectionTexture(gl, folder, bricks) {
  if (!/^[A-Za-z0-9_.-]+\.ktx2$/.test(bricks.indirection)) fail(`${folder}: bad file name ${bricks.indirection}`);
  const data = await fetchBytes(`bake/${folder}/${bricks.indirection}`);
  const texels = parseKtx2(data, bricks.indirection, 'unorm8', bricks.grid, false);
  const texture = gl.createTexture();
  gl.bindTexture(gl.TEXTURE_3D, texture);
  gl.texImage3D(gl.TEXTURE_3D, 0, gl.RGBA8, ...bricks.grid, 0, gl.RGBA, gl.UNSIGNED_BYTE, new Uint8Array(texels));
  checkGl(gl, `uploading ${bricks.indirection}`);
  setSampling(gl, gl.TEXTURE_3D, gl.NEAREST);
  return texture;
}

function setSampling(gl, target, filter) {
  gl.texParameteri(target, gl.TEXTURE_MIN_FILTER, filter);
  gl.texParameteri(target, gl.TEXTURE_MAG_FILTER, filter);
  for (const wrap of [gl.TEXTURE_WRAP_S, gl.TEXTURE_WRAP_T, gl.TEXTURE_WRAP_R]) {
    gl.texParameteri(target, wrap, gl.CLAMP_TO_EDGE);
  }
}

function entryOf(manifest, name, folder) {
  const entry = manifest.arrays.find((a) => a.name === name);
  if (!entry) fail(`${folder}/manifest.json has no array ${name}`);
  if (!/^[A-Za-z0-9_.-]+\.ktx2$/.test(entry.file)) fail(`${folder}: bad file name ${entry.file}`);
  return entry;
}

async function loadArray(gl, folder, manifest, name) {
  const entry = entryOf(manifest, name, folder);
  return arrayTexture(gl, entry, await fetchBytes(`bake/${folder}/${entry.file}`));
}

// Scale and bias of every group as a (groups × 2) RGBA32F texture: what relight.glsl fetches.
function rangesTexture(gl, scale, bias) {
  const groups = scale.length / 4;
  const data = new Float32Array(8 * groups);
  data.set(scale, 0);
  data.set(bias, 4 * groups);
  const texture = gl.createTexture();
  gl.bindTexture(gl.TEXTURE_2D, texture);
  gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA32F, groups, 2, 0, gl.RGBA, gl.FLOAT, data);
  checkGl(gl, 'uploading the scale and bias');
  setSampling(gl, gl.TEXTURE_2D, gl.NEAREST);
  return texture;
}

// An empty RGBA16F 3D texture a pass renders into, slice by slice.
function targetTexture(gl, size) {
  const texture = gl.createTexture();
  gl.bindTexture(gl.TEXTURE_3D, texture);
  gl.texStorage3D(gl.TEXTURE_3D, 1, gl.RGBA16F, size[0], size[1], size[2]);
  setSampling(gl, gl.TEXTURE_3D, gl.LINEAR);
  return texture;
}

// MbdGrid of a hat grid whose first and last nodes are `first` and `last`.
function grid(first, last, nodes, tiles) {
  const inv = first.map((a, k) => (nodes[k] > 1 && last[k] > a ? 1 / (last[k] - a) : 0));
  return { domain_min: first, inv_size: inv, nodes, tiles };
}

// ---------------------------------------------------------------- GL programs

const FULLSCREEN_VS = `#version 300 es
void main() {
  vec2 p = vec2(float((gl_VertexID & 1) << 2) - 1.0, float((gl_VertexID & 2) << 1) - 1.0);
  gl_Position = vec4(p, 0.0, 1.0);
}`;

function compile(gl, type, source, what) {
  const shader = gl.createShader(type);
  gl.shaderSource(shader, source);
  gl.compileShader(shader);
  if (!gl.getShaderParameter(shader, gl.COMPILE_STATUS)) {
    fail(`the ${what} shader does not compile:\n${gl.getShaderInfoLog(shader)}`);
  }
  return shader;
}

function program(gl, vs, fs, what) {
  const p = gl.createProgram();
  gl.attachShader(p, compile(gl, gl.VERTEX_SHADER, vs, what));
  gl.attachShader(p, compile(gl, gl.FRAGMENT_SHADER, fs, what));
  gl.linkProgram(p);
  if (!gl.getProgramParameter(p, gl.LINK_STATUS)) {
    fail(`the ${what} program does not link:\n${gl.getProgramInfoLog(p)}`);
  }
  const cache = new Map();
  const loc = (name) => {
    if (!cache.has(name)) cache.set(name, gl.getUniformLocation(p, name));
    return cache.get(name);
  };
  return {
    p,
    use() { gl.useProgram(p); return this; },
    int(name, v) { gl.uniform1i(loc(name), v); return this; },
    float(name, v) { gl.uniform1f(loc(name), v); return this; },
    vec3(name, v) { gl.uniform3fv(loc(name), v); return this; },
    vec4s(name, v) { gl.uniform4fv(loc(name), v); return this; },
    mat4(name, v) { gl.uniformMatrix4fv(loc(name), false, v); return this; },
    grid(name, g) {
      const pad = (a) => [a[0], a[1], a[2], 0];
      for (const key of ['domain_min', 'inv_size', 'nodes', 'tiles']) {
        gl.uniform4fv(loc(`${name}.${key}`), pad(g[key]));
      }
      return this;
    },
    texture(name, unit, target, texture) {
      gl.activeTexture(gl.TEXTURE0 + unit);
      gl.bindTexture(target, texture);
      gl.uniform1i(loc(name), unit);
      return this;
    },
  };
}

// Runs `prog` once per z slice of the 3D texture `target` of `size`.
function drawSlices(gl, prog, target, size, sliceUniform) {
  const fbo = gl.createFramebuffer();
  gl.bindFramebuffer(gl.FRAMEBUFFER, fbo);
  gl.viewport(0, 0, size[0], size[1]);
  gl.disable(gl.DEPTH_TEST);
  for (let z = 0; z < size[2]; z++) {
    gl.framebufferTextureLayer(gl.FRAMEBUFFER, gl.COLOR_ATTACHMENT0, target, 0, z);
    prog.int(sliceUniform, z);
    gl.drawArrays(gl.TRIANGLES, 0, 3);
  }
  gl.bindFramebuffer(gl.FRAMEBUFFER, null);
  gl.deleteFramebuffer(fbo);
}

// The voxel pass: for one voxel per fragment, its 7 texels of the voxel atlas (tiles along z,
// tile r = slices r·nz .. (r+1)·nz), written through 7 draw buffers at once.
const VOXEL_MAIN = `
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
void voxel_values(ivec3 voxel, out vec4 v[${RELIT_GROUPS}]);
void main() {
  ivec3 voxel = ivec3(ivec2(gl_FragCoord.xy), u_voxel_slice);
  float stored = u_validity_range.y + u_validity_range.x * texelFetch(u_validity, voxel, 0).r;
  vec4 v[${RELIT_GROUPS}];
  for (int r = 0; r < ${RELIT_GROUPS}; r++) v[r] = vec4(0.0);
  if (stored > 0.5) {
    voxel_values(voxel, v);
    // Slot 28 (always 0 in a relit texel) carries the validity, so filtering gives its weight.
    v[${RELIT_GROUPS - 1}].w = 1.0;
  }
  o_0 = v[0]; o_1 = v[1]; o_2 = v[2]; o_3 = v[3]; o_4 = v[4]; o_5 = v[5]; o_6 = v[6];
}
`;

// MBD: Σ c_l b̃_l at the voxel centre (prt-shaders' reconstruction).
const MBD_VOXEL = `
uniform vec3 u_node_step;
void voxel_values(ivec3 voxel, out vec4 v[MBD_RELIT_GROUPS]) {
  mbd_incident_radiance(u_mbd_coefficients.domain_min.xyz + vec3(voxel) * u_node_step, v);
}
`;

// Kept volumes: the voxel's relit texels.
const KEPT_VOXEL = `
uniform highp sampler3D u_relit_voxels;
void voxel_values(ivec3 voxel, out vec4 v[MBD_RELIT_GROUPS]) {
  for (int r = 0; r < MBD_RELIT_GROUPS; r++) {
    v[r] = texelFetch(u_relit_voxels, ivec3(voxel.x + r * u_voxels.x, voxel.y, voxel.z), 0);
  }
}
`;

// Runs the voxel pass `prog` once per z slice of the voxel grid, into the 7 tiles of `atlas`.
function drawVoxelSlices(gl, prog, atlas, voxels) {
  const fbo = gl.createFramebuffer();
  gl.bindFramebuffer(gl.FRAMEBUFFER, fbo);
  gl.viewport(0, 0, voxels[0], voxels[1]);
  gl.disable(gl.DEPTH_TEST);
  const buffers = [...Array(RELIT_GROUPS).keys()].map((r) => gl.COLOR_ATTACHMENT0 + r);
  gl.drawBuffers(buffers);
  for (let z = 0; z < voxels[2]; z++) {
    for (let r = 0; r < RELIT_GROUPS; r++) {
      gl.framebufferTextureLayer(gl.FRAMEBUFFER, buffers[r], atlas, 0, z + r * voxels[2]);
    }
    prog.int('u_voxel_slice', z);
    gl.drawArrays(gl.TRIANGLES, 0, 3);
  }
  gl.bindFramebuffer(gl.FRAMEBUFFER, null);
  gl.deleteFramebuffer(fbo);
}

const SCENE_VS = `#version 300 es
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
const SCENE_FS = `
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
  vec4 sh[MBD_RELIT_GROUPS];
  for (int r = 0; r < MBD_RELIT_GROUPS; r++) {
    sh[r] = textureLod(t, mbd_tile_uvw(g, local, r), 0.0);
  }
  float weight = sh[MBD_RELIT_GROUPS - 1].w;
  e = vec3(0.0);
  if (weight <= 1e-4) return false;
  for (int r = 0; r < MBD_RELIT_GROUPS; r++) sh[r] /= weight;
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
const SKY_FS = `
uniform vec4 u_sky[MBD_RELIT_GROUPS];
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
const TONEMAP_FS = `#version 300 es
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

// ---------------------------------------------------------------- sky

// A sky turned by `degrees` about +Y, as Sky::rotated_about_y: the turned sky's radiance towards
// R ω is the original's towards ω. In prt's SH (Y_1 ∝ -x, Y_3 ∝ -z, Y_5 ∝ -xy, Y_7 ∝ -yz,
// Y_4 ∝ xz, Y_8 ∝ z² - x²) the pairs (1, 3) and (5, 7) turn by the angle, (4, 8) by twice it.
function rotateSky(sh, degrees) {
  const a = degrees * Math.PI / 180;
  return sh.map((s) => {
    const out = s.slice();
    const turn = (i, j, angle) => {
      const c = Math.cos(angle);
      const n = Math.sin(angle);
      out[i] = c * s[i] + n * s[j];
      out[j] = -n * s[i] + c * s[j];
    };
    turn(1, 3, a);
    turn(5, 7, a);
    turn(4, 8, 2 * a);
    return out;
  });
}

// Incident-radiance SH per channel packed as 7 vec4 (value c·9 + j).
function packSky(sh) {
  const out = new Float32Array(4 * RELIT_GROUPS);
  for (let c = 0; c < 3; c++) for (let j = 0; j < 9; j++) out[9 * c + j] = sh[c][j];
  return out;
}

// ---------------------------------------------------------------- math

const sub = (a, b) => a.map((v, i) => v - b[i]);
const add = (a, b) => a.map((v, i) => v + b[i]);
const scale3 = (a, s) => a.map((v) => v * s);
const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
const normalize = (a) => scale3(a, 1 / Math.hypot(...a));

// Column-major view-projection of a pinhole (prt_trace::PinholeView) for a given aspect.
function viewProjection(camera, aspect, near, far) {
  const f = camera.forward;
  const r = normalize(cross(f, camera.up));
  const u = cross(r, f);
  const e = camera.position;
  const t = 1 / Math.tan(camera.yfov / 2);
  const view = [r[0], u[0], -f[0], 0, r[1], u[1], -f[1], 0, r[2], u[2], -f[2], 0,
    -dot(r, e), -dot(u, e), dot(f, e), 1];
  const proj = [t / aspect, 0, 0, 0, 0, t, 0, 0, 0, 0, (far + near) / (near - far), -1,
    0, 0, 2 * far * near / (near - far), 0];
  const out = new Float32Array(16);
  for (let c = 0; c < 4; c++) {
    for (let row = 0; row < 4; row++) {
      let s = 0;
      for (let k = 0; k < 4; k++) s += proj[k * 4 + row] * view[c * 4 + k];
      out[c * 4 + row] = s;
    }
  }
  return out;
}

// ---------------------------------------------------------------- the viewer

async function main() {
  const canvas = document.getElementById('canvas');
  if (CAPTURE) {
    document.body.classList.add('capture');
    const size = Number(PARAMS.get('size'));
    if (!(Number.isInteger(size) && size >= 1 && size <= 8192)) fail(`size=${PARAMS.get('size')} is not in 1..8192`);
    canvas.width = canvas.height = size;
    canvas.style.width = canvas.style.height = `${size}px`;
  }
  const gl = canvas.getContext('webgl2', { antialias: false, preserveDrawingBuffer: true });
  if (!gl) fail('this browser has no WebGL2');
  if (!gl.getExtension('EXT_color_buffer_float')) fail('WebGL2 without EXT_color_buffer_float: cannot render to float textures');
  if (gl.getParameter(gl.MAX_DRAW_BUFFERS) < RELIT_GROUPS) fail(`the voxel pass needs ${RELIT_GROUPS} draw buffers; this WebGL2 has ${gl.getParameter(gl.MAX_DRAW_BUFFERS)}`);
  // The volumes are tightly packed: a one-channel row (R8: x bytes, R16F: 2x) is not a multiple
  // of WebGL's default 4-byte row alignment when the grid's x size is not a multiple of 4.
  gl.pixelStorei(gl.UNPACK_ALIGNMENT, 1);

  const [mesh, views, skies, manifest] = await Promise.all([
    fetchBytes('bake/scene.mesh').then(parseMesh), fetchJson('views.json'), fetchJson('skies.json'),
    fetchJson('bake/mbd/manifest.json'),
  ]);
  if (views.length === 0) fail('the scene has no views (no triangles?)');
  const rank = manifest.attributes && manifest.attributes.rank;
  if (!Number.isInteger(rank) || rank < 1) fail('mbd/manifest.json has no rank attribute');
  const kernel = (name) => {
    const k = manifest.kernels && manifest.kernels[name];
    if (!k || k.kind !== 'hat') fail(`mbd/manifest.json: kernel ${name} is not a hat grid`);
    return k;
  };
  const coefficientKernel = kernel('coefficients');
  const basisKernel = kernel('basis');
  const basisEntry = entryOf(manifest, 'basis', 'mbd');
  const bricked = entryOf(manifest, 'coefficients', 'mbd').layout === 'bricks';
  if (basisEntry.channels !== TRANSFER_DIM * rank) fail(`mbd basis has ${basisEntry.channels} channels, not 324 × ${rank}`);

  const [common1, relight1, relightRank, reconstructRank] = await Promise.all([
    fetchText('shaders/common.glsl?rank=1'),
    fetchText('shaders/relight.glsl?rank=1'), fetchText(`shaders/relight.glsl?rank=${rank}`),
    fetchText(`shaders/reconstruct.glsl?rank=${rank}${bricked ? '&layout=bricks' : ''}`),
  ]);
  const relightPrograms = new Map([
    [1, program(gl, FULLSCREEN_VS, relight1, 'relight (rank 1)')],
    [rank, program(gl, FULLSCREEN_VS, relightRank, `relight (rank ${rank})`)],
  ]);
  const mbdVoxelProgram = program(gl, FULLSCREEN_VS, reconstructRank + VOXEL_MAIN + MBD_VOXEL, 'MBD voxel');
  const keptVoxelProgram = program(gl, FULLSCREEN_VS, common1 + VOXEL_MAIN + KEPT_VOXEL, 'kept-volume voxel');
  const sceneProgram = program(gl, SCENE_VS, common1 + SCENE_FS, 'scene');
  const skyProgram = program(gl, FULLSCREEN_VS, common1 + SKY_FS, 'sky');
  const toneProgram = program(gl, FULLSCREEN_VS, TONEMAP_FS, 'tone map');

  // Every method: a raw 324-D grid to relight, and the 7-tile voxel atlas it ends in.
  const methods = new Map();
  {
    const [coefficients, basis, validity] = await Promise.all(
      ['coefficients', 'basis', 'validity'].map((n) => loadArray(gl, 'mbd', manifest, n)));
    if (!coefficients.linear) fail('the coefficient volume needs float filtering (OES_texture_float_linear)');
    if (coefficients.bricks) coefficients.indirection = await indirectionTexture(gl, 'mbd', coefficients.bricks);
    const voxels = validity.size;
    const relitTiles = [RELIT_GROUPS, rank, 1];
    const basisNodes = basisKernel.nodes;
    const step = coefficientKernel.nodes.map((n, k) =>
      (n > 1 ? (coefficientKernel.domain_max[k] - coefficientKernel.domain_min[k]) / (n - 1) : 0));
    if (coefficientKernel.nodes.some((n, k) => n !== voxels[k])) fail('mbd: validity and coefficient grids differ');
    methods.set('mbd', {
      rank,
      voxels,
      validity,
      basis,
      basisRanges: rangesTexture(gl, basis.scale, basis.bias),
      basisGrid: grid(basisKernel.domain_min, basisKernel.domain_max, basisNodes, basis.tiles),
      relitGrid: grid(basisKernel.domain_min, basisKernel.domain_max, basisNodes, relitTiles),
      relit: targetTexture(gl, basisNodes.map((n, k) => n * relitTiles[k])),
      coefficients,
      coefficientGrid: grid(coefficientKernel.domain_min, coefficientKernel.domain_max, coefficientKernel.nodes, coefficients.tiles),
      step,
      atlas: targetTexture(gl, [voxels[0], voxels[1], RELIT_GROUPS * voxels[2]]),
      atlasGrid: grid(coefficientKernel.domain_min, coefficientKernel.domain_max, voxels, [1, 1, RELIT_GROUPS]),
      offset: step.map((s) => 0.5 * s),
    });
  }
  const kept = await fetch('bake/volumes/manifest.json');
  if (kept.ok) {
    const keptManifest = await kept.json();
    const validity = await loadArray(gl, 'volumes', keptManifest, 'validity');
    const voxels = validity.size;
    const lo = keptManifest.attributes.bounds_min;
    const hi = keptManifest.attributes.bounds_max;
    const edge = voxels.map((n, k) => (hi[k] - lo[k]) / n);
    const first = lo.map((v, k) => v + 0.5 * edge[k]);
    const last = hi.map((v, k) => v - 0.5 * edge[k]);
    for (const name of keptManifest.attributes.volumes || []) {
      // Nine 36-channel parts become one atlas of 81 groups, tile (group mod 9, part).
      const basisTiles = [9, 9, 1];
      const texture = gl.createTexture();
      gl.bindTexture(gl.TEXTURE_3D, texture);
      gl.texStorage3D(gl.TEXTURE_3D, 1, gl.RGBA16F, 9 * voxels[0], 9 * voxels[1], voxels[2]);
      setSampling(gl, gl.TEXTURE_3D, gl.NEAREST);
      const scale = new Float32Array(4 * BASIS_GROUPS);
      const bias = new Float32Array(4 * BASIS_GROUPS);
      for (let part = 0; part < 9; part++) {
        const entry = entryOf(keptManifest, `${name}.${part}`, 'volumes');
        if (entry.encoding !== 'f16' || entry.channels !== 36 || entry.layout !== 'volume') {
          fail(`volumes/${entry.file}: expected 36 f16 channels in the volume layout`);
        }
        const size = [voxels[0], voxels[1], 9 * voxels[2]];
        const texels = new Uint16Array(parseKtx2(await fetchBytes(`bake/volumes/${entry.file}`), entry.file, 'f16', size));
        const slab = 4 * voxels[0] * voxels[1] * voxels[2];
        for (let j = 0; j < 9; j++) {
          gl.texSubImage3D(gl.TEXTURE_3D, 0, j * voxels[0], part * voxels[1], 0, voxels[0], voxels[1], voxels[2],
            gl.RGBA, gl.HALF_FLOAT, texels.subarray(j * slab, (j + 1) * slab));
        }
        checkGl(gl, `uploading volumes/${entry.file}`);
        scale.fill(1, 36 * part, 36 * (part + 1));
      }
      methods.set(name, {
        rank: 1,
        voxels,
        validity,
        basis: { texture },
        basisRanges: rangesTexture(gl, scale, bias),
        basisGrid: grid(first, last, voxels, basisTiles),
        relitGrid: grid(first, last, voxels, [RELIT_GROUPS, 1, 1]),
        relit: targetTexture(gl, [RELIT_GROUPS * voxels[0], voxels[1], voxels[2]]),
        atlas: targetTexture(gl, [voxels[0], voxels[1], RELIT_GROUPS * voxels[2]]),
        atlasGrid: grid(first, last, voxels, [1, 1, RELIT_GROUPS]),
        offset: edge.map((e) => 0.5 * e),
      });
    }
  }

  // The relighting pass of one method for a sky: raw basis → relit basis → voxel atlas.
  const emptyVao = gl.createVertexArray();
  function relight(m, skySh) {
    gl.bindVertexArray(emptyVao);
    const relightProgram = relightPrograms.get(m.rank).use()
      .grid('u_mbd_basis', m.basisGrid).grid('u_mbd_relit', m.relitGrid)
      .vec4s('u_mbd_sky', packSky(skySh))
      .texture('u_mbd_basis_texture', 0, gl.TEXTURE_3D, m.basis.texture)
      .texture('u_mbd_basis_ranges', 1, gl.TEXTURE_2D, m.basisRanges);
    const relitSize = m.relitGrid.nodes.map((n, k) => n * m.relitGrid.tiles[k]);
    drawSlices(gl, relightProgram, m.relit, relitSize, 'u_mbd_slice');
    let voxel;
    if (m.coefficients) {
      voxel = mbdVoxelProgram.use()
        .grid('u_mbd_coefficients', m.coefficientGrid).grid('u_mbd_relit', m.relitGrid)
        .vec4s('u_mbd_coefficient_scale', m.coefficients.scale)
        .vec4s('u_mbd_coefficient_bias', m.coefficients.bias)
        .texture('u_mbd_coefficient_texture', 0, gl.TEXTURE_3D, m.coefficients.texture)
        .texture('u_mbd_relit_texture', 1, gl.TEXTURE_3D, m.relit)
        .vec3('u_node_step', m.step);
      const b = m.coefficients.bricks;
      if (b) {
        voxel.vec4s('u_mbd_bricks.grid', [...b.grid, b.size]).vec4s('u_mbd_bricks.atlas', [...b.atlas, 0])
          .texture('u_mbd_coefficient_indirection', 3, gl.TEXTURE_3D, m.coefficients.indirection);
      }
    } else {
      voxel = keptVoxelProgram.use().texture('u_relit_voxels', 0, gl.TEXTURE_3D, m.relit);
    }
    voxel.texture('u_validity', 2, gl.TEXTURE_3D, m.validity.texture);
    gl.uniform3iv(gl.getUniformLocation(voxel.p, 'u_voxels'), m.voxels);
    gl.uniform2f(gl.getUniformLocation(voxel.p, 'u_validity_range'), m.validity.scale[0], m.validity.bias[0]);
    drawVoxelSlices(gl, voxel, m.atlas, m.voxels);
  }

  // Scene geometry.
  const sceneVao = gl.createVertexArray();
  gl.bindVertexArray(sceneVao);
  for (const [name, data, size] of [['a_position', mesh.positions, 3], ['a_normal', mesh.normals, 3],
    ['a_albedo', mesh.albedo, 3], ['a_emission', mesh.emission, 3], ['a_double_sided', mesh.doubleSided, 1]]) {
    const loc = gl.getAttribLocation(sceneProgram.p, name);
    if (loc < 0) continue;
    const buffer = gl.createBuffer();
    gl.bindBuffer(gl.ARRAY_BUFFER, buffer);
    gl.bufferData(gl.ARRAY_BUFFER, data, gl.STATIC_DRAW);
    gl.enableVertexAttribArray(loc);
    gl.vertexAttribPointer(loc, size, gl.FLOAT, false, 0, 0);
  }
  const indexBuffer = gl.createBuffer();
  gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, indexBuffer);
  gl.bufferData(gl.ELEMENT_ARRAY_BUFFER, mesh.indices, gl.STATIC_DRAW);
  gl.bindVertexArray(null);
  const sceneSize = Math.hypot(...sub(mesh.bounds.hi, mesh.bounds.lo)) || 1;
  const sceneCentre = scale3(add(mesh.bounds.hi, mesh.bounds.lo), 0.5);

  // The linear radiance target (alpha: 1 where the scene is hit) and its depth buffer.
  let hdr = null;
  function hdrTarget(w, h) {
    if (hdr && hdr.w === w && hdr.h === h) return hdr;
    const color = gl.createTexture();
    gl.bindTexture(gl.TEXTURE_2D, color);
    gl.texStorage2D(gl.TEXTURE_2D, 1, gl.RGBA32F, w, h);
    setSampling(gl, gl.TEXTURE_2D, gl.NEAREST);
    const depth = gl.createRenderbuffer();
    gl.bindRenderbuffer(gl.RENDERBUFFER, depth);
    gl.renderbufferStorage(gl.RENDERBUFFER, gl.DEPTH_COMPONENT24, w, h);
    const fbo = gl.createFramebuffer();
    gl.bindFramebuffer(gl.FRAMEBUFFER, fbo);
    gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.COLOR_ATTACHMENT0, gl.TEXTURE_2D, color, 0);
    gl.framebufferRenderbuffer(gl.FRAMEBUFFER, gl.DEPTH_ATTACHMENT, gl.RENDERBUFFER, depth);
    if (gl.checkFramebufferStatus(gl.FRAMEBUFFER) !== gl.FRAMEBUFFER_COMPLETE) fail('cannot render to an RGBA32F target');
    gl.bindFramebuffer(gl.FRAMEBUFFER, null);
    hdr = { w, h, color, fbo };
    return hdr;
  }

  // ---- state and controls
  const ui = (id) => document.getElementById(id);
  const state = {
    camera: 0, view: null, method: 'mbd', diff: false, diffScale: 8, sky: 0, rotate: 0,
    exposure: null, relitFor: new Map(),
  };
  const intParam = (name, lo, hi) => {
    if (!PARAMS.has(name)) return null;
    const v = Number(PARAMS.get(name));
    if (!Number.isInteger(v) || v < lo || v > hi) fail(`${name}=${PARAMS.get(name)} is not in ${lo}..${hi}`);
    return v;
  };
  state.camera = intParam('camera', 0, views.length - 1) ?? 0;
  state.sky = intParam('sky', 0, skies.length - 1) ?? 0;
  if (PARAMS.has('rotate')) {
    state.rotate = Number(PARAMS.get('rotate'));
    if (!Number.isFinite(state.rotate)) fail(`rotate=${PARAMS.get('rotate')} is not a number`);
  }
  if (PARAMS.has('method')) {
    state.method = PARAMS.get('method');
    if (!methods.has(state.method)) {
      fail(`method=${state.method} is not in this bake (have: ${[...methods.keys()].join(', ')})`);
    }
  }
  state.diff = PARAMS.get('diff') === '1';
  if (PARAMS.has('diffScale')) {
    state.diffScale = Number(PARAMS.get('diffScale'));
    if (!(state.diffScale > 0 && Number.isFinite(state.diffScale))) fail(`diffScale=${PARAMS.get('diffScale')} is not a positive number`);
  }
  if (state.diff && !methods.has('reference')) fail('diff=1 needs the reference volume (bake with --keep-volumes always)');
  if (PARAMS.has('exposure')) {
    state.exposure = Number(PARAMS.get('exposure'));
    if (!(state.exposure > 0 && Number.isFinite(state.exposure))) fail(`exposure=${PARAMS.get('exposure')} is not a positive number`);
  }
  state.view = { ...views[state.camera] };

  const fill = (select, items, current) => {
    select.innerHTML = '';
    items.forEach(([value, label]) => select.add(new Option(label, value)));
    select.value = String(current);
  };
  fill(ui('camera'), views.map((v, i) => [i, `${i}: ${v.name}`]), state.camera);
  fill(ui('method'), [...methods.keys()].map((m) => [m, m]), state.method);
  fill(ui('sky'), skies.map((s, i) => [i, s.name]), state.sky);
  ui('rotate').value = state.rotate;
  ui('rotateValue').textContent = state.rotate;
  ui('diff').checked = state.diff;
  ui('diffScale').value = state.diffScale;
  ui('diff').disabled = !methods.has('reference');

  // ---- drawing
  const timing = { frames: 0, frameMs: 0, relightMs: 0 };
  function currentSky() {
    return rotateSky(skies[state.sky].sh, state.rotate);
  }
  function ensureRelit(name, skySh, key) {
    if (state.relitFor.get(name) === key) return false;
    relight(methods.get(name), skySh);
    state.relitFor.set(name, key);
    return true;
  }
  function sync() {
    const pixel = new Uint8Array(4);
    gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, pixel);
  }

  // Draws the linear image into the HDR target; returns the relighting time (ms, 0 if none).
  function drawHdr() {
    const w = canvas.width;
    const h = canvas.height;
    const target = hdrTarget(w, h);
    const skySh = currentSky();
    const key = `${state.sky}/${state.rotate}`;
    const t0 = performance.now();
    let relit = ensureRelit(state.method, skySh, key);
    if (state.diff) relit = ensureRelit('reference', skySh, key) || relit;
    let relightMs = 0;
    if (relit) {
      sync();
      relightMs = performance.now() - t0;
    }
    const m = methods.get(state.method);
    const v = state.view;
    gl.bindFramebuffer(gl.FRAMEBUFFER, target.fbo);
    gl.viewport(0, 0, w, h);
    gl.clearColor(0, 0, 0, 0);
    gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
    const right = normalize(cross(v.forward, v.up));
    const up = cross(right, v.forward);
    const tan = Math.tan(v.yfov / 2);
    gl.disable(gl.DEPTH_TEST);
    gl.bindVertexArray(emptyVao);
    skyProgram.use().vec4s('u_sky', packSky(skySh)).vec3('u_forward', v.forward).vec3('u_right', right)
      .vec3('u_up', up).float('u_show', state.diff ? 0 : 1);
    gl.uniform2f(gl.getUniformLocation(skyProgram.p, 'u_tan'), tan * w / h, tan);
    gl.uniform2f(gl.getUniformLocation(skyProgram.p, 'u_resolution'), w, h);
    gl.drawArrays(gl.TRIANGLES, 0, 3);
    gl.enable(gl.DEPTH_TEST);
    const distance = Math.hypot(...sub(sceneCentre, v.position));
    const near = Math.max(1e-4 * sceneSize, (distance - sceneSize) * 0.5, 1e-3 * sceneSize);
    const far = distance + 2 * sceneSize;
    const reference = state.diff ? methods.get('reference') : m;
    sceneProgram.use().mat4('u_view_proj', viewProjection(v, w / h, near, far)).vec3('u_eye', v.position)
      .grid('u_volume', m.atlasGrid).texture('u_volume_texture', 0, gl.TEXTURE_3D, m.atlas)
      .grid('u_reference', reference.atlasGrid).texture('u_reference_texture', 1, gl.TEXTURE_3D, reference.atlas)
      .vec3('u_offset', m.offset).float('u_diff_scale', state.diff ? state.diffScale : 0);
    gl.bindVertexArray(sceneVao);
    gl.drawElements(gl.TRIANGLES, mesh.indices.length, gl.UNSIGNED_INT, 0);
    gl.bindVertexArray(null);
    gl.bindFramebuffer(gl.FRAMEBUFFER, null);
    return relightMs;
  }

  // prt-render's ToneMap::auto: middle grey over the log-average luminance of lit hits.
  function autoExposure() {
    const target = hdrTarget(canvas.width, canvas.height);
    gl.bindFramebuffer(gl.FRAMEBUFFER, target.fbo);
    const pixels = new Float32Array(4 * target.w * target.h);
    gl.readPixels(0, 0, target.w, target.h, gl.RGBA, gl.FLOAT, pixels);
    gl.bindFramebuffer(gl.FRAMEBUFFER, null);
    let sum = 0;
    let count = 0;
    for (let i = 0; i < pixels.length; i += 4) {
      if (pixels[i + 3] <= 0) continue;
      const l = 0.2126 * pixels[i] + 0.7152 * pixels[i + 1] + 0.0722 * pixels[i + 2];
      if (l > 0 && Number.isFinite(l)) { sum += Math.log(l); count++; }
    }
    return count === 0 ? 1 : MIDDLE_GREY / Math.exp(sum / count);
  }

  function toneMap() {
    gl.bindFramebuffer(gl.FRAMEBUFFER, null);
    gl.viewport(0, 0, canvas.width, canvas.height);
    gl.disable(gl.DEPTH_TEST);
    gl.bindVertexArray(emptyVao);
    toneProgram.use().texture('u_hdr', 0, gl.TEXTURE_2D, hdrTarget(canvas.width, canvas.height).color)
      .float('u_exposure', state.exposure);
    gl.drawArrays(gl.TRIANGLES, 0, 3);
  }

  function frame() {
    const t0 = performance.now();
    const relightMs = drawHdr();
    if (state.exposure === null) state.exposure = autoExposure();
    toneMap();
    sync();
    const frameMs = performance.now() - t0;
    timing.frames++;
    timing.frameMs = frameMs;
    if (relightMs > 0) timing.relightMs = relightMs;
    ui('exposure').value = Math.log2(state.exposure);
    ui('exposureValue').textContent = Math.log2(state.exposure).toFixed(2);
    ui('stats').textContent = `frame ${frameMs.toFixed(1)} ms\nrelight ${timing.relightMs.toFixed(1)} ms` +
      ` (last)\n${canvas.width}×${canvas.height}, rank ${rank}\n${gl.getParameter(gl.RENDERER)}`;
  }

  if (CAPTURE) {
    frame();
    // Optional (?bench=N): time N steps of each kind at the server's wall clock, for
    // docs/results.md: a frame whose sky turned (relight + draw), a frame with the sky still
    // (draw only), and the relighting pass alone.
    const bench = intParam('bench', 0, 1000) ?? 0;
    if (bench > 0) {
      const mark = (label) => {
        const request = new XMLHttpRequest();
        request.open('GET', `bench?${encodeURIComponent(label)}`, false);
        request.send();
      };
      const rotate = state.rotate;
      mark('start');
      for (let i = 0; i < bench; i++) {
        state.rotate = rotate + i + 1;
        frame();
        mark(`frame with the sky turning (${state.method}, ${canvas.width}²)`);
      }
      for (let i = 0; i < bench; i++) {
        frame();
        mark(`frame with the sky still (${state.method}, ${canvas.width}²)`);
      }
      for (let i = 0; i < bench; i++) {
        state.relitFor.clear();
        ensureRelit(state.method, currentSky(), 'bench');
        sync();
        mark(`relighting pass (${state.method})`);
      }
      mark('done');
      state.rotate = rotate;
      state.relitFor.clear();
      frame();
    }
    checkGl(gl, 'drawing the frame');
    document.title = 'ready';
    return;
  }

  // ---- interactive: redraw on demand
  let dirty = true;
  const redraw = () => { dirty = true; };
  const resize = () => {
    const side = Math.max(128, Math.min(window.innerWidth - 270, window.innerHeight - 4));
    if (canvas.width !== side) { canvas.width = canvas.height = side; redraw(); }
  };
  window.addEventListener('resize', resize);
  resize();
  ui('camera').onchange = () => { state.camera = Number(ui('camera').value); state.view = { ...views[state.camera] }; redraw(); };
  ui('method').onchange = () => { state.method = ui('method').value; redraw(); };
  ui('sky').onchange = () => { state.sky = Number(ui('sky').value); redraw(); };
  ui('diff').onchange = () => { state.diff = ui('diff').checked; redraw(); };
  ui('diffScale').oninput = () => { state.diffScale = Math.max(1, Number(ui('diffScale').value) || 1); redraw(); };
  ui('rotate').oninput = () => {
    state.rotate = Number(ui('rotate').value);
    ui('rotateValue').textContent = state.rotate;
    redraw();
  };
  ui('exposure').oninput = () => { state.exposure = 2 ** Number(ui('exposure').value); redraw(); };
  ui('autoExposure').onclick = () => { state.exposure = null; redraw(); };

  // Orbit about the point the view looks at, at the scene centre's distance.
  let drag = null;
  canvas.addEventListener('pointerdown', (e) => { drag = [e.clientX, e.clientY]; canvas.setPointerCapture(e.pointerId); });
  canvas.addEventListener('pointerup', () => { drag = null; });
  canvas.addEventListener('pointermove', (e) => {
    if (!drag) return;
    const [dx, dy] = [e.clientX - drag[0], e.clientY - drag[1]];
    drag = [e.clientX, e.clientY];
    const v = state.view;
    const distance = Math.hypot(...sub(sceneCentre, v.position));
    const target = add(v.position, scale3(v.forward, distance));
    let offset = sub(v.position, target);
    const yaw = -dx * 0.01;
    const c = Math.cos(yaw);
    const s = Math.sin(yaw);
    offset = [c * offset[0] + s * offset[2], offset[1], -s * offset[0] + c * offset[2]];
    const right = normalize(cross(scale3(offset, -1), [0, 1, 0]));
    const pitch = -dy * 0.01;
    const along = dot(normalize(offset), [0, 1, 0]);
    if (Math.abs(along + Math.sin(pitch)) < 0.98) {
      const cp = Math.cos(pitch);
      const sp = Math.sin(pitch);
      const k = cross(right, offset);
      offset = add(add(scale3(offset, cp), scale3(k, sp)), scale3(right, dot(right, offset) * (1 - cp)));
    }
    const position = add(target, offset);
    const forward = normalize(sub(target, position));
    const r = normalize(cross(forward, [0, 1, 0]));
    state.view = { ...v, position, forward, up: cross(r, forward) };
    redraw();
  });
  canvas.addEventListener('wheel', (e) => {
    e.preventDefault();
    const v = state.view;
    const step = Math.sign(e.deltaY) * 0.05 * sceneSize;
    state.view = { ...v, position: sub(v.position, scale3(v.forward, step)) };
    redraw();
  }, { passive: false });

  let checked = false;
  const loop = () => {
    if (dirty) {
      dirty = false;
      frame();
      // Once: getError waits for the GPU.
      if (!checked) { checked = true; checkGl(gl, 'drawing the frame'); }
    }
    requestAnimationFrame(loop);
  };
  loop();
}

main().catch((e) => showError(e && e.message ? e.message : e));
