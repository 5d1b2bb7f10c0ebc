//! Synthetic test fields: smooth vector fields on curved low-dimensional manifolds in R^D, like
//! Figure 2 of the MBD paper, where one global basis needs many vectors but every small region
//! needs only a few.

use glam::Vec3;
use prt_core::{Aabb, GridField};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

use crate::MbdError;

/// A smooth field `f(x) = a(x) (γ₁(t₁(x)) + γ₂(t₂(x)))` on a curved surface in R^D.
///
/// * Each curve is `γ_k(t) = u_{k,0} + Σ_{j=1..J} (cos(π j t) u_{k,j} + sin(π j t) w_{k,j}) / j^1.5`
///   with random Gaussian directions (seeded), so the surface lies in no subspace of dimension
///   below `4J + 2`: a global basis needs that many vectors to be exact, and its error decays
///   slowly with the basis count, as for transfer volumes.
/// * The parameters `t₁(x), t₂(x)` and the amplitude `a(x)` vary smoothly over the box, so in a
///   small region the field stays close to the span of `γ₁ + γ₂` and its two tangents: locally it
///   is nearly rank 3, which is what a moving basis exploits.
///
/// `harmonics` is `J`; the field's values have magnitude of order one.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SyntheticField {
    /// Grid resolution.
    pub dims: [usize; 3],
    /// Vector dimension D.
    pub dim: usize,
    /// Number of harmonics J of the curve (its global rank is `2J + 1` when `D` allows).
    pub harmonics: usize,
    /// Seed of the curve's directions.
    pub seed: u64,
}

impl SyntheticField {
    /// The paper-sized default: 324-dimensional vectors, 8 harmonics.
    pub fn new(dims: [usize; 3], dim: usize) -> Self {
        Self {
            dims,
            dim,
            harmonics: 8,
            seed: 1,
        }
    }

    /// The field sampled at the voxel centres of its grid over `bounds`.
    ///
    /// Errors on an empty grid, `dim == 0`, or invalid bounds.
    pub fn build(&self, bounds: Aabb) -> Result<GridField, MbdError> {
        let directions = self.directions();
        let j_max = self.harmonics;
        let per_curve = (2 * j_max + 1) * self.dim;
        let dim = self.dim;
        let field = GridField::from_fn(self.dims, bounds, dim, |p, out| {
            let q = bounds.to_local(p);
            let (t, a) = manifold_coordinates(q);
            out.fill(0.0);
            for (k, &tk) in t.iter().enumerate() {
                let curve = &directions[k * per_curve..(k + 1) * per_curve];
                for (o, &u0) in out.iter_mut().zip(&curve[..dim]) {
                    *o += u0;
                }
                for j in 1..=j_max {
                    let phase = std::f32::consts::PI * j as f32 * tk;
                    let (s, c) = phase.sin_cos();
                    let amplitude = (j as f32).powf(-1.5);
                    let u = &curve[(2 * j - 1) * dim..2 * j * dim];
                    let w = &curve[2 * j * dim..(2 * j + 1) * dim];
                    for d in 0..dim {
                        out[d] += amplitude * (c * u[d] + s * w[d]);
                    }
                }
            }
            for o in out.iter_mut() {
                *o *= a;
            }
        })?;
        Ok(field)
    }

    /// `2 (2J + 1)` random directions of length about one, concatenated.
    fn directions(&self) -> Vec<f32> {
        let mut rng = Pcg64Mcg::seed_from_u64(self.seed);
        let n = 2 * (2 * self.harmonics + 1) * self.dim;
        let scale = 1.0 / (self.dim as f32).sqrt();
        (0..n).map(|_| standard_normal(&mut rng) * scale).collect()
    }
}

/// The two curve parameters and the amplitude at local coordinates `q ∈ [0, 1]³`.
fn manifold_coordinates(q: Vec3) -> ([f32; 2], f32) {
    use std::f32::consts::PI;
    let t1 = 0.5 * (q.x + q.y) + 0.15 * (2.0 * PI * q.z + 3.0 * q.x).sin();
    let t2 = 0.6 * q.z - 0.3 * q.x + 0.1 * (2.0 * PI * q.y).cos();
    let a = 1.0 + 0.4 * (PI * q.z + 1.0).sin() * (PI * q.y).cos();
    ([t1, t2], a)
}

/// A standard normal variate by the Box-Muller transform.
pub(crate) fn standard_normal(rng: &mut impl Rng) -> f32 {
    let u1: f64 = rng.random::<f64>().max(1e-300);
    let u2: f64 = rng.random::<f64>();
    ((-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()) as f32
}
