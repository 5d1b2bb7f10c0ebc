//! Seeded synthetic test matrices with a known spectrum, for tests and benchmark sweeps.

use ndarray::Array2;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;

use crate::LinalgError;
use crate::backend;

/// Standard normal samples by the Box-Muller transform (rand's core crate has no normal law).
pub(crate) fn gaussian_matrix(rows: usize, cols: usize, rng: &mut Pcg64) -> Array2<f64> {
    Array2::from_shape_simple_fn((rows, cols), || {
        let u1: f64 = 1.0 - rng.random::<f64>();
        let u2: f64 = rng.random::<f64>();
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    })
}

/// An `n x d` f32 matrix `Z diag(decay^i) V^T + noise E + offset`: `Z` (`n x rank`) and `E`
/// standard normal, `V` (`d x rank`) with orthonormal columns, and a constant `offset` added to
/// every entry (to exercise mean-centring).
///
/// The column covariance therefore has eigenvalues close to `decay^(2 i) + noise^2` for
/// `i < rank` and `noise^2` beyond: the "rank-40, spectrum 0.8^i, 1e-3 noise" matrix of the PCA
/// accuracy target is `low_rank_matrix(262144, 324, 40, 0.8, 1e-3, 0.0, seed)`.
///
/// # Errors
/// [`LinalgError::InvalidRank`] if `rank` is 0 or above `d`, [`LinalgError::Empty`] if `n` or
/// `d` is 0.
pub fn low_rank_matrix(
    n: usize,
    d: usize,
    rank: usize,
    decay: f64,
    noise: f64,
    offset: f64,
    seed: u64,
) -> Result<Array2<f32>, LinalgError> {
    if n == 0 || d == 0 {
        return Err(LinalgError::Empty {
            what: "low_rank_matrix shape",
        });
    }
    if rank == 0 || rank > d {
        return Err(LinalgError::InvalidRank { rank, max: d });
    }
    let mut rng = Pcg64::seed_from_u64(seed);
    let v = backend::thin_q(gaussian_matrix(d, rank, &mut rng).view());
    let mut z = gaussian_matrix(n, rank, &mut rng);
    for (i, mut col) in z.columns_mut().into_iter().enumerate() {
        col *= decay.powi(i as i32);
    }
    let mut x = z.dot(&v.t());
    x.mapv_inplace(|val| val + offset);
    let noise_m = gaussian_matrix(n, d, &mut rng);
    x.scaled_add(noise, &noise_m);
    Ok(x.mapv(|val| val as f32))
}
