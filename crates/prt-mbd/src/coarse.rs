//! The coarse start of [`crate::Mbd`] (beyond the paper): the field averaged over 2 × 2 × 2
//! voxels is fitted first, and the full-resolution solve starts from that fit's basis.

use prt_core::{Aabb, GridField};

use crate::MbdError;

/// [`crate::Mbd::coarse_start`]: solve on the field halved `levels` times first (an eighth of
/// the samples per level), each level starting from the basis of the coarser one; the basis
/// nodes stay the same, so a coarse basis is a start for the finer solve as it is. The
/// full-resolution solve then begins near its optimum and needs fewer of its costly
/// iterations ([`crate::SolverOptions::max_iterations`] still caps them).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CoarseStart {
    /// Times the field is halved (default 1). A level is skipped when halving would leave an
    /// axis with fewer voxels than basis nodes.
    pub levels: usize,
    /// Iteration cap of each coarse solve (default 64); the solver's stopping rule applies.
    pub iterations: usize,
}

impl Default for CoarseStart {
    fn default() -> Self {
        Self {
            levels: 1,
            iterations: 64,
        }
    }
}

/// Whether a grid of `dims` voxels can be halved ([`halved_grid`]) and keep at least `nodes[k]`
/// voxels on every axis of more than one voxel (what [`CoarseStart`] asks of each level).
pub fn can_halve(dims: [usize; 3], nodes: [usize; 3]) -> bool {
    dims.iter().any(|&n| n > 1) && (0..3).all(|k| dims[k] == 1 || dims[k].div_ceil(2) >= nodes[k])
}

/// The grid a [`CoarseStart`] level fits, made of a grid of `dims` voxels filling `bounds`:
/// voxels twice as large (axes of one voxel stay one voxel), `ceil(n / 2)` of them, the box
/// keeping its minimum corner and growing by a voxel on odd axes. Coarse voxel `i` covers voxels
/// `2i` and `2i + 1`.
pub fn halved_grid(dims: [usize; 3], bounds: Aabb) -> ([usize; 3], Aabb) {
    let coarse_dims = dims.map(|n| if n == 1 { 1 } else { n.div_ceil(2) });
    let voxel = bounds.size() / glam::Vec3::from_array(dims.map(|n| n as f32));
    let max = std::array::from_fn(|k| {
        let step = if dims[k] == 1 { 1 } else { 2 };
        bounds.min[k] + voxel[k] * (step * coarse_dims[k]) as f32
    });
    (
        coarse_dims,
        Aabb::new(bounds.min, glam::Vec3::from_array(max)),
    )
}

