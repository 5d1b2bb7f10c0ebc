use glam::Vec3;
use prt_core::{Aabb, CoreError, KernelWeights, SpatialKernels};

use crate::KernelError;

/// Wendland's C2 function of compact support (Wendland 1995), `(1 - t)^4 (4 t + 1)` for
/// `t = r / R` in `[0, 1)`, and 0 from `t = 1` on. It is 1 at the centre, twice continuously
/// differentiable, and positive definite in up to three dimensions.
#[inline]
pub fn wendland_c2(t: f64) -> f64 {
    if !(0.0..1.0).contains(&t) {
        return 0.0;
    }
    let q = 1.0 - t;
    let q2 = q * q;
    q2 * q2 * (4.0 * t + 1.0)
}

/// Shepard (partition-of-unity) kernels over scattered centres (Shepard 1968, with compactly
/// supported weights as in Wendland's "Scattered Data Approximation", ch. 15):
///
/// `w_i(x) = φ_i(x) / Σ_j φ_j(x)`, with `φ_i(x) = wendland_c2(|x - c_i| / R_i)`.
///
/// Kernel `i` is non-zero exactly on the open ball of radius `R_i` around `c_i`, so the family
/// is a partition of unity on the union of the balls and smooth (C2) wherever it is defined.
///
/// * **Domain**: the bounding box of the balls. A point of the box that no ball covers, or a
///   point outside the box, is [`CoreError::Uncovered`]; a non-finite point is
///   [`CoreError::NonFinite`]. Weights are computed in f64 and stored as f32; a kernel whose
///   normalised weight rounds to 0 in f32 (a point within ~1e-8 R of the edge of its ball while
///   other balls cover it well) is left out.
/// * **Queries** go through a uniform grid of buckets built once: each bucket lists the balls that
///   reach it, so an evaluation tests only the balls of one bucket (a sequential f32 rejection
///   test, then the exact f64 weight). The bucket size starts at half the median radius and
///   grows until there are at most `32 n + 4096` buckets and the lists are expected to hold at
///   most `64 n + 4096` entries, so memory stays linear in the number `n` of kernels for any mix
///   of radii.
/// * **`max_support`** is the longest bucket list: an upper bound of the number of kernels
///   non-zero at one point, computed from the data (the true maximum overlap can be smaller).
/// * Results are identical on every run; the weights come out sorted by kernel index.
///
/// ```
/// use glam::Vec3;
/// use prt_core::{KernelWeights, SpatialKernels};
/// use prt_kernels::Shepard;
///
/// let centres = vec![Vec3::ZERO, Vec3::X, Vec3::Y];
/// let kernels = Shepard::with_radius(centres, 1.5).unwrap();
/// let mut w = KernelWeights::default();
/// kernels.eval(Vec3::new(0.4, 0.3, 0.0), &mut w).unwrap();
/// assert_eq!(w.indices, vec![0, 1, 2]);
/// assert!((w.sum() - 1.0).abs() < 1e-6);
/// ```
#[derive(Debug, Clone, PartialEq)]
pub struct Shepard {
    centres: Vec<Vec3>,
    radii: Vec<f32>,
    domain: Aabb,
    buckets: Buckets,
    max_support: usize,
}

/// A uniform grid of cubic buckets over the domain, each listing (in CSR form) the kernels whose
/// ball reaches into it, in increasing index order.
#[derive(Debug, Clone, PartialEq)]
struct Buckets {
    origin: [f64; 3],
    size: f64,
    dims: [usize; 3],
    starts: Vec<usize>,
    items: Vec<u32>,
    /// Per entry, the kernel's centre and a slightly enlarged squared radius, stored with the
    /// list so that the rejection test reads memory sequentially.
    spheres: Vec<[f32; 4]>,
}

/// The bucket grid's budget: at most this many buckets...
const MAX_BUCKETS_PER_KERNEL: f64 = 32.0;
/// ...and at most this many list entries per kernel (each plus 4096).
const MAX_ENTRIES_PER_KERNEL: f64 = 64.0;

