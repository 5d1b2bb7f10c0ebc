//! What a bake needs in memory, estimated before anything large is allocated.
//!
//! The largest allocations of a bake are copies of the 324-D volume, `F = voxels × 324 × 4`
//! bytes each: the traced field; while a method is scored, its reconstruction on the grid (one
//! at a time: MBD's, each baseline's, the container's read back; none is kept) and the seam
//! measure's denoised reference and error; the seam view's denoised reference and one
//! projection residual; clustered PCA's working copy; and the copies made to keep the volumes
//! (`write_volumes`). While the volume is traced, only
//! its own copy exists, beside the surface cache (at least one point per triangle, more as the
//! voxels shrink) and the ray-tracing structures. [`MemoryEstimate`] takes the larger of the
//! two stages, adds the scene and a fixed allowance for the process itself, and is checked
//! against a budget before the trace starts.
//!
//! A sparse-brick bake ([`crate::Layout`]) holds its kept bricks and, once traced, their dense
//! scatter: two copies while tracing. Its masked clustered PCA clusters a compact copy of the
//! valid rows and projects it before scattering: one more copy after. How many voxels are
//! valid is known only after the probe pass, so the estimate counts every voxel valid (an
//! upper bound; what a sparse bake saves in memory is measured in docs/results.md).

use prt_trace::TRANSFER_DIM;

use crate::{BakeConfig, BakeError};

/// Bytes of the process before any bake-sized allocation: code, thread stacks, fonts, the
/// allocator's slack (measured: 110 MB at 32 voxels, which is mostly this).
const PROCESS_BYTES: u64 = 192 << 20;
/// Bytes per scene triangle held while tracing (triangles, BVH nodes, the tracer's copies).
const TRIANGLE_BYTES: u64 = 256;
/// Bytes per surface-cache point while tracing: position and normal (24, up to twice that while
/// the list grows) and a lazily evaluated 9-coefficient value per side (2 × 40).
const CACHE_POINT_BYTES: u64 = 128;

/// What a bake needs at its peak, by term.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MemoryEstimate {
    /// Voxels of the grid.
    pub voxels: u64,
    /// One copy of the 324-D volume in f32.
    pub field_bytes: u64,
    /// Volume copies alive at the peak (see the module docs).
    pub field_copies: u64,
    /// Volume copies alive while tracing: 1 dense, 2 sparse (the bricks and their scatter).
    pub trace_copies: u64,
    /// The scene's triangles and ray-tracing structures.
    pub scene_bytes: u64,
    /// The surface cache while tracing, counted at one point per triangle: a finer lattice
    /// only comes with smaller voxels, whose later volume copies outgrow it.
    pub cache_bytes: u64,
    /// The process itself.
    pub process_bytes: u64,
}

impl MemoryEstimate {
    /// The estimate for `config` on a scene box of `size` with `triangles` triangles.
    pub fn new(config: &BakeConfig, size: [f32; 3], triangles: usize) -> Self {
        Self::for_grid(config, config.grid_resolution(size), triangles)
    }

    /// The estimate for a grid of `dims` voxels.
    pub fn for_grid(config: &BakeConfig, dims: [usize; 3], triangles: usize) -> Self {
        let voxels = dims.iter().fold(1u64, |n, &d| n.saturating_mul(d as u64));
        let field_bytes = voxels.saturating_mul(TRANSFER_DIM as u64 * 4);
        // Traced field, one reconstruction being scored, the seam measure's denoised reference
        // and error: 4. Keeping the volumes (`write_volumes`) holds an f32 reconstruction and
        // its encoding: +1. Clustered PCA works on a copy: +1, and a sparse layout's masked fit
        // on a compact copy of the valid rows: +1.
        let sparse = config.layout.is_sparse(dims);
        let field_copies = 5 + if config.baselines {
            1 + u64::from(sparse)
        } else {
            0
        };
        MemoryEstimate {
            voxels,
            field_bytes,
            field_copies,
            // The denoiser writes a filtered copy next to the traced volume.
            trace_copies: 1 + u64::from(sparse) + u64::from(config.denoise.is_some()),
            scene_bytes: (triangles as u64).saturating_mul(TRIANGLE_BYTES),
            cache_bytes: (triangles as u64).saturating_mul(CACHE_POINT_BYTES),
            process_bytes: PROCESS_BYTES,
        }
    }

    /// The total in bytes: the process, the scene, and the larger of the trace (its volume
    /// copies and the surface cache) and what follows it (every volume copy).
    pub fn total(&self) -> u64 {
        let trace = self
            .field_bytes
            .saturating_mul(self.trace_copies)
            .saturating_add(self.cache_bytes);
        let after = self.field_bytes.saturating_mul(self.field_copies);
        trace
            .max(after)
            .saturating_add(self.scene_bytes)
            .saturating_add(self.process_bytes)
    }

    /// Checks the total against `budget` bytes; the error gives the need, the budget and the
    /// largest resolution (voxels along the longest axis) that fits, for a scene box of `size`.
    pub fn check(
        &self,
        config: &BakeConfig,
        size: [f32; 3],
        triangles: usize,
        budget: u64,
    ) -> Result<(), BakeError> {
        if self.total() <= budget {
            return Ok(());
        }
        Err(BakeError::OverMemoryBudget {
            need: self.total(),
            budget,
            largest_resolution: largest_resolution(config, size, triangles, budget),
        })
    }
}

