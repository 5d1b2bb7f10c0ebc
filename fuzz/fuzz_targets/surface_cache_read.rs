//! A plan's shared surface cache from untrusted bytes (`prt_bake::tiles::decode_surface_cache`)
//! under a fixed plan of the built-in Cornell box (4³ voxels in two tiles). The first byte picks
//! the mode: the file as it comes, or a cache encoded for the plan (`encode_surface_cache`, so
//! that the header, checksum and payload checks pass) whose entries and values are made from
//! the input, which must read back as it was written, or be refused naming a non-finite value.
#![no_main]

use std::path::Path;
use std::sync::OnceLock;
use std::time::Duration;

use libfuzzer_sys::fuzz_target;
use prt_bake::tiles::{TilePlan, decode_surface_cache, encode_surface_cache, plan_tiles};
use prt_bake::{BakeConfig, SceneInput};
use prt_texture::Limits;
use prt_trace::expert::SharedSurfaceCache;

fn plan() -> &'static TilePlan {
    static PLAN: OnceLock<TilePlan> = OnceLock::new();
    PLAN.get_or_init(|| {
        let config = BakeConfig {
            resolution: 4,
            rays_per_voxel: 12,
            cache_rays: 4,
            ..BakeConfig::default()
        };
        plan_tiles(&SceneInput::cornell_box(), None, &config, [2, 1, 1], 0).expect("the plan")
    })
}

fuzz_target!(|data: &[u8]| {
    let Some((&head, rest)) = data.split_first() else {
        return;
    };
    let plan = plan();
    let limits = Limits::small();
    let path = Path::new("surface_cache.bin");
    if head & 1 == 0 {
        if let Ok(cache) = decode_surface_cache(plan, rest, path, &limits) {
            assert!(
                cache
                    .values
                    .iter()
                    .flatten()
                    .flatten()
                    .all(|x| x.is_finite())
            );
            assert_eq!(cache.cache_rays, plan.config.cache_rays);
        }
        return;
    }
    // Entries from the input: each byte's low bit says whether it is evaluated, its value the
    // next 36 bytes (cycled) as f32.
    let entries = 2 * (rest.len() / 2).min(64);
    let mut floats = rest.chunks(4).cycle().map(|c| {
        let mut b = [0u8; 4];
        b[..c.len()].copy_from_slice(c);
        f32::from_le_bytes(b)
    });
    let values: Vec<Option<[f32; 9]>> = rest
        .iter()
        .take(entries)
        .map(|&b| (b & 1 == 1).then(|| std::array::from_fn(|_| floats.next().unwrap_or(0.0))))
        .collect();
    let cache = SharedSurfaceCache {
        spacing: 0.25,
        layout: u64::from(head),
        seed: plan.config.seed,
        cache_rays: plan.config.cache_rays,
        rays: 0,
        visibility_rays: 0,
        time: Duration::ZERO,
        values,
    };
    let bytes = encode_surface_cache(plan, &cache).expect("the plan's tiles");
    match decode_surface_cache(plan, &bytes, path, &limits) {
        Ok(read) => assert_eq!(read.values, cache.values),
        Err(error) => assert!(
            cache
                .values
                .iter()
                .flatten()
                .flatten()
                .any(|x| !x.is_finite()),
            "{error}"
        ),
    }
});
