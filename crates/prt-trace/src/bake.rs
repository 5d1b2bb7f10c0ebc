//! The 324-dimensional transfer-volume baker.

use std::f32::consts::PI;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, OnceLock};
use std::time::{Duration, Instant};

use glam::{Vec2, Vec3};
use prt_core::{Aabb, GridField, Progress};
use rayon::prelude::*;

use crate::bvh::{BuildQuality, RayTracer};
use crate::denoise::{DenoiseOptions, denoise};
use crate::sampling::{ICOSA, cosine_hemisphere, group_rotation, hash_seed, icosahedron};
use crate::sh::{SH9, TRANSFER_DIM, sh9};
use crate::{Scene, TraceError};

/// Offset of block `k` (0 = direct, 1..=3 = R, G, B direct-to-indirect) in a transfer vector.
pub const fn block(k: usize) -> std::ops::Range<usize> {
    k * SH9 * SH9..(k + 1) * SH9 * SH9
}

const STREAM_VOXEL: u64 = 1;
const STREAM_CACHE: u64 = 2;
const STREAM_BRUTE: u64 = 3;
const STREAM_REPLICATE: u64 = 4;
/// Independently scrambled direction streams per voxel when the variance is measured: their
/// means are independent, so their spread gives an unbiased estimate of the variance.
pub const REPLICATES: usize = 4;
const VOXEL_CHUNK: usize = 32;
/// Lattice points are pulled this fraction towards the triangle's centroid so that no cache
/// point sits exactly on an edge shared with a neighbouring wall.
const CACHE_SHRINK: f32 = 1e-3;
/// Largest lattice subdivision of one triangle (8385 points).
const MAX_SUBDIV: u16 = 128;
/// Budget of surface-cache points (about 300 MB with both sides); beyond it the spacing grows.
const MAX_CACHE_POINTS: usize = 4_000_000;
/// Icosahedra per voxel whose hits decide which entries a shared surface cache evaluates ahead
/// ([`TransferBaker::evaluate_surface_cache`]); the bakes sharing it evaluate the rest of what
/// their rays hit on first use.
const VISIBILITY_GROUPS: usize = 1;
/// Lattice steps by which the entries those hits read are grown on their triangle (a surface
/// seen at one point is mostly seen around it: fewer entries left to the bakes, each of which
/// would evaluate its own copy).
const VISIBILITY_DILATION: usize = 3;

/// How the direct-to-indirect (one-bounce) part is computed.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[non_exhaustive]
pub enum IndirectMode {
    /// Per-surface-point transfer vectors, each computed once (the first time a voxel ray's hit
    /// needs it) and interpolated at every voxel-ray hit (cost: touched cache points x
    /// `cache_rays`, independent of the voxel count). The default.
    #[default]
    SurfaceCache,
    /// `cache_rays` fresh hemisphere rays at every voxel-ray hit: the unbiased reference that
    /// validates the cache (cost: voxels x rays per voxel x `cache_rays`).
    BruteForce,
    /// Direct part only; the indirect blocks are zero.
    Off,
}

/// Options of [`TransferBaker`].
#[derive(Debug, Clone, PartialEq)]
pub struct BakeOptions {
    /// Grid resolution `[nx, ny, nz]`.
    pub resolution: [usize; 3],
    /// World-space margin added on every side of the scene bounds to form the grid box (ignored
    /// when `bounds` is given). An axis along which that box is still flat (a planar scene,
    /// margin 0) gets a thickness of one voxel edge of the longest axis.
    pub margin: f32,
    /// Explicit grid box. Voxels whose centre lies outside the scene bounds grown by `margin`
    /// are then not traced: they are zero and invalid.
    pub bounds: Option<Aabb>,
    /// Directions per voxel, rounded up to a multiple of 12 (whole rotated icosahedra; of 48,
    /// whole rounds of the [`REPLICATES`] streams, with adaptive sampling or the denoiser); at
    /// most 12 x 2^16.
    pub rays_per_voxel: usize,
    /// Cosine-weighted hemisphere rays per surface-cache point (and per hit in brute force); at
    /// most 2^16.
    pub cache_rays: usize,
    /// Largest spacing between surface-cache points on a triangle; `None`: the mean voxel edge. A triangle gets at most 128 subdivisions per edge, and the spacing grows by steps of
    /// 1.5x while the whole cache would exceed 4 million points.
    pub cache_spacing: Option<f32>,
    /// The validity of a voxel is decided on its first `probe_rays` directions (rounded up to a
    /// multiple of 12, at most `rays_per_voxel`): an invalid voxel costs only those.
    pub probe_rays: usize,
    /// A voxel is invalid (inside geometry) when more than this fraction of its probe rays hit
    /// a back face.
    pub max_backface_fraction: f32,
    /// How the one-bounce part is computed.
    pub indirect: IndirectMode,
    /// Seed of every random choice; the result depends on it and on nothing else (not on the
    /// thread count).
    pub seed: u64,
    /// BVH build quality.
    pub build_quality: BuildQuality,
    /// Opt-in: per-voxel adaptive sampling ([`AdaptiveSampling`]); `rays_per_voxel` is then the
    /// cap. `None`: every valid voxel traces `rays_per_voxel` directions.
    pub adaptive: Option<AdaptiveSampling>,
    /// Opt-in: the geometry-aware denoiser ([`DenoiseOptions`]) applied to the traced volume.
    pub denoise: Option<DenoiseOptions>,
}

/// Per-voxel adaptive sampling to a target standard error (an opt-in of [`BakeOptions`]).
///
/// A voxel's directions come from [`REPLICATES`] independently Owen-scrambled Sobol' streams of
/// rotated icosahedra, traced in rounds of one icosahedron per stream (48 directions); each
/// stream stays stratified, and the spread of the streams' means estimates the variance of the
/// voxel's transfer without bias. After `min_rays` (and the validity probe) a voxel stops at
/// the first round where that standard error, `sqrt(Σ_k Var(t̂_k))`, is at most
/// `target_error · ‖t̂‖`, or at the cap `rays_per_voxel`. Deterministic for a seed: each voxel's
/// rounds depend on its own rays only.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AdaptiveSampling {
    /// Relative standard error of the voxel's 324-D transfer vector at which it stops.
    pub target_error: f32,
    /// Directions every valid voxel traces at least (rounded up to whole rounds).
    pub min_rays: usize,
}

/// 5 % relative standard error after at least 96 directions.
impl Default for AdaptiveSampling {
    fn default() -> Self {
        Self {
            target_error: 0.05,
            min_rays: 96,
        }
    }
}

/// 32³ voxels over the scene bounds (no margin), 256 (→ 264) directions per voxel, 64 cache rays
/// per surface point at a mean-voxel-edge spacing, validity from 48 probe rays with at most 25 %
/// back faces, surface-cache indirect, seed 0, medium BVH; neither adaptive sampling nor the
/// denoiser (the paper's estimator).
impl Default for BakeOptions {
    fn default() -> Self {
        Self {
            resolution: [32; 3],
            margin: 0.0,
            bounds: None,
            rays_per_voxel: 256,
            cache_rays: 64,
            cache_spacing: None,
            probe_rays: 48,
            max_backface_fraction: 0.25,
            indirect: IndirectMode::SurfaceCache,
            seed: 0,
            build_quality: BuildQuality::Medium,
            adaptive: None,
            denoise: None,
        }
    }
}

/// Counters and timings of one bake.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct BakeStats {
    /// Voxels in the grid.
    pub voxels: usize,
    /// Voxels marked invalid by the back-face test.
    pub invalid_voxels: usize,
    /// Voxels outside the scene bounds plus margin (not traced).
    pub skipped_voxels: usize,
    /// Effective directions per voxel (a multiple of 12; with adaptive sampling, the cap).
    pub rays_per_voxel: usize,
    /// Surface-cache lattice points allocated (both sides of a point count once).
    pub cache_points: usize,
    /// Surface-cache entries (point sides) evaluated: those some voxel ray needed.
    pub cache_evaluated: usize,
    /// Rays traced for the surface cache.
    pub cache_rays: u64,
    /// Rays traced from voxels (plus brute-force hemisphere rays).
    pub voxel_rays: u64,
    /// BVH build time.
    pub bvh_time: Duration,
    /// Surface-cache lattice set-up time (its rays are traced during the voxel stage).
    pub cache_time: Duration,
    /// Voxel tracing time, including the surface-cache rays.
    pub voxel_time: Duration,
    /// Time of the denoiser (zero without it).
    pub denoise_time: Duration,
}

