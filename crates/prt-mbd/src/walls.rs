//! Basis kernels that do not reach across walls (beyond the paper, opt-in).
//!
//! On a scene like Sponza most of the volume is inside walls and columns (the baker's invalid,
//! zero voxels) and the valid voxels sit in thin slabs between them. A hat basis node then
//! serves every voxel of its 2 × 2 × 2-cell support, on both sides of a wall, although the
//! transfer on the two sides has nothing in common; clustered PCA groups voxels by value and so
//! follows the geometry. [`WallAware`] keeps the number of basis nodes and cuts each node's
//! kernel back to the voxels it can reach without crossing geometry:
//!
//! 1. **Reach.** For every node `n`, its *region* is the set of voxels whose centre its base
//!    kernel covers (weight > 0). The node's *seeds* are the valid voxels of the region where
//!    its base weight is largest (for a hat: the valid voxels nearest the node, which finds the
//!    right side of a wall when the node itself lies inside geometry). A flood fill through
//!    face-adjacent valid voxels of the region (6-connected, so a wall one voxel thick stops it,
//!    even a diagonal one) marks the voxels `n` reaches. [`WallOptions::max_detour`] can also
//!    cut voxels reached only by a long way round (geodesic steps over the L1 distance).
//! 2. **Weights at voxel centres.** A valid voxel `v` keeps the base weights of the nodes that
//!    reach it, renormalised to sum to one; if none of its nodes reaches it (a pocket no seed
//!    flood gets to) it keeps the base weights unchanged (counted by [`WallAware::fallbacks`]).
//!    An invalid voxel keeps the base weights of its nodes that reach one of its valid face
//!    neighbours (renormalised; else all of them): the half-voxel between a valid voxel and the
//!    wall, where the data still interpolates the valid voxel, is served by that side's nodes.
//! 3. **Anywhere.** The weights at `x` are the trilinear interpolation of the eight surrounding
//!    voxel centres' weights (clamped to the box like the field's own sampling). A convex
//!    combination of partitions of unity is one, so the family is a non-negative, continuous
//!    partition of unity: MBD stays seamless. With every voxel valid, every node reaches its
//!    whole region and the family is the base sampled at the voxel centres and interpolated
//!    trilinearly (identical to a hat grid wherever no node plane crosses a voxel-centre cell).
//!
//! The weights are per voxel rather than per basis cell, because walls are: that is the cost.
//! An engine stores, beside the `L` coefficients of each voxel, the voxel's masked weights
//! over its (at most 8, for a hat) nodes, or 8 bits of mask and recomputes the weights from
//! the hat; at runtime it blends eight voxels' weight lists instead of evaluating one hat
//! (up to 27 basis nodes instead of 8 at a point near a node plane). The solver batches per
//! [`SpatialKernels::support_cell`]: for a hat base, the voxel-centre cells between the same
//! node planes (the cells inside a basis cell share its 8 nodes; a slab of cells straddling a
//! node plane uses 12, an edge 18, a corner 27, when the nodes are at least a voxel apart).
//!
//! Measured (`docs/results.md`, MBD session 7; traced Sponza, L = 8, 125 nodes): the cut
//! removes only 6–7 % of the hat's weight at valid voxel centres (Sponza's open space is
//! connected inside most supports) and takes MBD from 1.96× to 1.70× CPCA's error at
//! 48 × 20 × 30 and from 1.83× to 1.68× at 72 × 30 × 44 with the hat over the field's box, and
//! to 1.66× / 1.62× with the hat over the voxel centres' box ([`crate::basis_box`], `Mbd`'s
//! layout since that session and what [`wall_aware_basis`] cuts); a detour limit or line of sight cuts more and
//! does worse; Cornell 0.81× → 0.79×. A solve costs 1.4–1.7× the hat grid's CPU (the cells
//! straddling node planes), so the plain hat grid stays the default.

use glam::Vec3;
use prt_core::{Aabb, CoreError, KernelWeights, SpatialKernels};
use prt_kernels::HatGrid;
use rayon::prelude::*;

