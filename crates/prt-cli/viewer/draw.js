// One frame: the sky and the scene in linear radiance into a float target, then prt-render's
// exposure and tone map onto the canvas.

import { fail } from './page.js';
import { setSampling } from './gl.js';
import { add, cross, normalize, packSky, scale3, sub, viewProjection } from './math.js';
import { light } from './methods.js';

const MIDDLE_GREY = 0.18;

// What drawing needs, made once: the programs and methods, a vertex array for the fullscreen
// passes, the scene's geometry and the HDR target.
export function createRenderer(gl, canvas, programs, methods, mesh) {
  const emptyVao = gl.createVertexArray();
  return {
    gl, canvas, programs, methods, emptyVao,
    scene: sceneGeometry(gl, programs.scene, mesh),
    hdrTarget: hdrTargets(gl),
  };
}

// The mesh's buffers in a vertex array, its index count, size and centre.
function sceneGeometry(gl, sceneProgram, mesh) {
  const vao = gl.createVertexArray();
  gl.bindVertexArray(vao);
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
  return {
    vao,
    count: mesh.indices.length,
    size: Math.hypot(...sub(mesh.bounds.hi, mesh.bounds.lo)) || 1,
    centre: scale3(add(mesh.bounds.hi, mesh.bounds.lo), 0.5),
  };
}

// The linear radiance target (alpha: 1 where the scene is hit) and its depth buffer, for a
// canvas size: made again only when the size changes.
function hdrTargets(gl) {
  let hdr = null;
  return (w, h) => {
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
  };
}

// Lights method `name` unless it is already lit for `key` (the sky and its rotation); true if
// it lit it.
export function ensureLit(renderer, litFor, name, skySh, key) {
  if (litFor.get(name) === key) return false;
  const { gl, programs, emptyVao, methods } = renderer;
  light(gl, programs, emptyVao, methods.get(name), skySh);
  litFor.set(name, key);
  return true;
}

// Lights what the frame shows (the method, and the reference for a difference) unless it is
// lit for this sky already; returns how long that took in ms (0: nothing lit).
export function lightShown(renderer, state, skySh) {
  const key = `${state.sky}/${state.rotate}`;
  const t0 = performance.now();
  let lit = ensureLit(renderer, state.litFor, state.method, skySh, key);
  if (state.diff) lit = ensureLit(renderer, state.litFor, 'reference', skySh, key) || lit;
  if (!lit) return 0;
  sync(renderer.gl);
  return performance.now() - t0;
}

// Waits for the GPU (a one-pixel read), so that times measured around it include the GPU's work.
export function sync(gl) {
  const pixel = new Uint8Array(4);
  gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, pixel);
}

// Draws the linear image of `state` lit by `skySh` into the HDR target.
export function drawHdr(renderer, state, skySh) {
  const { gl, canvas } = renderer;
  const w = canvas.width;
  const h = canvas.height;
  gl.bindFramebuffer(gl.FRAMEBUFFER, renderer.hdrTarget(w, h).fbo);
  gl.viewport(0, 0, w, h);
  gl.clearColor(0, 0, 0, 0);
  gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
  drawSky(renderer, state.view, skySh, state.diff ? 0 : 1);
  drawScene(renderer, state);
  gl.bindFramebuffer(gl.FRAMEBUFFER, null);
}

// The sky behind the scene (`show` 0: black, for the difference image).
function drawSky(renderer, v, skySh, show) {
  const { gl, canvas, programs } = renderer;
  const w = canvas.width;
  const h = canvas.height;
  const right = normalize(cross(v.forward, v.up));
  const up = cross(right, v.forward);
  const tan = Math.tan(v.yfov / 2);
  gl.disable(gl.DEPTH_TEST);
  gl.bindVertexArray(renderer.emptyVao);
  programs.sky.use().vec4s('u_sky', packSky(skySh)).vec3('u_forward', v.forward).vec3('u_right', right)
    .vec3('u_up', up).float('u_show', show);
  gl.uniform2f(gl.getUniformLocation(programs.sky.p, 'u_tan'), tan * w / h, tan);
  gl.uniform2f(gl.getUniformLocation(programs.sky.p, 'u_resolution'), w, h);
  gl.drawArrays(gl.TRIANGLES, 0, 3);
}

// The scene shaded from the method's voxel atlas (or its difference from the reference's).
function drawScene(renderer, state) {
  const { gl, canvas, methods, scene } = renderer;
  const v = state.view;
  const m = methods.get(state.method);
  gl.enable(gl.DEPTH_TEST);
  const distance = Math.hypot(...sub(scene.centre, v.position));
  const near = Math.max(1e-4 * scene.size, (distance - scene.size) * 0.5, 1e-3 * scene.size);
  const far = distance + 2 * scene.size;
  const reference = state.diff ? methods.get('reference') : m;
  renderer.programs.scene.use()
    .mat4('u_view_proj', viewProjection(v, canvas.width / canvas.height, near, far)).vec3('u_eye', v.position)
    .grid('u_volume', m.atlasGrid).texture('u_volume_texture', 0, gl.TEXTURE_3D, m.atlas)
    .grid('u_reference', reference.atlasGrid).texture('u_reference_texture', 1, gl.TEXTURE_3D, reference.atlas)
    .vec3('u_offset', m.offset).float('u_diff_scale', state.diff ? state.diffScale : 0);
  gl.bindVertexArray(scene.vao);
  gl.drawElements(gl.TRIANGLES, scene.count, gl.UNSIGNED_INT, 0);
  gl.bindVertexArray(null);
}

// prt-render's ToneMap::auto: middle grey over the log-average luminance of lit hits.
export function autoExposure(renderer) {
  const { gl, canvas } = renderer;
  const target = renderer.hdrTarget(canvas.width, canvas.height);
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

export function toneMap(renderer, exposure) {
  const { gl, canvas } = renderer;
  gl.bindFramebuffer(gl.FRAMEBUFFER, null);
  gl.viewport(0, 0, canvas.width, canvas.height);
  gl.disable(gl.DEPTH_TEST);
  gl.bindVertexArray(renderer.emptyVao);
  renderer.programs.tone.use().texture('u_hdr', 0, gl.TEXTURE_2D, renderer.hdrTarget(canvas.width, canvas.height).color)
    .float('u_exposure', exposure);
  gl.drawArrays(gl.TRIANGLES, 0, 3);
}