impl BakeStats {
    /// Voxels traced and valid.
    pub fn valid_voxels(&self) -> usize {
        self.voxels - self.invalid_voxels - self.skipped_voxels
    }

    /// The fraction of the grid's voxels that are valid (0 for an empty grid).
    pub fn valid_fraction(&self) -> f64 {
        if self.voxels == 0 {
            0.0
        } else {
            self.valid_voxels() as f64 / self.voxels as f64
        }
    }

    /// All rays traced.
    pub fn rays(&self) -> u64 {
        self.cache_rays + self.voxel_rays
    }

    /// Rays per second over the cache and voxel stages, in millions.
    pub fn mrays_per_second(&self) -> f64 {
        let t = (self.cache_time + self.voxel_time).as_secs_f64();
        if t > 0.0 {
            self.rays() as f64 / t / 1e6
        } else {
            0.0
        }
    }
}

/// The baker's output.
#[derive(Debug, Clone)]
pub struct TransferVolume {
    /// `voxels × 324` transfer vectors, layout `[direct 81 | R 81 | G 81 | B 81]`; each block is
    /// a 9×9 matrix stored row-major, `T[i * 9 + j]`, row `i` the SH coefficient of incident
    /// radiance at the voxel and column `j` the SH coefficient of the sky. Incident radiance in
    /// channel c is `l_i = Σ_j (D_ij + T^c_ij) s^c_j` for a sky with SH coefficients `s^c`.
    pub field: GridField,
    /// Per voxel: `false` for voxels inside geometry (too many back-face hits) or outside the
    /// scene bounds; their transfer is zero. Engines use it against light leaks.
    pub valid: Vec<bool>,
    /// Counters and timings.
    pub stats: BakeStats,
}

/// SH coefficients (order 3) of a constant sky of radiance `radiance`.
pub fn constant_sky(radiance: f32) -> [f32; SH9] {
    let mut s = [0.0; SH9];
    s[0] = radiance * 2.0 * PI.sqrt();
    s
}

/// Incident-radiance SH at a point (per channel R, G, B) from its 324-D transfer vector `t`
/// (layout of [`TransferVolume::field`]) lit by `sky`: `l^c_i = Σ_j (D_ij + T^c_ij) s^c_j`,
/// accumulated in f64. Linear in `t`, so it also lights any linear combination of transfer
/// vectors (an MBD basis vector, a PCA mean).
///
/// # Panics
/// If `t` does not hold [`TRANSFER_DIM`] values.
pub fn incident_radiance(t: &[f32], sky: &prt_sphere::Sky) -> [[f32; SH9]; 3] {
    assert_eq!(
        t.len(),
        TRANSFER_DIM,
        "a transfer vector has {TRANSFER_DIM} values"
    );
    let direct = &t[block(0)];
    let mut out = [[0.0f32; SH9]; 3];
    for (c, l) in out.iter_mut().enumerate() {
        let indirect = &t[block(c + 1)];
        let s = &sky.sh[c];
        for (i, li) in l.iter_mut().enumerate() {
            let row = i * SH9..(i + 1) * SH9;
            *li = direct[row.clone()]
                .iter()
                .zip(&indirect[row])
                .zip(s)
                .map(|((&d, &r), &sj)| (f64::from(d) + f64::from(r)) * f64::from(sj))
                .sum::<f64>() as f32;
        }
    }
    out
}

/// The clamped cosine's zonal factors per SH9 coefficient (A0 = π, A1 = 2π/3, A2 = π/4;
/// Ramamoorthi & Hanrahan 2001): irradiance is `Σ_i A_i l_i Y_i(n)`.
pub const CLAMPED_COSINE: [f32; SH9] = [
    PI,
    2.0 * PI / 3.0,
    2.0 * PI / 3.0,
    2.0 * PI / 3.0,
    PI / 4.0,
    PI / 4.0,
    PI / 4.0,
    PI / 4.0,
    PI / 4.0,
];

/// Irradiance `E(n) = ∫ L(ω) max(0, n·ω) dω` on a surface of unit normal `n` from radiance SH
/// `l`, by zonal convolution with the clamped cosine ([`CLAMPED_COSINE`]).
pub fn irradiance(l: &[f32; SH9], n: Vec3) -> f32 {
    let y = sh9(n);
    (0..SH9).map(|i| CLAMPED_COSINE[i] * l[i] * y[i]).sum()
}

impl TransferVolume {
    /// Incident-radiance SH at voxel `v`, `[direct, indirect R, indirect G, indirect B]`, for a
    /// sky with per-channel SH `sky` (R, G, B). The direct part is the same matrix for every
    /// channel; it is returned for channel R's sky (pass a grey sky for a single direct image).
    ///
    /// # Panics
    /// If `v` is not a voxel index of the field.
    pub fn incident(&self, v: usize, sky: &[[f32; SH9]; 3]) -> [[f32; SH9]; 4] {
        let t = self.field.voxel(v);
        let mut out = [[0.0; SH9]; 4];
        for k in 0..4usize {
            let s = &sky[k.saturating_sub(1)];
            let m = &t[block(k)];
            for i in 0..SH9 {
                out[k][i] = (0..SH9).map(|j| m[i * SH9 + j] * s[j]).sum();
            }
        }
        out
    }

    /// Fraction of the sphere of directions from voxel `v` that reaches the sky (`D_00`).
    ///
    /// # Panics
    /// If `v` is not a voxel index of the field.
    pub fn sky_visibility(&self, v: usize) -> f32 {
        self.field.voxel(v)[0]
    }
}

/// Per-slot surface data the hot loop reads (BVH order).
#[derive(Debug, Clone, Copy)]
struct SlotMaterial {
    albedo: [f32; 3],
    double_sided: bool,
}

/// Per-surface-point SH irradiance-transfer vectors `t_j(p) = (1/π) ∫_H V(p, ω) (n·ω) Y_j(ω) dω`
/// on a barycentric lattice over each triangle, for each side.
#[derive(Debug, Clone)]
pub(crate) struct SurfaceCache {
    /// First point of each slot.
    start: Vec<u32>,
    /// Lattice subdivision of each slot (0: a single point at the centroid).
    subdiv: Vec<u16>,
    /// Position and unit front normal of every lattice point.
    points: Vec<(Vec3, Vec3)>,
    /// `[point * 2 + side]`, side 0 = front, 1 = back; evaluated on first use. Each value is a
    /// pure function of (seed, point, side), so which thread evaluates it does not matter.
    values: Vec<OnceLock<[f32; SH9]>>,
    /// The seed its entries are evaluated with (a shared cache's, else the bake's).
    seed: u64,
    /// Entries a shared cache gave (not evaluated by this bake).
    given: usize,
}

fn lattice_len(m: usize) -> usize {
    if m == 0 { 1 } else { (m + 1) * (m + 2) / 2 }
}

fn lattice_index(m: usize, a: usize, b: usize) -> usize {
    // Row a (= 0..=m) holds the m + 1 - a points b = 0..=m - a.
    a * (m + 1) - a * a.saturating_sub(1) / 2 + b
}

impl SurfaceCache {
    /// A 64-bit FNV-1a hash of the lattice (each slot's subdivision, each point's position and
    /// normal): equal lattices, equal hashes; a shared cache laid on another lattice is refused.
    fn layout_hash(&self) -> u64 {
        let mut hash = 0xcbf2_9ce4_8422_2325u64;
        let mut eat = |bytes: &[u8]| {
            for &b in bytes {
                hash = (hash ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3);
            }
        };
        for &m in &self.subdiv {
            eat(&m.to_le_bytes());
        }
        for (p, n) in &self.points {
            for x in p.to_array().into_iter().chain(n.to_array()) {
                eat(&x.to_bits().to_le_bytes());
            }
        }
        hash
    }

