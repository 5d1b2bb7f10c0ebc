//! Ray queries over a compressed wide BVH (obvhs CWBVH) with triangles stored in BVH order.

use std::time::Duration;

use glam::{UVec2, Vec2, Vec3, Vec3A};
use obvhs::BvhBuildParams;
use obvhs::cwbvh::CwBvh;
use obvhs::cwbvh::builder::build_cwbvh_from_tris;
use obvhs::cwbvh::node::CwBvhNode;
use obvhs::ray::Ray;
use obvhs::rt_triangle::RtTriangle;
use obvhs::triangle::Triangle;
use rayon::prelude::*;

/// BVH build quality (obvhs presets).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[non_exhaustive]
pub enum BuildQuality {
    /// `fast_build`: quickest build, somewhat slower rays.
    Fast,
    /// `medium_build`: about Embree's build time with faster traversal (the default).
    #[default]
    Medium,
    /// `slow_build`: spatial pre-splits and more reinsertion, for the largest ray budgets.
    Slow,
    /// `very_slow_build`: pre-splits and a full reinsertion pass (obvhs's highest-quality preset).
    VerySlow,
}

/// The instruction sets the queries run with, chosen once when a tracer is built.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Isa {
    /// The build target's baseline (SSE2 on x86-64 without `-C target-cpu`).
    Baseline,
    /// x86-64-v3, detected at run time: see [`x86_v3`].
    #[cfg(target_arch = "x86_64")]
    X86V3,
}

impl Isa {
    /// The widest instruction set this CPU supports.
    fn detect() -> Self {
        #[cfg(target_arch = "x86_64")]
        if x86_v3::detected() {
            return Isa::X86V3;
        }
        Isa::Baseline
    }
}

/// The closest intersection of a ray with the scene.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    /// Distance along the (unit) ray direction.
    pub t: f32,
    /// Index of the triangle in [`crate::Scene::triangles`].
    pub triangle: u32,
    /// Barycentric coordinates `(u, v)` of the hit: the point is `(1-u-v) v0 + u v1 + v v2`.
    pub barycentrics: Vec2,
    /// Unit geometric normal from the triangle's winding, `(v1 - v0) × (v2 - v0)` normalised.
    pub normal: Vec3,
    /// Whether the ray hit the front face (the side the winding normal points to).
    pub front_face: bool,
}

/// A ray-tracing acceleration structure over a fixed set of triangles.
///
/// Closest-hit queries return distance, triangle, barycentrics, geometric normal and facing;
/// occlusion queries stop at the first hit. Batched versions run over rayon. Rays should have
/// unit directions (distances are then in scene units); `tmin`/`tmax` bound the accepted hits.
///
/// Like every CWBVH (quantised child boxes), traversal can miss a hit that a loop over all
/// triangles finds: in the tests, never for hits farther than 1e-3 from the origin over 200k
/// random rays, and 2 in 100k random Cornell-box rays whose origin lay within 6e-5 of a wall.
/// Offset ray origins off surfaces (the baker does, by 1e-4 of the scene diagonal).
#[derive(Clone)]
pub struct RayTracer {
    bvh: Option<CwBvh>,
    /// Triangles in BVH leaf order, so that a leaf's primitive ids index them directly.
    tris: Vec<RtTriangle>,
    /// Scene triangle index and unit normal of each slot of `tris`.
    slot_info: Vec<SlotInfo>,
    isa: Isa,
}

/// What a closest hit reports about its slot beyond the intersection test, precomputed so that
/// the hit record costs one 16-byte load instead of a gather and a square root per ray.
#[derive(Debug, Clone, Copy)]
#[repr(C, align(16))]
struct SlotInfo {
    /// Unit winding normal (`(v1 - v0) × (v2 - v0)` normalised; zero if degenerate).
    normal: Vec3,
    /// Index of the triangle in the scene.
    scene: u32,
}

impl std::fmt::Debug for RayTracer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RayTracer")
            .field("triangles", &self.tris.len())
            .finish_non_exhaustive()
    }
}

/// A closest hit in BVH slot terms (what the baker's hot loop uses).
#[derive(Debug, Clone, Copy)]
pub(crate) struct SlotHit {
    pub t: f32,
    pub slot: u32,
}