use crate::MbdError;
use crate::voxel_weights::VoxelWeights;

/// Options of [`WallAware`].
#[derive(Debug, Clone, PartialEq)]
pub struct WallOptions {
    /// A voxel counts as reached by a node only if its geodesic distance from the node's seeds
    /// (flood-fill steps through valid voxels) is at most `max_detour` times its L1 distance in
    /// voxels from the nearest seed, plus one step. Infinite (the default): every voxel the
    /// flood fill reaches inside the node's region.
    pub max_detour: f32,
    /// Also require a straight line of valid voxels from one of the node's seeds to the voxel
    /// (sampled every quarter voxel): the node serves only what it "sees". Stricter than any
    /// detour limit around a pillar or through an arch; off by default.
    pub line_of_sight: bool,
}

impl Default for WallOptions {
    fn default() -> Self {
        Self {
            max_detour: f32::INFINITY,
            line_of_sight: false,
        }
    }
}

/// Relative tolerance within which base weights count as the node's largest (seed ties).
const SEED_TIE: f32 = 1e-5;

/// A basis kernel family whose kernels stop at walls: a base family (a hat grid, or any
/// [`SpatialKernels`]) masked per voxel by flood-fill reachability through valid voxels and
/// interpolated trilinearly between voxel centres (module docs: [`crate::walls`]).
///
/// Extremes (tested): with every voxel valid it is the base at every voxel centre; a node
/// whose region holds no valid voxel gets zero weight except at voxels that fall back to the
/// base weights; a
/// single valid voxel, axes of one voxel, and more nodes than voxels are handled (weights stay
/// a non-negative partition of unity); points outside the box are clamped to it; a non-finite
/// point is [`CoreError::NonFinite`].
#[derive(Debug, Clone)]
pub struct WallAware<K> {
    base: K,
    weights: VoxelWeights,
    /// Per axis, the support-cell group of every voxel-centre cell (hat bases only).
    groups: Option<AxisGroups>,
    fallbacks: usize,
}

/// Per axis, a group id for each voxel-centre cell, and the number of groups.
#[derive(Debug, Clone)]
struct AxisGroups {
    ids: [Vec<u32>; 3],
    counts: [usize; 3],
}

/// The MBD basis of [`crate::Mbd`] with `nodes` basis nodes per axis (a [`HatGrid`] over
/// [`crate::basis_box`]), cut back at walls by the validity mask `valid` (one entry per voxel, `true`
/// where the field holds data).
///
/// Use it with the per-voxel hat coefficient kernels:
/// ```
/// # use prt_core::{Aabb, GridField, NoProgress};
/// # use prt_mbd::*;
/// # let field = SyntheticField::new([8, 6, 6], 6).build(Aabb::UNIT).unwrap();
/// # let valid: Vec<bool> = (0..field.num_voxels()).map(|v| v % 8 != 3).collect();
/// let mbd = Mbd { basis_nodes: [3, 3, 3], options: MbdOptions { rank: 2, max_iterations: 8, ..Default::default() } };
/// let basis = wall_aware_basis(&field, &valid, mbd.basis_nodes, &WallOptions::default()).unwrap();
/// let (coefficients, _) = mbd.kernels(&field).unwrap();
/// let (model, _) = solve(&field, coefficients, basis, &mbd.options, &NoProgress).unwrap();
/// # assert_eq!(model.basis().dim(), (27, 2, 6));
/// ```
///
/// # Errors
/// [`MbdError::InvalidKernels`] for an axis with fewer than 2 nodes, and the errors of
/// [`WallAware::new`].
pub fn wall_aware_basis(
    field: &prt_core::GridField,
    valid: &[bool],
    nodes: [usize; 3],
    options: &WallOptions,
) -> Result<WallAware<HatGrid>, MbdError> {
    if let Some(axis) = (0..3).find(|&k| nodes[k] < 2) {
        return Err(MbdError::InvalidKernels {
            which: "basis",
            why: format!("axis {axis} has {} nodes, need at least 2", nodes[axis]),
        });
    }
    let hat =
        HatGrid::new(nodes, crate::basis_box(field)).map_err(|e| MbdError::InvalidKernels {
            which: "basis",
            why: e.to_string(),
        })?;
    WallAware::from_hat(hat, field.dims(), field.bounds(), valid, options)
}

