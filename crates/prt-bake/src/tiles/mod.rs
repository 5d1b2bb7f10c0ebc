//! Tiled bakes: a bake split into tiles of the global voxel lattice, each traced by an
//! independent worker process, then merged into the container `prt bake` writes.
//!
//! The design: tiles *trace*, one merge step *solves*. A voxel's transfer depends on the scene
//! alone, not on its neighbours, so a tile traces exactly its voxels of the global lattice and
//! the assembled volume is a trace of the whole grid (with per-tile seeds: another Monte Carlo
//! sample of it). The merge then runs [`crate::bake_volume`] on it: the same MBD solve, scores
//! and container as a single-process bake, with one global moving basis, so tile borders cannot
//! become seams of the model. A worker's memory is set by its tile (plus the scene's BVH and
//! surface cache); the merge holds the whole volume. The measured trade is in docs/results.md
//! ("Tiled bakes").
//!
//! The plan (`plan.json`) and a tile's files are described in docs/formats.md.

mod cache;
mod checksum;
pub(crate) use checksum::Fnv1a64;
mod file;
mod merge;
mod partial;
mod plan;
mod report;
mod stream;
mod worker;

pub use cache::{
    SURFACE_CACHE_FILE, SURFACE_CACHE_MAGIC, SURFACE_CACHE_VERSION, SurfaceCacheFingerprint,
    SurfaceCacheHeader, SurfaceCacheWritten, decode_surface_cache, encode_surface_cache,
    ensure_surface_cache, evaluate_surface_cache, read_surface_cache, read_surface_cache_header,
};
pub use file::{
    TILE_FORMAT, TILE_VERSION, TileChecksums, TileData, TileFingerprint, TileStats, TileStatus,
    decode_tile, tile_status,
};
pub use merge::{AssembledVolume, HaloAgreement, TileSeams, assemble, tile_seams};
pub use partial::{
    BASIS_FORMAT, MERGE_FILE_VERSION, MERGE_MAGIC, MergeStage, PARTIAL_FORMAT, PartialError,
    basis_path, merge_dir, partial_path,
};
pub use plan::{
    PLAN_FILE, PLAN_FORMAT, PLAN_VERSION, PlanWritten, PlannedScene, TileError, TilePlan, TileSpec,
    VoxelRange, plan_tiles, write_plan,
};
pub use report::{HaloRecord, SeamRatios, StreamedRecord, TilesReport};
pub use stream::{
    BasisState, MapOutcome, MergeContext, Partial, ReduceOutcome, StageSums, StreamedMerge,
    map_tile, merge_from_partials, merge_streamed, reduce_stage,
};
pub use worker::{
    DONE_MARKER, TileOutcome, bake_tile, tile_dir, tile_is_done, tile_options, tile_trace_box,
};

#[cfg(test)]
mod tests {
    use glam::Vec3;
    use proptest::prelude::*;
    use prt_core::NoProgress;
    use prt_texture::Limits;

    use prt_trace::TransferVolume;

    use super::*;
    use crate::{BakeConfig, SceneInput};

    fn config(resolution: usize) -> BakeConfig {
        BakeConfig {
            resolution,
            rays_per_voxel: 12,
            cache_rays: 4,
            ..BakeConfig::default()
        }
    }

    fn scratch(name: &str) -> std::path::PathBuf {
        let dir = std::env::temp_dir().join(format!("prt-tiles-{}-{name}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        dir
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(24))]
        #[test]
        fn every_voxel_is_in_exactly_one_core_and_the_plan_reads_back(
            tx in 1usize..5, ty in 1usize..4, tz in 1usize..4, halo in 0usize..3,
        ) {
            let scene = SceneInput::cornell_box();
            let plan = plan_tiles(&scene, None, &config(6), [tx, ty, tz], halo).unwrap();
            prop_assert_eq!(plan.tiles.len(), tx * ty * tz);
            let dir = scratch(&format!("prop-{tx}{ty}{tz}{halo}"));
            plan.write(&dir).unwrap();
            // `read` checks the cover (each voxel in one core, cores inside traced boxes).
            prop_assert_eq!(TilePlan::read(&dir, &Limits::default()).unwrap(), plan.clone());
            for tile in &plan.tiles {
                for k in 0..3 {
                    let grown = tile.core.max[k] + halo;
                    prop_assert_eq!(tile.traced.max[k], grown.min(plan.lattice_dims[k]));
                    prop_assert_eq!(tile.traced.min[k], tile.core.min[k].saturating_sub(halo));
                }
            }
            let _ = std::fs::remove_dir_all(&dir);
        }
    }

