//! Dilation of valid probes into invalid ones, so that engines' trilinear filtering never
//! blends in the meaningless transfer of voxels inside geometry.

use prt_trace::LitVolume;

use crate::ExportError;

/// How invalid voxels are filled before export (the rule of Unity's adaptive probe volumes'
/// dilation: distance 1, squared-distance weighting; Unity stops after one iteration, prt's
/// default repeats it until no invalid voxel is left, since engines sample every voxel).
///
/// Each pass gives every voxel not yet known (invalid in the bake and not filled by an earlier
/// pass) the average of the known voxels within `radius` voxels (a (2r+1)³ cube), weighted by
/// `1 / d²` with `d` the distance in voxel steps; voxels with no known neighbour wait for the
/// next pass. Passes read only the previous pass's values (the result does not depend on the
/// voxel order). Valid voxels never change.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DilateConfig {
    /// Neighbourhood half-width in voxels (0 disables dilation).
    pub radius: usize,
    /// Number of passes (0 disables dilation).
    pub passes: usize,
}

impl DilateConfig {
    /// Passes of [`DilateConfig::default`]: as many as it takes to fill every invalid voxel
    /// (a flood fill from the valid voxels outwards, nearest first).
    pub const UNTIL_FILLED: usize = usize::MAX;
}

impl Default for DilateConfig {
    /// Radius 1, passes until every invalid voxel is filled (a volume with no valid voxel
    /// stays as it is).
    fn default() -> Self {
        DilateConfig {
            radius: 1,
            passes: Self::UNTIL_FILLED,
        }
    }
}

/// A dilated volume and what dilation did.
#[derive(Debug, Clone, PartialEq)]
pub struct Dilated {
    /// The volume: valid voxels as given, filled voxels averaged; `valid` is the bake's mask.
    pub volume: LitVolume,
    /// Invalid voxels that received a value.
    pub filled: usize,
    /// Invalid voxels left as they were (no known voxel within reach).
    pub unfilled: usize,
}

/// Fills invalid voxels of `volume` from their valid neighbours by the rule of
/// [`DilateConfig`].
pub fn dilate(volume: &LitVolume, config: &DilateConfig) -> Result<Dilated, ExportError> {
    volume.check()?;
    let mut out = volume.clone();
    let mut known = volume.valid.clone();
    let invalid = known.iter().filter(|&&k| !k).count();
    let r = config.radius as isize;
    let [nx, ny, nz] = volume.dims.map(|d| d as isize);
    let mut filled = 0;
    let passes = if r == 0 { 0 } else { config.passes };
    // Only the voxels still unknown are visited, so a flood fill through a deep solid costs
    // the remaining voxels per pass, not the grid.
    let mut pending: Vec<usize> = (0..out.voxels()).filter(|&v| !known[v]).collect();
    for _ in 0..passes {
        let mut updates = Vec::new();
        for &v in &pending {
            let [x, y, z] = out.coords(v).map(|i| i as isize);
            let mut acc = [[0.0f64; 9]; 3];
            let mut total = 0.0f64;
            for dz in -r..=r {
                for dy in -r..=r {
                    for dx in -r..=r {
                        let (px, py, pz) = (x + dx, y + dy, z + dz);
                        if (dx, dy, dz) == (0, 0, 0)
                            || !(0..nx).contains(&px)
                            || !(0..ny).contains(&py)
                            || !(0..nz).contains(&pz)
                        {
                            continue;
                        }
                        let u = (px + nx * (py + ny * pz)) as usize;
                        if !known[u] {
                            continue;
                        }
                        let w = 1.0 / (dx * dx + dy * dy + dz * dz) as f64;
                        total += w;
                        for c in 0..3 {
                            for j in 0..9 {
                                acc[c][j] += w * f64::from(out.radiance[u][c][j]);
                            }
                        }
                    }
                }
            }
            if total > 0.0 {
                updates.push((v, acc.map(|ch| ch.map(|s| (s / total) as f32))));
            }
        }
        if updates.is_empty() {
            break;
        }
        filled += updates.len();
        for (v, l) in updates {
            out.radiance[v] = l;
            known[v] = true;
        }
        pending.retain(|&v| !known[v]);
    }
    Ok(Dilated {
        volume: out,
        filled,
        unfilled: invalid - filled,
    })
}