impl WallAware<HatGrid> {
    /// [`WallAware::new`] for a hat grid over any box (e.g. the box of the voxel centres), with
    /// the hat's support cells: the solver then batches the voxel-centre cells between the same
    /// node planes, as it does for the hat grid's own cells.
    ///
    /// # Errors
    /// Those of [`WallAware::new`].
    pub fn from_hat(
        hat: HatGrid,
        dims: [usize; 3],
        bounds: Aabb,
        valid: &[bool],
        options: &WallOptions,
    ) -> Result<Self, MbdError> {
        let (nodes, domain) = (hat.nodes(), hat.domain());
        let mut kernels = WallAware::new(hat, dims, bounds, valid, options)?;
        kernels.groups = Some(hat_groups(dims, bounds, nodes, domain));
        Ok(kernels)
    }
}

impl<K: SpatialKernels> WallAware<K> {
    /// `base` cut back at walls on a `dims` voxel grid over `bounds` with validity mask `valid`
    /// (one entry per voxel, x fastest). Construction is a flood fill per node over its region
    /// (`O(Σ_n |region_n|)`) and a pass over the voxels.
    ///
    /// # Errors
    /// [`MbdError::ShapeMismatch`] if `valid` does not have one entry per voxel,
    /// [`MbdError::InvalidOption`] for an empty grid, a mask without valid voxels or a NaN or
    /// non-positive `max_detour`, [`MbdError::InvalidKernels`] for an empty base family or an
    /// invalid box, [`MbdError::KernelsDoNotCover`] if the base has no weight at some voxel
    /// centre.
    pub fn new(
        base: K,
        dims: [usize; 3],
        bounds: Aabb,
        valid: &[bool],
        options: &WallOptions,
    ) -> Result<Self, MbdError> {
        let n = VoxelWeights::voxel_count(dims, bounds)?;
        if valid.len() != n {
            return Err(MbdError::ShapeMismatch {
                what: "validity mask",
                expected: vec![n],
                got: vec![valid.len()],
            });
        }
        if !valid.iter().any(|&v| v) {
            return Err(MbdError::InvalidOption {
                what: "validity mask",
                why: "no voxel is valid".into(),
            });
        }
        if options.max_detour.is_nan() || options.max_detour <= 0.0 {
            return Err(MbdError::InvalidOption {
                what: "max_detour",
                why: format!("{} is not a positive number", options.max_detour),
            });
        }
        if base.is_empty() {
            return Err(MbdError::InvalidKernels {
                which: "basis",
                why: "the base family has no kernels".into(),
            });
        }
        let grid = Grid { dims, bounds };
        let rows = base_rows(&base, &grid, n)?;
        let reach = reach_masks(&rows, &grid, valid, base.len(), options);
        let (final_rows, fallbacks) = masked_rows(&rows, &reach, &grid, valid);
        Ok(WallAware {
            base,
            weights: VoxelWeights::new(dims, bounds, final_rows),
            groups: None,
            fallbacks,
        })
    }

    /// The base family.
    pub fn base(&self) -> &K {
        &self.base
    }

    /// Valid voxels none of whose nodes reaches them, which keep the base weights.
    pub fn fallbacks(&self) -> usize {
        self.fallbacks
    }

    /// The kernels non-zero at the centre of voxel `v` (renormalised masked base weights), as
    /// `(kernel, weight)` pairs; empty for `v` out of range.
    pub fn voxel_weights(&self, v: usize) -> impl Iterator<Item = (u32, f32)> + '_ {
        self.weights.row(v)
    }

    /// Mean number of kernels non-zero at a voxel centre (the base's is 8 for a hat grid at
    /// generic positions).
    pub fn mean_voxel_support(&self) -> f64 {
        self.weights.mean_row_len()
    }
}

