//! A denoiser for traced transfer volumes that never moves light through geometry: a joint
//! bilateral filter whose neighbours must be valid and see each other (the segment between the
//! voxel centres hits nothing), and whose range weight compares the difference of two voxels'
//! transfer vectors with the Monte Carlo noise the baker measured at both.

use glam::Vec3;
use prt_core::{GridField, Progress};
use rayon::prelude::*;

use crate::sh::TRANSFER_DIM;
use crate::{RayTracer, TraceError};

/// Options of the transfer-volume denoiser (an opt-in of [`crate::BakeOptions`]).
///
/// Voxel `v` becomes the weighted mean of itself and every neighbour `u` within `radius`
/// voxels along each axis that is valid and visible from it (no triangle between the two
/// centres), with weight `exp(−|o|² / (2 s²)) · exp(−max(0, d² − 1) / strength²)`: `o` the
/// offset in voxels, `s = (radius + 1) / 2`, and `d² = ‖t_u − t_v‖² / (σ²_u + σ²_v)` the
/// squared difference of the two transfer vectors in units of their measured noise (`σ²` the
/// estimated variance of each voxel's estimate, summed over its 324 components). Two voxels
/// whose difference is noise (`d² ≈ 1`) average fully; a real change of the light (an edge of
/// a shadow, a wall's neighbourhood) is kept. Deterministic: a fixed neighbour order and f64
/// sums.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DenoiseOptions {
    /// Neighbourhood half-width in voxels (1: 3³ voxels, 2: 5³).
    pub radius: usize,
    /// How many noise standard deviations of difference still average (larger: smoother).
    pub strength: f32,
}

/// Radius 2 (5³ neighbours), strength 1.
impl Default for DenoiseOptions {
    fn default() -> Self {
        Self {
            radius: 2,
            strength: 1.0,
        }
    }
}

/// Largest accepted radius (a 17³ neighbourhood).
const MAX_RADIUS: usize = 8;
/// Voxels filtered per parallel task.
const CHUNK: usize = 64;

impl DenoiseOptions {
    /// Errors: [`TraceError::InvalidOption`] for a radius of 0 or above 8, or a strength that
    /// is not finite and positive.
    pub fn validate(&self) -> Result<(), TraceError> {
        if !(1..=MAX_RADIUS).contains(&self.radius) {
            return Err(TraceError::InvalidOption {
                what: "denoise.radius",
                why: format!("{} is outside 1..={MAX_RADIUS}", self.radius),
            });
        }
        if !(self.strength.is_finite() && self.strength > 0.0) {
            return Err(TraceError::InvalidOption {
                what: "denoise.strength",
                why: format!("{} is not a finite positive number", self.strength),
            });
        }
        Ok(())
    }
}

/// One traced voxel as the denoiser reads it: its transfer vector and the estimated variance of
/// that estimate (summed over the components).
pub(crate) type Sample<'a> = (&'a [f32], f32);

