// The volumes the viewer can show ("methods"): the MBD container and the kept volumes
// (reference, BPCA, CPCA), each a raw 324-D grid to light and the 7-tile voxel atlas the
// lighting pass ends in.

import { checkGl, fail, fetchBytes } from './page.js';
import { parseKtx2 } from './formats.js';
import {
  arrayTexture, drawSlices, drawVoxelSlices, grid, indirectionTexture, rangesTexture, setSampling,
  targetTexture,
} from './gl.js';
import { packSky } from './math.js';
import { LIT_GROUPS } from './shaders.js';

const TRANSFER_DIM = 324;
// Texel groups of one kept volume's 324 channels (nine parts of 36).
const BASIS_GROUPS = 81;

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

async function loadIndirection(gl, folder, bricks) {
  if (!/^[A-Za-z0-9_.-]+\.ktx2$/.test(bricks.indirection)) fail(`${folder}: bad file name ${bricks.indirection}`);
  return indirectionTexture(gl, bricks, await fetchBytes(`bake/${folder}/${bricks.indirection}`));
}

// What the MBD container's manifest promises, checked before anything is fetched: its rank, its
// two hat grids and whether its coefficients are in bricks.
export function containerLayout(manifest) {
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
  return { manifest, rank, coefficientKernel, basisKernel, bricked };
}

// Every method of the bake by name: 'mbd', then the kept volumes if the bake kept them.
export async function loadMethods(gl, container) {
  const methods = new Map([['mbd', await loadMbd(gl, container)]]);
  const kept = await fetch('bake/volumes/manifest.json');
  if (kept.ok) {
    for (const [name, method] of await loadKeptVolumes(gl, await kept.json())) methods.set(name, method);
  }
  return methods;
}

async function loadMbd(gl, { manifest, rank, coefficientKernel, basisKernel }) {
  const [coefficients, basis, validity] = await Promise.all(
    ['coefficients', 'basis', 'validity'].map((n) => loadArray(gl, 'mbd', manifest, n)));
  if (!coefficients.linear) fail('the coefficient volume needs float filtering (OES_texture_float_linear)');
  if (coefficients.bricks) coefficients.indirection = await loadIndirection(gl, 'mbd', coefficients.bricks);
  const voxels = validity.size;
  const litTiles = [LIT_GROUPS, rank, 1];
  const basisNodes = basisKernel.nodes;
  const { domain_min: lo, domain_max: hi } = coefficientKernel;
  const step = coefficientKernel.nodes.map((n, k) => (n > 1 ? (hi[k] - lo[k]) / (n - 1) : 0));
  if (coefficientKernel.nodes.some((n, k) => n !== voxels[k])) fail('mbd: validity and coefficient grids differ');
  return {
    rank,
    voxels,
    validity,
    basis,
    basisRanges: rangesTexture(gl, basis.scale, basis.bias),
    basisGrid: grid(basisKernel.domain_min, basisKernel.domain_max, basisNodes, basis.tiles),
    litGrid: grid(basisKernel.domain_min, basisKernel.domain_max, basisNodes, litTiles),
    lit: targetTexture(gl, basisNodes.map((n, k) => n * litTiles[k])),
    coefficients,
    coefficientGrid: grid(lo, hi, coefficientKernel.nodes, coefficients.tiles),
    step,
    atlas: targetTexture(gl, [voxels[0], voxels[1], LIT_GROUPS * voxels[2]]),
    atlasGrid: grid(lo, hi, voxels, [1, 1, LIT_GROUPS]),
    offset: step.map((s) => 0.5 * s),
  };
}

