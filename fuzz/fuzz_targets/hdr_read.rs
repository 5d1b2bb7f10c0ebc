//! Any byte string given to the Radiance HDR reader gives an image or a typed error. An image
//! that decodes re-encodes and decodes to the same pixels (RGBE is exact on decoded values).
#![no_main]

use libfuzzer_sys::fuzz_target;
use prt_texture::Limits;
use prt_texture::hdr::{decode_hdr, encode_hdr};

fuzz_target!(|data: &[u8]| {
    let limits = Limits::small();
    if let Ok(image) = decode_hdr(data, &limits) {
        let bytes = encode_hdr(&image).expect("decoded pixels are finite");
        let again = decode_hdr(&bytes, &limits).expect("our own output parses");
        assert_eq!(again, image);
    }
});
