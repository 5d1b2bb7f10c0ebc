//! A scene read from untrusted bytes through `Scene::load_gltf_slice`. An input starting like a
//! glTF document (`{`) or a GLB file (`glTF`) is loaded as it is, so the files of
//! prt-trace's `tests/good_scenes` and `tests/bad_scenes` are a seed corpus; any other input is
//! split into a JSON document and a binary buffer (a 1-byte tag, a 2-byte little-endian JSON
//! length, the JSON, the buffer) and packed into a GLB whose BIN chunk is the buffer. Any input
//! gives a scene or a typed error.
#![no_main]

use libfuzzer_sys::fuzz_target;
use prt_trace::{LoadOptions, Scene};

/// A GLB container holding `json` and, when not empty, `bin`, each padded to 4 bytes.
fn glb(json: &[u8], bin: &[u8]) -> Vec<u8> {
    let pad = |n: usize| n.div_ceil(4) * 4;
    let (json_len, bin_len) = (pad(json.len()), pad(bin.len()));
    let total = 12 + 8 + json_len + if bin.is_empty() { 0 } else { 8 + bin_len };
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(total as u32).to_le_bytes());
    out.extend_from_slice(&(json_len as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(json);
    out.resize(20 + json_len, b' ');
    if !bin.is_empty() {
        out.extend_from_slice(&(bin_len as u32).to_le_bytes());
        out.extend_from_slice(b"BIN\0");
        out.extend_from_slice(bin);
        out.resize(total, 0);
    }
    out
}

fuzz_target!(|data: &[u8]| {
    let options = LoadOptions {
        max_bytes: 1 << 20,
        max_triangles: 1 << 20,
        ..LoadOptions::default()
    };
    let packed;
    let bytes = if data.starts_with(b"{") || data.starts_with(b"glTF") {
        data
    } else {
        if data.len() < 3 {
            return;
        }
        let split = (usize::from(u16::from_le_bytes([data[1], data[2]])) + 3).min(data.len());
        packed = glb(&data[3..split], &data[split..]);
        &packed[..]
    };
    if let Ok(scene) = Scene::load_gltf_slice(bytes, None, &options) {
        assert_eq!(scene.triangles().len(), scene.material_ids().len());
        for (t, &m) in scene.triangles().iter().zip(scene.material_ids()) {
            assert!(t.iter().all(|v| v.is_finite()));
            assert!((m as usize) < scene.materials().len());
        }
        assert_eq!(scene.bounds().is_some(), !scene.triangles().is_empty());
    }
});