impl RayTracer {
    /// Builds a CWBVH over `triangles` with the default ([`BuildQuality::Medium`]) quality.
    pub fn new(triangles: &[[Vec3; 3]]) -> Self {
        Self::with_quality(triangles, BuildQuality::Medium)
    }

    /// Builds a CWBVH over `triangles`. An empty slice gives a tracer whose rays all miss.
    pub fn with_quality(triangles: &[[Vec3; 3]], quality: BuildQuality) -> Self {
        if triangles.is_empty() {
            return Self {
                bvh: None,
                tris: Vec::new(),
                slot_info: Vec::new(),
                isa: Isa::detect(),
            };
        }
        let input: Vec<Triangle> = triangles
            .iter()
            .map(|t| Triangle {
                v0: t[0].into(),
                v1: t[1].into(),
                v2: t[2].into(),
            })
            .collect();
        let params = match quality {
            BuildQuality::Fast => BvhBuildParams::fast_build(),
            BuildQuality::Medium => BvhBuildParams::medium_build(),
            BuildQuality::Slow => BvhBuildParams::slow_build(),
            BuildQuality::VerySlow => BvhBuildParams::very_slow_build(),
        };
        let bvh = build_cwbvh_from_tris(&input, params, &mut Duration::default());
        let tris: Vec<RtTriangle> = bvh
            .primitive_indices
            .iter()
            .map(|&i| {
                let t = &input[i as usize];
                RtTriangle::new(t.v0, t.v1, t.v2)
            })
            .collect();
        let slot_info = bvh
            .primitive_indices
            .iter()
            .zip(&tris)
            // RtTriangle's ng = -(v1 - v0) × (v2 - v0) (see `slot_normal`).
            .map(|(&scene, t)| SlotInfo {
                normal: Vec3::from(-t.ng).normalize_or_zero(),
                scene,
            })
            .collect();
        Self {
            bvh: Some(bvh),
            tris,
            slot_info,
            isa: Isa::detect(),
        }
    }

