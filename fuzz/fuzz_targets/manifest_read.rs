//! A container read from untrusted bytes: the input is split into a manifest and one KTX2 file
//! that the loader serves under every name. Any input gives a container or a typed error.
#![no_main]

use libfuzzer_sys::fuzz_target;
use prt_texture::Limits;
use prt_texture::container::LoadedContainer;

fuzz_target!(|data: &[u8]| {
    if data.len() < 2 {
        return;
    }
    let split = (usize::from(u16::from_le_bytes([data[0], data[1]])) + 2).min(data.len());
    let (manifest, texture) = (&data[2..split], &data[split..]);
    if let Ok(loaded) = LoadedContainer::decode(manifest, &Limits::small(), |_| Ok(texture.to_vec())) {
        for ((name, array), entry) in loaded.arrays.iter().zip(&loaded.manifest.arrays) {
            assert_eq!(name, &entry.name);
            assert_eq!(array.data.len(), array.nodes() * array.channels);
        }
    }
});