impl<K> crate::polish::sealed::Sealed for WallAware<K> {
    fn layout(&self) -> crate::polish::BasisLayout<'_> {
        crate::polish::BasisLayout::Voxels(&self.weights)
    }
}

impl<K: SpatialKernels> crate::PolishBasis for WallAware<K> {}

impl<K: SpatialKernels> SpatialKernels for WallAware<K> {
    fn len(&self) -> usize {
        self.base.len()
    }

    fn max_support(&self) -> usize {
        self.weights.max_support()
    }

    fn domain(&self) -> Aabb {
        self.weights.bounds()
    }

    /// The trilinear blend of the eight surrounding voxel centres' weights; points outside the
    /// box are clamped to it.
    fn eval(&self, x: Vec3, out: &mut KernelWeights) -> Result<(), CoreError> {
        self.weights.eval(x, out)
    }

    /// For a hat base: the voxel-centre cells between the same basis-node planes form one
    /// group (they share the same few nodes); other bases have no cells.
    fn support_cell(&self, x: Vec3) -> Option<usize> {
        let groups = self.groups.as_ref()?;
        let (cell, _) = self.weights.locate(x).ok()?;
        let g = [0, 1, 2].map(|k| groups.ids[k][cell[k]] as usize);
        Some(g[0] + groups.counts[0] * (g[1] + groups.counts[1] * g[2]))
    }

    fn num_support_cells(&self) -> usize {
        self.groups
            .as_ref()
            .map_or(0, |g| g.counts.iter().product())
    }

    fn centre(&self, i: usize) -> Option<Vec3> {
        self.base.centre(i)
    }
}

/// The voxel grid.
struct Grid {
    dims: [usize; 3],
    bounds: Aabb,
}

impl Grid {
    fn centre(&self, v: usize) -> Vec3 {
        let d = self.dims;
        let c = [v % d[0], (v / d[0]) % d[1], v / (d[0] * d[1])];
        let size = self.bounds.size();
        Vec3::from_array(
            [0, 1, 2].map(|k| self.bounds.min[k] + (c[k] as f32 + 0.5) * size[k] / d[k] as f32),
        )
    }

    fn coords(&self, v: usize) -> [usize; 3] {
        let d = self.dims;
        [v % d[0], (v / d[0]) % d[1], v / (d[0] * d[1])]
    }

    /// Face neighbours of `v`.
    fn neighbours(&self, v: usize) -> impl Iterator<Item = usize> {
        let c = self.coords(v);
        let d = self.dims;
        let stride = [1, d[0], d[0] * d[1]];
        (0..6).filter_map(move |i| {
            let (k, up) = (i / 2, i % 2 == 1);
            if up {
                (c[k] + 1 < d[k]).then(|| v + stride[k])
            } else {
                (c[k] > 0).then(|| v - stride[k])
            }
        })
    }
}

/// The base family's non-zero weights at every voxel centre.
fn base_rows<K: SpatialKernels>(
    base: &K,
    grid: &Grid,
    n: usize,
) -> Result<Vec<Vec<(u32, f32)>>, MbdError> {
    (0..n)
        .into_par_iter()
        .map_init(KernelWeights::default, |w, v| {
            let x = grid.centre(v);
            let uncovered = MbdError::KernelsDoNotCover {
                which: "basis",
                point: x.to_array(),
            };
            match base.eval(x, w) {
                Ok(()) => {}
                Err(CoreError::Uncovered { .. }) => return Err(uncovered),
                Err(e) => return Err(e.into()),
            }
            let row: Vec<(u32, f32)> = w.iter().filter(|&(_, wi)| wi > 0.0).collect();
            if row.is_empty() {
                return Err(uncovered);
            }
            Ok(row)
        })
        .collect()
}

