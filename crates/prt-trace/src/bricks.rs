//! Sparse bricks: the transfer volume traced and stored only in the bricks of voxels that hold
//! a valid voxel (or, opt-in, only those near geometry).

use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use prt_core::ndarray::Array2;
use prt_core::{Aabb, GridField, Progress};
use rayon::prelude::*;

use crate::bake::{SurfaceCache, TransferBaker, TransferVolume};
use crate::denoise::denoise;
use crate::sh::TRANSFER_DIM;
use crate::{BakeStats, TraceError};

/// Marks an absent brick in [`BrickMap`]'s indirection.
const ABSENT: u32 = u32::MAX;

/// Options of [`TransferBaker::bake_bricks`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BrickOptions {
    /// Voxels along each edge of a brick (4: the bricks of Unity's adaptive probe volumes).
    pub edge: usize,
    /// `None` keeps every brick with a valid voxel, so the kept voxels equal a dense bake's.
    /// `Some(d)` also drops bricks none of whose valid voxels sees geometry within `d` (world
    /// units) along its probe rays: open space far from every surface, which a renderer never
    /// shades.
    pub max_distance: Option<f32>,
}

/// Bricks of 4³ voxels, every brick with a valid voxel kept.
impl Default for BrickOptions {
    fn default() -> Self {
        Self {
            edge: 4,
            max_distance: None,
        }
    }
}

/// The indirection of a sparse volume: which bricks of a voxel grid are stored, and where.
///
/// The grid of `dims` voxels is split into bricks of `edge³` voxels (bricks at the grid's upper
/// faces are cut short); brick `(bx, by, bz)` has flat index `bx + bdx * (by + bdy * bz)` and
/// its voxels occupy rows `slot * edge³ ..` of the stored data, x fastest inside the brick.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BrickMap {
    dims: [usize; 3],
    edge: usize,
    brick_dims: [usize; 3],
    slots: Vec<u32>,
    kept: usize,
}

impl BrickMap {
    /// The map of a `dims` grid in bricks of `edge` voxels keeping the bricks for which
    /// `keep(brick index)` holds, in brick order.
    ///
    /// # Panics
    /// If `edge` is zero.
    pub fn new(dims: [usize; 3], edge: usize, mut keep: impl FnMut(usize) -> bool) -> Self {
        assert!(edge > 0, "a brick has at least one voxel per edge");
        let brick_dims = dims.map(|d| d.div_ceil(edge));
        let mut kept = 0usize;
        let slots = (0..brick_dims.iter().product::<usize>())
            .map(|b| {
                if keep(b) {
                    kept += 1;
                    (kept - 1) as u32
                } else {
                    ABSENT
                }
            })
            .collect();
        Self {
            dims,
            edge,
            brick_dims,
            slots,
            kept,
        }
    }

    /// The map keeping every brick that holds a voxel with `keep[voxel]` (x-fastest voxels).
    pub fn from_voxels(dims: [usize; 3], edge: usize, keep: &[bool]) -> Self {
        let mut any = vec![false; dims.map(|d| d.div_ceil(edge.max(1))).iter().product()];
        for (v, _) in keep.iter().enumerate().filter(|(_, k)| **k) {
            any[brick_of(dims, edge, v)] = true;
        }
        Self::new(dims, edge, |b| any[b])
    }

    /// Voxels of the grid per axis.
    pub fn dims(&self) -> [usize; 3] {
        self.dims
    }

    /// Voxels along a brick's edge.
    pub fn edge(&self) -> usize {
        self.edge
    }

    /// Bricks per axis.
    pub fn brick_dims(&self) -> [usize; 3] {
        self.brick_dims
    }

    /// Bricks in the grid.
    pub fn bricks(&self) -> usize {
        self.slots.len()
    }

    /// Bricks stored.
    pub fn kept_bricks(&self) -> usize {
        self.kept
    }

    /// Rows of stored data: kept bricks × edge³.
    pub fn stored_voxels(&self) -> usize {
        self.kept * self.edge.pow(3)
    }

    /// The slot of brick `b` (flat brick index), `None` when it is not stored.
    pub fn slot(&self, b: usize) -> Option<usize> {
        self.slots
            .get(b)
            .filter(|&&s| s != ABSENT)
            .map(|&s| s as usize)
    }