    /// The instruction set the queries run with, detected at run time: `"x86-64-v3"` (AVX2,
    /// FMA, BMI1/2, LZCNT, POPCNT) or `"baseline"` (the build target's). Results are
    /// bit-identical either way.
    pub fn instruction_set(&self) -> &'static str {
        match self.isa {
            Isa::Baseline => "baseline",
            #[cfg(target_arch = "x86_64")]
            Isa::X86V3 => "x86-64-v3",
        }
    }

    /// This tracer on the build target's baseline instruction set, whatever the CPU has (to
    /// measure what the run-time selection gains; the results are the same).
    pub fn with_baseline_instruction_set(self) -> Self {
        Self {
            isa: Isa::Baseline,
            ..self
        }
    }

    /// Number of BVH primitive slots (the triangle count, more when spatial splits duplicate).
    pub(crate) fn slots(&self) -> usize {
        self.tris.len()
    }

    /// Scene triangle index of a BVH slot.
    pub(crate) fn scene_triangle(&self, slot: u32) -> u32 {
        self.slot_info[slot as usize].scene
    }

    /// Vertices of a BVH slot's triangle.
    pub(crate) fn slot_vertices(&self, slot: u32) -> [Vec3; 3] {
        let t = &self.tris[slot as usize];
        [t.v0.into(), (t.v0 - t.e1).into(), (t.v0 + t.e2).into()]
    }

    /// Unnormalised winding normal of a slot, `(v1 - v0) × (v2 - v0)`.
    #[inline]
    pub(crate) fn slot_normal(&self, slot: u32) -> Vec3 {
        // RtTriangle stores e1 = v0 - v1, e2 = v2 - v0, ng = e1 × e2 = -(v1 - v0) × (v2 - v0).
        (-self.tris[slot as usize].ng).into()
    }

    /// Barycentrics `(u, v)` (weights of v1, v2) of the hit of `ray` on a slot.
    #[inline]
    pub(crate) fn slot_barycentrics(&self, slot: u32, origin: Vec3, dir: Vec3) -> Vec2 {
        // The `u`, `v` of `RtTriangle::intersect`, bit for bit (the same operations, one
        // reciprocal), recomputed once per ray after traversal rather than kept for every
        // accepted candidate.
        let t = &self.tris[slot as usize];
        let d = Vec3A::from(dir);
        let r = d.cross(t.v0 - Vec3A::from(origin));
        let inv_det = 1.0 / t.ng.dot(d);
        Vec2::new(r.dot(t.e2) * inv_det, r.dot(t.e1) * inv_det)
    }

    /// Closest hit in slot terms, on the instruction set chosen at construction.
    #[inline]
    pub(crate) fn closest_slot(
        &self,
        origin: Vec3,
        dir: Vec3,
        tmin: f32,
        tmax: f32,
    ) -> Option<SlotHit> {
        match self.isa {
            Isa::Baseline => self.closest_slot_inline(origin, dir, tmin, tmax),
            #[cfg(target_arch = "x86_64")]
            // SAFETY: `Isa::X86V3` is only chosen after `x86_v3::detected()` confirmed every
            // feature the function is compiled with.
            Isa::X86V3 => unsafe { x86_v3::closest_slot(self, origin, dir, tmin, tmax) },
        }
    }

    /// obvhs's closest-hit traversal (`CwBvh::ray_traverse`), written out with its `traverse!`
    /// macro so that it is compiled inside each instruction-set wrapper (a shared generic
    /// instance of `ray_traverse` would be compiled once, for the baseline).
    #[inline(always)]
    fn closest_slot_inline(
        &self,
        origin: Vec3,
        dir: Vec3,
        tmin: f32,
        tmax: f32,
    ) -> Option<SlotHit> {
        self.closest_slot_with(origin, dir, tmin, tmax, CwBvhNode::intersect_ray)
    }

    /// [`RayTracer::closest_slot_inline`] with a given child-box test, which must return what
    /// `CwBvhNode::intersect_ray` returns.
    #[inline(always)]
    fn closest_slot_with(
        &self,
        origin: Vec3,
        dir: Vec3,
        tmin: f32,
        tmax: f32,
        node_test: impl Fn(&CwBvhNode, &Ray, u32) -> u32,
    ) -> Option<SlotHit> {
        let bvh = self.bvh.as_ref()?;
        let mut ray = query_ray(origin, dir, tmin, tmax);
        let tris = &self.tris;
        let mut best = None;
        let mut state = bvh.new_traversal(ray.direction);
        let mut node;
        obvhs::traverse!(bvh, node, state, node_test(node, &ray, state.oct_inv4), {
            let t = tris[state.primitive_id as usize].intersect(&ray);
            if t < ray.tmax {
                best = Some(SlotHit {
                    t,
                    slot: state.primitive_id,
                });
                ray.tmax = t;
            }
        });
        best
    }

    /// The full hit record of a slot hit, computed once per ray after traversal.
    #[inline(always)]
    fn hit_record(&self, h: SlotHit, origin: Vec3, dir: Vec3) -> Hit {
        let info = self.slot_info[h.slot as usize];
        Hit {
            t: h.t,
            triangle: info.scene,
            barycentrics: self.slot_barycentrics(h.slot, origin, dir),
            normal: info.normal,
            // From the unnormalised normal (in cache after the hit test), as before.
            front_face: self.slot_normal(h.slot).dot(dir) < 0.0,
        }
    }

    /// obvhs's any-hit traversal (`CwBvh::ray_traverse_miss`: stops at the first hit), written
    /// out like [`RayTracer::closest_slot_inline`].
    #[inline(always)]
    fn occluded_inline(&self, origin: Vec3, dir: Vec3, tmin: f32, tmax: f32) -> bool {
        self.occluded_with(origin, dir, tmin, tmax, CwBvhNode::intersect_ray)
    }

    /// [`RayTracer::occluded_inline`] with a given child-box test (see
    /// [`RayTracer::closest_slot_with`]).
    #[inline(always)]
    fn occluded_with(
        &self,
        origin: Vec3,
        dir: Vec3,
        tmin: f32,
        tmax: f32,
        node_test: impl Fn(&CwBvhNode, &Ray, u32) -> u32,
    ) -> bool {
        let Some(bvh) = self.bvh.as_ref() else {
            return false;
        };
        let ray = query_ray(origin, dir, tmin, tmax);
        let tris = &self.tris;
        let mut occluded = false;
        let mut state = bvh.new_traversal(ray.direction);
        let mut node;
        'traversal: {
            obvhs::traverse!(bvh, node, state, node_test(node, &ray, state.oct_inv4), {
                if tris[state.primitive_id as usize].intersect(&ray) < ray.tmax {
                    occluded = true;
                    break 'traversal;
                }
            });
        }
        occluded
    }

    /// Distance and scene triangle index of the closest hit of the ray `origin + t dir`,
    /// `tmin <= t <= tmax`, if any: the cheapest closest-hit query (traversal and the
    /// intersection tests only, as obvhs's own benchmarks time it). [`RayTracer::closest_hit`]
    /// adds barycentrics, normal and facing.
    #[inline]
    pub fn closest_triangle(
        &self,
        origin: Vec3,
        dir: Vec3,
        tmin: f32,
        tmax: f32,
    ) -> Option<(f32, u32)> {
        let h = self.closest_slot(origin, dir, tmin, tmax)?;
        Some((h.t, self.scene_triangle(h.slot)))
    }

    /// The closest hit of the ray `origin + t dir`, `tmin <= t <= tmax`, if any.
    #[inline]
    pub fn closest_hit(&self, origin: Vec3, dir: Vec3, tmin: f32, tmax: f32) -> Option<Hit> {
        let h = self.closest_slot(origin, dir, tmin, tmax)?;
        Some(self.hit_record(h, origin, dir))
    }

    /// Whether anything lies on the ray within `[tmin, tmax]` (stops at the first hit found).
    #[inline]
    pub fn occluded(&self, origin: Vec3, dir: Vec3, tmin: f32, tmax: f32) -> bool {
        match self.isa {
            Isa::Baseline => self.occluded_inline(origin, dir, tmin, tmax),
            #[cfg(target_arch = "x86_64")]
            // SAFETY: `Isa::X86V3` is only chosen after `x86_v3::detected()` confirmed every
            // feature the function is compiled with.
            Isa::X86V3 => unsafe { x86_v3::occluded(self, origin, dir, tmin, tmax) },
        }
    }

    /// Closest hits of a chunk of rays into `out` (same length).
    #[inline(always)]
    fn closest_hits_with(
        &self,
        rays: &[(Vec3, Vec3)],
        tmin: f32,
        tmax: f32,
        out: &mut [Option<Hit>],
        node_test: impl Fn(&CwBvhNode, &Ray, u32) -> u32 + Copy,
    ) {
        for (o, &(origin, dir)) in out.iter_mut().zip(rays) {
            *o = self
                .closest_slot_with(origin, dir, tmin, tmax, node_test)
                .map(|h| self.hit_record(h, origin, dir));
        }
    }

    /// Occlusion of a chunk of rays into `out` (same length).
    #[inline(always)]
    fn occluded_batch_with(
        &self,
        rays: &[(Vec3, Vec3)],
        tmin: f32,
        tmax: f32,
        out: &mut [bool],
        node_test: impl Fn(&CwBvhNode, &Ray, u32) -> u32 + Copy,
    ) {
        for (o, &(origin, dir)) in out.iter_mut().zip(rays) {
            *o = self.occluded_with(origin, dir, tmin, tmax, node_test);
        }
    }

    /// Closest hits of a batch of rays `(origin, dir)` with `[tmin, tmax]`, in parallel.
    pub fn closest_hits(&self, rays: &[(Vec3, Vec3)], tmin: f32, tmax: f32) -> Vec<Option<Hit>> {
        let mut out = vec![None; rays.len()];
        out.par_chunks_mut(BATCH_CHUNK)
            .zip(rays.par_chunks(BATCH_CHUNK))
            .for_each(|(out, rays)| match self.isa {
                Isa::Baseline => {
                    self.closest_hits_with(rays, tmin, tmax, out, CwBvhNode::intersect_ray)
                }
                #[cfg(target_arch = "x86_64")]
                // SAFETY: `Isa::X86V3` is only chosen after `x86_v3::detected()` confirmed
                // every feature the function is compiled with.
                Isa::X86V3 => unsafe { x86_v3::closest_hits(self, rays, tmin, tmax, out) },
            });
        out
    }

    /// Occlusion of a batch of rays `(origin, dir)` with `[tmin, tmax]`, in parallel.
    pub fn occluded_batch(&self, rays: &[(Vec3, Vec3)], tmin: f32, tmax: f32) -> Vec<bool> {
        let mut out = vec![false; rays.len()];
        out.par_chunks_mut(BATCH_CHUNK)
            .zip(rays.par_chunks(BATCH_CHUNK))
            .for_each(|(out, rays)| match self.isa {
                Isa::Baseline => {
                    self.occluded_batch_with(rays, tmin, tmax, out, CwBvhNode::intersect_ray)
                }
                #[cfg(target_arch = "x86_64")]
                // SAFETY: `Isa::X86V3` is only chosen after `x86_v3::detected()` confirmed
                // every feature the function is compiled with.
                Isa::X86V3 => unsafe { x86_v3::occluded_batch(self, rays, tmin, tmax, out) },
            });
        out
    }
}