/// Filters the voxels `targets` of `grid` (its dims and centres; row `r` of `out` receives voxel
/// `targets[r]`, `TRANSFER_DIM` values) from the traced voxels `sample(v)` (`None`: invalid or
/// not stored, neither filtered nor used). A target without a sample is written as zeros.
pub(crate) fn denoise<'a>(
    grid: &GridField,
    tracer: &RayTracer,
    options: &DenoiseOptions,
    sample: &(dyn Fn(usize) -> Option<Sample<'a>> + Sync),
    targets: &[usize],
    out: &mut [f32],
    progress: &dyn Progress,
) -> Result<(), TraceError> {
    options.validate()?;
    let [nx, ny, nz] = grid.dims();
    let r = options.radius as i64;
    let s = (options.radius as f64 + 1.0) / 2.0;
    let offsets: Vec<([i64; 3], f64)> = (-r..=r)
        .flat_map(|z| (-r..=r).flat_map(move |y| (-r..=r).map(move |x| [x, y, z])))
        .filter(|o| *o != [0, 0, 0])
        .map(|o| {
            let d2 = (o[0] * o[0] + o[1] * o[1] + o[2] * o[2]) as f64;
            (o, (-d2 / (2.0 * s * s)).exp())
        })
        .collect();
    let inv_strength2 = 1.0 / f64::from(options.strength).powi(2);
    out.par_chunks_mut(TRANSFER_DIM * CHUNK)
        .zip(targets.par_chunks(CHUNK))
        .try_for_each(|(out, targets)| {
            progress.check()?;
            let mut acc = [0.0f64; TRANSFER_DIM];
            for (o, &v) in out.chunks_exact_mut(TRANSFER_DIM).zip(targets) {
                let Some((tv, var_v)) = sample(v) else {
                    o.fill(0.0);
                    continue;
                };
                let (x, y, z) = (
                    (v % nx) as i64,
                    (v / nx % ny) as i64,
                    (v / (nx * ny)) as i64,
                );
                let cv = grid.centre_of(v);
                for (a, &t) in acc.iter_mut().zip(tv) {
                    *a = f64::from(t);
                }
                let mut total = 1.0f64;
                for &(off, spatial) in &offsets {
                    let (ux, uy, uz) = (x + off[0], y + off[1], z + off[2]);
                    if ux < 0
                        || uy < 0
                        || uz < 0
                        || ux >= nx as i64
                        || uy >= ny as i64
                        || uz >= nz as i64
                    {
                        continue;
                    }
                    let u = ux as usize + nx * (uy as usize + ny * uz as usize);
                    let Some((tu, var_u)) = sample(u) else {
                        continue;
                    };
                    let noise = f64::from(var_v) + f64::from(var_u);
                    let diff2: f64 = tv
                        .iter()
                        .zip(tu)
                        .map(|(&a, &b)| (f64::from(a) - f64::from(b)).powi(2))
                        .sum();
                    let excess = if noise > 0.0 {
                        (diff2 / noise - 1.0).max(0.0)
                    } else if diff2 > 0.0 {
                        f64::INFINITY
                    } else {
                        0.0
                    };
                    let w = spatial * (-excess * inv_strength2).exp();
                    // A negligible weight is dropped before its visibility ray is traced.
                    if w < 1e-4 || !visible(tracer, cv, grid.centre_of(u)) {
                        continue;
                    }
                    for (a, &t) in acc.iter_mut().zip(tu) {
                        *a += w * f64::from(t);
                    }
                    total += w;
                }
                for (o, a) in o.iter_mut().zip(&acc) {
                    *o = (a / total) as f32;
                }
            }
            Ok::<(), TraceError>(())
        })
}

