// The page half of crates/prt-cli/tests/threejs.rs: with a renderer and a prt probe grid that
// webgl.html / webgpu.html set up as the README shows, renders white Lambert test surfaces and
// the baked scene into a float render target (linear radiance, no tone mapping, no other light)
// and POSTs the pixels (little-endian f32 RGBA) back to the server that served the page.
//
// case.json (beside the export, written by the test): { gi, points: [ { p, n } ], scene: {
// mesh: JSON URL, size, camera: { position, forward, up, yfov, near, far } } }; for
// lightmap.html: { lightmap: URL of the export, size, camera }.
import * as THREE from 'three';

async function post( name, body ) {

	const response = await fetch( `/result/${name}`, { method: 'POST', body } );
	if ( ! response.ok ) throw new Error( `POST /result/${name}: ${response.status}` );

}

// Reports an error (and stops the test waiting) from anywhere in the page.
export function reportErrors() {

	const fail = ( what ) => post( 'error', String( what ) ).catch( () => {} );
	addEventListener( 'error', ( e ) => fail( e.error?.stack ?? e.message ) );
	addEventListener( 'unhandledrejection', ( e ) => fail( e.reason?.stack ?? e.reason ) );
	return fail;

}

function floatTarget( renderer, width, height ) {

	const options = { type: THREE.FloatType, format: THREE.RGBAFormat, depthBuffer: true };
	const target = renderer.isWebGPURenderer
		? new THREE.RenderTarget( width, height, options )
		: new THREE.WebGLRenderTarget( width, height, options );
	target.texture.minFilter = target.texture.magFilter = THREE.NearestFilter;
	target.texture.generateMipmaps = false;
	return target;

}

// RGBA f32 of the whole target, rows as the renderer returns them.
async function readPixels( renderer, target ) {

	const { width, height } = target;
	if ( renderer.isWebGPURenderer ) {

		const data = await renderer.readRenderTargetPixelsAsync( target, 0, 0, width, height );
		if ( ! ( data instanceof Float32Array ) ) throw new Error( `read back a ${data.constructor.name}` );
		return data;

	}

	const data = new Float32Array( 4 * width * height );
	renderer.readRenderTargetPixels( target, 0, 0, width, height, data );
	return data;

}

// One white Lambert triangle per point, in the plane through p normal to n (vertex normals n,
// front face towards n), each seen head-on by an orthographic camera through a 1 × 1 viewport
// at x = index of a one-row target: that pixel's centre lies on the camera axis, so its
// fragment is at p exactly and the grid is sampled at p + n · spacing / 2.
async function renderPoints( renderer, grid, points ) {

	const width = Math.max( 64, Math.ceil( points.length / 64 ) * 64 );
	const target = floatTarget( renderer, width, 1 );
	const scene = new THREE.Scene();
	scene.add( grid );
	const material = new THREE.MeshLambertMaterial( { color: 0xffffff } );
	const size = 1e-3; // inradius of the triangle
	const camera = new THREE.OrthographicCamera( - size / 8, size / 8, size / 8, - size / 8, size / 4, 4 * size );
	renderer.setRenderTarget( target );
	renderer.setClearColor( 0x000000, 0 );
	renderer.clear();
	const autoClear = renderer.autoClear;
	renderer.autoClear = false;
	target.scissorTest = true;
	for ( let i = 0; i < points.length; i ++ ) {

		const p = new THREE.Vector3().fromArray( points[ i ].p );
		const n = new THREE.Vector3().fromArray( points[ i ].n ).normalize();
		const a = new THREE.Vector3().crossVectors( n, Math.abs( n.y ) < 0.9 ? new THREE.Vector3( 0, 1, 0 ) : new THREE.Vector3( 1, 0, 0 ) ).normalize();
		const b = new THREE.Vector3().crossVectors( n, a );
		const s3 = Math.sqrt( 3 );
		const corners = [ [ 2, 0 ], [ - 1, s3 ], [ - 1, - s3 ] ].map( ( [ u, v ] ) => p.clone().addScaledVector( a, u * size ).addScaledVector( b, v * size ) );
		const geometry = new THREE.BufferGeometry();
		geometry.setAttribute( 'position', new THREE.Float32BufferAttribute( corners.flatMap( ( c ) => c.toArray() ), 3 ) );
		geometry.setAttribute( 'normal', new THREE.Float32BufferAttribute( [ ...n.toArray(), ...n.toArray(), ...n.toArray() ], 3 ) );
		const mesh = new THREE.Mesh( geometry, material );
		mesh.frustumCulled = false;
		scene.add( mesh );
		camera.position.copy( p ).addScaledVector( n, 2 * size );
		camera.up.copy( a );
		camera.lookAt( p );
		camera.updateMatrixWorld();
		target.viewport.set( i, 0, 1, 1 );
		target.scissor.set( i, 0, 1, 1 );
		renderer.setRenderTarget( target );
		renderer.render( scene, camera );
		scene.remove( mesh );
		geometry.dispose();

	}

	renderer.autoClear = autoClear;
	const pixels = await readPixels( renderer, target );
	renderer.setRenderTarget( null );
	target.dispose();
	return pixels.slice( 0, 4 * points.length );

}

