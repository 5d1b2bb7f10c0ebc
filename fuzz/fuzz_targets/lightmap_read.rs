//! A lightmap folder read from untrusted bytes: the input is split into a manifest, a UV file
//! and a KTX2 lightmap (two little-endian u16 lengths first). Any input gives a folder or a
//! typed error, and a folder holds what its manifest says.
#![no_main]

use libfuzzer_sys::fuzz_target;
use prt_lightmap::{LightmapFolder, LightmapManifest};
use prt_texture::Limits;

fuzz_target!(|data: &[u8]| {
    if data.len() < 4 {
        return;
    }
    let manifest_len = usize::from(u16::from_le_bytes([data[0], data[1]]));
    let uvs_len = usize::from(u16::from_le_bytes([data[2], data[3]]));
    let rest = &data[4..];
    let manifest_end = manifest_len.min(rest.len());
    let uvs_end = (manifest_end + uvs_len).min(rest.len());
    let (manifest, uvs, ktx2) = (
        &rest[..manifest_end],
        &rest[manifest_end..uvs_end],
        &rest[uvs_end..],
    );
    let Ok(manifest) = LightmapManifest::parse(manifest) else {
        return;
    };
    if let Ok(folder) = LightmapFolder::parse(manifest, ktx2, uvs, &Limits::small()) {
        let map = &folder.lightmap;
        let texels = (map.width * map.height) as usize;
        assert_eq!(map.irradiance.len(), 3 * texels);
        assert_eq!(map.coefficients.len(), map.basis.len());
        assert!(map.coefficients.iter().all(|c| c.len() == 3 * texels));
        assert!(map.irradiance.iter().all(|v| v.is_finite()));
        assert!(folder.uvs.iter().flatten().all(|p| p.is_finite()));
    }
});