    /// Lattice points (both sides of a point count once).
    pub(crate) fn points(&self) -> usize {
        self.values.len() / 2
    }

    /// Entries (point sides) this bake evaluated so far (not those a shared cache gave).
    pub(crate) fn evaluated(&self) -> usize {
        self.values.iter().filter(|v| v.get().is_some()).count() - self.given
    }

    #[inline]
    /// The interpolated transfer of `side` of `slot` at the barycentrics `uv()`, evaluating
    /// missing lattice entries with `eval(point, side)`.
    fn lookup(
        &self,
        slot: u32,
        side: usize,
        uv: impl FnOnce() -> Vec2,
        eval: impl Fn(usize, usize) -> [f32; SH9],
    ) -> [f32; SH9] {
        let value = |point: usize| self.values[point * 2 + side].get_or_init(|| eval(point, side));
        let Corners::Three(points, weights) = self.corners(slot, uv) else {
            return *value(self.start[slot as usize] as usize);
        };
        let mut out = [0.0f32; SH9];
        for (&point, &w) in points.iter().zip(&weights) {
            let v = value(point);
            for k in 0..SH9 {
                out[k] += w * v[k];
            }
        }
        out
    }

    #[inline]
    /// The lattice points [`SurfaceCache::lookup`] interpolates on `slot` at the barycentrics
    /// `uv()`.
    fn corners(&self, slot: u32, uv: impl FnOnce() -> Vec2) -> Corners {
        let s = slot as usize;
        let start = self.start[s] as usize;
        let m = self.subdiv[s] as usize;
        if m == 0 {
            return Corners::One(start);
        }
        let uv = uv();
        let fu = (uv.x.clamp(0.0, 1.0)) * m as f32;
        let fv = (uv.y.clamp(0.0, 1.0)) * m as f32;
        let i = (fu.floor() as usize).min(m - 1);
        let j = (fv.floor() as usize).min(m - 1 - i);
        let du = (fu - i as f32).clamp(0.0, 1.0);
        let dv = (fv - j as f32).clamp(0.0, 1.0);
        let (corners, weights) = if du + dv <= 1.0 || i + j + 2 > m {
            let w0 = (1.0 - du - dv).max(0.0);
            ([(i, j), (i + 1, j), (i, j + 1)], [w0, du, dv])
        } else {
            (
                [(i + 1, j + 1), (i, j + 1), (i + 1, j)],
                [du + dv - 1.0, 1.0 - du, 1.0 - dv],
            )
        };
        Corners::Three(
            corners.map(|(a, b)| start + lattice_index(m, a, b)),
            weights,
        )
    }
}

impl SurfaceCache {
    /// Marks in `hits` the lattice neighbours (same slot, same side) of every marked entry.
    fn dilate(&self, hits: &[AtomicBool]) {
        let before: Vec<bool> = hits.iter().map(|h| h.load(Ordering::Relaxed)).collect();
        for (s, &m) in self.subdiv.iter().enumerate() {
            let m = m as usize;
            if m == 0 {
                continue;
            }
            let start = self.start[s] as usize;
            for side in 0..2 {
                for a in 0..=m {
                    for b in 0..=(m - a) {
                        if !before[(start + lattice_index(m, a, b)) * 2 + side] {
                            continue;
                        }
                        let (a, b) = (a as i64, b as i64);
                        for (da, db) in [(1, 0), (-1, 0), (0, 1), (0, -1), (1, -1), (-1, 1)] {
                            let (na, nb) = (a + da, b + db);
                            if na < 0 || nb < 0 || na + nb > m as i64 {
                                continue;
                            }
                            let p = start + lattice_index(m, na as usize, nb as usize);
                            hits[p * 2 + side].store(true, Ordering::Relaxed);
                        }
                    }
                }
            }
        }
    }
}

/// The lattice points a surface-cache lookup reads.
enum Corners {
    /// A slot of a single point.
    One(usize),
    /// The corners of the lattice cell hit, with their interpolation weights.
    Three([usize; 3], [f32; 3]),
}

/// A surface cache evaluated ahead of the bakes that share it
/// ([`TransferBaker::evaluate_surface_cache`], [`TransferBaker::with_surface_cache`]): the
/// tiles of a tiled bake trace it once between them.
#[derive(Debug, Clone, PartialEq)]
pub struct SharedSurfaceCache {
    /// The spacing its lattice was laid with (after the point budget's coarsening).
    pub spacing: f32,
    /// A hash of its lattice (slot subdivisions, point positions and normals) that a bake
    /// using it must reproduce.
    pub layout: u64,
    /// The seed its rays were scrambled with.
    pub seed: u64,
    /// Hemisphere rays per entry.
    pub cache_rays: usize,
    /// Rays traced to find the entries to evaluate and to evaluate them.
    pub rays: u64,
    /// Of `rays`, those traced to find the entries voxel rays hit.
    pub visibility_rays: u64,
    /// Wall time of laying and evaluating it.
    pub time: Duration,
    /// Per entry (`point * 2 + side`, side 0 the front): its SH9 transfer, `None` for one not
    /// evaluated ahead (no ray of the visibility pass hit it).
    pub values: Vec<Option<[f32; SH9]>>,
}

impl SharedSurfaceCache {
    /// Lattice points (both sides of a point count once).
    pub fn points(&self) -> usize {
        self.values.len() / 2
    }

    /// Entries evaluated.
    pub fn evaluated(&self) -> usize {
        self.values.iter().filter(|v| v.is_some()).count()
    }
}

/// Bakes transfer volumes of one scene (see the crate docs for the method).
///
/// ```
/// use prt_core::NoProgress;
/// use prt_trace::{BakeOptions, Scene, TransferBaker};
///
/// let scene = Scene::cornell_box();
/// let options = BakeOptions { resolution: [4, 4, 4], rays_per_voxel: 48, cache_rays: 16, ..Default::default() };
/// let volume = TransferBaker::new(&scene, options)?.bake(&NoProgress)?;
/// assert_eq!(volume.field.dim(), 324);
/// assert_eq!(volume.valid.len(), 64);
/// # Ok::<(), prt_trace::TraceError>(())
/// ```
#[derive(Debug)]
pub struct TransferBaker<'s> {
    scene: &'s Scene,
    pub(crate) options: BakeOptions,
    /// Shared with the bakes of parts of this one's scene ([`TransferBaker::part`]).
    tracer: Arc<RayTracer>,
    materials: Vec<SlotMaterial>,
    grid: Aabb,
    /// Voxels whose centre is outside this box are skipped.
    trace_box: Option<Aabb>,
    /// Ray-origin offset off surfaces.
    eps: f32,
    /// Icosahedra per voxel (the cap with adaptive sampling).
    groups: usize,
    probe_groups: usize,
    /// Icosahedra every valid voxel traces before adaptive sampling may stop it.
    min_groups: usize,
    /// Whether directions come from [`REPLICATES`] streams (the variance is measured).
    replicated: bool,
    pub(crate) bvh_time: Duration,
    /// A surface cache evaluated ahead ([`TransferBaker::with_surface_cache`]), used instead of
    /// building one.
    shared_cache: Option<SurfaceCache>,
}

impl<'s> TransferBaker<'s> {
    /// Validates the options and builds the BVH.
    ///
    /// Errors: [`TraceError::EmptyScene`] for a scene without triangles unless
    /// `options.bounds` is given; [`TraceError::InvalidOption`] for a zero resolution, zero rays,
    /// a negative or non-finite margin or spacing, or invalid bounds.
    pub fn new(scene: &'s Scene, options: BakeOptions) -> Result<Self, TraceError> {
        Self::build(scene, options, None)
    }

    /// A baker of the same scene with `options`, validated as [`TransferBaker::new`] validates
    /// them, on this baker's ray tracer (no BVH is built; its build quality is this one's):
    /// e.g. a tile of this bake's grid, whose surface-cache slots are this bake's.
    fn part(&self, options: BakeOptions) -> Result<Self, TraceError> {
        let options = BakeOptions {
            build_quality: self.options.build_quality,
            ..options
        };
        Self::build(self.scene, options, Some(Arc::clone(&self.tracer)))
    }

