// Vectors (3-element arrays), the camera's projection and orbit, and the sky's SH.

import { LIT_GROUPS } from './shaders.js';

export const sub = (a, b) => a.map((v, i) => v - b[i]);
export const add = (a, b) => a.map((v, i) => v + b[i]);
export const scale3 = (a, s) => a.map((v) => v * s);
export const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
export const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
export const normalize = (a) => scale3(a, 1 / Math.hypot(...a));

// Column-major view-projection of a pinhole (prt_trace::PinholeView) for a given aspect.
export function viewProjection(camera, aspect, near, far) {
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

// `view` orbited about the point it looks at, at the distance of `centre`: `yaw` radians about
// +Y, then `pitch` about its right axis unless that comes within about 11° of a pole.
export function orbit(view, centre, yaw, pitch) {
  const distance = Math.hypot(...sub(centre, view.position));
  const target = add(view.position, scale3(view.forward, distance));
  let offset = sub(view.position, target);
  const c = Math.cos(yaw);
  const s = Math.sin(yaw);
  offset = [c * offset[0] + s * offset[2], offset[1], -s * offset[0] + c * offset[2]];
  const right = normalize(cross(scale3(offset, -1), [0, 1, 0]));
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
  return { ...view, position, forward, up: cross(r, forward) };
}

// A sky turned by `degrees` about +Y, as Sky::rotated_about_y: the turned sky's radiance towards
// R ω is the original's towards ω. In prt's SH (Y_1 ∝ -x, Y_3 ∝ -z, Y_5 ∝ -xy, Y_7 ∝ -yz,
// Y_4 ∝ xz, Y_8 ∝ z² - x²) the pairs (1, 3) and (5, 7) turn by the angle, (4, 8) by twice it.
export function rotateSky(sh, degrees) {
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
export function packSky(sh) {
  const out = new Float32Array(4 * LIT_GROUPS);
  for (let c = 0; c < 3; c++) for (let j = 0; j < 9; j++) out[9 * c + j] = sh[c][j];
  return out;
}