// The baked scene (per material: albedo, emission, sidedness, flat triangles) from the camera
// `prt render --camera K` uses; the back of a single-sided surface is black, as in prt render.
async function renderScene( renderer, grid, spec ) {

	const mesh = await ( await fetch( spec.mesh ) ).json();
	const scene = new THREE.Scene();
	scene.add( grid );
	for ( const m of mesh.materials ) {

		const geometry = new THREE.BufferGeometry();
		geometry.setAttribute( 'position', new THREE.Float32BufferAttribute( m.positions, 3 ) );
		geometry.setAttribute( 'normal', new THREE.Float32BufferAttribute( m.normals, 3 ) );
		const lit = new THREE.MeshLambertMaterial( {
			color: new THREE.Color().setRGB( ...m.albedo, THREE.LinearSRGBColorSpace ),
			emissive: new THREE.Color().setRGB( ...m.emission, THREE.LinearSRGBColorSpace ),
			side: m.double_sided ? THREE.DoubleSide : THREE.FrontSide,
		} );
		scene.add( new THREE.Mesh( geometry, lit ) );
		if ( ! m.double_sided ) scene.add( new THREE.Mesh( geometry, new THREE.MeshBasicMaterial( { color: 0x000000, side: THREE.BackSide } ) ) );

	}

	return renderView( renderer, scene, spec.camera, spec.size );

}

// `scene` from `camera` ({ position, forward, up, yfov, near, far }) into a size × size float
// target; its RGBA f32 pixels.
async function renderView( renderer, scene, camera, size ) {

	const { position, forward, up, yfov, near, far } = camera;
	const view = new THREE.PerspectiveCamera( THREE.MathUtils.radToDeg( yfov ), 1, near, far );
	view.position.fromArray( position );
	view.up.fromArray( up );
	view.lookAt( new THREE.Vector3().fromArray( position ).add( new THREE.Vector3().fromArray( forward ) ) );
	view.updateMatrixWorld();
	const target = floatTarget( renderer, size, size );
	renderer.setRenderTarget( target );
	renderer.setClearColor( 0x000000, 0 );
	renderer.render( scene, view );
	const pixels = await readPixels( renderer, target );
	renderer.setRenderTarget( null );
	target.dispose();
	return pixels;

}

// Which renderer, backend and device drew: for the test's log.
async function describe( renderer ) {

	if ( renderer.isWebGPURenderer ) {

		const backend = renderer.backend.isWebGPUBackend ? 'WebGPU' : 'WebGL 2 fallback';
		const info = renderer.backend.isWebGPUBackend ? renderer.backend.device.adapterInfo : undefined;
		const adapter = info ? `, adapter ${info.vendor} ${info.architecture}${info.isFallbackAdapter ? ' (fallback)' : ''}` : '';
		return `WebGPURenderer, ${backend} backend${adapter}`;

	}

	const gl = renderer.getContext();
	const debug = gl.getExtension( 'WEBGL_debug_renderer_info' );
	return `WebGLRenderer, ${debug ? gl.getParameter( debug.UNMASKED_RENDERER_WEBGL ) : gl.getParameter( gl.RENDERER )}`;

}

export async function runCheck( renderer, grid, spec ) {

	renderer.toneMapping = THREE.NoToneMapping;
	const points = await renderPoints( renderer, grid, spec.points );
	await post( 'points', points );
	const pixels = await renderScene( renderer, grid, spec.scene );
	await post( 'scene', pixels );
	await post( 'done', await describe( renderer ) );

}

// lightmap.html: the scene load-prt-lightmap.js returned, lit by its lightmap only (no other
// light, no tone mapping), from the case's camera.
export async function runLightmapCheck( renderer, lightmapped, spec ) {

	renderer.toneMapping = THREE.NoToneMapping;
	const scene = new THREE.Scene();
	scene.add( lightmapped );
	await post( 'scene', await renderView( renderer, scene, spec.camera, spec.size ) );
	await post( 'done', await describe( renderer ) );

}
