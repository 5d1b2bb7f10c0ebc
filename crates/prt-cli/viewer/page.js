// The page around the viewer: its error box, WebGL error checks, fetches that fail on the page,
// and the URL's parameters.

export const PARAMS = new URLSearchParams(location.search);
// `?size=N`: one fixed frame for screenshots (tests, benchmarks), without the controls.
export const CAPTURE = PARAMS.has('size');

// index.html's, defined there so that a module that cannot be fetched or parsed shows too.
export const showError = window.showError;

export function fail(message) {
  showError(message);
  throw new Error(message);
}

// WebGL reports a failed call only through getError (and the console): fail on the page instead
// of drawing black.
export function checkGl(gl, what) {
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
export const fetchJson = async (url) => (await fetchOk(url)).json();
export const fetchText = async (url) => (await fetchOk(url)).text();
export const fetchBytes = async (url) => (await fetchOk(url)).arrayBuffer();

// The URL's `name` as an integer in lo..hi, or null without one.
export function intParam(name, lo, hi) {
  if (!PARAMS.has(name)) return null;
  const v = Number(PARAMS.get(name));
  if (!Number.isInteger(v) || v < lo || v > hi) fail(`${name}=${PARAMS.get(name)} is not in ${lo}..${hi}`);
  return v;
}

// The URL's `name` as a finite number, or null without one.
export function numberParam(name) {
  if (!PARAMS.has(name)) return null;
  const v = Number(PARAMS.get(name));
  if (!Number.isFinite(v)) fail(`${name}=${PARAMS.get(name)} is not a number`);
  return v;
}

// The URL's `name` as a finite number above 0, or null without one.
export function positiveParam(name) {
  if (!PARAMS.has(name)) return null;
  const v = Number(PARAMS.get(name));
  if (!(v > 0 && Number.isFinite(v))) fail(`${name}=${PARAMS.get(name)} is not a positive number`);
  return v;
}