    /// [`TransferBaker::new`] on `tracer` when given, else on a BVH built here.
    fn build(
        scene: &'s Scene,
        options: BakeOptions,
        tracer: Option<Arc<RayTracer>>,
    ) -> Result<Self, TraceError> {
        let invalid = |what, why: String| Err(TraceError::InvalidOption { what, why });
        if options.resolution.contains(&0) {
            return invalid(
                "resolution",
                format!("{:?} has a zero axis", options.resolution),
            );
        }
        if options.rays_per_voxel == 0 {
            return invalid("rays_per_voxel", "must be positive".into());
        }
        // Sobol' sample indices (icosahedra per voxel, cache rays per point) must stay below 2^16.
        if options.rays_per_voxel > ICOSA << 16 {
            return invalid(
                "rays_per_voxel",
                format!("{} exceeds {}", options.rays_per_voxel, ICOSA << 16),
            );
        }
        if options.cache_rays > 1 << 16 {
            return invalid(
                "cache_rays",
                format!("{} exceeds {}", options.cache_rays, 1 << 16),
            );
        }
        if options.indirect != IndirectMode::Off && options.cache_rays == 0 {
            return invalid(
                "cache_rays",
                "must be positive when the indirect part is computed".into(),
            );
        }
        if !(options.margin.is_finite() && options.margin >= 0.0) {
            return invalid(
                "margin",
                format!("{} is not a finite non-negative length", options.margin),
            );
        }
        if let Some(s) = options.cache_spacing
            && !(s.is_finite() && s > 0.0)
        {
            return invalid(
                "cache_spacing",
                format!("{s} is not a finite positive length"),
            );
        }
        if let Some(a) = options.adaptive {
            if !(a.target_error.is_finite() && a.target_error >= 0.0) {
                return invalid(
                    "adaptive.target_error",
                    format!("{} is not a finite non-negative error", a.target_error),
                );
            }
            if a.min_rays == 0 {
                return invalid("adaptive.min_rays", "must be positive".into());
            }
        }
        if let Some(d) = options.denoise {
            d.validate()?;
        }
        if !(0.0..=1.0).contains(&options.max_backface_fraction) {
            return invalid(
                "max_backface_fraction",
                format!("{} is outside [0, 1]", options.max_backface_fraction),
            );
        }
        let scene_bounds = scene.bounds();
        let (grid, trace_box) = match (options.bounds, scene_bounds) {
            (Some(b), sb) => {
                if !b.is_valid() {
                    return invalid("bounds", format!("{b:?} is not a finite box"));
                }
                (b, sb.map(|s| s.expand(options.margin)))
            }
            (None, Some(sb)) => (
                thicken_flat_axes(sb.expand(options.margin), options.resolution),
                None,
            ),
            (None, None) => return Err(TraceError::EmptyScene),
        };
        let diag = scene_bounds.map_or(1.0, |b| b.size().length()).max(1e-6);
        let replicated = options.adaptive.is_some() || options.denoise.is_some();
        let round = if replicated { REPLICATES } else { 1 };
        let groups = options
            .rays_per_voxel
            .div_ceil(ICOSA)
            .next_multiple_of(round);
        let probe_groups = options.probe_rays.div_ceil(ICOSA).clamp(1, groups);
        let min_groups = options.adaptive.map_or(groups, |a| {
            a.min_rays
                .div_ceil(ICOSA)
                .max(probe_groups)
                .next_multiple_of(round)
                .min(groups)
        });
        let t0 = Instant::now();
        let tracer = tracer.unwrap_or_else(|| {
            Arc::new(RayTracer::with_quality(
                scene.triangles(),
                options.build_quality,
            ))
        });
        let bvh_time = t0.elapsed();
        let materials = (0..tracer.slots() as u32)
            .map(|s| {
                let m = scene.material_of(tracer.scene_triangle(s) as usize);
                SlotMaterial {
                    albedo: m.albedo.to_array(),
                    double_sided: m.double_sided,
                }
            })
            .collect();
        Ok(Self {
            scene,
            options,
            tracer,
            materials,
            grid,
            trace_box,
            eps: 1e-4 * diag,
            groups,
            probe_groups,
            min_groups,
            replicated,
            bvh_time,
            shared_cache: None,
        })
    }

    /// The ray tracer built over the scene.
    pub fn tracer(&self) -> &RayTracer {
        &self.tracer
    }

    /// The scene being baked.
    pub fn scene(&self) -> &Scene {
        self.scene
    }

    /// The box the grid covers.
    pub fn grid_bounds(&self) -> Aabb {
        self.grid
    }

    /// Effective directions per voxel (a multiple of 12; with adaptive sampling, the cap).
    pub fn rays_per_voxel(&self) -> usize {
        self.groups * ICOSA
    }

    fn cache_spacing(&self) -> f32 {
        self.options.cache_spacing.unwrap_or_else(|| {
            let [nx, ny, nz] = self.options.resolution;
            let cell = self.grid.size() / Vec3::new(nx as f32, ny as f32, nz as f32);
            // A flat grid axis (zero extent) does not count.
            let axes = cell.cmpgt(Vec3::ZERO).bitmask().count_ones().max(1);
            (cell.element_sum() / axes as f32).max(1e-6)
        })
    }

    /// Hemisphere transfer `t_j = (1/R) Σ_k V(ω_k) Y_j(ω_k)` with R cosine-weighted rays about `n`.
    fn hemisphere_transfer(&self, p: Vec3, n: Vec3, scramble: u32) -> [f32; SH9] {
        let origin = p + n * self.eps;
        let r = self.options.cache_rays;
        let mut acc = [0.0f32; SH9];
        for k in 0..r as u32 {
            let [u1, u2, _, _] = sobol_burley::sample_4d(k, 0, scramble);
            let w = cosine_hemisphere(n, u1, u2);
            if !self.tracer.occluded(origin, w, 0.0, f32::INFINITY) {
                let y = sh9(w);
                for j in 0..SH9 {
                    acc[j] += y[j];
                }
            }
        }
        acc.map(|a| a / r as f32)
    }

    /// Lattice subdivision of every slot for a spacing (0: one point at the centroid).
    fn subdivisions(&self, spacing: f32) -> Vec<u16> {
        (0..self.tracer.slots() as u32)
            .map(|s| {
                let v = self.tracer.slot_vertices(s);
                let longest = (v[1] - v[0])
                    .length()
                    .max((v[2] - v[0]).length())
                    .max((v[2] - v[1]).length());
                if longest <= spacing {
                    0
                } else {
                    (longest / spacing).ceil().min(MAX_SUBDIV as f32) as u16
                }
            })
            .collect()
    }

    /// The surface cache's lattice, unevaluated, and the spacing it was laid with.
    fn build_cache(&self) -> (SurfaceCache, f32) {
        // Coarsen the spacing until the lattice fits the point budget (deterministically).
        let mut spacing = self.cache_spacing();
        let mut subdiv = self.subdivisions(spacing);
        // (At worst one point per triangle remains, which the triangle count already paid for.)
        while subdiv
            .iter()
            .map(|&m| lattice_len(m as usize))
            .sum::<usize>()
            > MAX_CACHE_POINTS
            && subdiv.iter().any(|&m| m > 0)
        {
            spacing *= 1.5;
            subdiv = self.subdivisions(spacing);
        }
        (self.lay_cache(subdiv), spacing)
    }