/// Rays per parallel task of the batched queries (one instruction-set dispatch each).
const BATCH_CHUNK: usize = 256;

/// The queries compiled for x86-64-v3 (AVX2, FMA, BMI1/2, LZCNT, POPCNT), chosen at run time.
///
/// obvhs's traversal is generic code compiled in this crate, so enabling the wider features on
/// these wrappers recompiles it whole (VEX encoding, one-instruction `count_ones` /
/// `leading_zeros` in the node-group bookkeeping) without a `-C target-cpu` for the whole
/// build, and [`intersect_node`] tests all 8 child boxes of a node at once. No arithmetic is
/// contracted or reordered (Rust emits no fast-math flags), so the results are bit-identical
/// to the baseline's.
#[cfg(target_arch = "x86_64")]
mod x86_v3 {
    use std::arch::x86_64::*;

    use glam::{Vec3, Vec3A};
    use obvhs::cwbvh::node::CwBvhNode;
    use obvhs::ray::Ray;

    use super::{Hit, RayTracer, SlotHit};

    /// Whether this CPU has every feature the functions below are compiled with.
    pub(super) fn detected() -> bool {
        is_x86_feature_detected!("avx2")
            && is_x86_feature_detected!("fma")
            && is_x86_feature_detected!("bmi1")
            && is_x86_feature_detected!("bmi2")
            && is_x86_feature_detected!("lzcnt")
            && is_x86_feature_detected!("popcnt")
    }