/// The memory budget a bake gets when none is given: four fifths of the machine's physical
/// memory (`/proc/meminfo`), or 8 GiB where that cannot be read.
pub fn default_memory_budget() -> u64 {
    let total_kib = std::fs::read_to_string("/proc/meminfo")
        .ok()
        .and_then(|text| {
            text.lines()
                .find_map(|l| l.strip_prefix("MemTotal:"))
                .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<u64>().ok())
        });
    total_kib.map_or(8 << 30, |kib| kib * 1024 / 5 * 4)
}

/// The largest resolution (voxels along the longest axis, at least 2) whose bake fits `budget`
/// bytes with `config`'s other knobs, or `None` if not even 2 does.
pub fn largest_resolution(
    config: &BakeConfig,
    size: [f32; 3],
    triangles: usize,
    budget: u64,
) -> Option<usize> {
    let fits = |resolution: usize| {
        let config = BakeConfig {
            resolution,
            ..config.clone()
        };
        MemoryEstimate::new(&config, size, triangles).total() <= budget
    };
    if !fits(2) {
        return None;
    }
    // The need grows with the resolution: bisect between a fit and a miss.
    let (mut lo, mut hi) = (2usize, config.resolution.max(3));
    while fits(hi) {
        lo = hi;
        hi = hi.saturating_mul(2);
    }
    while hi - lo > 1 {
        let mid = lo + (hi - lo) / 2;
        if fits(mid) {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    Some(lo)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Measured peak RSS of `prt bake` (release build, 2 threads) on the Cornell box (32
    /// triangles) and Sponza (262087; docs/results.md, "Memory"): the estimate must not be below
    /// it, nor far above it.
    #[test]
    fn the_estimate_covers_measured_peaks_without_wasting_the_budget() {
        for (dims, triangles, baselines, measured_kib) in [
            ([32usize, 31, 32], 32usize, true, 362_588u64),
            ([48, 47, 48], 32, true, 873_388),
            ([64, 63, 64], 32, true, 2_052_740),
            ([64, 63, 64], 32, false, 1_561_108),
            ([32, 13, 20], 262_087, true, 204_308),
            ([48, 20, 30], 262_087, true, 367_752),
        ] {
            let resolution = dims[0];
            // `prt bake` always writes the container.
            let config = BakeConfig {
                resolution,
                baselines,
                container: Some("mbd".into()),
                layout: crate::Layout::Dense,
                ..BakeConfig::default()
            };
            let estimate = MemoryEstimate::for_grid(&config, dims, triangles).total();
            let measured = measured_kib * 1024;
            // Sponza at 32 voxels is mostly the fixed process allowance.
            let slack = if triangles > 1000 { 3 } else { 2 };
            assert!(
                estimate >= measured && estimate <= measured * slack,
                "{dims:?}, baselines {baselines}: estimate {estimate} vs measured {measured}"
            );
        }
    }

    #[test]
    fn a_coarse_grid_over_many_triangles_counts_the_surface_cache() {
        // 16³ voxels over 5 million triangles: the cache (a point per triangle) outweighs every
        // copy of the small volume.
        let config = BakeConfig {
            resolution: 16,
            ..BakeConfig::default()
        };
        let estimate = MemoryEstimate::for_grid(&config, [16; 3], 5_000_000);
        let cache = 5_000_000 * CACHE_POINT_BYTES;
        assert!(estimate.field_bytes * estimate.field_copies < cache);
        assert!(
            estimate.total() >= cache + estimate.scene_bytes + estimate.process_bytes,
            "{estimate:?}"
        );
    }

    #[test]
    fn the_largest_resolution_fits_and_one_more_does_not() {
        let config = BakeConfig {
            resolution: 1000,
            ..BakeConfig::default()
        };
        let size = [2.0f32, 1.0, 1.5];
        for budget in [1u64 << 30, 8 << 30, 20 << 30] {
            let best = largest_resolution(&config, size, 1000, budget).expect("some fit");
            let at = |resolution| {
                MemoryEstimate::new(
                    &BakeConfig {
                        resolution,
                        ..config.clone()
                    },
                    size,
                    1000,
                )
                .total()
            };
            assert!(
                at(best) <= budget && at(best + 1) > budget,
                "budget {budget}"
            );
        }
        assert_eq!(largest_resolution(&config, size, 1000, 1 << 20), None);
    }

    #[test]
    fn an_oversized_bake_is_refused_with_its_need_and_the_largest_resolution() {
        let config = BakeConfig {
            resolution: 1000,
            ..BakeConfig::default()
        };
        let size = [1.0f32; 3];
        let estimate = MemoryEstimate::new(&config, size, 32);
        assert!(estimate.total() > 1 << 40, "{}", estimate.total());
        match estimate.check(&config, size, 32, 16 << 30) {
            Err(BakeError::OverMemoryBudget {
                need,
                budget,
                largest_resolution: Some(res),
            }) => {
                assert_eq!((need, budget), (estimate.total(), 16 << 30));
                assert!((100..200).contains(&res), "{res}");
            }
            other => panic!("{other:?}"),
        }
        assert!(estimate.check(&config, size, 32, u64::MAX).is_ok());
    }
}