// The kept volumes (`--keep-volumes`) as [name, method] pairs; they share one validity grid.
async function loadKeptVolumes(gl, keptManifest) {
  const validity = await loadArray(gl, 'volumes', keptManifest, 'validity');
  const voxels = validity.size;
  const lo = keptManifest.attributes.bounds_min;
  const hi = keptManifest.attributes.bounds_max;
  const edge = voxels.map((n, k) => (hi[k] - lo[k]) / n);
  const first = lo.map((v, k) => v + 0.5 * edge[k]);
  const last = hi.map((v, k) => v - 0.5 * edge[k]);
  const kept = [];
  for (const name of keptManifest.attributes.volumes || []) {
    const { texture, scale, bias } = await keptBasis(gl, keptManifest, name, voxels);
    kept.push([name, {
      rank: 1,
      voxels,
      validity,
      basis: { texture },
      basisRanges: rangesTexture(gl, scale, bias),
      basisGrid: grid(first, last, voxels, [9, 9, 1]),
      litGrid: grid(first, last, voxels, [LIT_GROUPS, 1, 1]),
      lit: targetTexture(gl, [LIT_GROUPS * voxels[0], voxels[1], voxels[2]]),
      atlas: targetTexture(gl, [voxels[0], voxels[1], LIT_GROUPS * voxels[2]]),
      atlasGrid: grid(first, last, voxels, [1, 1, LIT_GROUPS]),
      offset: edge.map((e) => 0.5 * e),
    }]);
  }
  return kept;
}

// Nine 36-channel parts of a kept volume become one atlas of 81 groups, tile (group mod 9,
// part); the parts are f16 as they are (scale 1, bias 0).
async function keptBasis(gl, keptManifest, name, voxels) {
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
  return { texture, scale, bias };
}

// ---------------------------------------------------------------- lighting

// The lighting pass of method `m` for a sky: raw basis → lit basis → voxel atlas.
// `emptyVao`: the fullscreen passes draw without attributes.
export function light(gl, programs, emptyVao, m, skySh) {
  gl.bindVertexArray(emptyVao);
  const lightProgram = programs.light.get(m.rank).use()
    .grid('u_mbd_basis', m.basisGrid).grid('u_mbd_lit', m.litGrid)
    .vec4s('u_mbd_sky', packSky(skySh))
    .texture('u_mbd_basis_texture', 0, gl.TEXTURE_3D, m.basis.texture)
    .texture('u_mbd_basis_ranges', 1, gl.TEXTURE_2D, m.basisRanges);
  const litSize = m.litGrid.nodes.map((n, k) => n * m.litGrid.tiles[k]);
  drawSlices(gl, lightProgram, m.lit, litSize, 'u_mbd_slice');
  const voxel = m.coefficients ? mbdVoxelPass(gl, programs.mbdVoxel, m) : keptVoxelPass(gl, programs.keptVoxel, m);
  voxel.texture('u_validity', 2, gl.TEXTURE_3D, m.validity.texture);
  gl.uniform3iv(gl.getUniformLocation(voxel.p, 'u_voxels'), m.voxels);
  gl.uniform2f(gl.getUniformLocation(voxel.p, 'u_validity_range'), m.validity.scale[0], m.validity.bias[0]);
  drawVoxelSlices(gl, voxel, m.atlas, m.voxels);
}

// The MBD voxel pass, bound: Σ c_l b̃_l from the coefficients and the lit basis.
function mbdVoxelPass(gl, prog, m) {
  const voxel = prog.use()
    .grid('u_mbd_coefficients', m.coefficientGrid).grid('u_mbd_lit', m.litGrid)
    .vec4s('u_mbd_coefficient_scale', m.coefficients.scale)
    .vec4s('u_mbd_coefficient_bias', m.coefficients.bias)
    .texture('u_mbd_coefficient_texture', 0, gl.TEXTURE_3D, m.coefficients.texture)
    .texture('u_mbd_lit_texture', 1, gl.TEXTURE_3D, m.lit)
    .vec3('u_node_step', m.step);
  const b = m.coefficients.bricks;
  if (b) {
    voxel.vec4s('u_mbd_bricks.grid', [...b.grid, b.size]).vec4s('u_mbd_bricks.atlas', [...b.atlas, 0])
      .texture('u_mbd_coefficient_indirection', 3, gl.TEXTURE_3D, m.coefficients.indirection);
  }
  return voxel;
}

// A kept volume's voxel pass, bound: its lit voxels are already the values.
function keptVoxelPass(gl, prog, m) {
  return prog.use().texture('u_lit_voxels', 0, gl.TEXTURE_3D, m.lit);
}
