//! Basis kernels placed where the scene is: scattered Shepard kernels at k-means centres of the
//! valid voxels (beyond the paper, which uses a regular hat grid).
//!
//! The same number of basis kernels as a regular grid goes where the data is, as CPCA's
//! clusters do, while the basis stays a smooth partition of unity (Wendland C2 Shepard
//! kernels), so the model stays seamless. Measured (`docs/results.md`, MBD session 5): spreading
//! the kernels evenly over the valid voxels does *not* help (a hat node inside geometry still
//! serves the valid voxels in its support); weighting the placement by the field's energy does,
//! on coarse volumes with most of their energy next to walls (traced Sponza 48 × 20 × 30: MBD
//! 1.96× → 1.70× CPCA's error), and not on finer or smooth ones (Sponza at 96 voxels, Cornell),
//! so the regular hat grid stays the solver's default.

use glam::Vec3;
use prt_core::GridField;
use prt_kernels::Shepard;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;
use rayon::prelude::*;

use crate::MbdError;

/// How the valid voxels are weighted when the basis centres are placed (weighted k-means: more
/// weight draws more centres).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[non_exhaustive]
pub enum Placement {
    /// Every valid voxel counts the same: centres spread evenly over the valid space.
    Uniform,
    /// Weight `‖f(v)‖`: more centres where the field is large (the best measured placement).
    #[default]
    Energy,
    /// Weight `sqrt(mean ‖f(v) − f(u)‖²)` over the valid face neighbours `u` of `v`: more
    /// centres where the field changes from voxel to voxel.
    Variation,
}

/// Options of [`scene_adapted_basis`].
#[derive(Debug, Clone, PartialEq)]
pub struct AdaptedBasisOptions {
    /// Weighting of the k-means placement (default [`Placement::Energy`]).
    pub placement: Placement,
    /// Each kernel's support radius starts at the distance to its `neighbours`-th nearest
    /// other centre (default 12), so a point is covered by about this many kernels. Smaller is
    /// more local and cheaper; with 125 energy-placed kernels, 8 and 12 tie on traced Sponza
    /// and 16 is 5 % worse, while traced Cornell gains 12 % from 8 to 12 and 5 % more at 16
    /// (`docs/results.md`, MBD session 5).
    pub neighbours: usize,
    /// Seed of the k-means++ seeding.
    pub seed: u64,
    /// Lloyd iterations at most (default 50).
    pub max_iterations: usize,
}

impl Default for AdaptedBasisOptions {
    fn default() -> Self {
        Self {
            placement: Placement::Energy,
            neighbours: 12,
            seed: 0,
            max_iterations: 50,
        }
    }
}

/// Relative margin by which radii exceed what coverage needs (so that no point of the box lies
/// on the edge of its only ball, where the weight vanishes).
const COVERAGE_MARGIN: f64 = 1e-3;

/// `nodes` Shepard basis kernels (Wendland C2, partition of unity) placed by weighted k-means on
/// the centres of the voxels where `valid` is true, for use as MBD basis kernels with
/// [`crate::solve`]:
///
/// 1. weights per [`AdaptedBasisOptions::placement`] (floored at `1e-6` of their mean so that
///    every valid voxel can hold a centre; all uniform for a zero field);
/// 2. weighted k-means++ seeding, then Lloyd iterations on the voxel positions (f64);
/// 3. each centre snapped to the member voxel nearest its cluster's weighted mean, so every
///    centre sits at the centre of a valid voxel (a cluster's mean can fall inside geometry);
/// 4. radius of each kernel: the distance to its `neighbours`-th nearest other centre, then
///    enlarged until every voxel cube of the grid (valid or not) lies inside the ball of its
///    nearest centre, which covers the field's whole box, as the solver requires.
///
/// Deterministic for a seed (the assignments are computed in parallel, the sums sequentially).
///
/// Measured (`docs/results.md`, MBD session 5): with 125 kernels at L = 8,
/// [`Placement::Energy`] takes traced Sponza 48 × 20 × 30 from the regular hat grid's 1.96× to
/// 1.70× CPCA's error (no gain at 96 × 40 × 59), while [`Placement::Uniform`] is worse than the
/// hat grid (2.20×); on traced Cornell energy placement is 2 % above the hat grid. A solve
/// costs 2–3× the hat grid's CPU.
///
/// # Errors
/// [`MbdError::ShapeMismatch`] if `valid` does not have one entry per voxel,
/// [`MbdError::InvalidOption`] if `nodes` is 0 or exceeds the number of valid voxels, or
/// `neighbours` is 0, and [`prt_core::CoreError::NonFinite`] for NaN/Inf in the field (only
/// read by the weighted placements, but always checked).
pub fn scene_adapted_basis(
    field: &GridField,
    valid: &[bool],
    nodes: usize,
    options: &AdaptedBasisOptions,
) -> Result<Shepard, MbdError> {
    let n = field.num_voxels();
    if valid.len() != n {
        return Err(MbdError::ShapeMismatch {
            what: "validity mask",
            expected: vec![n],
            got: vec![valid.len()],
        });
    }
    field.check_finite()?;
    let members: Vec<usize> = (0..n).filter(|&v| valid[v]).collect();
    if nodes == 0 || nodes > members.len() {
        return Err(MbdError::InvalidOption {
            what: "nodes",
            why: format!(
                "{nodes} basis kernels for {} valid voxels (need 1..={})",
                members.len(),
                members.len()
            ),
        });
    }
    if options.neighbours == 0 {
        return Err(MbdError::InvalidOption {
            what: "neighbours",
            why: "must be at least 1".into(),
        });
    }
    let points: Vec<[f64; 3]> = members
        .iter()
        .map(|&v| field.centre_of(v).to_array().map(f64::from))
        .collect();
    let weights = placement_weights(field, valid, &members, options.placement);
    let mut centres = seed_plus_plus(&points, &weights, nodes, options.seed);
    let mut assignment = vec![u32::MAX; points.len()];
    for _ in 0..options.max_iterations.max(1) {
        let changed = assign(&points, &centres, &mut assignment);
        if changed == 0 {
            break;
        }
        update_means(&points, &weights, &assignment, &mut centres);
    }
    assign(&points, &centres, &mut assignment);
    let snapped = snap_to_members(&points, &assignment, &centres);
    let radii = covering_radii(field, &snapped, options.neighbours);
    let centres: Vec<Vec3> = snapped
        .iter()
        .map(|c| Vec3::new(c[0] as f32, c[1] as f32, c[2] as f32))
        .collect();
    Shepard::new(centres, radii).map_err(|e| MbdError::InvalidKernels {
        which: "basis",
        why: e.to_string(),
    })
}

