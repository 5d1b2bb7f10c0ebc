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

mod merge;
mod plan;
mod stream;
mod worker;

pub use merge::{AssembledVolume, HaloAgreement, TileSeams, assemble, tile_seams};
pub use plan::{
    PLAN_FILE, PLAN_FORMAT, PLAN_VERSION, PlannedScene, TileError, TilePlan, TileSpec, VoxelRange,
    plan_tiles, scene_hash,
};
pub use stream::{StreamedMerge, merge_streamed};
pub use worker::{
    DONE_MARKER, TileOutcome, TileStats, bake_tile, tile_dir, tile_is_done, tile_options,
};

#[cfg(test)]
mod tests {
    use glam::Vec3;
    use proptest::prelude::*;
    use prt_core::NoProgress;

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
            prop_assert_eq!(TilePlan::read(&dir).unwrap(), plan.clone());
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
        let first = plan.tiles[1].core.min.map(|i| i as f32);
        let want = lattice.min + (Vec3::from_array(first) + 0.5) * cell;
        let got = bounds.min
            + 0.5 * bounds.size() / Vec3::from_array(options.resolution.map(|n| n as f32));
        assert!((want - got).abs().max_element() < 1e-5, "{want} vs {got}");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
