//! Any byte string given to the KTX2 reader gives a texture or a typed error: never a panic,
//! never an allocation beyond `Limits::small()`. A texture that parses re-serialises and
//! parses back to the same texture.
#![no_main]

use libfuzzer_sys::fuzz_target;
use prt_texture::{Ktx2Texture, Limits};

fuzz_target!(|data: &[u8]| {
    let limits = Limits::small();
    if let Ok(texture) = Ktx2Texture::from_bytes(data, &limits) {
        let bytes = texture.to_bytes().expect("a parsed texture serialises");
        let again = Ktx2Texture::from_bytes(&bytes, &limits).expect("our own output parses");
        assert_eq!(again, texture);
        for level in 0..texture.levels().len() {
            texture.level_f32(level).expect("parsed levels decode");
        }
    }
});
