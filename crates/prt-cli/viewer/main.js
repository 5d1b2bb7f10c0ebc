// prt view: the scene of a bake folder lit by its compressed transfer volume, on the GPU.
//
// Per sky change: the raw basis (324-D per basis node) is lit by prt-shaders' lighting pass into
// SH9 RGB per node; a voxel pass evaluates Σ_l c_l(x) b̃_l(x) with prt-shaders' reconstruction at
// every valid voxel centre (what `prt render --method mbd` samples). Kept volumes (reference,
// BPCA, CPCA) go through the same lighting pass with rank 1 over the voxel grid. Each pixel then
// samples the result trilinearly over valid voxels (value·valid and valid, divided) and shows
// emission + albedo/π · E(n), tone-mapped like prt-render (exposure, ACES fit, sRGB).
//
// This module holds the viewer's state and what drives frames: the controls (or, with ?size=N,
// one captured frame and an optional benchmark) and the redraw loop.

import {
  CAPTURE, PARAMS, checkGl, fail, fetchBytes, fetchJson, intParam, numberParam, positiveParam,
  showError,
} from './page.js';
import { parseMesh } from './formats.js';
import { compilePrograms } from './gl.js';
import { LIT_GROUPS } from './shaders.js';
import { orbit, rotateSky, scale3, sub } from './math.js';
import { containerLayout, loadMethods } from './methods.js';
import { autoExposure, createRenderer, drawHdr, ensureLit, lightShown, sync, toneMap } from './draw.js';

async function main() {
  const canvas = document.getElementById('canvas');
  if (CAPTURE) sizeForCapture(canvas);
  const gl = webgl2(canvas);
  const [mesh, views, skies, manifest] = await Promise.all([
    fetchBytes('bake/scene.mesh').then(parseMesh), fetchJson('views.json'), fetchJson('skies.json'),
    fetchJson('bake/mbd/manifest.json'),
  ]);
  if (views.length === 0) fail('the scene has no views (no triangles?)');
  const container = containerLayout(manifest);
  const programs = await compilePrograms(gl, container.rank, container.bricked);
  const methods = await loadMethods(gl, container);
  const renderer = createRenderer(gl, canvas, programs, methods, mesh);
  const state = initialState(views, skies, methods);
  fillControls(state, views, skies, methods);
  const frame = frameDrawer(renderer, state, skies, container.rank);
  if (CAPTURE) capture(renderer, state, skies, frame);
  else interact(renderer, state, views, frame);
}

function sizeForCapture(canvas) {
  document.body.classList.add('capture');
  const size = intParam('size', 1, 8192);
  canvas.width = canvas.height = size;
  canvas.style.width = canvas.style.height = `${size}px`;
}

// The canvas's WebGL2 context, with what the passes need checked.
function webgl2(canvas) {
  const gl = canvas.getContext('webgl2', { antialias: false, preserveDrawingBuffer: true });
  if (!gl) fail('this browser has no WebGL2');
  if (!gl.getExtension('EXT_color_buffer_float')) fail('WebGL2 without EXT_color_buffer_float: cannot render to float textures');
  if (gl.getParameter(gl.MAX_DRAW_BUFFERS) < LIT_GROUPS) fail(`the voxel pass needs ${LIT_GROUPS} draw buffers; this WebGL2 has ${gl.getParameter(gl.MAX_DRAW_BUFFERS)}`);
  // The volumes are tightly packed: a one-channel row (R8: x bytes, R16F: 2x) is not a multiple
  // of WebGL's default 4-byte row alignment when the grid's x size is not a multiple of 4.
  gl.pixelStorei(gl.UNPACK_ALIGNMENT, 1);
  return gl;
}

// ---------------------------------------------------------------- state and controls

// What the frame shows, from the URL's parameters (checked) or the defaults.
function initialState(views, skies, methods) {
  const state = {
    camera: intParam('camera', 0, views.length - 1) ?? 0,
    sky: intParam('sky', 0, skies.length - 1) ?? 0,
    rotate: numberParam('rotate') ?? 0,
    view: null,
    method: 'mbd',
    diff: false,
    diffScale: 8,
    exposure: null, // null: automatic at the next frame
    litFor: new Map(), // method name → the sky it is lit for
  };
  if (PARAMS.has('method')) {
    state.method = PARAMS.get('method');
    if (!methods.has(state.method)) {
      fail(`method=${state.method} is not in this bake (have: ${[...methods.keys()].join(', ')})`);
    }
  }
  state.diff = PARAMS.get('diff') === '1';
  state.diffScale = positiveParam('diffScale') ?? state.diffScale;
  if (state.diff && !methods.has('reference')) fail('diff=1 needs the reference volume (bake with --keep-volumes always)');
  state.exposure = positiveParam('exposure');
  state.view = { ...views[state.camera] };
  return state;
}