    /// The unevaluated surface cache of lattice subdivisions `subdiv` (one per slot).
    fn lay_cache(&self, subdiv: Vec<u16>) -> SurfaceCache {
        let slots = self.tracer.slots();
        let mut start = Vec::with_capacity(slots);
        // (point, front normal) for every lattice point.
        let mut points: Vec<(Vec3, Vec3)> = Vec::new();
        for s in 0..slots as u32 {
            let v = self.tracer.slot_vertices(s);
            let n = self.tracer.slot_normal(s).normalize_or_zero();
            let m = subdiv[s as usize] as usize;
            start.push(points.len() as u32);
            let centroid = (v[0] + v[1] + v[2]) / 3.0;
            if m == 0 {
                points.push((centroid, n));
                continue;
            }
            for a in 0..=m {
                for b in 0..=(m - a) {
                    let p = v[0]
                        + (v[1] - v[0]) * (a as f32 / m as f32)
                        + (v[2] - v[0]) * (b as f32 / m as f32);
                    points.push((p + (centroid - p) * CACHE_SHRINK, n));
                }
            }
        }
        let values = (0..points.len() * 2).map(|_| OnceLock::new()).collect();
        SurfaceCache {
            start,
            subdiv,
            points,
            values,
            seed: self.options.seed,
            given: 0,
        }
    }

    /// The validity test of [`TransferBaker::voxel_transfer`] alone: the same probe rays, only
    /// counted. Returns `(valid, distance to the nearest hit or infinity, rays traced)`; the
    /// validity equals `voxel_transfer`'s bit for bit (same directions, same test).
    pub(crate) fn probe_voxel(&self, x: Vec3, voxel: usize) -> (bool, f32, u64) {
        let dirs = icosahedron();
        let mut backfaces = 0usize;
        let mut nearest = f32::INFINITY;
        for g in 0..self.probe_groups {
            let q = self.rotation(voxel, g);
            for &d in dirs.iter() {
                let w = q * d;
                if let Some(hit) = self.tracer.closest_slot(x, w, 0.0, f32::INFINITY) {
                    nearest = nearest.min(hit.t);
                    if self.tracer.slot_normal(hit.slot).dot(w) >= 0.0 {
                        backfaces += 1;
                    }
                }
            }
        }
        let rays = (self.probe_groups * ICOSA) as u64;
        (!self.probe_rejects(backfaces), nearest, rays)
    }

    /// Whether `backfaces` of the probe rays make a voxel invalid (inside geometry).
    fn probe_rejects(&self, backfaces: usize) -> bool {
        backfaces as f32 > self.options.max_backface_fraction * (self.probe_groups * ICOSA) as f32
    }

    /// Whether voxel centre `x` lies outside the traced box (explicit bounds only).
    pub(crate) fn outside_trace_box(&self, x: Vec3) -> bool {
        self.trace_box.is_some_and(|b| !b.contains(x))
    }

    /// The grid of voxels the baker traces (zero-valued).
    pub(crate) fn empty_field(&self, dim: usize) -> Result<GridField, TraceError> {
        Ok(GridField::new(self.options.resolution, self.grid, dim)?)
    }

    /// The surface cache the indirect mode needs (`None` without one): a copy of the one given
    /// to [`TransferBaker::with_surface_cache`] (what this bake evaluates stays its own), else a
    /// fresh one; and its set-up time.
    pub(crate) fn surface_cache(&self) -> (Option<SurfaceCache>, Duration) {
        let t0 = Instant::now();
        let cache = match (self.options.indirect, &self.shared_cache) {
            (IndirectMode::SurfaceCache, Some(shared)) => Some(shared.clone()),
            (IndirectMode::SurfaceCache, None) => Some(self.build_cache().0),
            (IndirectMode::BruteForce | IndirectMode::Off, _) => None,
        };
        (cache, t0.elapsed())
    }

    /// Marks in `hits` (`point * 2 + side`) the entries of `cache` that the first
    /// [`VISIBILITY_GROUPS`] icosahedra of this bake's voxels look up: the rays its bake traces
    /// first, closest hits only. Returns the rays traced.
    fn mark_cache_hits(
        &self,
        cache: &SurfaceCache,
        hits: &[AtomicBool],
        progress: &dyn Progress,
    ) -> Result<u64, TraceError> {
        if self.options.indirect != IndirectMode::SurfaceCache {
            return Ok(0);
        }
        let grid = self.empty_field(1)?;
        let groups = VISIBILITY_GROUPS.min(self.groups);
        let traced = AtomicU64::new(0);
        let mark =
            |point: usize, side: usize| hits[point * 2 + side].store(true, Ordering::Relaxed);
        (0..grid.num_voxels())
            .into_par_iter()
            .with_min_len(VOXEL_CHUNK)
            .try_for_each(|v| {
                progress.check()?;
                progress.inc(1);
                let x = grid.centre_of(v);
                if self.outside_trace_box(x) {
                    return Ok(());
                }
                for g in 0..groups {
                    let q = self.rotation(v, g);
                    for &d in icosahedron().iter() {
                        let w = q * d;
                        let Some(hit) = self.tracer.closest_slot(x, w, 0.0, f32::INFINITY) else {
                            continue;
                        };
                        let front = self.tracer.slot_normal(hit.slot).dot(w) < 0.0;
                        if !(front || self.materials[hit.slot as usize].double_sided) {
                            continue;
                        }
                        let side = usize::from(!front);
                        let uv = || self.tracer.slot_barycentrics(hit.slot, x, w);
                        match cache.corners(hit.slot, uv) {
                            Corners::One(point) => mark(point, side),
                            Corners::Three(points, _) => {
                                points.into_iter().for_each(|p| mark(p, side))
                            }
                        }
                    }
                }
                traced.fetch_add((groups * ICOSA) as u64, Ordering::Relaxed);
                Ok::<(), TraceError>(())
            })?;
        Ok(traced.into_inner())
    }

    /// Evaluates ahead the part of this bake's surface cache that the bakes of `parts` (bakes
    /// of this scene, e.g. the tiles of this bake's grid) look up with the first icosahedron of
    /// each voxel, grown by three lattice steps on each triangle; each entry the value a bake
    /// with these options computes on first use. A bake
    /// given it ([`TransferBaker::with_surface_cache`]) evaluates any other entry its rays hit
    /// on first use, with the same seed, so the cache's values and the bake's bytes do not
    /// depend on which entries were evaluated ahead. Use it to share one cache between bakes of
    /// parts of one grid (the tiles of a tiled bake) so that they trace the entries most of
    /// them need once. Deterministic for the seed on any thread count. Errors:
    /// [`TraceError::InvalidOption`] when the indirect mode has no surface cache or a part's
    /// options are invalid, [`TraceError::Core`]`(Cancelled)` when cancelled.
    pub fn evaluate_surface_cache(
        &self,
        parts: &[BakeOptions],
        progress: &dyn Progress,
    ) -> Result<SharedSurfaceCache, TraceError> {
        if self.options.indirect != IndirectMode::SurfaceCache {
            return Err(TraceError::InvalidOption {
                what: "indirect",
                why: format!("{:?} has no surface cache", self.options.indirect),
            });
        }
        let t0 = Instant::now();
        let (cache, spacing) = self.build_cache();
        let entries = cache.values.len();
        let hits: Vec<AtomicBool> = (0..entries).map(|_| AtomicBool::new(false)).collect();
        progress.message("surface cache: the entries voxel rays hit");
        progress.set_len(
            parts
                .iter()
                .map(|o| o.resolution.iter().product::<usize>() as u64)
                .sum(),
        );
        let mut visibility_rays = 0;
        for options in parts {
            visibility_rays += self
                .part(options.clone())?
                .mark_cache_hits(&cache, &hits, progress)?;
        }
        for _ in 0..VISIBILITY_DILATION {
            cache.dilate(&hits);
        }
        progress.message("surface cache");
        progress.set_len(entries as u64);
        let values = (0..entries)
            .into_par_iter()
            .with_min_len(256)
            .map(|entry| {
                let (point, side) = (entry / 2, entry % 2);
                progress.check()?;
                progress.inc(1);
                if !hits[entry].load(Ordering::Relaxed) {
                    return Ok(None);
                }
                let (p, n) = cache.points[point];
                let n = if side == 0 { n } else { -n };
                let scramble = hash_seed(self.options.seed, STREAM_CACHE, entry as u64);
                Ok(Some(self.hemisphere_transfer(p, n, scramble)))
            })
            .collect::<Result<Vec<_>, TraceError>>()?;
        let evaluated = values.iter().filter(|v| v.is_some()).count() as u64;
        Ok(SharedSurfaceCache {
            spacing,
            layout: cache.layout_hash(),
            seed: self.options.seed,
            cache_rays: self.options.cache_rays,
            rays: visibility_rays + evaluated * self.options.cache_rays as u64,
            visibility_rays,
            time: t0.elapsed(),
            values,
        })
    }