    /// The brick (flat index) holding voxel `v`.
    pub fn brick_of(&self, v: usize) -> usize {
        brick_of(self.dims, self.edge, v)
    }

    /// The row of voxel `v` in the stored data, `None` when its brick is not stored.
    pub fn row(&self, v: usize) -> Option<usize> {
        let slot = self.slot(self.brick_of(v))?;
        let [x, y, z] = voxel_coords(self.dims, v).map(|c| c % self.edge);
        Some(slot * self.edge.pow(3) + x + self.edge * (y + self.edge * z))
    }

    /// The voxel (flat grid index) of local position `k` (x fastest) in brick `b`, `None` where
    /// a brick at the grid's upper faces is cut short.
    pub fn voxel_in_brick(&self, b: usize, k: usize) -> Option<usize> {
        let e = self.edge;
        let bc = voxel_coords(self.brick_dims, b);
        let local = [k % e, (k / e) % e, k / (e * e)];
        let c: [usize; 3] = std::array::from_fn(|a| bc[a] * e + local[a]);
        (c[0] < self.dims[0] && c[1] < self.dims[1] && c[2] < self.dims[2])
            .then(|| c[0] + self.dims[0] * (c[1] + self.dims[1] * c[2]))
    }

    /// The kept bricks' flat indices, in slot order.
    pub fn kept(&self) -> impl Iterator<Item = usize> + '_ {
        self.slots
            .iter()
            .enumerate()
            .filter(|(_, s)| **s != ABSENT)
            .map(|(b, _)| b)
    }
}

fn voxel_coords(dims: [usize; 3], v: usize) -> [usize; 3] {
    [
        v % dims[0],
        (v / dims[0]) % dims[1],
        v / (dims[0] * dims[1]),
    ]
}

fn brick_of(dims: [usize; 3], edge: usize, v: usize) -> usize {
    let bd = dims.map(|d| d.div_ceil(edge));
    let [x, y, z] = voxel_coords(dims, v).map(|c| c / edge);
    x + bd[0] * (y + bd[1] * z)
}

/// Counters of a sparse bake (the tracer's own counters are in [`BrickedVolume::stats`]).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct BrickStats {
    /// Voxels whose validity was probed (every voxel inside the traced box).
    pub probed_voxels: usize,
    /// Voxels traced in full: the valid voxels of the kept bricks.
    pub traced_voxels: usize,
    /// Rows of stored data (kept bricks × edge³).
    pub stored_voxels: usize,
    /// Valid voxels dropped with their brick by [`BrickOptions::max_distance`].
    pub dropped_valid_voxels: usize,
    /// Time of the probe pass that classifies the bricks.
    pub probe_time: Duration,
}

/// A transfer volume stored in bricks: only the kept bricks' voxels hold data.
#[derive(Debug, Clone)]
pub struct BrickedVolume {
    /// Which bricks are stored and where.
    pub bricks: BrickMap,
    /// `stored voxels × 324` transfer vectors, in the layout of [`TransferVolume::field`],
    /// brick by brick (see [`BrickMap`]); invalid voxels of a kept brick are zero.
    pub data: Array2<f32>,
    /// Per voxel of the whole grid: valid and kept. A dropped brick's voxels are `false`.
    pub valid: Vec<bool>,
    /// The box the whole grid covers (its voxels per axis are [`BrickMap::dims`]).
    pub bounds: Aabb,
    /// The tracer's counters (`invalid_voxels` counts every voxel not valid and kept).
    pub stats: BakeStats,
    /// The bricks' counters.
    pub brick_stats: BrickStats,
}

impl BrickedVolume {
    /// The transfer vector of voxel `v`, `None` when its brick is not stored.
    pub fn voxel(&self, v: usize) -> Option<&[f32]> {
        let row = self.bricks.row(v)?;
        self.data.row(row).to_slice()
    }

    /// The dense volume: the stored voxels scattered into a [`GridField`], zero elsewhere.
    /// Equal to [`TransferBaker::bake`]'s volume on every valid voxel, bit for bit, when every
    /// brick with a valid voxel was kept.
    pub fn to_dense(&self) -> Result<TransferVolume, TraceError> {
        let mut field = GridField::new(self.bricks.dims(), self.bounds, TRANSFER_DIM)?;
        let mut data = field.data_mut();
        for (v, mut row) in data.outer_iter_mut().enumerate() {
            if let Some(src) = self.voxel(v) {
                row.iter_mut().zip(src).for_each(|(o, &x)| *o = x);
            }
        }
        Ok(TransferVolume {
            field,
            valid: self.valid.clone(),
            stats: self.stats.clone(),
        })
    }
}

