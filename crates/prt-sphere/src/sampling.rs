//! Point sets on the sphere: Halton(2,3), Owen-scrambled Sobol (`sobol_burley`), Fibonacci,
//! stratified, and the maps from the unit square to the sphere and hemispheres.
//!
//! Sphere maps follow Probulator (`z = 1 − 2u`, `φ = 2πv`, `(r cos φ, r sin φ, z)`) so that fits
//! on Halton samples reproduce its published figures; hemisphere maps are around +Y (up).
use glam::{DVec3, Vec3};

/// Radical inverse of `index` in `base` (the Halton coordinate).
pub fn radical_inverse(mut index: u64, base: u64) -> f64 {
    let inv = 1.0 / base as f64;
    let mut f = inv;
    let mut r = 0.0;
    while index > 0 {
        r += f * (index % base) as f64;
        index /= base;
        f *= inv;
    }
    r
}

/// Uniform map of the unit square onto the sphere: `z = 1 − 2u`, `φ = 2πv` (Probulator).
pub fn uniform_sphere(u: f64, v: f64) -> Vec3 {
    let z = 1.0 - 2.0 * u;
    let r = (1.0 - z * z).max(0.0).sqrt();
    let phi = 2.0 * std::f64::consts::PI * v;
    DVec3::new(r * phi.cos(), r * phi.sin(), z).as_vec3()
}

/// Uniform map onto the upper (+Y) hemisphere: `y = u`, `φ = 2πv`.
pub fn uniform_hemisphere(u: f64, v: f64) -> Vec3 {
    let y = u;
    let r = (1.0 - y * y).max(0.0).sqrt();
    let phi = 2.0 * std::f64::consts::PI * v;
    DVec3::new(r * phi.cos(), y, r * phi.sin()).as_vec3()
}

/// Cosine-weighted map onto the upper (+Y) hemisphere (density `cos θ / π`): `y = √u`.
pub fn cosine_hemisphere(u: f64, v: f64) -> Vec3 {
    let y = u.sqrt();
    let r = (1.0 - u).max(0.0).sqrt();
    let phi = 2.0 * std::f64::consts::PI * v;
    DVec3::new(r * phi.cos(), y, r * phi.sin()).as_vec3()
}

/// Probulator's fit input: Halton(2,3) points with indices `1..=n` mapped by [`uniform_sphere`].
pub fn halton_sphere(n: usize) -> Vec<Vec3> {
    (1..=n as u64)
        .map(|i| uniform_sphere(radical_inverse(i, 2), radical_inverse(i, 3)))
        .collect()
}

/// `n` Owen-scrambled Sobol points (Burley 2020, crate `sobol_burley`) with seed `seed`, mapped
/// by [`uniform_sphere`]. At most 2^16 points per seed.
pub fn sobol_sphere(n: usize, seed: u32) -> Vec<Vec3> {
    (0..n as u32)
        .map(|i| {
            let u = sobol_burley::sample(i, 0, seed) as f64;
            let v = sobol_burley::sample(i, 1, seed) as f64;
            uniform_sphere(u, v)
        })
        .collect()
}

/// `n` points on a Fibonacci sphere around +Y (see [`crate::fibonacci_axes`]).
pub fn fibonacci_sphere(n: usize) -> Vec<Vec3> {
    crate::fibonacci_axes(n)
}

/// `nu × nv` jittered-stratified points on the sphere (one per cell of the unit square, jitter
/// from a hash of the cell index and `seed`, so the set is reproducible).
pub fn stratified_sphere(nu: usize, nv: usize, seed: u64) -> Vec<Vec3> {
    let mut out = Vec::with_capacity(nu * nv);
    for i in 0..nu {
        for j in 0..nv {
            let h = hash64(((i * nv + j) as u64) ^ seed.rotate_left(32));
            let ju = (h >> 40) as f64 / (1u64 << 24) as f64;
            let jv = ((h >> 16) & 0xff_ffff) as f64 / (1u64 << 24) as f64;
            out.push(uniform_sphere(
                (i as f64 + ju) / nu as f64,
                (j as f64 + jv) / nv as f64,
            ));
        }
    }
    out
}

/// SplitMix64 finaliser: a good 64-bit mix for per-cell jitter.
fn hash64(mut x: u64) -> u64 {
    x = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    x ^ (x >> 31)
}

/// Gauss-Legendre nodes and weights on `[-1, 1]` (`n` points, exact for degree `2n − 1`).
pub fn gauss_legendre(n: usize) -> (Vec<f64>, Vec<f64>) {
    let mut nodes = vec![0.0; n];
    let mut weights = vec![0.0; n];
    for i in 0..n.div_ceil(2) {
        let mut x = (std::f64::consts::PI * (i as f64 + 0.75) / (n as f64 + 0.5)).cos();
        let mut dp = 1.0;
        for _ in 0..100 {
            let (mut p0, mut p1) = (1.0, x);
            for k in 2..=n {
                let p2 = ((2 * k - 1) as f64 * x * p1 - (k - 1) as f64 * p0) / k as f64;
                p0 = p1;
                p1 = p2;
            }
            let p = if n == 0 {
                1.0
            } else if n == 1 {
                x
            } else {
                p1
            };
            let pm1 = if n == 1 { 1.0 } else { p0 };
            dp = n as f64 * (x * p - pm1) / (x * x - 1.0);
            let dx = p / dp;
            x -= dx;
            if dx.abs() < 1e-15 {
                break;
            }
        }
        let w = 2.0 / ((1.0 - x * x) * dp * dp);
        nodes[i] = x;
        weights[i] = w;
        nodes[n - 1 - i] = -x;
        weights[n - 1 - i] = w;
    }
    (nodes, weights)
}

/// A product quadrature of the sphere: Gauss-Legendre in `y = cos θ` (`n` nodes) times `2n`
/// equispaced azimuths. Exact for spherical polynomials of degree `<= 2n − 1`.
pub fn sphere_quadrature(n: usize) -> (Vec<Vec3>, Vec<f64>) {
    let (ys, ws) = gauss_legendre(n);
    let nphi = 2 * n;
    let mut dirs = Vec::with_capacity(n * nphi);
    let mut weights = Vec::with_capacity(n * nphi);
    for (y, w) in ys.iter().zip(&ws) {
        let r = (1.0 - y * y).max(0.0).sqrt();
        for k in 0..nphi {
            let phi = 2.0 * std::f64::consts::PI * (k as f64 + 0.5) / nphi as f64;
            dirs.push(DVec3::new(r * phi.cos(), *y, r * phi.sin()).as_vec3());
            weights.push(w * 2.0 * std::f64::consts::PI / nphi as f64);
        }
    }
    (dirs, weights)
}

/// [`sphere_quadrature`] in f64 directions (for high-order reference tests).
pub fn sphere_quadrature_f64(n: usize) -> (Vec<DVec3>, Vec<f64>) {
    let (ys, ws) = gauss_legendre(n);
    let nphi = 2 * n;
    let mut dirs = Vec::with_capacity(n * nphi);
    let mut weights = Vec::with_capacity(n * nphi);
    for (y, w) in ys.iter().zip(&ws) {
        let r = (1.0 - y * y).max(0.0).sqrt();
        for k in 0..nphi {
            let phi = 2.0 * std::f64::consts::PI * (k as f64 + 0.5) / nphi as f64;
            dirs.push(DVec3::new(r * phi.cos(), *y, r * phi.sin()));
            weights.push(w * 2.0 * std::f64::consts::PI / nphi as f64);
        }
    }
    (dirs, weights)
}
