// WebGL2 pieces: container arrays as textures, render targets, grids, programs and the passes
// that render into a 3D texture slice by slice.

import { checkGl, fail, fetchText } from './page.js';
import { parseKtx2 } from './formats.js';
import {
  FULLSCREEN_VS, KEPT_VOXEL, MBD_VOXEL, LIT_GROUPS, SCENE_FS, SCENE_VS, SKY_FS, TONEMAP_FS,
  VOXEL_MAIN,
} from './shaders.js';

// ---------------------------------------------------------------- textures

export function setSampling(gl, target, filter) {
  gl.texParameteri(target, gl.TEXTURE_MIN_FILTER, filter);
  gl.texParameteri(target, gl.TEXTURE_MAG_FILTER, filter);
  for (const wrap of [gl.TEXTURE_WRAP_S, gl.TEXTURE_WRAP_T, gl.TEXTURE_WRAP_R]) {
    gl.texParameteri(target, wrap, gl.CLAMP_TO_EDGE);
  }
}

// A container array as a WebGL texture in its layout, with its per-group scale and bias.
export function arrayTexture(gl, entry, data) {
  const { groups, bricks, tiles, size } = arrayLayout(entry);
  const single = entry.single_channel === true;
  const texels = parseKtx2(data, entry.file, entry.encoding, size, single);
  const texture = gl.createTexture();
  gl.bindTexture(gl.TEXTURE_3D, texture);
  uploadTexels(gl, entry.encoding, single, size, texels);
  checkGl(gl, `uploading ${entry.file} (${size.join('×')} texels)`);
  const floatTexels = entry.encoding === 'f32' || entry.encoding.endsWith('16') && entry.encoding !== 'f16';
  const filter = floatTexels && !gl.getExtension('OES_texture_float_linear') ? gl.NEAREST : gl.LINEAR;
  setSampling(gl, gl.TEXTURE_3D, filter);
  const { scale, bias } = groupRanges(entry, groups);
  return { texture, size, tiles, groups, scale, bias, linear: filter === gl.LINEAR, bricks };
}

// Texel groups (4 channels each), tiles and texture size of an array's layout.
function arrayLayout(entry) {
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
  return { groups, bricks, tiles, size };
}

// Uploads `texels` (KTX2 level 0) to the bound TEXTURE_3D in the format of its encoding.
function uploadTexels(gl, encoding, single, [w, h, d], texels) {
  const upload = (internal, format, type, array) =>
    gl.texImage3D(gl.TEXTURE_3D, 0, internal, w, h, d, 0, format, type, array);
  if (single) {
    switch (encoding) {
      case 'f32': upload(gl.R32F, gl.RED, gl.FLOAT, new Float32Array(texels)); break;
      case 'f16': upload(gl.R16F, gl.RED, gl.HALF_FLOAT, new Uint16Array(texels)); break;
      case 'unorm8': upload(gl.R8, gl.RED, gl.UNSIGNED_BYTE, new Uint8Array(texels)); break;
    }
  } else switch (encoding) {
    case 'f32': upload(gl.RGBA32F, gl.RGBA, gl.FLOAT, new Float32Array(texels)); break;
    case 'f16': upload(gl.RGBA16F, gl.RGBA, gl.HALF_FLOAT, new Uint16Array(texels)); break;
    case 'unorm8': upload(gl.RGBA8, gl.RGBA, gl.UNSIGNED_BYTE, new Uint8Array(texels)); break;
    case 'snorm8': upload(gl.RGBA8_SNORM, gl.RGBA, gl.BYTE, new Int8Array(texels)); break;
    case 'unorm16': case 'snorm16': {
      // WebGL2 has no 16-bit normalised textures: the normalised value as f32.
      const signed = encoding === 'snorm16';
      const q = signed ? new Int16Array(texels) : new Uint16Array(texels);
      const t = new Float32Array(q.length);
      for (let i = 0; i < q.length; i++) t[i] = signed ? Math.max(q[i] / 32767, -1) : q[i] / 65535;
      upload(gl.RGBA32F, gl.RGBA, gl.FLOAT, t);
      break;
    }
  }
}

// Per-channel scale and bias over whole groups (channels past the array's: 0).
function groupRanges(entry, groups) {
  const scale = new Float32Array(4 * groups);
  const bias = new Float32Array(4 * groups);
  for (let c = 0; c < 4 * groups; c++) {
    const range = entry.ranges && entry.ranges[c];
    scale[c] = c < entry.channels ? (range ? range.scale : 1) : 0;
    bias[c] = c < entry.channels && range ? range.bias : 0;
  }
  return { scale, bias };
}

