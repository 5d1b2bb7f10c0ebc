// The files the viewer reads itself: the scene mesh and KTX2 (only what prt writes; both in
// docs/formats.md).

import { fail } from './page.js';

// ---------------------------------------------------------------- scene mesh

// Little-endian reads from `buffer` that fail, naming the part, past its end.
function meshReader(buffer) {
  const view = new DataView(buffer);
  const r = { at: 0 };
  r.need = (bytes, what) => {
    if (r.at + bytes > buffer.byteLength) fail(`scene.mesh is truncated in its ${what}`);
  };
  r.u32 = (what) => { r.need(4, what); const v = view.getUint32(r.at, true); r.at += 4; return v; };
  r.f32s = (n, what) => {
    r.need(4 * n, what);
    const out = new Float32Array(n);
    for (let i = 0; i < n; i++) out[i] = view.getFloat32(r.at + 4 * i, true);
    r.at += 4 * n;
    return out;
  };
  r.u32s = (n, what) => {
    r.need(4 * n, what);
    const out = new Uint32Array(buffer.slice(r.at, r.at + 4 * n));
    r.at += 4 * n;
    return out;
  };
  r.skipName = (what) => {
    const len = r.u32(what);
    if (len === 0xffffffff) return;
    const padded = Math.ceil(len / 4) * 4;
    r.need(padded, what);
    r.at += padded;
  };
  return r;
}

export function parseMesh(buffer) {
  const r = meshReader(buffer);
  r.need(8, 'magic');
  const magic = new Uint8Array(buffer, 0, 8);
  if (String.fromCharCode(...magic) !== 'PRTMESH\0') fail('scene.mesh is not a prt scene mesh');
  r.at = 8;
  const version = r.u32('header');
  if (version !== 1) fail(`scene.mesh has version ${version}; this viewer reads version 1`);
  const [vertices, triangles, materials] = [r.u32('header'), r.u32('header'), r.u32('header')];
  r.u32('header'); r.u32('header'); // cameras (the views come from /views.json), reserved
  if (28 * vertices + 12 * triangles > buffer.byteLength) fail('scene.mesh counts exceed its size');
  const positions = r.f32s(3 * vertices, 'positions');
  const normals = r.f32s(3 * vertices, 'normals');
  const vertexMaterials = r.u32s(vertices, 'vertex materials');
  const indices = r.u32s(3 * triangles, 'indices');
  const table = [];
  for (let m = 0; m < materials; m++) {
    const albedo = r.f32s(3, 'materials');
    const emission = r.f32s(3, 'materials');
    const flags = r.u32('materials');
    r.skipName('materials');
    table.push({ albedo, emission, doubleSided: (flags & 1) ? 1 : 0 });
  }
  for (const i of indices) if (i >= vertices) fail(`scene.mesh has an index ${i} ≥ ${vertices} vertices`);
  return { positions, normals, ...vertexAttributes(positions, vertexMaterials, table), indices };
}

// Each vertex's material as attributes (the shaders draw flat per-vertex materials), and the
// bounds of the positions.
function vertexAttributes(positions, vertexMaterials, table) {
  const vertices = vertexMaterials.length;
  const albedo = new Float32Array(3 * vertices);
  const emission = new Float32Array(3 * vertices);
  const doubleSided = new Float32Array(vertices);
  const lo = [Infinity, Infinity, Infinity];
  const hi = [-Infinity, -Infinity, -Infinity];
  for (let v = 0; v < vertices; v++) {
    const m = table[vertexMaterials[v]];
    if (!m) fail(`scene.mesh vertex ${v} names material ${vertexMaterials[v]} of ${table.length}`);
    albedo.set(m.albedo, 3 * v);
    emission.set(m.emission, 3 * v);
    doubleSided[v] = m.doubleSided;
    for (let k = 0; k < 3; k++) {
      lo[k] = Math.min(lo[k], positions[3 * v + k]);
      hi[k] = Math.max(hi[k], positions[3 * v + k]);
    }
  }
  return { albedo, emission, doubleSided, bounds: { lo, hi } };
}

// ---------------------------------------------------------------- KTX2

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
export function parseKtx2(buffer, name, encoding, size, singleChannel) {
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