impl Shepard {
    /// Kernels centred at `centres` with support radii `radii`.
    ///
    /// Errors: no centres ([`KernelError::Empty`]), `radii.len() != centres.len()`
    /// ([`KernelError::LengthMismatch`]), a non-finite centre or radius
    /// ([`KernelError::NonFinite`] with the kernel's index), a radius `<= 0`
    /// ([`KernelError::InvalidRadius`]), balls reaching beyond the f32 range
    /// ([`KernelError::InvalidDomain`]), more than `u32::MAX` kernels
    /// ([`KernelError::TooManyKernels`]).
    pub fn new(centres: Vec<Vec3>, radii: Vec<f32>) -> Result<Shepard, KernelError> {
        if centres.is_empty() {
            return Err(KernelError::Empty {
                what: "Shepard centres",
            });
        }
        if radii.len() != centres.len() {
            return Err(KernelError::LengthMismatch {
                what: "Shepard radii",
                expected: centres.len(),
                got: radii.len(),
            });
        }
        if centres.len() > u32::MAX as usize {
            return Err(KernelError::TooManyKernels {
                what: format!("{} Shepard centres", centres.len()),
            });
        }
        if let Some(index) = centres.iter().position(|c| !c.is_finite()) {
            return Err(KernelError::NonFinite {
                what: "centre",
                index,
            });
        }
        if let Some(index) = radii.iter().position(|r| !r.is_finite()) {
            return Err(KernelError::NonFinite {
                what: "radius",
                index,
            });
        }
        if let Some(index) = radii.iter().position(|&r| r <= 0.0) {
            return Err(KernelError::InvalidRadius {
                index,
                radius: radii[index],
            });
        }
        let mut min = Vec3::INFINITY;
        let mut max = Vec3::NEG_INFINITY;
        for (&c, &r) in centres.iter().zip(&radii) {
            min = min.min(c - Vec3::splat(r));
            max = max.max(c + Vec3::splat(r));
        }
        let domain = Aabb { min, max };
        if !domain.is_valid() {
            return Err(KernelError::InvalidDomain {
                min: min.to_array(),
                max: max.to_array(),
            });
        }
        let buckets = Buckets::build(&centres, &radii, domain);
        let max_support = buckets
            .starts
            .windows(2)
            .map(|s| s[1] - s[0])
            .max()
            .unwrap_or(0);
        Ok(Shepard {
            centres,
            radii,
            domain,
            buckets,
            max_support,
        })
    }

    /// Kernels centred at `centres`, all of support radius `radius` (errors as [`Shepard::new`]).
    pub fn with_radius(centres: Vec<Vec3>, radius: f32) -> Result<Shepard, KernelError> {
        let radii = vec![radius; centres.len()];
        Shepard::new(centres, radii)
    }

    /// The kernel centres.
    pub fn centres(&self) -> &[Vec3] {
        &self.centres
    }

    /// The support radii, parallel to [`Shepard::centres`].
    pub fn radii(&self) -> &[f32] {
        &self.radii
    }

    /// Buckets per axis of the acceleration grid (for diagnostics and benchmarks).
    pub fn bucket_dims(&self) -> [usize; 3] {
        self.buckets.dims
    }

    /// φ_i at `x`, the unnormalised kernel, in f64.
    #[inline]
    fn phi(&self, i: usize, x: [f64; 3]) -> f64 {
        let r = self.radii[i] as f64;
        let d2 = squared_distance(x, self.centres[i]);
        if d2 < r * r {
            wendland_c2(d2.sqrt() / r)
        } else {
            0.0
        }
    }
}

#[inline]
fn squared_distance(x: [f64; 3], c: Vec3) -> f64 {
    let dx = x[0] - c.x as f64;
    let dy = x[1] - c.y as f64;
    let dz = x[2] - c.z as f64;
    dx * dx + dy * dy + dz * dz
}

impl Buckets {
    fn build(centres: &[Vec3], radii: &[f32], domain: Aabb) -> Buckets {
        let n = centres.len() as f64;
        let extent: [f64; 3] = std::array::from_fn(|k| domain.max[k] as f64 - domain.min[k] as f64);
        let mut sorted: Vec<f32> = radii.to_vec();
        sorted.sort_unstable_by(f32::total_cmp);
        let median = sorted[sorted.len() / 2] as f64;
        // Start at half the median radius (a query then tests about 2x more balls than cover
        // it), but no finer than the bucket budget allows.
        let max_buckets = MAX_BUCKETS_PER_KERNEL * n + 4096.0;
        let volume: f64 = extent.iter().product();
        let mut size = (0.5 * median).max((volume / max_buckets).cbrt());
        let dims_for = |size: f64| extent.map(|e| ((e / size).ceil() as usize).max(1));
        loop {
            let dims = dims_for(size);
            let buckets: f64 = dims.iter().map(|&d| d as f64).product();
            // Expected list entries: the buckets met by each ball's bounding box.
            let entries: f64 = radii
                .iter()
                .map(|&r| {
                    let span = 2.0 * r as f64 / size + 1.0;
                    dims.iter().map(|&d| span.min(d as f64)).product::<f64>()
                })
                .sum();
            let within_budget =
                buckets <= max_buckets && entries <= MAX_ENTRIES_PER_KERNEL * n + 4096.0;
            if within_budget || buckets <= 1.0 {
                break;
            }
            size *= 1.5;
        }
        let dims = dims_for(size);
        let origin = domain.min.to_array().map(|v| v as f64);
        let layout = Layout { origin, size, dims };
        // Two passes over the same visits: count, then fill (CSR), so lists are in index order.
        let mut starts = vec![0usize; dims[0] * dims[1] * dims[2] + 1];
        for (&c, &r) in centres.iter().zip(radii) {
            layout.for_each_reached(c, r, |b| starts[b + 1] += 1);
        }
        for b in 1..starts.len() {
            starts[b] += starts[b - 1];
        }
        let mut fill = starts.clone();
        let mut items = vec![0u32; starts[starts.len() - 1]];
        let mut spheres = vec![[0.0f32; 4]; items.len()];
        for (i, (&c, &r)) in centres.iter().zip(radii).enumerate() {
            // f32 differences of f32 inputs are exact to 2^-24 relative, so a squared distance
            // computed in f32 is within 1e-6 of the true one: 1e-5 of slack (and the smallest
            // normal, against underflow) never rejects a covering kernel.
            let reach = r * r * (1.0 + 1e-5) + f32::MIN_POSITIVE;
            layout.for_each_reached(c, r, |b| {
                items[fill[b]] = i as u32;
                spheres[fill[b]] = [c.x, c.y, c.z, reach];
                fill[b] += 1;
            });
        }
        Buckets {
            origin,
            size,
            dims,
            starts,
            items,
            spheres,
        }
    }