const ui = (id) => document.getElementById(id);

function fillControls(state, views, skies, methods) {
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
}

const currentSky = (state, skies) => rotateSky(skies[state.sky].sh, state.rotate);

// ---------------------------------------------------------------- frames

// Draws `state` (lit first if its sky changed) and shows the times in the stats box.
function frameDrawer(renderer, state, skies, rank) {
  const { gl, canvas } = renderer;
  let lastLightMs = 0;
  return () => {
    const t0 = performance.now();
    const skySh = currentSky(state, skies);
    const lightMs = lightShown(renderer, state, skySh);
    drawHdr(renderer, state, skySh);
    if (state.exposure === null) state.exposure = autoExposure(renderer);
    toneMap(renderer, state.exposure);
    sync(gl);
    const frameMs = performance.now() - t0;
    if (lightMs > 0) lastLightMs = lightMs;
    ui('exposure').value = Math.log2(state.exposure);
    ui('exposureValue').textContent = Math.log2(state.exposure).toFixed(2);
    ui('stats').textContent = `frame ${frameMs.toFixed(1)} ms\nlight ${lastLightMs.toFixed(1)} ms` +
      ` (last)\n${canvas.width}×${canvas.height}, rank ${rank}\n${gl.getParameter(gl.RENDERER)}`;
  };
}

// ?size=N: one frame, then the title says whether it got drawn (what tests and screenshots wait
// for).
function capture(renderer, state, skies, frame) {
  frame();
  const bench = intParam('bench', 0, 1000) ?? 0;
  if (bench > 0) runBench(renderer, state, skies, frame, bench);
  checkGl(renderer.gl, 'drawing the frame');
  document.title = 'ready';
}

// ?bench=N: times N steps of each kind at the server's wall clock, for docs/results.md: a frame
// whose sky turned (light + draw), a frame with the sky still (draw only), and the lighting
// pass alone. Each mark is a synchronous request, so the server's clock sees each step end.
function runBench(renderer, state, skies, frame, bench) {
  const mark = (label) => {
    const request = new XMLHttpRequest();
    request.open('GET', `bench?${encodeURIComponent(label)}`, false);
    request.send();
  };
  const { width } = renderer.canvas;
  const rotate = state.rotate;
  mark('start');
  for (let i = 0; i < bench; i++) {
    state.rotate = rotate + i + 1;
    frame();
    mark(`frame with the sky turning (${state.method}, ${width}²)`);
  }
  for (let i = 0; i < bench; i++) {
    frame();
    mark(`frame with the sky still (${state.method}, ${width}²)`);
  }
  for (let i = 0; i < bench; i++) {
    state.litFor.clear();
    ensureLit(renderer, state.litFor, state.method, currentSky(state, skies), 'bench');
    sync(renderer.gl);
    mark(`lighting pass (${state.method})`);
  }
  mark('done');
  state.rotate = rotate;
  state.litFor.clear();
  frame();
}

// ---------------------------------------------------------------- interactive

// Redraws on demand: controls, the pointer and resizing mark the frame dirty.
function interact(renderer, state, views, frame) {
  const { gl, canvas } = renderer;
  let dirty = true;
  const redraw = () => { dirty = true; };
  const resize = () => {
    const side = Math.max(128, Math.min(window.innerWidth - 270, window.innerHeight - 4));
    if (canvas.width !== side) { canvas.width = canvas.height = side; redraw(); }
  };
  window.addEventListener('resize', resize);
  resize();
  listenToControls(state, views, redraw);
  listenToPointer(canvas, state, renderer.scene, redraw);
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

function listenToControls(state, views, redraw) {
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
}

// Drag: orbit about the point the view looks at, at the scene centre's distance. Wheel: dolly.
function listenToPointer(canvas, state, scene, redraw) {
  let drag = null;
  canvas.addEventListener('pointerdown', (e) => { drag = [e.clientX, e.clientY]; canvas.setPointerCapture(e.pointerId); });
  canvas.addEventListener('pointerup', () => { drag = null; });
  canvas.addEventListener('pointermove', (e) => {
    if (!drag) return;
    const [dx, dy] = [e.clientX - drag[0], e.clientY - drag[1]];
    drag = [e.clientX, e.clientY];
    state.view = orbit(state.view, scene.centre, -dx * 0.01, -dy * 0.01);
    redraw();
  });
  canvas.addEventListener('wheel', (e) => {
    e.preventDefault();
    const v = state.view;
    const step = Math.sign(e.deltaY) * 0.05 * scene.size;
    state.view = { ...v, position: sub(v.position, scale3(v.forward, step)) };
    redraw();
  }, { passive: false });
}

main().catch((e) => showError(e && e.message ? e.message : e));