/// Per voxel, parallel to its base row: whether that row's node reaches the voxel.
fn reach_masks(
    rows: &[Vec<(u32, f32)>],
    grid: &Grid,
    valid: &[bool],
    nodes: usize,
    options: &WallOptions,
) -> Vec<Vec<bool>> {
    // Each node's region: the voxels its base kernel covers, with the weight there.
    let mut regions: Vec<Vec<(u32, f32)>> = vec![Vec::new(); nodes];
    for (v, row) in rows.iter().enumerate() {
        for &(i, w) in row {
            regions[i as usize].push((v as u32, w));
        }
    }
    let reached: Vec<Vec<u32>> = regions
        .par_iter()
        .enumerate()
        .map(|(node, region)| flood(node as u32, region, rows, grid, valid, options))
        .collect();
    let mut masks: Vec<Vec<bool>> = rows.iter().map(|r| vec![false; r.len()]).collect();
    for (node, voxels) in reached.iter().enumerate() {
        for &v in voxels {
            let v = v as usize;
            if let Some(p) = rows[v].iter().position(|&(i, _)| i as usize == node) {
                masks[v][p] = true;
            }
        }
    }
    masks
}

/// The valid voxels of `region` that `node` reaches: a breadth-first flood fill through face
/// neighbours that are valid and inside the region, from the valid voxels of largest weight.
fn flood(
    node: u32,
    region: &[(u32, f32)],
    rows: &[Vec<(u32, f32)>],
    grid: &Grid,
    valid: &[bool],
    options: &WallOptions,
) -> Vec<u32> {
    let max_detour = options.max_detour;
    let in_region = |v: usize| rows[v].iter().any(|&(i, _)| i == node);
    let best = region
        .iter()
        .filter(|&&(v, _)| valid[v as usize])
        .map(|&(_, w)| w)
        .fold(0.0f32, f32::max);
    if best <= 0.0 {
        return Vec::new();
    }
    let seeds: Vec<u32> = region
        .iter()
        .filter(|&&(v, w)| valid[v as usize] && w >= best * (1.0 - SEED_TIE))
        .map(|&(v, _)| v)
        .collect();
    let seed_coords: Vec<[usize; 3]> = seeds.iter().map(|&s| grid.coords(s as usize)).collect();
    // Steps from the seeds, keyed by voxel (regions are small boxes: a sorted map is enough).
    let mut steps: std::collections::HashMap<u32, u32> = seeds.iter().map(|&s| (s, 0)).collect();
    let mut queue: std::collections::VecDeque<u32> = seeds.iter().copied().collect();
    let mut reached = Vec::new();
    while let Some(v) = queue.pop_front() {
        let s = steps[&v];
        let within = max_detour.is_infinite() || {
            let c = grid.coords(v as usize);
            let straight = seed_coords
                .iter()
                .map(|sc| (0..3).map(|k| sc[k].abs_diff(c[k])).sum::<usize>())
                .min()
                .unwrap_or(0);
            s as f32 <= max_detour * straight as f32 + 1.0
        };
        let seen = !options.line_of_sight
            || seed_coords
                .iter()
                .any(|sc| visible(grid, valid, *sc, grid.coords(v as usize)));
        if within && seen {
            reached.push(v);
        }
        for u in grid.neighbours(v as usize) {
            if valid[u] && !steps.contains_key(&(u as u32)) && in_region(u) {
                steps.insert(u as u32, s + 1);
                queue.push_back(u as u32);
            }
        }
    }
    reached
}

/// Whether the segment between the centres of voxels `a` and `b` passes through valid voxels
/// only (sampled every quarter voxel).
fn visible(grid: &Grid, valid: &[bool], a: [usize; 3], b: [usize; 3]) -> bool {
    let delta = [0, 1, 2].map(|k| b[k] as f64 - a[k] as f64);
    let longest = delta.iter().fold(0.0f64, |m, d| m.max(d.abs()));
    let steps = (4.0 * longest).ceil() as usize;
    (1..steps).all(|s| {
        let t = s as f64 / steps as f64;
        let c = [0, 1, 2].map(|k| (a[k] as f64 + t * delta[k]).round() as usize);
        valid[c[0] + grid.dims[0] * (c[1] + grid.dims[1] * c[2])]
    })
}

