// Loads what `prt export BAKE --target threejs --out DIR` wrote as a three.js light probe grid.
// GridClass: LightProbeGridWebGL (WebGLRenderer) or LightProbeGrid (WebGPURenderer, after
// `await renderer.init()`). The atlas replaces grid.bake( renderer, scene ); no prt code runs.
import { LinearFilter } from 'three';
import { KTX2Loader } from 'three/addons/loaders/KTX2Loader.js';

export async function loadPrtProbeGrid( renderer, url, GridClass ) {

	const placement = await ( await fetch( `${url}/light_probe_grid.json` ) ).json();
	const loader = new KTX2Loader().detectSupport( renderer ); // RGBA16F: no Basis transcoder
	const atlas = await loader.loadAsync( `${url}/${placement.texture}` );
	loader.dispose();
	atlas.minFilter = atlas.magFilter = LinearFilter; // the atlas is sampled trilinearly
	atlas.generateMipmaps = false;
	atlas.needsUpdate = true;

	// One cell per probe, probes at cell centres (three.js >= 0.187): the baked box grown by
	// one voxel on every side, whose probes repeat the outermost baked voxels.
	const [ w, h, d ] = placement.size;
	const [ nx, ny, nz ] = placement.resolution;
	const grid = new GridClass( w, h, d, nx, ny, nz );
	grid.position.fromArray( placement.position );
	grid.updateBoundingBox();
	grid.texture = atlas;
	return grid;

}