impl TransferBaker<'_> {
    /// Bakes only the bricks of voxels that matter: a probe pass (the validity test's rays of
    /// every voxel, nothing else) classifies the voxels, every brick without a valid voxel (and,
    /// with [`BrickOptions::max_distance`], every brick far from geometry) is dropped, and the
    /// valid voxels of the kept bricks are traced exactly as [`TransferBaker::bake`] traces
    /// them: same rays, same surface cache, same bits. Memory is the kept bricks' data.
    ///
    /// Progress sees the probe pass (voxels) then the traced voxels' directions. Errors as
    /// [`TransferBaker::bake`], and [`TraceError::InvalidOption`] for a zero brick edge or a
    /// negative or non-finite distance.
    pub fn bake_bricks(
        &self,
        options: &BrickOptions,
        progress: &dyn Progress,
    ) -> Result<BrickedVolume, TraceError> {
        if options.edge == 0 {
            return Err(TraceError::InvalidOption {
                what: "brick edge",
                why: "must be positive".into(),
            });
        }
        if let Some(d) = options.max_distance
            && !(d.is_finite() && d >= 0.0)
        {
            return Err(TraceError::InvalidOption {
                what: "brick max_distance",
                why: format!("{d} is not a finite non-negative length"),
            });
        }
        // Only the geometry of the grid: no data is allocated for it.
        let grid = self.empty_field(1)?;
        let (dims, bounds) = (grid.dims(), grid.bounds());
        let voxels = grid.num_voxels();

        // The probe pass: validity and the distance to the nearest hit of every voxel.
        let t0 = Instant::now();
        progress.message("probing voxels");
        progress.set_len(voxels as u64);
        let probe_rays = AtomicU64::new(0);
        let mut probe = vec![(false, f32::INFINITY); voxels];
        const PROBE_CHUNK: usize = 256;
        probe
            .par_chunks_mut(PROBE_CHUNK)
            .enumerate()
            .try_for_each(|(c, out)| {
                progress.check()?;
                let mut rays = 0;
                for (k, o) in out.iter_mut().enumerate() {
                    let v = c * PROBE_CHUNK + k;
                    let x = grid.centre_of(v);
                    if self.outside_trace_box(x) {
                        continue;
                    }
                    let (valid, nearest, r) = self.probe_voxel(x, v);
                    *o = (valid, nearest);
                    rays += r;
                }
                probe_rays.fetch_add(rays, Ordering::Relaxed);
                progress.inc(out.len() as u64);
                Ok::<(), TraceError>(())
            })?;
        let probe_time = t0.elapsed();
        let near = |v: usize| {
            let (valid, nearest) = probe[v];
            valid && options.max_distance.is_none_or(|d| nearest <= d)
        };
        let mut keep = vec![false; voxels];
        keep.iter_mut().enumerate().for_each(|(v, k)| *k = near(v));
        let bricks = BrickMap::from_voxels(dims, options.edge, &keep);
        let valid: Vec<bool> = (0..voxels)
            .map(|v| probe[v].0 && bricks.slot(bricks.brick_of(v)).is_some())
            .collect();
        let skipped = (0..voxels)
            .filter(|&v| self.outside_trace_box(grid.centre_of(v)))
            .count();
        let probed_valid = probe.iter().filter(|p| p.0).count();
        drop(probe);

        // The full trace of the kept bricks' valid voxels.
        let (cache, cache_time) = self.surface_cache();
        let t1 = Instant::now();
        let brick_len = options.edge.pow(3);
        let mut data = vec![0.0f32; bricks.stored_voxels() * TRANSFER_DIM];
        let mut variance = vec![0.0f32; bricks.stored_voxels()];
        let traced: Vec<(usize, usize)> = bricks
            .kept()
            .flat_map(|b| (0..brick_len).map(move |k| (b, k)))
            .enumerate()
            .filter_map(|(row, (b, k))| {
                let v = bricks.voxel_in_brick(b, k)?;
                valid[v].then_some((row, v))
            })
            .collect();
        let per_voxel = self.rays_per_voxel() as u64;
        progress.message("tracing bricks");
        progress.set_len(traced.len() as u64 * per_voxel);
        let cache_rays = AtomicU64::new(0);
        let voxel_rays = AtomicU64::new(probe_rays.into_inner());
        {
            // Rows are brick-contiguous, so a chunk of rows is a chunk of bricks.
            let rows_per_chunk = brick_len * BRICKS_PER_CHUNK;
            data.par_chunks_mut(TRANSFER_DIM * rows_per_chunk)
                .zip(variance.par_chunks_mut(rows_per_chunk))
                .enumerate()
                .try_for_each(|(c, (out, var))| {
                    progress.check()?;
                    let base = c * rows_per_chunk;
                    let first = traced.partition_point(|&(row, _)| row < base);
                    let last = traced.partition_point(|&(row, _)| row < base + rows_per_chunk);
                    let mut rays = 0;
                    for &(row, v) in &traced[first..last] {
                        let o = &mut out[(row - base) * TRANSFER_DIM..][..TRANSFER_DIM];
                        let (is_valid, r) = self.voxel_transfer(
                            grid.centre_of(v),
                            v,
                            cache.as_ref(),
                            &cache_rays,
                            o,
                            &mut var[row - base],
                        );
                        debug_assert!(is_valid, "the probe pass found voxel {v} valid");
                        rays += r;
                    }
                    voxel_rays.fetch_add(rays, Ordering::Relaxed);
                    progress.inc((last - first) as u64 * per_voxel);
                    Ok::<(), TraceError>(())
                })?;
        }
        let voxel_time = t1.elapsed();
        let cache_points = cache.as_ref().map_or(0, SurfaceCache::points);
        let cache_evaluated = cache.as_ref().map_or(0, SurfaceCache::evaluated);
        drop(cache);
        let t2 = Instant::now();
        if let Some(options) = &self.options.denoise {
            // Row r of the bricks holds voxel targets[r] (usize::MAX: past the grid's edge).
            let targets: Vec<usize> = bricks
                .kept()
                .flat_map(|b| (0..brick_len).map(move |k| (b, k)))
                .map(|(b, k)| bricks.voxel_in_brick(b, k).unwrap_or(usize::MAX))
                .collect();
            let sample = |v: usize| {
                if v >= voxels || !valid[v] {
                    return None;
                }
                let row = bricks.row(v)?;
                Some((&data[row * TRANSFER_DIM..][..TRANSFER_DIM], variance[row]))
            };
            let mut out = vec![0.0f32; data.len()];
            progress.message("denoising");
            denoise(
                &grid,
                self.tracer(),
                options,
                &sample,
                &targets,
                &mut out,
                progress,
            )?;
            data = out;
        }
        let kept_valid = traced.len();
        let stats = BakeStats {
            voxels,
            invalid_voxels: voxels - kept_valid - skipped,
            skipped_voxels: skipped,
            rays_per_voxel: self.rays_per_voxel(),
            cache_points,
            cache_evaluated,
            cache_rays: cache_rays.into_inner(),
            voxel_rays: voxel_rays.into_inner(),
            bvh_time: self.bvh_time,
            cache_time,
            voxel_time,
            denoise_time: if self.options.denoise.is_some() {
                t2.elapsed()
            } else {
                Duration::ZERO
            },
        };
        if kept_valid == 0 {
            return Err(TraceError::NoValidVoxels {
                voxels,
                invalid: voxels - skipped,
                skipped,
            });
        }
        let brick_stats = BrickStats {
            probed_voxels: voxels - skipped,
            traced_voxels: kept_valid,
            stored_voxels: bricks.stored_voxels(),
            dropped_valid_voxels: probed_valid - kept_valid,
            probe_time,
        };
        let data =
            Array2::from_shape_vec((bricks.stored_voxels(), TRANSFER_DIM), data).map_err(|e| {
                TraceError::InvalidOption {
                    what: "bricks",
                    why: e.to_string(),
                }
            })?;
        Ok(BrickedVolume {
            bricks,
            data,
            valid,
            bounds,
            stats,
            brick_stats,
        })
    }
}

/// Bricks traced per parallel task.
const BRICKS_PER_CHUNK: usize = 2;
