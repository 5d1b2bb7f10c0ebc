// A lightmap folder (`prt lightmap --out DIR`): the scene from the bake's camera lit by its lightmap, emission +
// albedo/π · E(uv1), tone-mapped like prt-render (exposure, ACES fit, sRGB). The page polls
// /lightmap/state and loads the irradiance again whenever the bake has written a new preview.
//
// URL parameters: &size=PX (one fixed frame for screenshots, the title `ready` once drawn),
// &exposure=E (else automatic from the first lightmap, then kept so refreshes compare),
// &until=N (with size: keep polling until a lightmap of at least N samples per texel is shown),
// &poll=MS (polling interval, 1000).

import { CAPTURE, checkGl, fail, fetchBytes, fetchJson, intParam, positiveParam } from './page.js';
import { viewProjection } from './math.js';

const VS = `#version 300 es
layout(location = 0) in vec3 a_position;
layout(location = 1) in vec2 a_uv;
layout(location = 2) in vec3 a_albedo;
layout(location = 3) in vec3 a_emission;
uniform mat4 u_viewProjection;
out vec2 v_uv;
out vec3 v_albedo;
out vec3 v_emission;
void main() {
  v_uv = a_uv;
  v_albedo = a_albedo;
  v_emission = a_emission;
  gl_Position = u_viewProjection * vec4(a_position, 1.0);
}`;

const FS = `#version 300 es
precision highp float;
uniform highp sampler2D u_lightmap;
uniform float u_exposure;
in vec2 v_uv;
in vec3 v_albedo;
in vec3 v_emission;
out vec4 o_color;
float display(float v) {
  float x = max(v * u_exposure, 0.0);
  float c = clamp((x * (2.51 * x + 0.03)) / (x * (2.43 * x + 0.59) + 0.14), 0.0, 1.0);
  return c <= 0.0031308 ? 12.92 * c : 1.055 * pow(c, 1.0 / 2.4) - 0.055;
}
void main() {
  vec3 radiance = v_emission + v_albedo / 3.14159265358979 * texture(u_lightmap, v_uv).rgb;
  o_color = vec4(display(radiance.r), display(radiance.g), display(radiance.b), 1.0);
}`;

const FLOATS_PER_CORNER = 11;

function parseMesh(buffer) {
  const magic = new TextDecoder().decode(new Uint8Array(buffer, 0, 8));
  if (magic !== 'PRTLMV1\n') fail('bake/view_mesh.bin is not a lightmap view mesh');
  const view = new DataView(buffer);
  const triangles = view.getUint32(8, true);
  const camera = new Float32Array(buffer.slice(12, 52));
  const corners = new Float32Array(buffer.slice(52));
  if (corners.length !== triangles * 3 * FLOATS_PER_CORNER) fail('bake/view_mesh.bin is truncated');
  return {
    triangles,
    corners,
    camera: {
      position: [...camera.slice(0, 3)],
      forward: [...camera.slice(3, 6)],
      up: [...camera.slice(6, 9)],
      yfov: camera[9],
    },
  };
}

function parseIrradiance(buffer) {
  const magic = new TextDecoder().decode(new Uint8Array(buffer, 0, 8));
  if (magic !== 'PRTLMI1\n') fail('bake/view_irradiance.bin is not a lightmap irradiance file');
  const view = new DataView(buffer);
  const width = view.getUint32(8, true);
  const height = view.getUint32(12, true);
  const samples = view.getUint32(16, true);
  const data = new Float32Array(buffer.slice(20));
  if (data.length !== width * height * 3) fail('bake/view_irradiance.bin is truncated');
  return { width, height, samples, data };
}

// The exposure that shows the mean lit texel of an albedo-0.5 surface at a middle grey.
function autoExposure(irradiance) {
  let sum = 0;
  let count = 0;
  for (let i = 0; i < irradiance.data.length; i += 3) {
    const e = 0.2126 * irradiance.data[i] + 0.7152 * irradiance.data[i + 1] + 0.0722 * irradiance.data[i + 2];
    if (e > 0) {
      sum += e;
      count += 1;
    }
  }
  const radiance = count > 0 ? (0.5 * sum) / (count * Math.PI) : 1;
  return 0.18 / radiance;
}

function program(gl) {
  const compile = (type, source) => {
    const shader = gl.createShader(type);
    gl.shaderSource(shader, source);
    gl.compileShader(shader);
    if (!gl.getShaderParameter(shader, gl.COMPILE_STATUS)) fail(`shader: ${gl.getShaderInfoLog(shader)}`);
    return shader;
  };
  const p = gl.createProgram();
  gl.attachShader(p, compile(gl.VERTEX_SHADER, VS));
  gl.attachShader(p, compile(gl.FRAGMENT_SHADER, FS));
  gl.linkProgram(p);
  if (!gl.getProgramParameter(p, gl.LINK_STATUS)) fail(`program: ${gl.getProgramInfoLog(p)}`);
  return p;
}

