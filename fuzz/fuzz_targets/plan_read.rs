//! A tiled bake's `plan.json` from untrusted bytes (`prt_bake::tiles::TilePlan::decode`): any input
//! gives a typed error or a plan whose tiles partition its lattice, that every tile's
//! fingerprint can be made for, and that reads back the same after writing.
#![no_main]

use libfuzzer_sys::fuzz_target;
use prt_bake::tiles::{TileFingerprint, TilePlan};
use prt_texture::Limits;

fuzz_target!(|data: &[u8]| {
    let limits = Limits::small();
    let Ok(plan) = TilePlan::decode(data, &limits) else {
        return;
    };
    let dims = plan.lattice_dims;
    let voxels: usize = dims.iter().product();
    assert!(voxels as u64 <= limits.max_bytes);
    let cores: usize = plan.tiles.iter().map(|t| t.core.len()).sum();
    assert_eq!(cores, voxels, "the cores partition the lattice");
    for (i, tile) in plan.tiles.iter().enumerate() {
        assert_eq!(tile.index, i);
        for k in 0..3 {
            assert!(tile.traced.min[k] <= tile.core.min[k]);
            assert!(tile.core.min[k] < tile.core.max[k]);
            assert!(tile.core.max[k] <= tile.traced.max[k]);
            assert!(tile.traced.max[k] <= dims[k]);
        }
        let fingerprint = TileFingerprint::of(&plan, i).expect("a fingerprint");
        assert_eq!(fingerprint.traced, tile.traced);
    }
    let bytes = serde_json::to_vec(&plan).expect("a plan serialises");
    assert_eq!(
        TilePlan::decode(&bytes, &limits).expect("it reads back"),
        plan
    );
});