    /// obvhs's lower bound on box entry distances (`cwbvh::node::EPSILON`, crate-private).
    const BOX_EPSILON: f32 = 0.0001;

    /// `CwBvhNode::intersect_ray` on 8 lanes: obvhs tests the 8 quantised child boxes 4 at a
    /// time and gathers the hit mask with a branch per child; here one 256-bit pass does the
    /// same IEEE operations in the same order (so the same bits) and the mask is gathered
    /// without branches (variable shifts and an OR reduction).
    #[target_feature(enable = "avx2,fma,bmi1,bmi2,lzcnt,popcnt")]
    #[inline]
    pub(super) fn intersect_node(node: &CwBvhNode, ray: &Ray, oct_inv4: u32) -> u32 {
        let extent = Vec3A::new(
            f32::from_bits(u32::from(node.e[0]) << 23),
            f32::from_bits(u32::from(node.e[1]) << 23),
            f32::from_bits(u32::from(node.e[2]) << 23),
        );
        let scale = extent * ray.inv_direction;
        let offset = (Vec3A::from(node.p) - ray.origin) * ray.inv_direction;
        // 8 quantised planes as f32 lanes.
        let planes = |q: [u8; 8]| {
            _mm256_cvtepi32_ps(_mm256_cvtepu8_epi32(_mm_cvtsi64_si128(i64::from_le_bytes(
                q,
            ))))
        };
        // Entry and exit distances along one axis: the near plane is the max plane when the
        // ray runs towards -axis.
        let axis = |lo: [u8; 8], hi: [u8; 8], negative: bool, scale: f32, offset: f32| {
            let (near, far) = if negative { (hi, lo) } else { (lo, hi) };
            let (s, o) = (_mm256_set1_ps(scale), _mm256_set1_ps(offset));
            (
                _mm256_add_ps(_mm256_mul_ps(planes(near), s), o),
                _mm256_add_ps(_mm256_mul_ps(planes(far), s), o),
            )
        };
        let d = ray.direction;
        let (x0, x1) = axis(
            node.child_min_x,
            node.child_max_x,
            d.x < 0.0,
            scale.x,
            offset.x,
        );
        let (y0, y1) = axis(
            node.child_min_y,
            node.child_max_y,
            d.y < 0.0,
            scale.y,
            offset.y,
        );
        let (z0, z1) = axis(
            node.child_min_z,
            node.child_max_z,
            d.z < 0.0,
            scale.z,
            offset.z,
        );
        let enter = _mm256_max_ps(x0, _mm256_max_ps(y0, z0));
        let exit = _mm256_min_ps(x1, _mm256_min_ps(y1, z1));
        let enter = _mm256_max_ps(enter, _mm256_set1_ps(BOX_EPSILON));
        let exit = _mm256_min_ps(exit, _mm256_set1_ps(ray.tmax));
        let hit = _mm256_castps_si256(_mm256_cmp_ps::<_CMP_LE_OS>(enter, exit));

        let (child_bits8, bit_index8) = node.get_child_and_index_bits(oct_inv4);
        let lanes = |v: u64| _mm256_cvtepu8_epi32(_mm_cvtsi64_si128(v as i64));
        let bits = _mm256_and_si256(
            _mm256_sllv_epi32(lanes(child_bits8), lanes(bit_index8)),
            hit,
        );
        let bits = _mm_or_si128(
            _mm256_castsi256_si128(bits),
            _mm256_extracti128_si256::<1>(bits),
        );
        let bits = _mm_or_si128(bits, _mm_shuffle_epi32::<0b01_00_11_10>(bits));
        let bits = _mm_or_si128(bits, _mm_shuffle_epi32::<0b10_11_00_01>(bits));
        _mm_cvtsi128_si32(bits) as u32
    }