/// Placement weight of every valid voxel (parallel to `members`).
fn placement_weights(
    field: &GridField,
    valid: &[bool],
    members: &[usize],
    placement: Placement,
) -> Vec<f64> {
    let norm2 = |a: &[f32], b: Option<&[f32]>| -> f64 {
        match b {
            Some(b) => a
                .iter()
                .zip(b)
                .map(|(&x, &y)| (f64::from(x) - f64::from(y)).powi(2))
                .sum(),
            None => a.iter().map(|&x| f64::from(x).powi(2)).sum(),
        }
    };
    let dims = field.dims();
    let raw: Vec<f64> = members
        .par_iter()
        .map(|&v| match placement {
            Placement::Uniform => 1.0,
            Placement::Energy => norm2(field.voxel(v), None).sqrt(),
            Placement::Variation => {
                let xyz = [
                    v % dims[0],
                    (v / dims[0]) % dims[1],
                    v / (dims[0] * dims[1]),
                ];
                let stride = [1, dims[0], dims[0] * dims[1]];
                let (mut sum, mut count) = (0.0, 0usize);
                for k in 0..3 {
                    let neighbours = [
                        xyz[k].checked_sub(1).map(|_| v - stride[k]),
                        (xyz[k] + 1 < dims[k]).then(|| v + stride[k]),
                    ];
                    for u in neighbours.into_iter().flatten().filter(|&u| valid[u]) {
                        sum += norm2(field.voxel(v), Some(field.voxel(u)));
                        count += 1;
                    }
                }
                if count == 0 {
                    0.0
                } else {
                    (sum / count as f64).sqrt()
                }
            }
        })
        .collect();
    let mean = raw.iter().sum::<f64>() / raw.len() as f64;
    if mean > 0.0 {
        raw.iter().map(|&w| w.max(1e-6 * mean)).collect()
    } else {
        vec![1.0; raw.len()]
    }
}

fn distance2(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    (0..3).map(|k| (a[k] - b[k]).powi(2)).sum()
}

/// Weighted k-means++: each next centre is a point drawn with probability proportional to its
/// weight times its squared distance to the nearest chosen centre. Points are distinct and all
/// weights positive, so `k ≤ points.len()` centres are distinct points.
fn seed_plus_plus(points: &[[f64; 3]], weights: &[f64], k: usize, seed: u64) -> Vec<[f64; 3]> {
    let mut rng = Pcg64Mcg::seed_from_u64(seed);
    let mut draw = |scores: &mut dyn Iterator<Item = f64>, total: f64| -> Option<usize> {
        let target = rng.random::<f64>() * total;
        let mut last = None;
        let mut acc = 0.0;
        for (i, s) in scores.enumerate() {
            if s > 0.0 {
                acc += s;
                last = Some(i);
                if acc > target {
                    break;
                }
            }
        }
        last
    };
    let total: f64 = weights.iter().sum();
    let first = draw(&mut weights.iter().copied(), total).unwrap_or(0);
    let mut centres = vec![points[first]];
    let mut nearest: Vec<f64> = points
        .iter()
        .map(|p| distance2(p, &points[first]))
        .collect();
    while centres.len() < k {
        let total: f64 = nearest.iter().zip(weights).map(|(d, w)| d * w).sum();
        let next = draw(&mut nearest.iter().zip(weights).map(|(d, w)| d * w), total);
        let Some(next) = next else { break };
        centres.push(points[next]);
        for (d, p) in nearest.iter_mut().zip(points) {
            *d = d.min(distance2(p, &points[next]));
        }
    }
    centres
}

