//! Fields shared by the integration tests.

use prt_core::{Aabb, GridField};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

/// A field that is exactly a rank-`rank` MBD with one global basis: random voxel coefficients
/// times fixed random vectors; its trilinear interpolation is representable exactly.
pub fn global_rank_field(dims: [usize; 3], dim: usize, rank: usize, seed: u64) -> GridField {
    let mut rng = Pcg64Mcg::seed_from_u64(seed);
    let basis: Vec<f32> = (0..rank * dim).map(|_| rng.random::<f32>() - 0.5).collect();
    GridField::from_fn(dims, Aabb::UNIT, dim, |_, out| {
        out.fill(0.0);
        for l in 0..rank {
            let c = rng.random::<f32>() * 2.0 - 1.0;
            for d in 0..dim {
                out[d] += c * basis[l * dim + d];
            }
        }
    })
    .unwrap()
}