    /// [`intersect_node`] as the traversal's child-box test (a `#[target_feature]` function
    /// is not an `Fn`; a closure defined here inherits the features).
    #[target_feature(enable = "avx2,fma,bmi1,bmi2,lzcnt,popcnt")]
    #[inline]
    fn node_test() -> impl Fn(&CwBvhNode, &Ray, u32) -> u32 + Copy {
        |node, ray, oct| intersect_node(node, ray, oct)
    }

    #[target_feature(enable = "avx2,fma,bmi1,bmi2,lzcnt,popcnt")]
    pub(super) fn closest_slot(
        tracer: &RayTracer,
        origin: Vec3,
        dir: Vec3,
        tmin: f32,
        tmax: f32,
    ) -> Option<SlotHit> {
        tracer.closest_slot_with(origin, dir, tmin, tmax, node_test())
    }

    #[target_feature(enable = "avx2,fma,bmi1,bmi2,lzcnt,popcnt")]
    pub(super) fn occluded(
        tracer: &RayTracer,
        origin: Vec3,
        dir: Vec3,
        tmin: f32,
        tmax: f32,
    ) -> bool {
        tracer.occluded_with(origin, dir, tmin, tmax, node_test())
    }

    #[target_feature(enable = "avx2,fma,bmi1,bmi2,lzcnt,popcnt")]
    pub(super) fn closest_hits(
        tracer: &RayTracer,
        rays: &[(Vec3, Vec3)],
        tmin: f32,
        tmax: f32,
        out: &mut [Option<Hit>],
    ) {
        tracer.closest_hits_with(rays, tmin, tmax, out, node_test());
    }

    #[target_feature(enable = "avx2,fma,bmi1,bmi2,lzcnt,popcnt")]
    pub(super) fn occluded_batch(
        tracer: &RayTracer,
        rays: &[(Vec3, Vec3)],
        tmin: f32,
        tmax: f32,
        out: &mut [bool],
    ) {
        tracer.occluded_batch_with(rays, tmin, tmax, out, node_test());
    }
}

/// The obvhs ray of a query, with `-0.0` direction components made `+0.0`.
///
/// obvhs picks a node's near and far planes from the traversal octant (`direction < 0.0`, false
/// for `-0.0`) but takes the reciprocal's sign from the sign bit (`-1 / ε` for `-0.0`), so an
/// axis-parallel ray with a `-0.0` component swapped them and missed every box.
#[inline(always)]
fn query_ray(origin: Vec3, dir: Vec3, tmin: f32, tmax: f32) -> Ray {
    // Adding +0.0 maps -0.0 to +0.0 and leaves every other value as it is.
    Ray::new(
        Vec3A::from(origin),
        Vec3A::from(dir + Vec3::ZERO),
        tmin,
        tmax,
    )
}