// Mean 8-bit RGB of the drawn frame over the middle rows of two column bands (3..13 % and
// 87..97 % of the width, the side walls of the Cornell box): what the test compares across
// refreshes.
function bandMeans(gl, size) {
  const pixels = new Uint8Array(size * size * 4);
  gl.readPixels(0, 0, size, size, gl.RGBA, gl.UNSIGNED_BYTE, pixels);
  const band = (from) => {
    const sum = [0, 0, 0];
    let n = 0;
    for (let y = Math.floor(0.3 * size); y < Math.floor(0.7 * size); y++) {
      for (let x = Math.floor(from * size); x < Math.floor((from + 0.1) * size); x++) {
        for (let c = 0; c < 3; c++) sum[c] += pixels[4 * (y * size + x) + c];
        n += 1;
      }
    }
    return sum.map((s) => Math.round(s / n));
  };
  return { left: band(0.03), right: band(0.87) };
}

async function main() {
  const size = intParam('size', 16, 4096) ?? 768;
  const until = intParam('until', 1, 1 << 30);
  const pollMs = intParam('poll', 10, 600000) ?? 1000;
  if (CAPTURE) document.body.classList.add('capture');
  const canvas = document.getElementById('canvas');
  canvas.width = size;
  canvas.height = size;
  const gl = canvas.getContext('webgl2', { antialias: false });
  if (!gl) fail('this browser has no WebGL2');
  const mesh = parseMesh(await fetchBytes('bake/view_mesh.bin'));
  const prog = program(gl);
  const vao = gl.createVertexArray();
  gl.bindVertexArray(vao);
  const buffer = gl.createBuffer();
  gl.bindBuffer(gl.ARRAY_BUFFER, buffer);
  gl.bufferData(gl.ARRAY_BUFFER, mesh.corners, gl.STATIC_DRAW);
  const stride = 4 * FLOATS_PER_CORNER;
  [[0, 3, 0], [1, 2, 3], [2, 3, 5], [3, 3, 8]].forEach(([location, count, offset]) => {
    gl.enableVertexAttribArray(location);
    gl.vertexAttribPointer(location, count, gl.FLOAT, false, stride, 4 * offset);
  });
  const texture = gl.createTexture();
  gl.bindTexture(gl.TEXTURE_2D, texture);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.LINEAR);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.LINEAR);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE);
  checkGl(gl, 'mesh and lightmap texture');

  const camera = mesh.camera;
  let exposure = positiveParam('exposure');
  let shown = null;
  const draw = () => {
    if (shown === null) return;
    gl.viewport(0, 0, size, size);
    gl.clearColor(0.067, 0.067, 0.067, 1);
    gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
    gl.enable(gl.DEPTH_TEST);
    gl.useProgram(prog);
    gl.uniformMatrix4fv(gl.getUniformLocation(prog, 'u_viewProjection'), false,
      viewProjection(camera, 1, 0.01, 1000));
    gl.uniform1f(gl.getUniformLocation(prog, 'u_exposure'), exposure);
    gl.uniform1i(gl.getUniformLocation(prog, 'u_lightmap'), 0);
    gl.bindVertexArray(vao);
    gl.drawArrays(gl.TRIANGLES, 0, mesh.triangles * 3);
    checkGl(gl, 'drawing the scene');
    const means = bandMeans(gl, size);
    const stats = document.getElementById('stats');
    stats.dataset.samples = shown;
    stats.dataset.left = means.left.join(',');
    stats.dataset.right = means.right.join(',');
    stats.textContent = `${shown} samples per texel`;
  };

  let stamp = null;
  for (;;) {
    const state = await fetchJson('lightmap/state');
    if (state.stamp !== null && state.stamp !== stamp) {
      const irradiance = parseIrradiance(await fetchBytes('bake/view_irradiance.bin'));
      stamp = state.stamp;
      gl.bindTexture(gl.TEXTURE_2D, texture);
      gl.pixelStorei(gl.UNPACK_ALIGNMENT, 1);
      gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGB16F, irradiance.width, irradiance.height, 0, gl.RGB,
        gl.FLOAT, irradiance.data);
      checkGl(gl, 'uploading the lightmap');
      if (exposure === null) exposure = autoExposure(irradiance);
      shown = irradiance.samples;
      draw();
      await fetch(`lightmap/shown?${shown}`);
      if (CAPTURE && (until === null || shown >= until)) {
        document.title = 'ready';
        return;
      }
    }
    await new Promise((resolve) => setTimeout(resolve, pollMs));
  }
}

main();