/// `field` averaged over 2 × 2 × 2 voxels (axes of one voxel stay one voxel; an odd last
/// voxel averages itself alone) and, with `valid`, each coarse voxel valid when one of its
/// voxels is, averaging the valid ones only; the box keeps its minimum corner and grows by a
/// voxel on odd axes. Sums in f64.
pub(crate) fn halve(
    field: &GridField,
    valid: Option<&[bool]>,
) -> Result<(GridField, Option<Vec<bool>>), MbdError> {
    let dims = field.dims();
    let step = dims.map(|n| if n == 1 { 1 } else { 2 });
    let (coarse_dims, coarse_bounds) = halved_grid(dims, field.bounds());
    let d = field.dim();
    let mut coarse = GridField::new(coarse_dims, coarse_bounds, d)?;
    let mut coarse_valid = valid.map(|_| vec![false; coarse.num_voxels()]);
    let mut sum = vec![0.0f64; d];
    for cz in 0..coarse_dims[2] {
        for cy in 0..coarse_dims[1] {
            for cx in 0..coarse_dims[0] {
                sum.fill(0.0);
                let mut count = 0usize;
                for z in cz * step[2]..((cz + 1) * step[2]).min(dims[2]) {
                    for y in cy * step[1]..((cy + 1) * step[1]).min(dims[1]) {
                        for x in cx * step[0]..((cx + 1) * step[0]).min(dims[0]) {
                            let v = field.index(x, y, z);
                            if valid.is_some_and(|valid| !valid[v]) {
                                continue;
                            }
                            count += 1;
                            for (s, &f) in sum.iter_mut().zip(field.voxel(v)) {
                                *s += f as f64;
                            }
                        }
                    }
                }
                let c = coarse.index(cx, cy, cz);
                if let Some(coarse_valid) = coarse_valid.as_mut() {
                    coarse_valid[c] = count > 0;
                }
                if count > 0 {
                    for (o, &s) in coarse.voxel_mut(c).iter_mut().zip(&sum) {
                        *o = (s / count as f64) as f32;
                    }
                }
            }
        }
    }
    Ok((coarse, coarse_valid))
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn field(dims: [usize; 3], seed: u64) -> GridField {
        let mut state = seed | 1;
        GridField::from_fn(dims, Aabb::UNIT, 3, |_, out| {
            for o in out {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                *o = (state % 1000) as f32 / 100.0;
            }
        })
        .unwrap()
    }

    proptest! {
        #[test]
        fn halving_preserves_the_valid_mean_and_the_box_corner(
            nx in 1usize..7, ny in 1usize..7, nz in 1usize..7, seed in 0u64..1000, masked: bool,
        ) {
            let dims = [nx, ny, nz];
            let f = field(dims, seed);
            let valid: Vec<bool> = (0..f.num_voxels()).map(|v| !masked || !(v * 7 + seed as usize).is_multiple_of(3)).collect();
            let (c, cv) = halve(&f, masked.then_some(valid.as_slice())).unwrap();
            prop_assert_eq!(c.bounds().min, f.bounds().min);
            for k in 0..3 {
                prop_assert_eq!(c.dims()[k], if dims[k] == 1 { 1 } else { dims[k].div_ceil(2) });
                // The coarse voxel is two fine ones (one on an axis of one voxel).
                let ratio = c.voxel_size()[k] / f.voxel_size()[k];
                let expected = if dims[k] == 1 { 1.0 } else { 2.0 };
                prop_assert!((ratio - expected).abs() < 1e-5, "axis {}: ratio {}", k, ratio);
            }
            // Each coarse voxel is the mean of the valid fine voxels inside it.
            for v in 0..f.num_voxels() {
                let [x, y, z] = f.coords(v);
                let cx = if dims[0] == 1 { 0 } else { x / 2 };
                let cy = if dims[1] == 1 { 0 } else { y / 2 };
                let cz = if dims[2] == 1 { 0 } else { z / 2 };
                let cvox = c.index(cx, cy, cz);
                if let Some(cv) = &cv {
                    prop_assert!(!valid[v] || cv[cvox]);
                }
            }
            let total_fine: f64 = (0..f.num_voxels()).filter(|&v| valid[v]).map(|v| f.voxel(v)[0] as f64).sum();
            let count_fine = (0..f.num_voxels()).filter(|&v| valid[v]).count();
            prop_assume!(count_fine > 0);
            // Weighted by the count of valid voxels each coarse voxel averaged, the sums agree.
            let mut total_coarse = 0.0f64;
            for v in 0..f.num_voxels() {
                if valid[v] {
                    let [x, y, z] = f.coords(v);
                    let cvox = c.index(
                        if dims[0] == 1 { 0 } else { x / 2 },
                        if dims[1] == 1 { 0 } else { y / 2 },
                        if dims[2] == 1 { 0 } else { z / 2 },
                    );
                    total_coarse += c.voxel(cvox)[0] as f64;
                }
            }
            prop_assert!((total_fine - total_coarse).abs() <= 1e-4 * total_fine.abs().max(1.0));
        }
    }

    #[test]
    fn halving_stops_before_an_axis_has_fewer_voxels_than_nodes() {
        assert!(can_halve([10, 10, 1], [5, 5, 2]));
        assert!(!can_halve([10, 8, 10], [5, 5, 5]));
        assert!(!can_halve([1, 1, 1], [2, 2, 2]));
    }
}