/// Closest hit by testing every triangle (the reference for the BVH's tests and sweeps).
pub fn brute_force_closest(
    triangles: &[[Vec3; 3]],
    origin: Vec3,
    dir: Vec3,
    tmin: f32,
    tmax: f32,
) -> Option<(u32, f32)> {
    let ray = Ray::new(origin.into(), dir.into(), tmin, tmax);
    let mut best: Option<(u32, f32)> = None;
    for (i, t) in triangles.iter().enumerate() {
        let rt = RtTriangle::new(t[0].into(), t[1].into(), t[2].into());
        let d = rt.intersect(&ray);
        if d.is_finite() && best.is_none_or(|(_, b)| d < b) {
            best = Some((i as u32, d));
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// Random rays with origins in and around the Cornell box (`[-1, 1] × [0, 2] × [-1, 1]`),
    /// one in 50 with an axis-aligned direction (obvhs clamps its reciprocals).
    fn rays(count: usize, seed: u64) -> Vec<(Vec3, Vec3)> {
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(seed);
        (0..count)
            .map(|i| {
                let o = Vec3::new(rng.random(), rng.random(), rng.random()) * 2.4
                    - Vec3::new(1.2, 0.2, 1.2);
                let d = if i % 50 == 0 {
                    Vec3::AXES[i / 50 % 3]
                } else {
                    Vec3::new(rng.random(), rng.random(), rng.random()) * 2.0 - 1.0
                };
                (o, d.normalize_or(Vec3::Y))
            })
            .collect()
    }

    fn bits(h: &Option<Hit>) -> Option<[u32; 7]> {
        h.map(|h| {
            [
                h.t.to_bits(),
                h.triangle,
                h.barycentrics.x.to_bits(),
                h.barycentrics.y.to_bits(),
                h.normal.x.to_bits(),
                h.normal.y.to_bits() ^ h.normal.z.to_bits().rotate_left(7),
                u32::from(h.front_face),
            ]
        })
    }

    /// Why a test of the x86-64-v3 path fails: build.rs ignores these tests (`prt_skip_x86_64_v3`)
    /// when the building CPU lacks the features, so a test that runs never skips.
    const LACKS_X86_64_V3: &str = "this CPU lacks x86-64-v3 (the test runs because \
        PRT_REQUIRE_CPU=1 or because the CPU that built it had it)";

    /// The run-time-selected instruction set gives bit-identical results to the baseline, for
    /// the single-ray and the batched queries, with infinite and finite `tmax`.
    #[test]
    #[cfg_attr(
        prt_skip_x86_64_v3,
        ignore = "needs a CPU with x86-64-v3, absent at build time (PRT_REQUIRE_CPU=1 requires it)"
    )]
    fn detected_instruction_set_matches_the_baseline_bit_for_bit() {
        let scene = crate::Scene::cornell_box();
        let wide = RayTracer::new(scene.triangles());
        assert_ne!(wide.isa, Isa::Baseline, "{LACKS_X86_64_V3}");
        let base = wide.clone().with_baseline_instruction_set();
        let rays = rays(20_000, 3);
        for tmax in [f32::INFINITY, 0.5] {
            let a = base.closest_hits(&rays, 1e-3, tmax);
            let b = wide.closest_hits(&rays, 1e-3, tmax);
            assert!(a.iter().filter(|h| h.is_some()).count() > rays.len() / 10);
            assert!(a.iter().zip(&b).all(|(x, y)| bits(x) == bits(y)));
            let a = base.occluded_batch(&rays, 1e-3, tmax);
            let b = wide.occluded_batch(&rays, 1e-3, tmax);
            assert_eq!(a, b);
            for &(o, d) in rays.iter().take(2000) {
                assert_eq!(
                    bits(&base.closest_hit(o, d, 1e-3, tmax)),
                    bits(&wide.closest_hit(o, d, 1e-3, tmax))
                );
                assert_eq!(
                    base.occluded(o, d, 1e-3, tmax),
                    wide.occluded(o, d, 1e-3, tmax)
                );
            }
        }
    }

    /// The 8-wide child-box test returns obvhs's hit mask on every node of a BVH over a random
    /// triangle soup, for rays from inside and outside it with infinite and finite `tmax`.
    #[cfg(target_arch = "x86_64")]
    #[test]
    #[cfg_attr(
        prt_skip_x86_64_v3,
        ignore = "needs a CPU with x86-64-v3, absent at build time (PRT_REQUIRE_CPU=1 requires it)"
    )]
    fn eight_wide_node_test_matches_obvhs_on_every_node() {
        assert!(x86_v3::detected(), "{LACKS_X86_64_V3}");
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(11);
        let mut point = || Vec3::new(rng.random(), rng.random(), rng.random()) * 2.0 - 1.0;
        let soup: Vec<[Vec3; 3]> = (0..3000)
            .map(|_| {
                let c = point();
                [c, c + point() * 0.1, c + point() * 0.1]
            })
            .collect();
        let tracer = RayTracer::new(&soup);
        let Some(bvh) = tracer.bvh.as_ref() else {
            panic!("the soup has triangles")
        };
        assert!(bvh.nodes.len() > 100);
        let (mut tested, mut hit) = (0usize, 0usize);
        for (o, d) in rays(300, 13) {
            for tmax in [f32::INFINITY, 0.3] {
                let ray = Ray::new(o.into(), d.into(), 0.0, tmax);
                let oct = bvh.new_traversal(ray.direction).oct_inv4;
                for node in &bvh.nodes {
                    // SAFETY: `detected()` confirmed the features `intersect_node` needs.
                    let ours = unsafe { x86_v3::intersect_node(node, &ray, oct) };
                    assert_eq!(ours, node.intersect_ray(&ray, oct));
                    tested += 1;
                    hit += usize::from(ours != 0);
                }
            }
        }
        assert!(
            hit > tested / 1000 && hit < tested,
            "{hit} of {tested} nodes hit"
        );
    }

    /// The hit record names the scene triangle that was hit, its unit winding normal and the
    /// facing, and its barycentrics reproduce the hit point.
    #[test]
    fn hit_record_describes_the_scene_triangle() {
        let scene = crate::Scene::cornell_box();
        let tracer = RayTracer::new(scene.triangles());
        let mut hits = 0;
        for (o, d) in rays(5000, 17) {
            let Some(h) = tracer.closest_hit(o, d, 1e-3, f32::INFINITY) else {
                continue;
            };
            hits += 1;
            let [v0, v1, v2] = scene.triangles()[h.triangle as usize];
            let n = (v1 - v0).cross(v2 - v0).normalize();
            assert!((h.normal - n).length() < 1e-5, "{} vs {n}", h.normal);
            assert_eq!(h.front_face, n.dot(d) < 0.0);
            let p = v0 + (v1 - v0) * h.barycentrics.x + (v2 - v0) * h.barycentrics.y;
            assert!(
                (p - (o + d * h.t)).length() < 1e-4,
                "{p} vs {}",
                o + d * h.t
            );
        }
        assert!(hits > 2500, "{hits} hits");
    }

    /// The written-out traversals return exactly what obvhs's own `ray_traverse` and
    /// `ray_traverse_miss` return.
    #[test]
    fn traversal_matches_obvhs_ray_traverse() {
        let scene = crate::Scene::cornell_box();
        let tracer = RayTracer::new(scene.triangles());
        let Some(bvh) = tracer.bvh.as_ref() else {
            panic!("the Cornell box has triangles")
        };
        for (o, d) in rays(20_000, 5) {
            let ray = Ray::new(o.into(), d.into(), 0.0, f32::INFINITY);
            let mut hit = obvhs::ray::RayHit::none();
            let theirs = bvh
                .ray_traverse(ray, &mut hit, |r, id| tracer.tris[id].intersect(r))
                .then_some((hit.t.to_bits(), hit.primitive_id));
            let ours = tracer
                .closest_slot(o, d, 0.0, f32::INFINITY)
                .map(|h| (h.t.to_bits(), h.slot));
            assert_eq!(ours, theirs);
            let blocked = !bvh.ray_traverse_miss(ray, |r, id| tracer.tris[id].intersect(r));
            assert_eq!(tracer.occluded(o, d, 0.0, f32::INFINITY), blocked);
        }
    }
}
