//! Any byte string given to the EXR reader gives layers or a typed error (the `exr` crate's
//! own parser included), within `Limits::small()`.
#![no_main]

use libfuzzer_sys::fuzz_target;
use prt_texture::Limits;
use prt_texture::exr_io::decode_exr;

fuzz_target!(|data: &[u8]| {
    if let Ok(layers) = decode_exr(data, &Limits::small()) {
        for layer in &layers {
            assert_eq!(layer.data.len(), layer.channels * layer.width as usize * layer.height as usize);
        }
    }
});
