//! A distributed merge's partial file from untrusted bytes
//! (`prt_bake::tiles::MergeContext::decode_partial`) under a fixed plan of the built-in Cornell
//! box (8³ voxels in two tiles, 3 basis nodes per axis, rank 2) and a fixed basis. The first
//! byte picks the stage (coarse, sweep-1, coefficients), the tile and the mode (high bit): the
//! file as it comes, or a payload of the right size made from the input under a header with the
//! right fingerprint and checksum, so that the payload's checks are reached. Any input gives a
//! typed error or a partial of the stage and tile asked for.
#![no_main]

use std::path::Path;
use std::sync::OnceLock;

use libfuzzer_sys::fuzz_target;
use ndarray::Array3;
use prt_bake::tiles::{
    BasisState, MERGE_FILE_VERSION, MERGE_MAGIC, MergeContext, MergeStage, PARTIAL_FORMAT,
    TilePlan, plan_tiles,
};
use prt_bake::{BakeConfig, SceneInput};
use prt_texture::Limits;

const SWEEPS: usize = 1;

fn setup() -> &'static (TilePlan, BakeConfig) {
    static SETUP: OnceLock<(TilePlan, BakeConfig)> = OnceLock::new();
    SETUP.get_or_init(|| {
        let config = BakeConfig {
            resolution: 8,
            rays_per_voxel: 12,
            cache_rays: 4,
            rank: 2,
            basis_nodes: 3,
            ..BakeConfig::default()
        };
        let plan =
            plan_tiles(&SceneInput::cornell_box(), None, &config, [2, 1, 1], 1).expect("the plan");
        (plan, config)
    })
}

/// 64-bit FNV-1a as `fnv1a64:HEX`, the checksum the header records.
fn fnv1a64(bytes: &[u8]) -> String {
    let mut hash = 0xcbf2_9ce4_8422_2325u64;
    for &b in bytes {
        hash = (hash ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3);
    }
    format!("fnv1a64:{hash:016x}")
}

/// The payload bytes of a partial of `stage` for either tile, from the plan's numbers: a coarse
/// box of 2 × 4 × 4 voxels (8³ halved, each tile's half), the tile's node box (2 × 3 × 3 nodes
/// of 3³), the tile's core (4 × 8 × 8 voxels).
fn payload_len(stage: MergeStage) -> usize {
    match stage {
        MergeStage::Coarse => 2 * 4 * 4 * (4 + 8 * 324),
        MergeStage::Sweep(_) => 88 + 8 * 2 * 3 * 3 * (27 * 2 * 2 + 2 * 324),
        MergeStage::Coefficients => 4 * 8 * 8 * (1 + 4 * 2),
    }
}

fuzz_target!(|data: &[u8]| {
    let Some((&head, rest)) = data.split_first() else {
        return;
    };
    let (plan, config) = setup();
    let context = MergeContext::new(plan, config, SWEEPS).expect("the merge");
    let stages = [
        MergeStage::Coarse,
        MergeStage::Sweep(1),
        MergeStage::Coefficients,
    ];
    let stage = stages[usize::from(head & 0x3) % 3];
    let tile = usize::from((head >> 2) & 1);
    let basis: Option<BasisState> = stage.input(SWEEPS).map(|input| {
        let basis = Array3::from_shape_fn((27, 2, 324), |(n, l, d)| {
            ((n * 7 + l * 3 + d) % 11) as f32 * 0.1 - 0.5
        });
        context.basis_state(input, basis, 0.5).expect("a basis")
    });
    let limits = Limits::small();
    let path = Path::new("tile.part");
    let bytes = if head & 0x80 == 0 {
        rest.to_vec()
    } else {
        if rest.is_empty() {
            return;
        }
        let mut payload: Vec<u8> = rest
            .iter()
            .copied()
            .cycle()
            .take(payload_len(stage))
            .collect();
        if let MergeStage::Sweep(_) = stage {
            // The normal equations' own header: grid, first node, extent, rank, dimension.
            let header: [u64; 11] = [3, 3, 3, tile as u64, 0, 0, 2, 3, 3, 2, 324];
            for (i, v) in header.iter().enumerate() {
                payload[8 * i..8 * i + 8].copy_from_slice(&v.to_le_bytes());
            }
        }
        let header = serde_json::json!({
            "format": PARTIAL_FORMAT,
            "version": MERGE_FILE_VERSION,
            "stage": stage.to_string(),
            "tile": tile,
            "fingerprint": context.partial_fingerprint(stage, tile, basis.as_ref()),
            "residual": f64::from(rest[0]),
            "energy": 1.0,
            "weighted_residual": f64::from(rest[0]) * 0.5,
            "weighted_energy": 0.25,
            "magnitude": f64::from(rest[rest.len() - 1]),
            "payload_bytes": payload.len(),
            "checksum": fnv1a64(&payload),
        });
        let header = serde_json::to_vec(&header).expect("header");
        let mut bytes = MERGE_MAGIC.to_vec();
        bytes.extend_from_slice(&(header.len() as u32).to_le_bytes());
        bytes.extend_from_slice(&header);
        bytes.extend_from_slice(&payload);
        bytes
    };
    if let Ok(partial) = context.decode_partial(stage, tile, basis.as_ref(), path, &bytes, &limits)
    {
        assert_eq!((partial.stage, partial.tile), (stage, tile));
        assert!(partial.residual.is_finite() && partial.energy.is_finite());
        // It reads back from its own encoding.
        let again = context.encode_partial(&partial, basis.as_ref());
        let back = context
            .decode_partial(stage, tile, basis.as_ref(), path, &again, &limits)
            .expect("its own encoding");
        assert_eq!(back, partial);
    }
});