    /// This baker using `shared` (from [`TransferBaker::evaluate_surface_cache`] of a bake of
    /// the same scene with the same cache knobs, e.g. of the whole grid this one is a part of)
    /// as its surface cache: it traces cache rays only for the entries its rays hit that
    /// `shared` lacks, evaluated with `shared`'s seed. Errors ([`TraceError::InvalidOption`])
    /// when this bake has no surface cache, or `shared` was laid on another lattice (another
    /// scene, spacing or tracer) or with other cache rays.
    pub fn with_surface_cache(mut self, shared: &SharedSurfaceCache) -> Result<Self, TraceError> {
        let invalid = |why: String| TraceError::InvalidOption {
            what: "surface cache",
            why,
        };
        if self.options.indirect != IndirectMode::SurfaceCache {
            return Err(invalid(format!(
                "{:?} has no surface cache",
                self.options.indirect
            )));
        }
        if shared.cache_rays != self.options.cache_rays {
            return Err(invalid(format!(
                "it was traced with {} rays per point, this bake asks for {}",
                shared.cache_rays, self.options.cache_rays
            )));
        }
        if !(shared.spacing.is_finite() && shared.spacing > 0.0) {
            return Err(invalid(format!(
                "its spacing {} is not positive",
                shared.spacing
            )));
        }
        let mut cache = self.lay_cache(self.subdivisions(shared.spacing));
        let layout = cache.layout_hash();
        if layout != shared.layout || cache.values.len() != shared.values.len() {
            return Err(invalid(format!(
                "it was laid on another lattice ({} entries, layout {:016x}; this scene's has {} \
                 entries, layout {layout:016x})",
                shared.values.len(),
                shared.layout,
                cache.values.len()
            )));
        }
        for (slot, value) in cache.values.iter().zip(&shared.values) {
            if let Some(v) = value {
                let _ = slot.set(*v);
                cache.given += 1;
            }
        }
        cache.seed = shared.seed;
        self.shared_cache = Some(cache);
        Ok(self)
    }

    /// The rotation of icosahedron `g` of voxel `voxel`: one Sobol' stream per voxel, or with
    /// replicates, group `g` is number `g / REPLICATES` of stream `g % REPLICATES`.
    fn rotation(&self, voxel: usize, g: usize) -> glam::Quat {
        if self.replicated {
            let stream = (voxel * REPLICATES + g % REPLICATES) as u64;
            let scramble = hash_seed(self.options.seed, STREAM_REPLICATE, stream);
            group_rotation((g / REPLICATES) as u32, scramble)
        } else {
            group_rotation(
                g as u32,
                hash_seed(self.options.seed, STREAM_VOXEL, voxel as u64),
            )
        }
    }

    /// Transfer vector of one voxel into `out` (324 values) and, with replicates, the estimated
    /// variance of its estimate (`Σ_k Var(t̂_k)`, else 0) into `variance`; returns `(valid, rays
    /// traced)`.
    pub(crate) fn voxel_transfer(
        &self,
        x: Vec3,
        voxel: usize,
        cache: Option<&SurfaceCache>,
        cache_rays: &AtomicU64,
        out: &mut [f32],
        variance: &mut f32,
    ) -> (bool, u64) {
        let streams = if self.replicated { REPLICATES } else { 1 };
        let mut acc = [[0.0f64; TRANSFER_DIM]; REPLICATES];
        let mut group = [0.0f32; TRANSFER_DIM];
        let mut backfaces = 0usize;
        let mut rays = 0u64;
        let mut traced = self.groups;
        for g in 0..self.groups {
            let q = self.rotation(voxel, g);
            group.fill(0.0);
            rays += self.trace_group(
                x,
                voxel,
                g,
                q,
                cache,
                cache_rays,
                &mut group,
                &mut backfaces,
            );
            for (a, &gv) in acc[g % streams].iter_mut().zip(group.iter()) {
                *a += gv as f64;
            }
            if g + 1 == self.probe_groups && self.probe_rejects(backfaces) {
                out.fill(0.0);
                *variance = 0.0;
                return (false, rays);
            }
            if let Some(adaptive) = self.options.adaptive
                && (g + 1) % REPLICATES == 0
                && g + 1 >= self.min_groups
                && g + 1 < self.groups
            {
                let (mean, var) = replicate_mean(&acc, (g + 1) / REPLICATES);
                let norm2: f64 = mean.iter().map(|m| m * m).sum();
                if var <= f64::from(adaptive.target_error).powi(2) * norm2 {
                    traced = g + 1;
                    break;
                }
            }
        }
        let (mean, var) = replicate_mean(&acc[..streams], traced / streams);
        for (o, m) in out.iter_mut().zip(mean.iter()) {
            *o = *m as f32;
        }
        *variance = if self.replicated { var as f32 } else { 0.0 };
        (true, rays)
    }

    /// Traces icosahedron `g` (rotation `q`) of voxel `voxel` at `x`, adding its unnormalised
    /// contributions into `group` and its back-face hits into `backfaces`; returns rays traced.
    #[allow(clippy::too_many_arguments)]
    fn trace_group(
        &self,
        x: Vec3,
        voxel: usize,
        g: usize,
        q: glam::Quat,
        cache: Option<&SurfaceCache>,
        cache_rays: &AtomicU64,
        group: &mut [f32; TRANSFER_DIM],
        backfaces: &mut usize,
    ) -> u64 {
        let mut rays = 0u64;
        for (k, &d) in icosahedron().iter().enumerate() {
            let w = q * d;
            let y = sh9(w);
            rays += 1;
            let Some(hit) = self.tracer.closest_slot(x, w, 0.0, f32::INFINITY) else {
                for i in 0..SH9 {
                    for j in 0..SH9 {
                        group[i * SH9 + j] += y[i] * y[j];
                    }
                }
                continue;
            };
            let ng = self.tracer.slot_normal(hit.slot);
            let front = ng.dot(w) < 0.0;
            if !front {
                *backfaces += 1;
            }
            let mat = self.materials[hit.slot as usize];
            if !(front || mat.double_sided) || self.options.indirect == IndirectMode::Off {
                continue;
            }
            let side = usize::from(!front);
            let t = match cache {
                Some(c) => c.lookup(
                    hit.slot,
                    side,
                    || self.tracer.slot_barycentrics(hit.slot, x, w),
                    |point, side| {
                        let (p, n) = c.points[point];
                        let n = if side == 0 { n } else { -n };
                        let scramble = hash_seed(c.seed, STREAM_CACHE, (2 * point + side) as u64);
                        cache_rays.fetch_add(self.options.cache_rays as u64, Ordering::Relaxed);
                        self.hemisphere_transfer(p, n, scramble)
                    },
                ),
                None => {
                    let n = ng.normalize_or_zero() * if front { 1.0 } else { -1.0 };
                    let ray_index = (g * ICOSA + k) as u64;
                    let s = hash_seed(self.options.seed ^ voxel as u64, STREAM_BRUTE, ray_index);
                    rays += self.options.cache_rays as u64;
                    self.hemisphere_transfer(x + w * hit.t, n, s)
                }
            };
            for c in 0..3 {
                let rho_t = t.map(|tj| tj * mat.albedo[c]);
                let base = (c + 1) * SH9 * SH9;
                for i in 0..SH9 {
                    for j in 0..SH9 {
                        group[base + i * SH9 + j] += y[i] * rho_t[j];
                    }
                }
            }
        }
        rays
    }