    /// The kernels listed in the bucket holding `x` (clamped to the grid).
    #[inline]
    fn candidates(&self, x: [f64; 3]) -> (&[u32], &[[f32; 4]]) {
        let mut flat = 0;
        for k in (0..3).rev() {
            let u = ((x[k] - self.origin[k]) / self.size).floor();
            let b = (u.max(0.0) as usize).min(self.dims[k] - 1);
            flat = flat * self.dims[k] + b;
        }
        let range = self.starts[flat]..self.starts[flat + 1];
        (&self.items[range.clone()], &self.spheres[range])
    }
}

/// The geometry of the bucket grid while it is being built.
struct Layout {
    origin: [f64; 3],
    size: f64,
    dims: [usize; 3],
}

impl Layout {
    /// Calls `visit(flat bucket index)` for every bucket the ball `(c, r)` reaches. The test is
    /// conservative (a slack of 1e-6 of a bucket), so rounding in the bucket of a query point can
    /// only add candidates, never lose a ball that covers the point.
    fn for_each_reached(&self, c: Vec3, r: f32, mut visit: impl FnMut(usize)) {
        let r = r as f64 + self.size * 1e-6;
        let c = c.to_array().map(|v| v as f64);
        let range = |k: usize, v: f64| {
            let u = ((v - self.origin[k]) / self.size).floor();
            (u.max(0.0) as usize).min(self.dims[k] - 1)
        };
        let lo: [usize; 3] = std::array::from_fn(|k| range(k, c[k] - r));
        let hi: [usize; 3] = std::array::from_fn(|k| range(k, c[k] + r));
        // Squared distance from the centre to bucket b's slab along axis k.
        let gap = |k: usize, b: usize| {
            let a = self.origin[k] + b as f64 * self.size;
            let d = (a - c[k]).max(c[k] - (a + self.size)).max(0.0);
            d * d
        };
        for bz in lo[2]..=hi[2] {
            let gz = gap(2, bz);
            for by in lo[1]..=hi[1] {
                let gy = gz + gap(1, by);
                if gy >= r * r {
                    continue;
                }
                for bx in lo[0]..=hi[0] {
                    if gy + gap(0, bx) < r * r {
                        visit(bx + self.dims[0] * (by + self.dims[1] * bz));
                    }
                }
            }
        }
    }
}

impl SpatialKernels for Shepard {
    fn len(&self) -> usize {
        self.centres.len()
    }

    fn max_support(&self) -> usize {
        self.max_support
    }

    fn domain(&self) -> Aabb {
        self.domain
    }

    fn eval(&self, x: Vec3, out: &mut KernelWeights) -> Result<(), CoreError> {
        out.clear();
        if let Some(index) = (0..3).find(|&k| !x[k].is_finite()) {
            return Err(CoreError::NonFinite {
                what: "query point",
                index,
            });
        }
        let uncovered = CoreError::Uncovered {
            point: x.to_array(),
        };
        if !self.domain.contains(x) {
            return Err(uncovered);
        }
        let p = x.to_array().map(|v| v as f64);
        // Pass 1: the covering kernels and the normaliser, in f64 (φ can be far below f32's range
        // near the edge of a ball). Pass 2 recomputes φ rather than keeping an f64 scratch buffer.
        let mut sum = 0.0f64;
        let (items, spheres) = self.buckets.candidates(p);
        for (&i, s) in items.iter().zip(spheres) {
            let d2 = (x.x - s[0]).powi(2) + (x.y - s[1]).powi(2) + (x.z - s[2]).powi(2);
            if d2 >= s[3] {
                continue;
            }
            let phi = self.phi(i as usize, p);
            if phi > 0.0 {
                sum += phi;
                out.push(i, 0.0);
            }
        }
        if sum <= 0.0 {
            out.clear();
            return Err(uncovered);
        }
        let mut kept = 0;
        for j in 0..out.len() {
            let i = out.indices[j];
            let w = (self.phi(i as usize, p) / sum) as f32;
            if w > 0.0 {
                out.indices[kept] = i;
                out.weights[kept] = w;
                kept += 1;
            }
        }
        out.indices.truncate(kept);
        out.weights.truncate(kept);
        Ok(())
    }

    fn centre(&self, i: usize) -> Option<Vec3> {
        self.centres.get(i).copied()
    }
}