// The indirection of a brick-layout array: RGBA8 unorm, one texel per brick, read with texelFetch.
export function indirectionTexture(gl, bricks, data) {
  const texels = parseKtx2(data, bricks.indirection, 'unorm8', bricks.grid, false);
  const texture = gl.createTexture();
  gl.bindTexture(gl.TEXTURE_3D, texture);
  gl.texImage3D(gl.TEXTURE_3D, 0, gl.RGBA8, ...bricks.grid, 0, gl.RGBA, gl.UNSIGNED_BYTE, new Uint8Array(texels));
  checkGl(gl, `uploading ${bricks.indirection}`);
  setSampling(gl, gl.TEXTURE_3D, gl.NEAREST);
  return texture;
}

// Scale and bias of every group as a (groups × 2) RGBA32F texture: what light.glsl fetches.
export function rangesTexture(gl, scale, bias) {
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
export function targetTexture(gl, size) {
  const texture = gl.createTexture();
  gl.bindTexture(gl.TEXTURE_3D, texture);
  gl.texStorage3D(gl.TEXTURE_3D, 1, gl.RGBA16F, size[0], size[1], size[2]);
  setSampling(gl, gl.TEXTURE_3D, gl.LINEAR);
  return texture;
}

// MbdGrid of a hat grid whose first and last nodes are `first` and `last`.
export function grid(first, last, nodes, tiles) {
  const inv = first.map((a, k) => (nodes[k] > 1 && last[k] > a ? 1 / (last[k] - a) : 0));
  return { domain_min: first, inv_size: inv, nodes, tiles };
}

// ---------------------------------------------------------------- programs

function compile(gl, type, source, what) {
  const shader = gl.createShader(type);
  gl.shaderSource(shader, source);
  gl.compileShader(shader);
  if (!gl.getShaderParameter(shader, gl.COMPILE_STATUS)) {
    fail(`the ${what} shader does not compile:\n${gl.getShaderInfoLog(shader)}`);
  }
  return shader;
}

// A linked program with chainable uniform setters (locations looked up once).
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

// Every program the viewer draws with, for a container of `rank` (`bricked`: its coefficients
// in bricks), with prt-shaders' GLSL from the server.
export async function compilePrograms(gl, rank, bricked) {
  const [common1, light1, lightRank, reconstructRank] = await Promise.all([
    fetchText('shaders/common.glsl?rank=1'),
    fetchText('shaders/light.glsl?rank=1'), fetchText(`shaders/light.glsl?rank=${rank}`),
    fetchText(`shaders/reconstruct.glsl?rank=${rank}${bricked ? '&layout=bricks' : ''}`),
  ]);
  return {
    // By rank: kept volumes are lit with rank 1, the container with its own.
    light: new Map([
      [1, program(gl, FULLSCREEN_VS, light1, 'light (rank 1)')],
      [rank, program(gl, FULLSCREEN_VS, lightRank, `light (rank ${rank})`)],
    ]),
    mbdVoxel: program(gl, FULLSCREEN_VS, reconstructRank + VOXEL_MAIN + MBD_VOXEL, 'MBD voxel'),
    keptVoxel: program(gl, FULLSCREEN_VS, common1 + VOXEL_MAIN + KEPT_VOXEL, 'kept-volume voxel'),
    scene: program(gl, SCENE_VS, common1 + SCENE_FS, 'scene'),
    sky: program(gl, FULLSCREEN_VS, common1 + SKY_FS, 'sky'),
    tone: program(gl, FULLSCREEN_VS, TONEMAP_FS, 'tone map'),
  };
}

// ---------------------------------------------------------------- passes into 3D textures

// Runs `prog` once per z slice of the 3D texture `target` of `size`.
export function drawSlices(gl, prog, target, size, sliceUniform) {
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

// Runs the voxel pass `prog` once per z slice of the voxel grid, into the 7 tiles of `atlas`.
export function drawVoxelSlices(gl, prog, atlas, voxels) {
  const fbo = gl.createFramebuffer();
  gl.bindFramebuffer(gl.FRAMEBUFFER, fbo);
  gl.viewport(0, 0, voxels[0], voxels[1]);
  gl.disable(gl.DEPTH_TEST);
  const buffers = [...Array(LIT_GROUPS).keys()].map((r) => gl.COLOR_ATTACHMENT0 + r);
  gl.drawBuffers(buffers);
  for (let z = 0; z < voxels[2]; z++) {
    for (let r = 0; r < LIT_GROUPS; r++) {
      gl.framebufferTextureLayer(gl.FRAMEBUFFER, buffers[r], atlas, 0, z + r * voxels[2]);
    }
    prog.int('u_voxel_slice', z);
    gl.drawArrays(gl.TRIANGLES, 0, 3);
  }
  gl.bindFramebuffer(gl.FRAMEBUFFER, null);
  gl.deleteFramebuffer(fbo);
}