    /// Bakes the volume. Reports voxel directions traced to `progress` (its length is voxels x
    /// rays per voxel; surface-cache rays are traced along the way) and returns
    /// [`TraceError::Core`]`(Cancelled)` if it is cancelled, [`TraceError::NoValidVoxels`] if
    /// every voxel is inside geometry or outside the scene bounds plus margin (the volume would
    /// be all zero and all masked). [`BakeStats::valid_fraction`] tells how much is valid.
    pub fn bake(&self, progress: &dyn Progress) -> Result<TransferVolume, TraceError> {
        let field = self.empty_field(TRANSFER_DIM)?;
        let voxels = field.num_voxels();
        let cache_rays = AtomicU64::new(0);
        let (cache, cache_time) = self.surface_cache();
        let cache_points = cache.as_ref().map_or(0, SurfaceCache::points);

        let t1 = Instant::now();
        let voxel_rays = AtomicU64::new(0);
        let invalid = AtomicU64::new(0);
        let skipped = AtomicU64::new(0);
        let per_voxel = (self.groups * ICOSA) as u64;
        progress.message("tracing voxels");
        progress.set_len(voxels as u64 * per_voxel);
        let mut valid = vec![false; voxels];
        let mut variance = vec![0.0f32; voxels];
        let mut field = field;
        let centres: Vec<Vec3> = (0..voxels).map(|v| field.centre_of(v)).collect();
        {
            let mut data = field.data_mut();
            let Some(slice) = data.as_slice_mut() else {
                unreachable!("a fresh GridField is in standard layout")
            };
            slice
                .par_chunks_mut(TRANSFER_DIM * VOXEL_CHUNK)
                .zip(valid.par_chunks_mut(VOXEL_CHUNK))
                .zip(variance.par_chunks_mut(VOXEL_CHUNK))
                .enumerate()
                .try_for_each(|(c, ((out, ok), var))| {
                    progress.check()?;
                    let mut rays = 0;
                    for (k, ((o, okv), var)) in out
                        .chunks_exact_mut(TRANSFER_DIM)
                        .zip(ok.iter_mut())
                        .zip(var.iter_mut())
                        .enumerate()
                    {
                        let v = c * VOXEL_CHUNK + k;
                        let x = centres[v];
                        if self.outside_trace_box(x) {
                            skipped.fetch_add(1, Ordering::Relaxed);
                            continue;
                        }
                        let (is_valid, r) =
                            self.voxel_transfer(x, v, cache.as_ref(), &cache_rays, o, var);
                        *okv = is_valid;
                        if !is_valid {
                            invalid.fetch_add(1, Ordering::Relaxed);
                        }
                        rays += r;
                    }
                    voxel_rays.fetch_add(rays, Ordering::Relaxed);
                    progress.inc(ok.len() as u64 * per_voxel);
                    Ok::<(), TraceError>(())
                })?;
        }
        let voxel_time = t1.elapsed();
        let cache_evaluated = cache.as_ref().map_or(0, SurfaceCache::evaluated);
        drop(cache);
        let t2 = Instant::now();
        if let Some(options) = &self.options.denoise {
            let traced = field;
            field = self.empty_field(TRANSFER_DIM)?;
            let targets: Vec<usize> = (0..voxels).collect();
            let sample = |v: usize| valid[v].then(|| (traced.voxel(v), variance[v]));
            let mut data = field.data_mut();
            let Some(out) = data.as_slice_mut() else {
                unreachable!("a fresh GridField is in standard layout")
            };
            progress.message("denoising");
            denoise(
                &traced,
                &self.tracer,
                options,
                &sample,
                &targets,
                out,
                progress,
            )?;
        }
        let stats = BakeStats {
            voxels,
            invalid_voxels: invalid.into_inner() as usize,
            skipped_voxels: skipped.into_inner() as usize,
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
        if stats.valid_voxels() == 0 {
            return Err(TraceError::NoValidVoxels {
                voxels,
                invalid: stats.invalid_voxels,
                skipped: stats.skipped_voxels,
            });
        }
        Ok(TransferVolume {
            field,
            valid,
            stats,
        })
    }
}

/// The mean of the streams' transfer estimates, each the sum `acc[r]` of `groups` icosahedra,
/// and the unbiased estimate of its variance summed over the components,
/// `Σ_k Σ_r (m_rk − m̄_k)² / (R (R − 1))` (0 for a single stream).
pub(crate) fn replicate_mean(
    acc: &[[f64; TRANSFER_DIM]],
    groups: usize,
) -> ([f64; TRANSFER_DIM], f64) {
    let streams = acc.len();
    let scale = 4.0 * std::f64::consts::PI / (groups.max(1) * ICOSA) as f64;
    let mut mean = [0.0f64; TRANSFER_DIM];
    for a in acc {
        for (m, &x) in mean.iter_mut().zip(a.iter()) {
            *m += x * scale;
        }
    }
    mean.iter_mut().for_each(|m| *m /= streams as f64);
    if streams < 2 {
        return (mean, 0.0);
    }
    let spread: f64 = acc
        .iter()
        .map(|a| {
            a.iter()
                .zip(&mean)
                .map(|(&x, &m)| (x * scale - m).powi(2))
                .sum::<f64>()
        })
        .sum();
    (mean, spread / (streams * (streams - 1)) as f64)
}

/// Gives a box derived from a flat scene (all triangles in one axis-aligned plane, no margin)
/// a thickness of one voxel edge of its longest axis along every axis where it has none,
/// centred on the plane, so that the grid and everything fitted over it have a real extent.
fn thicken_flat_axes(b: Aabb, resolution: [usize; 3]) -> Aabb {
    let size = b.size();
    let longest = size.max_element();
    let edge = longest / resolution.iter().copied().max().unwrap_or(1).max(1) as f32;
    let half = Vec3::from_array(std::array::from_fn(|a| {
        if size[a] > 1e-6 * longest {
            0.0
        } else {
            0.5 * edge
        }
    }));
    Aabb::new(b.min - half, b.max + half)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// A one-triangle cache with subdivision `m` whose entries hold an affine function of the
    /// lattice's barycentrics, `f(u, v) = 1 + 2u - 3v` (first component) and `u + v` (second).
    fn affine_cache(m: usize) -> SurfaceCache {
        let n = if m == 0 { 1 } else { (m + 1) * (m + 2) / 2 };
        let values: Vec<OnceLock<[f32; SH9]>> = (0..2 * n).map(|_| OnceLock::new()).collect();
        if m > 0 {
            for a in 0..=m {
                for b in 0..=(m - a) {
                    let (u, v) = (a as f32 / m as f32, b as f32 / m as f32);
                    let mut x = [0.0; SH9];
                    x[0] = 1.0 + 2.0 * u - 3.0 * v;
                    x[1] = u + v;
                    let _ = values[2 * lattice_index(m, a, b)].set(x);
                }
            }
        }
        SurfaceCache {
            start: vec![0],
            subdiv: vec![m as u16],
            points: vec![(Vec3::ZERO, Vec3::Y); n],
            values,
            seed: 0,
            given: 0,
        }
    }

    /// A dilation marks the six lattice neighbours of a marked point on its side only; at a
    /// corner, the two that exist.
    #[test]
    fn a_dilation_marks_the_lattice_neighbours_on_the_same_side() {
        let m = 4;
        let cache = affine_cache(m);
        let marked = |hits: &[AtomicBool], side: usize| {
            (0..hits.len() / 2)
                .filter(|p| hits[p * 2 + side].load(Ordering::Relaxed))
                .count()
        };
        let hits: Vec<AtomicBool> = (0..cache.values.len())
            .map(|_| AtomicBool::new(false))
            .collect();
        hits[2 * lattice_index(m, 1, 1)].store(true, Ordering::Relaxed);
        hits[2 * lattice_index(m, 0, 0) + 1].store(true, Ordering::Relaxed);
        cache.dilate(&hits);
        assert_eq!((marked(&hits, 0), marked(&hits, 1)), (7, 3));
        for (a, b) in [(0, 1), (2, 1), (1, 0), (1, 2), (2, 0), (0, 2)] {
            assert!(hits[2 * lattice_index(m, a, b)].load(Ordering::Relaxed));
        }
    }

    #[test]
    fn lattice_indices_enumerate_the_lattice_in_order() {
        for m in 1..9 {
            let mut k = 0;
            for a in 0..=m {
                for b in 0..=(m - a) {
                    assert_eq!(lattice_index(m, a, b), k);
                    k += 1;
                }
            }
            assert_eq!(k, lattice_len(m));
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(256))]
        /// Linear interpolation on the lattice reproduces affine functions exactly, anywhere in
        /// the triangle (including its edges), for every subdivision.
        #[test]
        fn cache_interpolation_reproduces_affine_functions(m in 1usize..12, u in 0f32..1.0, t in 0f32..1.0) {
            let v = (1.0 - u) * t;
            let cache = affine_cache(m);
            let x = cache.lookup(0, 0, || Vec2::new(u, v), |_, _| unreachable!("every entry is set"));
            prop_assert!((x[0] - (1.0 + 2.0 * u - 3.0 * v)).abs() < 1e-4, "{} vs {}", x[0], 1.0 + 2.0 * u - 3.0 * v);
            prop_assert!((x[1] - (u + v)).abs() < 1e-4);
        }
    }