    #[test]
    fn seeds_differ_per_tile_and_repeat_per_plan() {
        let scene = SceneInput::cornell_box();
        let a = plan_tiles(&scene, None, &config(8), [2, 2, 2], 1).unwrap();
        let b = plan_tiles(&scene, None, &config(8), [2, 2, 2], 1).unwrap();
        assert_eq!(a, b);
        let mut seeds: Vec<u64> = a.tiles.iter().map(|t| t.seed).collect();
        seeds.dedup();
        assert_eq!(seeds.len(), 8);
    }

    #[test]
    fn more_tiles_than_voxels_is_refused() {
        let scene = SceneInput::cornell_box();
        let error = plan_tiles(&scene, None, &config(4), [5, 1, 1], 0).unwrap_err();
        assert!(matches!(error, TileError::InvalidTiling(_)), "{error}");
    }

    #[test]
    fn a_changed_scene_is_refused_and_a_tile_covers_its_lattice_voxels() {
        let scene = SceneInput::cornell_box();
        let plan = plan_tiles(&scene, None, &config(4), [2, 1, 1], 0).unwrap();
        let dir = scratch("changed");
        let mut edited = SceneInput::cornell_box();
        edited.scene.set_uniform_albedo(Vec3::splat(0.5));
        let error = bake_tile(&plan, &dir, &edited, 0, false, &NoProgress).unwrap_err();
        assert!(matches!(error, TileError::SceneChanged { .. }), "{error}");
        assert!(!tile_is_done(&dir, 0));
        // The tile's voxel centres are the lattice's.
        let options = tile_options(&plan, 1).unwrap();
        let bounds = options.bounds.unwrap();
        let lattice = plan.lattice_bounds();
        let cell = lattice.size() / Vec3::from_array(plan.lattice_dims.map(|n| n as f32));
        // (With the default denoiser the worker traces its box grown by the radius.)
        let traced = tile_trace_box(&plan, 1).unwrap();
        assert_eq!(traced.min[0], plan.tiles[1].core.min[0] - 1);
        let first = traced.min.map(|i| i as f32);
        let want = lattice.min + (Vec3::from_array(first) + 0.5) * cell;
        let got = bounds.min
            + 0.5 * bounds.size() / Vec3::from_array(options.resolution.map(|n| n as f32));
        assert!((want - got).abs().max_element() < 1e-5, "{want} vs {got}");
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// The per-voxel squared differences `‖a_v − b_v‖²` over the voxels valid in both, grouped
    /// into 3³ blocks (the radius-1 denoiser correlates a voxel with its neighbours, so blocks,
    /// not voxels, are the independent samples): each block's mean.
    fn block_differences(a: &TransferVolume, b: &TransferVolume) -> Vec<f64> {
        let dims = a.field.dims();
        assert_eq!(dims, b.field.dims());
        let blocks = dims.map(|n| n.div_ceil(3));
        let mut sums = vec![(0.0f64, 0usize); blocks.iter().product()];
        for v in 0..a.field.num_voxels() {
            if !(a.valid[v] && b.valid[v]) {
                continue;
            }
            let d: f64 = a
                .field
                .voxel(v)
                .iter()
                .zip(b.field.voxel(v))
                .map(|(&x, &y)| (f64::from(x) - f64::from(y)).powi(2))
                .sum();
            let [x, y, z] = a.field.coords(v).map(|i| i / 3);
            let block = &mut sums[x + blocks[0] * (y + blocks[1] * z)];
            block.0 += d;
            block.1 += 1;
        }
        sums.iter()
            .filter(|s| s.1 > 0)
            .map(|s| s.0 / s.1 as f64)
            .collect()
    }

    /// Whether `a` and `c` are equally far from `b`: the mean over blocks of
    /// `‖a − b‖² − ‖c − b‖²` within four standard errors of zero. Returns the two mean squared
    /// differences and the verdict.
    fn equally_far(a: &TransferVolume, c: &TransferVolume, b: &TransferVolume) -> (f64, f64, bool) {
        let (ab, cb) = (block_differences(a, b), block_differences(c, b));
        assert_eq!(ab.len(), cb.len());
        let n = ab.len() as f64;
        let gaps: Vec<f64> = ab.iter().zip(&cb).map(|(x, y)| x - y).collect();
        let mean = gaps.iter().sum::<f64>() / n;
        let var = gaps.iter().map(|g| (g - mean).powi(2)).sum::<f64>() / (n - 1.0);
        let (mean_ab, mean_cb) = (ab.iter().sum::<f64>() / n, cb.iter().sum::<f64>() / n);
        (mean_ab, mean_cb, mean.abs() <= 4.0 * (var / n).sqrt())
    }

    /// A 2×2 tiled bake with the denoiser is as far from the one-machine bake as another seed
    /// of the one-machine bake's voxel rays over the same surface cache (its tiles traced with a margin of the denoiser's radius, every
    /// kept voxel filtered with all its neighbours); the same tiles without the denoiser are
    /// not.
    #[test]
    fn a_tiled_bake_is_denoised_like_a_one_machine_bake() {
        let scene = SceneInput::cornell_box();
        let denoised = BakeConfig {
            rays_per_voxel: 96,
            cache_rays: 16,
            ..config(12)
        };
        // The tiles share the one-machine bake's surface cache (the plan's, of the bake's
        // seed): the other seed traces other voxel rays over that same cache.
        let one_machine = |seed: u64, cache: Option<&prt_trace::expert::SharedSurfaceCache>| {
            let options = prt_trace::BakeOptions {
                resolution: denoised
                    .grid_resolution(scene.scene.bounds().unwrap().size().to_array()),
                rays_per_voxel: denoised.rays_per_voxel,
                cache_rays: denoised.cache_rays,
                seed,
                denoise: denoised.denoise_options(),
                ..prt_trace::BakeOptions::default()
            };
            let baker = prt_trace::TransferBaker::new(&scene.scene, options).unwrap();
            match cache {
                Some(cache) => baker.with_surface_cache(cache).unwrap(),
                None => baker,
            }
            .bake(&NoProgress)
            .unwrap()
        };
        let tiled = |config: &BakeConfig, name: &str| {
            let plan = plan_tiles(&scene, None, config, [2, 2, 1], 0).unwrap();
            let dir = scratch(name);
            plan.write(&dir).unwrap();
            for index in 0..plan.tiles.len() {
                bake_tile(&plan, &dir, &scene, index, false, &NoProgress).unwrap();
            }
            let assembled = assemble(&plan, &dir, &Limits::default()).unwrap();
            let _ = std::fs::remove_dir_all(&dir);
            assembled.volume
        };
        let shared = evaluate_surface_cache(
            &plan_tiles(&scene, None, &denoised, [1, 1, 1], 0).unwrap(),
            &scene,
            &NoProgress,
        )
        .unwrap();
        let (b, c) = (one_machine(0, None), one_machine(1, Some(&shared)));
        let a = tiled(&denoised, "denoised");
        assert_eq!(a.field.bounds(), b.field.bounds());
        let (tiled_error, seed_error, same) = equally_far(&a, &c, &b);
        assert!(
            same,
            "tiled {tiled_error:.4e} against another seed {seed_error:.4e}"
        );
        let raw = tiled(
            &BakeConfig {
                denoise: None,
                ..denoised.clone()
            },
            "raw",
        );
        let (raw_error, _, same) = equally_far(&raw, &c, &b);
        assert!(
            !same && raw_error > seed_error,
            "undenoised tiles {raw_error:.4e} against another seed {seed_error:.4e}"
        );
    }

    /// `plan.json`'s bytes with `lattice_dims` replaced.
    fn with_dims(plan: &TilePlan, dims: serde_json::Value) -> Vec<u8> {
        let mut value = serde_json::to_value(plan).unwrap();
        value["lattice_dims"] = dims;
        serde_json::to_vec(&value).unwrap()
    }

    /// The JSON pointers of a plan's numbers that size or place something.
    const PLAN_NUMBERS: [&str; 12] = [
        "/lattice_dims/0",
        "/lattice_dims/2",
        "/counts/0",
        "/counts/1",
        "/halo",
        "/tiles/0/index",
        "/tiles/0/core/max/0",
        "/tiles/1/core/min/0",
        "/tiles/1/traced/max/2",
        "/config/resolution",
        "/config/rays_per_voxel",
        "/config/rank",
    ];

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]
        /// Any number anywhere that sizes or places something: a typed error or a plan that
        /// holds together, never a panic.
        #[test]
        fn any_number_in_a_plan_is_refused_or_consistent(
            field in 0..PLAN_NUMBERS.len(),
            value in prop_oneof![0u64..20, any::<u64>(), (1u64 << 31)..(1u64 << 33)],
            tile_field in 0..4usize,
        ) {
            let scene = SceneInput::cornell_box();
            let plan = plan_tiles(&scene, None, &config(6), [2, 1, 1], 1).unwrap();
            let mut json = serde_json::to_value(&plan).unwrap();
            *json.pointer_mut(PLAN_NUMBERS[field]).unwrap() = value.into();
            let bytes = serde_json::to_vec(&json).unwrap();
            if let Ok(read) = TilePlan::decode(&bytes, &Limits::small()) {
                let cores: usize = read.tiles.iter().map(|t| t.core.len()).sum();
                prop_assert_eq!(cores, read.lattice_dims.iter().product::<usize>());
            }
            // A tile.json with the number in its fingerprint: refused, never a panic.
            let mut stats = serde_json::json!({
                "format": TILE_FORMAT, "version": TILE_VERSION, "index": 0,
                "fingerprint": TileFingerprint::of(&plan, 0).unwrap(),
            });
            let pointer = ["/index", "/fingerprint/traced/max/0", "/fingerprint/seed", "/version"];
            *stats.pointer_mut(pointer[tile_field]).unwrap() = value.into();
            let stats = serde_json::to_vec(&stats).unwrap();
            prop_assert!(decode_tile(&plan, 0, &stats, &[], &[], &Limits::small()).is_err());
        }
    }

    #[test]
    fn a_damaged_plan_is_a_typed_error_before_any_allocation() {
        let scene = SceneInput::cornell_box();
        let plan = plan_tiles(&scene, None, &config(6), [2, 1, 1], 1).unwrap();
        let limits = Limits::default();
        let bytes = serde_json::to_vec(&plan).unwrap();
        assert_eq!(TilePlan::decode(&bytes, &limits).unwrap(), plan);
        let huge = serde_json::json!([1u64 << 32, 6, 6]);
        let error = TilePlan::decode(&with_dims(&plan, huge), &limits).unwrap_err();
        assert!(
            matches!(error, TileError::TooLarge { value, .. } if value == 1 << 32),
            "{error}"
        );
        let error =
            TilePlan::decode(&with_dims(&plan, serde_json::json!([0, 6, 6])), &limits).unwrap_err();
        assert!(matches!(error, TileError::Malformed { .. }), "{error}");
        // Every dimension allowed, their product overflows.
        let open = Limits {
            max_dimension: u32::MAX,
            max_bytes: u64::MAX - 1,
            ..limits
        };
        let overflow = serde_json::json!([1u64 << 31, 1u64 << 31, 1u64 << 31]);
        let error = TilePlan::decode(&with_dims(&plan, overflow), &open).unwrap_err();
        assert!(
            matches!(
                error,
                TileError::TooLarge {
                    value: u64::MAX,
                    ..
                }
            ),
            "{error}"
        );
        // Dimensions that fit the limits but not the tiles.
        let error =
            TilePlan::decode(&with_dims(&plan, serde_json::json!([9, 6, 6])), &limits).unwrap_err();
        assert!(matches!(error, TileError::Malformed { .. }), "{error}");
        let error = TilePlan::decode(
            &bytes,
            &Limits {
                max_bytes: 100,
                ..limits
            },
        )
        .unwrap_err();
        assert!(matches!(error, TileError::TooLarge { .. }), "{error}");
        // A seed that is not the plan's derivation, an extra tile.
        let mut value = serde_json::to_value(&plan).unwrap();
        value["tiles"][1]["seed"] = serde_json::json!(7);
        let error = TilePlan::decode(&serde_json::to_vec(&value).unwrap(), &limits).unwrap_err();
        assert!(matches!(error, TileError::Malformed { .. }), "{error}");
        let mut value = serde_json::to_value(&plan).unwrap();
        let first = value["tiles"][0].clone();
        value["tiles"].as_array_mut().unwrap().push(first);
        let error = TilePlan::decode(&serde_json::to_vec(&value).unwrap(), &limits).unwrap_err();
        assert!(matches!(error, TileError::Malformed { .. }), "{error}");
    }

    #[test]
    fn a_tile_is_checked_against_its_fingerprint_checksums_and_limits() {
        let scene = SceneInput::cornell_box();
        let plan = plan_tiles(&scene, None, &config(4), [2, 1, 1], 1).unwrap();
        let dir = scratch("checked");
        assert_eq!(
            write_plan(&plan, &dir, false, &Limits::default()).unwrap(),
            PlanWritten::New
        );
        bake_tile(&plan, &dir, &scene, 0, false, &NoProgress).unwrap();
        assert_eq!(tile_status(&plan, &dir, 0).unwrap(), TileStatus::Done);
        assert_eq!(tile_status(&plan, &dir, 1).unwrap(), TileStatus::NotDone);
        let files = tile_dir(&dir, 0);
        let read = |name: &str| std::fs::read(files.join(name)).unwrap();
        let (info, transfer, valid) = (read("tile.json"), read("transfer.f32"), read("valid.u8"));
        let limits = Limits::default();
        let tile = decode_tile(&plan, 0, &info, &transfer, &valid, &limits).unwrap();
        assert_eq!(tile.transfer.len(), plan.tiles[0].traced.len() * 324);
        assert_eq!(
            tile.stats.fingerprint,
            TileFingerprint::of(&plan, 0).unwrap()
        );

        // A finite float altered: the checksum names the file.
        let mut altered = transfer.clone();
        altered[40] ^= 1;
        let error = decode_tile(&plan, 0, &info, &altered, &valid, &limits).unwrap_err();
        assert!(
            matches!(&error, TileError::Damaged { index: 0, path, .. }
                if path.ends_with("transfer.f32")),
            "{error}"
        );
        // Over the limits: refused before the payload is looked at.
        let small = Limits {
            max_bytes: 1024,
            ..limits
        };
        let error = decode_tile(&plan, 0, &info, &[], &[], &small).unwrap_err();
        assert!(matches!(error, TileError::TooLarge { .. }), "{error}");

        // The same tile under a plan with other rays is stale, naming the knob.
        let other = plan_tiles(
            &scene,
            None,
            &BakeConfig {
                rays_per_voxel: 24,
                ..config(4)
            },
            [2, 1, 1],
            1,
        )
        .unwrap();
        let error = decode_tile(&other, 0, &info, &transfer, &valid, &limits).unwrap_err();
        assert!(
            matches!(&error, TileError::StaleTile { index: 0, differences, .. }
                if differences == &["rays_per_voxel: 12 → 24"]),
            "{error}"
        );
        assert!(matches!(
            tile_status(&other, &dir, 0).unwrap(),
            TileStatus::Stale(_)
        ));
        // Writing that plan over the first is refused, naming the knob; replacing removes the
        // tiles.
        let error = write_plan(&other, &dir, false, &limits).unwrap_err();
        assert!(
            matches!(&error, TileError::PlanExists { differences, .. }
                if differences == &["config.rays_per_voxel: 12 → 24"]),
            "{error}"
        );
        assert_eq!(
            write_plan(&plan, &dir, false, &limits).unwrap(),
            PlanWritten::Unchanged
        );
        // A tile.json of the first tile format (no fingerprint) is stale.
        let mut old: serde_json::Value = serde_json::from_slice(&info).unwrap();
        let object = old.as_object_mut().unwrap();
        object.remove("format");
        object.remove("version");
        let old = serde_json::to_vec(&old).unwrap();
        let error = decode_tile(&plan, 0, &old, &transfer, &valid, &limits).unwrap_err();
        assert!(matches!(error, TileError::StaleTile { .. }), "{error}");
        // The stale tile is traced again, to the same bytes.
        std::fs::write(files.join("tile.json"), &old).unwrap();
        let outcome = bake_tile(&plan, &dir, &scene, 0, false, &NoProgress).unwrap();
        assert!(
            matches!(&outcome, TileOutcome::Baked { stale, .. } if !stale.is_empty()),
            "{outcome:?}"
        );
        assert_eq!(read("tile.json"), info);
        assert_eq!(read("transfer.f32"), transfer);
        assert_eq!(
            write_plan(&other, &dir, true, &limits).unwrap(),
            PlanWritten::Replaced { removed_tiles: 1 }
        );
        assert!(!tile_is_done(&dir, 0));
        let _ = std::fs::remove_dir_all(&dir);
    }
}
