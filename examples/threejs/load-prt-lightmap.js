// Loads what `prt lightmap SCENE --engine threejs --out OUT` wrote into OUT/threejs: the scene
// (lightmap_scene.glb, the lightmap UVs as TEXCOORD_1, which GLTFLoader names uv1) with the
// irradiance lightmap (lightmap.ktx2, RGBA16F of E) as every material's lightMap on channel 1.
// three.js's lightMap holds irradiance: a pixel gets diffuseColor / π · texel.
import { LinearFilter } from 'three';
import { GLTFLoader } from 'three/addons/loaders/GLTFLoader.js';
import { KTX2Loader } from 'three/addons/loaders/KTX2Loader.js';

export async function loadPrtLightmap( renderer, url ) {

	const placement = await ( await fetch( `${url}/lightmap.json` ) ).json();
	const loader = new KTX2Loader().detectSupport( renderer ); // RGBA16F: no Basis transcoder
	const lightMap = await loader.loadAsync( `${url}/${placement.texture}` );
	loader.dispose();
	lightMap.channel = 1; // uv1 = TEXCOORD_1
	lightMap.minFilter = lightMap.magFilter = LinearFilter; // no mip levels: charts would bleed
	lightMap.generateMipmaps = false;
	lightMap.needsUpdate = true;

	const gltf = await new GLTFLoader().loadAsync( `${url}/${placement.scene}` );
	gltf.scene.traverse( ( object ) => {

		if ( ! object.isMesh ) return;
		object.material.lightMap = lightMap;
		object.material.lightMapIntensity = 1;
		object.material.needsUpdate = true;

	} );
	return gltf.scene;

}