    /// The replicate streams' variance estimate is unbiased: over many seeds, its mean equals
    /// the spread of the estimates themselves, within a tolerance from the sampling variance of
    /// both sides. Direct part only: the surface cache's noise is shared by a voxel's streams.
    #[test]
    fn the_variance_estimate_is_unbiased() {
        let scene = Scene::cornell_box();
        let seeds = 96u64;
        // Voxels (x, y, z) of an 8³ grid in the open near walls and boxes, where visibility
        // varies with the directions.
        let voxels = [(1, 6, 6), (6, 1, 1), (4, 5, 2)].map(|(x, y, z)| x + 8 * (y + 8 * z));
        let (mut estimated, mut spread) = (Vec::new(), Vec::new());
        for &v in &voxels {
            let mut means: Vec<[f64; TRANSFER_DIM]> = Vec::new();
            let mut variances = Vec::new();
            for seed in 0..seeds {
                let options = BakeOptions {
                    resolution: [8; 3],
                    rays_per_voxel: 96,
                    indirect: IndirectMode::Off,
                    seed,
                    adaptive: Some(AdaptiveSampling {
                        target_error: 0.0,
                        min_rays: 96,
                    }),
                    ..BakeOptions::default()
                };
                let baker = TransferBaker::new(&scene, options).unwrap();
                let field = baker.empty_field(1).unwrap();
                let (mut t, mut var) = (vec![0.0f32; TRANSFER_DIM], 0.0);
                let rays = AtomicU64::new(0);
                let (valid, _) =
                    baker.voxel_transfer(field.centre_of(v), v, None, &rays, &mut t, &mut var);
                assert!(valid, "voxel {v}");
                means.push(std::array::from_fn(|k| f64::from(t[k])));
                variances.push(f64::from(var));
            }
            let n = seeds as f64;
            let grand: Vec<f64> = (0..TRANSFER_DIM)
                .map(|k| means.iter().map(|m| m[k]).sum::<f64>() / n)
                .collect();
            // Per seed, an unbiased sample of the estimate's variance (summed over components).
            let deviation: Vec<f64> = means
                .iter()
                .map(|m| {
                    m.iter()
                        .zip(&grand)
                        .map(|(a, b)| (a - b).powi(2))
                        .sum::<f64>()
                        * n
                        / (n - 1.0)
                })
                .collect();
            estimated.push(variances);
            spread.push(deviation);
        }
        let mean_and_se = |x: &[f64]| {
            let n = x.len() as f64;
            let m = x.iter().sum::<f64>() / n;
            let var = x.iter().map(|a| (a - m).powi(2)).sum::<f64>() / (n - 1.0);
            (m, (var / n).sqrt())
        };
        for (est, dev) in estimated.iter().zip(&spread) {
            let ((e, se_e), (d, se_d)) = (mean_and_se(est), mean_and_se(dev));
            assert!(d > 0.0, "the voxel has noise");
            let tolerance = 4.0 * (se_e * se_e + se_d * se_d).sqrt();
            assert!(
                (e - d).abs() <= tolerance,
                "estimated {e:.4e} ± {se_e:.1e}, observed {d:.4e} ± {se_d:.1e}"
            );
        }
    }

    #[test]
    fn replicate_means_average_the_streams() {
        let mut acc = [[0.0f64; TRANSFER_DIM]; 2];
        acc[0][0] = 12.0;
        acc[1][0] = 24.0;
        let (mean, var) = replicate_mean(&acc, 1);
        let unit = 4.0 * std::f64::consts::PI / 12.0;
        assert!((mean[0] - 18.0 * unit).abs() < 1e-12);
        // Two streams at ±6 units from the mean: s² = 72 unit², Var(mean) = s² / 2.
        assert!((var - 36.0 * unit * unit).abs() < 1e-9, "{var}");
        assert_eq!(replicate_mean(&acc[..1], 1).1, 0.0);
    }

    #[test]
    fn a_single_point_cache_evaluates_once() {
        let cache = affine_cache(0);
        let calls = AtomicU64::new(0);
        let eval = |_: usize, _: usize| {
            calls.fetch_add(1, Ordering::Relaxed);
            [0.5; SH9]
        };
        for _ in 0..3 {
            assert_eq!(cache.lookup(0, 1, || Vec2::ZERO, eval), [0.5; SH9]);
        }
        assert_eq!(calls.into_inner(), 1);
    }

    /// A bake using a cache evaluated ahead is the bake that evaluates it on the way, bit for
    /// bit, and evaluates only the entries its rays hit that the cache lacks (with the cache's
    /// seed: an empty cache changes no byte); a cache of another lattice or other cache rays is
    /// refused.
    #[test]
    fn a_shared_surface_cache_gives_the_same_bake_evaluating_only_what_it_lacks() {
        let scene = crate::Scene::cornell_box();
        let options = BakeOptions {
            resolution: [5, 5, 5],
            rays_per_voxel: 24,
            cache_rays: 8,
            seed: 3,
            ..BakeOptions::default()
        };
        let baker = TransferBaker::new(&scene, options.clone()).unwrap();
        let own = baker.bake(&prt_core::NoProgress).unwrap();
        let shared = baker
            .evaluate_surface_cache(std::slice::from_ref(&options), &prt_core::NoProgress)
            .unwrap();
        assert_eq!(
            shared.visibility_rays,
            (125 * VISIBILITY_GROUPS * ICOSA) as u64
        );
        assert_eq!(
            shared.rays,
            shared.visibility_rays + (shared.evaluated() * 8) as u64
        );
        let with = |shared: &SharedSurfaceCache| {
            TransferBaker::new(&scene, options.clone())
                .unwrap()
                .with_surface_cache(shared)
                .unwrap()
                .bake(&prt_core::NoProgress)
                .unwrap()
        };
        let given = with(&shared);
        assert_eq!(given.field.data(), own.field.data());
        assert_eq!(given.valid, own.valid);
        // It evaluates what its rays hit beyond the shared entries.
        assert!(given.stats.cache_evaluated < own.stats.cache_evaluated);
        assert!(given.stats.cache_evaluated + shared.evaluated() >= own.stats.cache_evaluated);
        assert_eq!(
            given.stats.cache_rays,
            8 * given.stats.cache_evaluated as u64
        );
        assert_eq!(given.stats.voxel_rays, own.stats.voxel_rays);
        assert_eq!(given.stats.cache_points, shared.points());
        let empty = SharedSurfaceCache {
            values: vec![None; shared.values.len()],
            ..shared.clone()
        };
        let again = with(&empty);
        assert_eq!(again.field.data(), own.field.data());
        assert_eq!(again.stats.cache_evaluated, own.stats.cache_evaluated);

        let refused = |options: BakeOptions, shared: &SharedSurfaceCache| {
            TransferBaker::new(&scene, options)
                .unwrap()
                .with_surface_cache(shared)
                .unwrap_err()
        };
        let other_rays = BakeOptions {
            cache_rays: 16,
            ..options.clone()
        };
        assert!(matches!(
            refused(other_rays, &shared),
            TraceError::InvalidOption { .. }
        ));
        let coarser = SharedSurfaceCache {
            spacing: shared.spacing * 3.0,
            ..shared.clone()
        };
        assert!(matches!(
            refused(options, &coarser),
            TraceError::InvalidOption { .. }
        ));
    }
}
