//! A finished tile's files from untrusted bytes (`prt_bake::tiles::decode_tile`) under a fixed plan of
//! the built-in Cornell box (4³ voxels in two tiles with a halo of 1). The first byte picks the
//! tile (low bits) and the mode (high bit): `tile.json`, `transfer.f32` and `valid.u8` as they
//! come (`[u16 json length][json][u32 transfer length][transfer][valid]`), or a payload of the
//! right size made from the input under a `tile.json` with the plan's fingerprint and the
//! payload's checksums, so that the payload's checks are reached. Any input gives a typed error
//! or a tile of the plan's size with finite values and 0 / 1 validity.
#![no_main]

use std::sync::OnceLock;

use libfuzzer_sys::fuzz_target;
use prt_bake::tiles::{
    TILE_FORMAT, TILE_VERSION, TileChecksums, TileData, TileError, TileFingerprint, TilePlan,
    TileStats, decode_tile, plan_tiles,
};
use prt_bake::{BakeConfig, SceneInput};
use prt_texture::Limits;

fn plan() -> &'static TilePlan {
    static PLAN: OnceLock<TilePlan> = OnceLock::new();
    PLAN.get_or_init(|| {
        let config = BakeConfig {
            resolution: 4,
            rays_per_voxel: 12,
            cache_rays: 4,
            ..BakeConfig::default()
        };
        plan_tiles(&SceneInput::cornell_box(), None, &config, [2, 1, 1], 1).expect("the plan")
    })
}

/// 64-bit FNV-1a as `fnv1a64:HEX`, the checksum tile.json records.
fn fnv1a64(bytes: &[u8]) -> String {
    let mut hash = 0xcbf2_9ce4_8422_2325u64;
    for &b in bytes {
        hash = (hash ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3);
    }
    format!("fnv1a64:{hash:016x}")
}

fn take<'a>(data: &mut &'a [u8], n: usize) -> &'a [u8] {
    let (head, rest) = data.split_at(n.min(data.len()));
    *data = rest;
    head
}

fn check(result: Result<TileData, TileError>, plan: &TilePlan, index: usize) {
    let Ok(tile) = result else {
        return;
    };
    let n = plan.tiles[index].traced.len();
    assert_eq!(tile.transfer.len(), n * 324);
    assert_eq!(tile.valid.len(), n);
    assert!(tile.transfer.iter().all(|x| x.is_finite()));
    assert_eq!(tile.stats.index, index);
    assert_eq!(
        tile.stats.fingerprint,
        TileFingerprint::of(plan, index).expect("a fingerprint")
    );
}

fuzz_target!(|data: &[u8]| {
    let Some((&head, mut rest)) = data.split_first() else {
        return;
    };
    let plan = plan();
    let limits = Limits::small();
    let index = usize::from(head & 0x7f) % plan.tiles.len();
    if head & 0x80 == 0 {
        let json_len = take(&mut rest, 2);
        let json_len = usize::from(u16::from_le_bytes([
            json_len.first().copied().unwrap_or(0),
            json_len.get(1).copied().unwrap_or(0),
        ]));
        let json = take(&mut rest, json_len);
        let transfer_len = take(&mut rest, 4);
        let mut len = [0u8; 4];
        len[..transfer_len.len()].copy_from_slice(transfer_len);
        let transfer = take(&mut rest, u32::from_le_bytes(len) as usize);
        check(
            decode_tile(plan, index, json, transfer, rest, &limits),
            plan,
            index,
        );
        return;
    }
    if rest.is_empty() {
        return;
    }
    let n = plan.tiles[index].traced.len();
    let transfer: Vec<u8> = rest.iter().copied().cycle().take(n * 324 * 4).collect();
    let valid: Vec<u8> = rest
        .iter()
        .rev()
        .cycle()
        .take(n)
        .map(|&b| if b == 0xff { 2 } else { b & 1 })
        .collect();
    let stats = TileStats {
        format: TILE_FORMAT.into(),
        version: TILE_VERSION,
        index,
        fingerprint: TileFingerprint::of(plan, index).expect("a fingerprint"),
        checksums: TileChecksums {
            transfer: fnv1a64(&transfer),
            valid: fnv1a64(&valid),
        },
        voxels: n,
        invalid_voxels: 0,
        skipped_voxels: 0,
        rays_per_voxel: 12,
        voxel_rays: 0,
        cache_rays: 0,
        cache_points: 0,
        cache_evaluated: 0,
    };
    let json = serde_json::to_vec(&stats).expect("tile.json");
    check(
        decode_tile(plan, index, &json, &transfer, &valid, &limits),
        plan,
        index,
    );
});
