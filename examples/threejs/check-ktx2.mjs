// Parses every KTX2 file of prt exports with ktx-parse (the parser three.js's KTX2Loader uses)
// and checks vkFormat, dimensions and level size against the layouts in docs/formats.md.
// Usage: node check-ktx2.mjs EXPORT_DIR... (folders written by `prt export --target ...`).
import { readFileSync, existsSync } from 'node:fs';
import { join } from 'node:path';
import { read } from 'ktx-parse';

const VK = { R8_UNORM: 9, R16G16B16A16_SFLOAT: 97, E5B9G9R9_UFLOAT_PACK32: 123 };
const BYTES = { 9: 1, 97: 8, 123: 4 };
let checked = 0;

function check( path, dims, vkFormat ) {
	const ktx = read( new Uint8Array( readFileSync( path ) ) );
	const got = [ ktx.pixelWidth, ktx.pixelHeight, ktx.pixelDepth ];
	if ( ktx.vkFormat !== vkFormat ) throw new Error( `${path}: vkFormat ${ktx.vkFormat}, expected ${vkFormat}` );
	if ( got.join() !== dims.join() ) throw new Error( `${path}: dims ${got}, expected ${dims}` );
	if ( ktx.levels.length !== 1 ) throw new Error( `${path}: ${ktx.levels.length} levels` );
	const size = dims[ 0 ] * dims[ 1 ] * dims[ 2 ] * BYTES[ vkFormat ];
	if ( ktx.levels[ 0 ].levelData.byteLength !== size ) throw new Error( `${path}: level of ${ktx.levels[ 0 ].levelData.byteLength} bytes, expected ${size}` );
	checked ++;
}

for ( const dir of process.argv.slice( 2 ) ) {
	const json = ( name ) => JSON.parse( readFileSync( join( dir, name ), 'utf8' ) );
	let grid;
	if ( existsSync( join( dir, 'irradiance_volume.json' ) ) ) {
		const doc = json( 'irradiance_volume.json' );
		grid = doc.grid.resolution;
		const [ x, y, z ] = grid;
		check( join( dir, doc.texture ), [ x, 2 * y, 3 * z ], VK[ doc.texel_format ] );
	} else if ( existsSync( join( dir, 'light_probe_grid.json' ) ) ) {
		const doc = json( 'light_probe_grid.json' );
		grid = doc.resolution;
		const [ x, y, z ] = grid;
		check( join( dir, doc.texture ), [ x, y, 7 * ( z + 2 ) ], VK.R16G16B16A16_SFLOAT );
	} else if ( existsSync( join( dir, 'sh.json' ) ) ) {
		const doc = json( 'sh.json' );
		grid = doc.grid.resolution;
		const [ x, y, z ] = grid;
		for ( const name of doc.l1.files ) check( join( dir, name ), grid, VK.R16G16B16A16_SFLOAT );
		check( join( dir, doc.l2.file ), [ x, y, 9 * z ], VK.R16G16B16A16_SFLOAT );
	} else {
		throw new Error( `${dir}: no prt export placement JSON` );
	}
	check( join( dir, 'validity.ktx2' ), grid, VK.R8_UNORM );
}
if ( checked === 0 ) throw new Error( 'no export folder given' );
console.log( `ktx-parse: ${checked} KTX2 files parsed with the stated vkFormat and dimensions` );
