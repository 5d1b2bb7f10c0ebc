//! Any byte string given to the scene-mesh reader gives a scene or a typed error within the
//! limits; a scene read back encodes and decodes to the same triangles.
#![no_main]

use libfuzzer_sys::fuzz_target;
use prt_texture::Limits;
use prt_trace::mesh::{decode_mesh, encode_mesh};

fuzz_target!(|data: &[u8]| {
    let limits = Limits::small();
    if let Ok(scene) = decode_mesh(data, &limits) {
        let bytes = encode_mesh(&scene).expect("a decoded scene encodes");
        let again = decode_mesh(&bytes, &Limits::default()).expect("round trip");
        assert_eq!(again.triangles(), scene.triangles());
        assert_eq!(again.material_ids(), scene.material_ids());
    }
});