/// Whether the segment between two voxel centres hits no triangle.
fn visible(tracer: &RayTracer, a: Vec3, b: Vec3) -> bool {
    let d = b - a;
    let length = d.length();
    length == 0.0 || !tracer.occluded(a, d / length, 0.0, length)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{AdaptiveSampling, BakeOptions, Scene, TransferBaker};
    use prt_core::NoProgress;

    /// The thin-wall rooms on a 15 × 8 × 8 grid: voxel column x = 7 is the wall.
    fn rooms() -> (Scene, [usize; 3]) {
        (Scene::thin_wall_rooms(2.0 / 15.0), [15, 8, 8])
    }

    #[test]
    fn the_denoiser_never_moves_light_across_a_wall() {
        let (scene, resolution) = rooms();
        let options = BakeOptions {
            resolution,
            ..BakeOptions::default()
        };
        let baker = TransferBaker::new(&scene, options).unwrap();
        let grid = baker.empty_field(1).unwrap();
        let voxels = grid.num_voxels();
        // Every voxel valid with a noise so large that only visibility can stop averaging.
        let field = |lit_scale: f32| -> Vec<f32> {
            (0..voxels * TRANSFER_DIM)
                .map(|i| {
                    let v = i / TRANSFER_DIM;
                    let base = ((i * 7919) % 101) as f32 / 101.0;
                    if grid.centre_of(v).x < 0.0 {
                        lit_scale * (1.0 + base)
                    } else {
                        base
                    }
                })
                .collect()
        };
        let filter = |data: &[f32]| {
            let sample = |v: usize| Some((&data[v * TRANSFER_DIM..][..TRANSFER_DIM], 1e9f32));
            let targets: Vec<usize> = (0..voxels).collect();
            let mut out = vec![0.0; data.len()];
            let options = DenoiseOptions {
                radius: 3,
                strength: 100.0,
            };
            denoise(
                &grid,
                baker.tracer(),
                &options,
                &sample,
                &targets,
                &mut out,
                &NoProgress,
            )
            .unwrap();
            out
        };
        let (dim, bright) = (filter(&field(1.0)), filter(&field(1000.0)));
        let wall = 1.0 / 15.0;
        let mut checked = 0;
        for v in 0..voxels {
            let x = grid.centre_of(v).x;
            let row = v * TRANSFER_DIM..(v + 1) * TRANSFER_DIM;
            if x > wall {
                // The dark room sees nothing of the lit one, however bright.
                assert_eq!(dim[row.clone()], bright[row], "voxel {v}");
                checked += 1;
            } else if x < -wall {
                // The filter did average: inside the lit room the values moved.
                assert_ne!(dim[row.clone()], field(1.0)[row]);
            }
        }
        assert_eq!(checked, 7 * 8 * 8);
    }

    /// The dark room's mean transfer after adaptive sampling and the denoiser lies within the
    /// noise of a 16×-ray reference: no light came through the wall.
    #[test]
    fn the_dark_room_matches_a_reference_with_16x_the_rays() {
        let (scene, resolution) = rooms();
        let bake = |rays: usize, seed: u64, denoise: Option<DenoiseOptions>| {
            let options = BakeOptions {
                resolution,
                rays_per_voxel: rays,
                cache_rays: 16,
                seed,
                adaptive: Some(AdaptiveSampling {
                    target_error: if denoise.is_some() { 0.1 } else { 0.0 },
                    min_rays: 48,
                }),
                denoise,
                ..BakeOptions::default()
            };
            let baker = TransferBaker::new(&scene, options).unwrap();
            let volume = baker.bake(&NoProgress).unwrap();
            // The variance of every dark voxel's own estimate, as the baker measured it.
            let cache = baker.surface_cache().0;
            let rays = std::sync::atomic::AtomicU64::new(0);
            let mut dark = Vec::new();
            for v in 0..volume.field.num_voxels() {
                let x = volume.field.centre_of(v);
                if x.x > 1.0 / 15.0 && volume.valid[v] {
                    let (mut t, mut var) = (vec![0.0; TRANSFER_DIM], 0.0);
                    baker.voxel_transfer(x, v, cache.as_ref(), &rays, &mut t, &mut var);
                    dark.push((v, f64::from(var)));
                }
            }
            (volume, dark)
        };
        let denoised = DenoiseOptions::default();
        let (test, dark) = bake(96, 3, Some(denoised));
        let (reference, reference_dark) = bake(16 * 96, 1001, None);
        assert_eq!(dark.len(), reference_dark.len());
        let n = dark.len() as f64;
        let mean = |volume: &crate::TransferVolume| -> Vec<f64> {
            let mut m = vec![0.0; TRANSFER_DIM];
            for &(v, _) in &dark {
                for (a, &t) in m.iter_mut().zip(volume.field.voxel(v)) {
                    *a += f64::from(t) / n;
                }
            }
            m
        };
        let (a, b) = (mean(&test), mean(&reference));
        let distance2: f64 = a.iter().zip(&b).map(|(x, y)| (x - y).powi(2)).sum();
        // E‖mean − truth‖² = Σ_v Var_v / n² for each bake (the denoiser only lowers it); the
        // squared norm of a 324-D error concentrates near its mean, 9× is far beyond noise.
        let noise: f64 = dark.iter().chain(&reference_dark).map(|d| d.1).sum::<f64>() / (n * n);
        let lit: f64 = (0..test.field.num_voxels())
            .filter(|&v| test.field.centre_of(v).x < -1.0 / 15.0)
            .map(|v| f64::from(test.field.voxel(v)[0]))
            .sum::<f64>()
            / n;
        let dark_level = b[0];
        assert!(
            lit > 2.0 * dark_level,
            "the lit room ({lit}) is brighter than the dark one ({dark_level})"
        );
        assert!(
            distance2 <= 9.0 * noise,
            "dark room off by {:.3e} against a noise of {:.3e} (sky visibility {} vs {})",
            distance2.sqrt(),
            noise.sqrt(),
            a[0],
            b[0]
        );
    }
}
