//! Real spherical harmonics of order 3 (bands 0..=2, nine functions), evaluated by `prt-sphere`:
//! the basis of a transfer vector's rows and columns; use it to evaluate or project a direction.
//!
//! Orthonormal over the sphere, Condon–Shortley phase included (Sloan, "Stupid Spherical
//! Harmonics (SH) Tricks", 2008). prt's convention (prt-sphere's docs): the textbook frame
//! `(x_t, y_t, z_t)`, whose polar axis is `z_t`, is prt's `(Z, X, Y)`, so the polar axis is +Y.
//! Flat index `i = l (l + 1) + m`:
//!
//! | i | (l, m) | Y_i |
//! |---|---|---|
//! | 0 | (0, 0) | 0.282095 |
//! | 1 | (1, -1) | -0.488603 y_t |
//! | 2 | (1, 0) | 0.488603 z_t |
//! | 3 | (1, 1) | -0.488603 x_t |
//! | 4 | (2, -2) | 1.092548 x_t y_t |
//! | 5 | (2, -1) | -1.092548 y_t z_t |
//! | 6 | (2, 0) | 0.315392 (3 z_t² - 1) |
//! | 7 | (2, 1) | -1.092548 x_t z_t |
//! | 8 | (2, 2) | 0.546274 (x_t² - y_t²) |

use glam::Vec3;

/// Number of SH coefficients of order 3 (bands 0, 1, 2).
pub const SH9: usize = 9;

/// Dimension of a transfer vector: `[direct 81 | R 81 | G 81 | B 81]`.
pub const TRANSFER_DIM: usize = 4 * SH9 * SH9;

/// The nine real SH functions of order 3 at unit direction `dir` (prt frame, +Y up), exactly
/// `prt_sphere::eval_sh(3, dir, ..)`, so that transfer matrices and prt-sphere's projections
/// (environment maps, PLSQ fits) share one basis.
#[inline]
pub fn sh9(dir: Vec3) -> [f32; SH9] {
    let mut y = [0.0; SH9];
    prt_sphere::eval_sh(3, dir, &mut y);
    y
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    /// Textbook real SH from associated Legendre polynomials in spherical coordinates.
    fn textbook(l: i32, m: i32, theta: f64, phi: f64) -> f64 {
        let ct = theta.cos();
        let st = theta.sin();
        let p = |l: i32, m: i32| -> f64 {
            // Associated Legendre P_l^m(cos theta) with Condon–Shortley phase, l <= 2.
            match (l, m) {
                (0, 0) => 1.0,
                (1, 0) => ct,
                (1, 1) => -st,
                (2, 0) => 0.5 * (3.0 * ct * ct - 1.0),
                (2, 1) => -3.0 * st * ct,
                (2, 2) => 3.0 * st * st,
                _ => unreachable!(),
            }
        };
        let fact = |n: i32| (1..=n).map(f64::from).product::<f64>();
        let am = m.abs();
        let k = ((2 * l + 1) as f64 / (4.0 * PI) * fact(l - am) / fact(l + am)).sqrt();
        if m == 0 {
            k * p(l, 0)
        } else if m > 0 {
            2f64.sqrt() * k * (m as f64 * phi).cos() * p(l, m)
        } else {
            2f64.sqrt() * k * (am as f64 * phi).sin() * p(l, am)
        }
    }

    #[test]
    fn matches_textbook_formulas_with_y_as_polar_axis() {
        for a in 0..17 {
            for b in 0..33 {
                let theta = PI * (a as f64 + 0.5) / 17.0;
                let phi = 2.0 * PI * b as f64 / 33.0;
                let (xt, yt, zt) = (
                    theta.sin() * phi.cos(),
                    theta.sin() * phi.sin(),
                    theta.cos(),
                );
                // (x_t, y_t, z_t) = (Z, X, Y)  =>  X = y_t, Y = z_t, Z = x_t.
                let dir = Vec3::new(yt as f32, zt as f32, xt as f32);
                let y = sh9(dir);
                for l in 0..3 {
                    for m in -l..=l {
                        let i = (l * (l + 1) + m) as usize;
                        let expected = textbook(l, m, theta, phi);
                        assert!(
                            (y[i] as f64 - expected).abs() < 1e-5,
                            "l={l} m={m}: {} vs {expected}",
                            y[i]
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn orthonormal_under_quadrature() {
        // Gauss-free midpoint quadrature in (cos theta, phi): exact enough for degree-4 products.
        let (nu, nphi) = (400, 800);
        let mut gram = [[0.0f64; SH9]; SH9];
        for a in 0..nu {
            let z = -1.0 + 2.0 * (a as f64 + 0.5) / nu as f64;
            let r = (1.0 - z * z).sqrt();
            for b in 0..nphi {
                let phi = 2.0 * PI * (b as f64 + 0.5) / nphi as f64;
                let dir = Vec3::new((r * phi.cos()) as f32, z as f32, (r * phi.sin()) as f32);
                let y = sh9(dir);
                let w = 4.0 * PI / (nu * nphi) as f64;
                for i in 0..SH9 {
                    for j in 0..SH9 {
                        gram[i][j] += w * y[i] as f64 * y[j] as f64;
                    }
                }
            }
        }
        for i in 0..SH9 {
            for j in 0..SH9 {
                let e = if i == j { 1.0 } else { 0.0 };
                assert!(
                    (gram[i][j] - e).abs() < 2e-4,
                    "G[{i}][{j}] = {}",
                    gram[i][j]
                );
            }
        }
    }
}