/// Per voxel, the renormalised weights of the nodes that reach it (valid voxels) or reach a
/// valid face neighbour (invalid voxels), the base weights where no node qualifies; and the
/// number of valid voxels that fell back.
fn masked_rows(
    rows: &[Vec<(u32, f32)>],
    reach: &[Vec<bool>],
    grid: &Grid,
    valid: &[bool],
) -> (Vec<Vec<(u32, f32)>>, usize) {
    let out: Vec<(Vec<(u32, f32)>, bool)> = (0..rows.len())
        .into_par_iter()
        .map(|v| {
            let row = &rows[v];
            let keep: Vec<bool> = if valid[v] {
                reach[v].clone()
            } else {
                row.iter()
                    .map(|&(i, _)| {
                        grid.neighbours(v).any(|u| {
                            valid[u]
                                && rows[u]
                                    .iter()
                                    .zip(&reach[u])
                                    .any(|(&(j, _), &r)| r && j == i)
                        })
                    })
                    .collect()
            };
            let total: f64 = row
                .iter()
                .zip(&keep)
                .filter(|(_, k)| **k)
                .map(|(&(_, w), _)| f64::from(w))
                .sum();
            if total <= 0.0 {
                let sum: f64 = row.iter().map(|&(_, w)| f64::from(w)).sum();
                let base = row.iter().map(|&(i, w)| (i, (f64::from(w) / sum) as f32));
                return (base.collect(), valid[v]);
            }
            let masked = row
                .iter()
                .zip(&keep)
                .filter(|(_, k)| **k)
                .map(|(&(i, w), _)| (i, (f64::from(w) / total) as f32));
            (masked.collect(), false)
        })
        .collect();
    let fallbacks = out.iter().filter(|(_, f)| *f).count();
    (out.into_iter().map(|(r, _)| r).collect(), fallbacks)
}

/// For a hat grid with `nodes` nodes per axis over `domain`, on a voxel grid over `bounds`: per
/// axis, voxel-centre cell `j` (between centres `j` and `j + 1`) touches the nodes from
/// `floor(u_j)` to `ceil(u_{j+1})`, `u` the centre's coordinate in node spacings (clamped to
/// the grid); cells with the same range form one group. Rounding can only widen a range, which
/// costs a little batching and nothing else.
fn hat_groups(dims: [usize; 3], bounds: Aabb, nodes: [usize; 3], domain: Aabb) -> AxisGroups {
    let mut ids: [Vec<u32>; 3] = Default::default();
    let mut counts = [0usize; 3];
    for k in 0..3 {
        let d = dims[k];
        let last = nodes[k].saturating_sub(1);
        let voxel = (f64::from(bounds.max[k]) - f64::from(bounds.min[k])) / d as f64;
        let span = f64::from(domain.max[k]) - f64::from(domain.min[k]);
        let u = |i: usize| {
            if last == 0 || span <= 0.0 {
                return 0.0;
            }
            let x = f64::from(bounds.min[k]) + (i as f64 + 0.5) * voxel;
            ((x - f64::from(domain.min[k])) / span * last as f64).clamp(0.0, last as f64)
        };
        let cells = d.saturating_sub(1).max(1);
        let mut previous = None;
        let mut id = 0u32;
        for j in 0..cells {
            let range = (u(j).floor() as usize, u((j + 1).min(d - 1)).ceil() as usize);
            if previous.is_some_and(|p| p != range) {
                id += 1;
            }
            previous = Some(range);
            ids[k].push(id);
        }
        counts[k] = id as usize + 1;
    }
    AxisGroups { ids, counts }
}