fn nearest_centre(p: &[f64; 3], centres: &[[f64; 3]]) -> (usize, f64) {
    centres
        .iter()
        .enumerate()
        .map(|(i, c)| (i, distance2(p, c)))
        .fold(
            (0, f64::INFINITY),
            |best, x| if x.1 < best.1 { x } else { best },
        )
}

/// Assigns every point to its nearest centre (ties to the lower index); returns how many
/// assignments changed.
fn assign(points: &[[f64; 3]], centres: &[[f64; 3]], assignment: &mut [u32]) -> usize {
    assignment
        .par_iter_mut()
        .zip(points)
        .map(|(a, p)| {
            let best = nearest_centre(p, centres).0 as u32;
            let changed = usize::from(*a != best);
            *a = best;
            changed
        })
        .sum()
}

/// Moves every centre to the weighted mean of its points (an empty cluster keeps its centre).
fn update_means(
    points: &[[f64; 3]],
    weights: &[f64],
    assignment: &[u32],
    centres: &mut [[f64; 3]],
) {
    let mut sums = vec![[0.0f64; 4]; centres.len()];
    for ((p, &w), &a) in points.iter().zip(weights).zip(assignment) {
        let s = &mut sums[a as usize];
        for k in 0..3 {
            s[k] += w * p[k];
        }
        s[3] += w;
    }
    for (c, s) in centres.iter_mut().zip(&sums) {
        if s[3] > 0.0 {
            *c = [s[0] / s[3], s[1] / s[3], s[2] / s[3]];
        }
    }
}

/// Each centre moved to its member point nearest to it. Clusters partition the points, so the
/// results are distinct; a centre without members (possible only when Lloyd's last move emptied
/// it) takes the point farthest from every other snapped centre.
fn snap_to_members(points: &[[f64; 3]], assignment: &[u32], centres: &[[f64; 3]]) -> Vec<[f64; 3]> {
    let mut best: Vec<Option<(f64, usize)>> = vec![None; centres.len()];
    for (i, (p, &a)) in points.iter().zip(assignment).enumerate() {
        let d = distance2(p, &centres[a as usize]);
        let slot = &mut best[a as usize];
        if slot.is_none_or(|(bd, _)| d < bd) {
            *slot = Some((d, i));
        }
    }
    let mut snapped: Vec<Option<[f64; 3]>> =
        best.iter().map(|b| b.map(|(_, i)| points[i])).collect();
    for c in 0..snapped.len() {
        if snapped[c].is_none() {
            let taken: Vec<[f64; 3]> = snapped.iter().flatten().copied().collect();
            let farthest = points
                .iter()
                .map(|p| nearest_centre(p, &taken).1)
                .enumerate()
                .fold((0, -1.0), |b, x| if x.1 > b.1 { x } else { b })
                .0;
            snapped[c] = Some(points[farthest]);
        }
    }
    snapped.into_iter().flatten().collect()
}

/// Support radii: the distance to the `neighbours`-th nearest other centre, enlarged so that
/// the ball of each voxel's nearest centre contains the whole voxel cube (its centre's distance
/// plus the cube's half diagonal), with a relative margin.
fn covering_radii(field: &GridField, centres: &[[f64; 3]], neighbours: usize) -> Vec<f32> {
    let mut radii: Vec<f64> = centres
        .iter()
        .map(|c| {
            let mut d: Vec<f64> = centres.iter().map(|o| distance2(c, o).sqrt()).collect();
            d.sort_unstable_by(f64::total_cmp);
            // d[0] is the centre itself.
            d.get(neighbours.min(d.len() - 1)).copied().unwrap_or(0.0)
        })
        .collect();
    let half_diagonal = 0.5 * f64::from(field.voxel_size().length());
    let needed: Vec<(usize, f64)> = (0..field.num_voxels())
        .into_par_iter()
        .map(|v| {
            let p = field.centre_of(v).to_array().map(f64::from);
            let (i, d2) = nearest_centre(&p, centres);
            (i, d2.sqrt() + half_diagonal)
        })
        .collect();
    for (i, r) in needed {
        radii[i] = radii[i].max(r);
    }
    radii
        .iter()
        .map(|&r| (r * (1.0 + COVERAGE_MARGIN)) as f32)
        .collect()
}
