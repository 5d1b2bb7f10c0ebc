//! Changing view with an in-out BRDF factorisation (Overbeck's thesis §7.2, after Wang, Tran
//! and Luebke 2004 and Liu et al. 2004): `ρ(ωi, ωo) ≈ Σ_k σ_k h_k(ωo) g_k(ωi)` in the surface's
//! local frame, so that a glossy point's outgoing radiance is
//! `B(ωo) = Σ_k σ_k h_k(ωo) (T_k · L)` with one lighting-independent transport row per term,
//! `T_k[t] = ∫_t V(ωi) g_k(ωi) cos θi dωi`. The lighting enters only through the `K` scalars
//! `T_k · L` (relit incrementally like any other transport row) and the view only through
//! `h_k(ωo)`, so moving the camera under fixed lighting costs no lighting work at all.
//!
//! The factorisation is the truncated SVD of the BRDF tabulated on a paraboloid map of the
//! upper hemisphere for both directions: cell centre `(u, v)` of an `m × m` grid over
//! `[−1, 1]²` is the direction `(2u, 2v, 1 − u² − v²) / (1 + u² + v²)` (cells whose centre lies
//! outside the unit disk are below the horizon), with solid angle `4 / (1 + u² + v²)² du dv`.
//! Rows and columns are weighted by the square roots of the cells' solid angles, so the
//! truncation is optimal in the solid-angle L2 norm over `(ωi, ωo)`. Factors between cell
//! centres are bilinear; cells outside the disk hold the Nyström extension of the factor at the
//! horizon (`g_k(ω) = σ_k⁻¹ Σ_o ρ(ω, o) h_k(o) Ω_o`), so lookups near the horizon stay smooth.

use glam::{Mat3, Vec3};
use ndarray::Array2;

use crate::WaveletError;

/// Options of [`BrdfFactorisation::fit`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FactorisationConfig {
    /// Cells per side of the paraboloid grid of each direction (`m`; about `π m² / 4` cells lie
    /// on the hemisphere, and the SVD is of that size squared).
    pub grid: usize,
    /// Terms `K` kept.
    pub terms: usize,
}

impl Default for FactorisationConfig {
    /// A 32 × 32 grid (about 800 directions each way) and 6 terms.
    fn default() -> Self {
        Self { grid: 32, terms: 6 }
    }
}

/// A BRDF factored into `K` products of an outgoing and an incoming factor.
#[derive(Debug, Clone, PartialEq)]
pub struct BrdfFactorisation {
    grid: usize,
    sigma: Vec<f32>,
    /// `out_table[k · m² + cell]` = `h_k` at a cell centre.
    out_table: Vec<f32>,
    /// `in_table[k · m² + cell]` = `g_k` at a cell centre.
    in_table: Vec<f32>,
    /// Every singular value of the weighted table, descending.
    spectrum: Vec<f64>,
}

/// The direction of paraboloid coordinates `(u, v)` (upper hemisphere inside the unit disk).
pub fn paraboloid_direction(u: f32, v: f32) -> Vec3 {
    let r2 = u * u + v * v;
    Vec3::new(2.0 * u, 2.0 * v, 1.0 - r2) / (1.0 + r2)
}

/// The paraboloid coordinates of a direction with `z > −1`: `(x, y) / (1 + z)`.
pub fn paraboloid_coordinates(dir: Vec3) -> (f32, f32) {
    let d = 1.0 + dir.z;
    (dir.x / d, dir.y / d)
}

/// The rotation from world to a local frame whose +Z is `normal` (unit): the frame the
/// factorisation is tabulated in. Any tangent serves an isotropic BRDF; this one is glam's.
pub fn local_frame(normal: Vec3) -> Mat3 {
    let (t, b) = normal.any_orthonormal_pair();
    Mat3::from_cols(t, b, normal).transpose()
}

impl BrdfFactorisation {
    /// Tabulates `brdf(ωi, ωo)` (local frame, +Z the normal, both directions unit and above the
    /// horizon) and keeps the `terms` largest singular triples. Errors: a zero grid or term
    /// count, more terms than hemisphere cells, a non-finite BRDF value, or an SVD failure.
    pub fn fit(
        brdf: &dyn Fn(Vec3, Vec3) -> f32,
        config: &FactorisationConfig,
    ) -> Result<Self, WaveletError> {
        let m = config.grid;
        let cells: Vec<(usize, Vec3, f64)> = (0..m * m)
            .filter_map(|c| {
                let (u, v) = cell_centre(m, c);
                let r2 = (u * u + v * v) as f64;
                (r2 < 1.0).then(|| {
                    let du = 2.0 / m as f64;
                    (
                        c,
                        paraboloid_direction(u, v),
                        4.0 / (1.0 + r2).powi(2) * du * du,
                    )
                })
            })
            .collect();
        let n = cells.len();
        if config.terms == 0 || config.terms > n {
            return Err(WaveletError::Invalid {
                what: "BRDF factorisation",
                why: format!(
                    "{} terms on a {m} x {m} grid ({n} hemisphere cells)",
                    config.terms
                ),
            });
        }
        // a[o][i] = √Ω_o ρ(ω_i, ω_o) √Ω_i.
        let mut a = Array2::<f64>::zeros((n, n));
        for (o, &(_, wo, omega_o)) in cells.iter().enumerate() {
            for (i, &(_, wi, omega_i)) in cells.iter().enumerate() {
                let value = brdf(wi, wo);
                if !value.is_finite() {
                    return Err(WaveletError::NonFinite {
                        what: "tabulated BRDF (out cell × in cell)",
                        index: o * n + i,
                    });
                }
                a[[o, i]] = (omega_o * omega_i).sqrt() * value as f64;
            }
        }
        let svd = prt_linalg::thin_svd(a.view()).map_err(|e| WaveletError::Invalid {
            what: "BRDF factorisation",
            why: e.to_string(),
        })?;
        let k = config.terms;
        let mut out_table = vec![0.0f32; k * m * m];
        let mut in_table = vec![0.0f32; k * m * m];
        for t in 0..k {
            for (j, &(c, _, omega)) in cells.iter().enumerate() {
                out_table[t * m * m + c] = (svd.u[[j, t]] / omega.sqrt()) as f32;
                in_table[t * m * m + c] = (svd.vt[[t, j]] / omega.sqrt()) as f32;
            }
        }
        let sigma: Vec<f32> = svd.s.iter().take(k).map(|&s| s as f32).collect();
        // Cells below the horizon: the Nyström extension at the horizon direction of the cell.
        for c in 0..m * m {
            let (u, v) = cell_centre(m, c);
            let r = (u * u + v * v).sqrt();
            if r < 1.0 {
                continue;
            }
            let edge = paraboloid_direction(u / r, v / r);
            for t in 0..k {
                if sigma[t] <= 0.0 {
                    continue;
                }
                let (mut h, mut g) = (0.0f64, 0.0f64);
                for &(j, w, omega) in &cells {
                    h += brdf(w, edge) as f64 * in_table[t * m * m + j] as f64 * omega;
                    g += brdf(edge, w) as f64 * out_table[t * m * m + j] as f64 * omega;
                }
                out_table[t * m * m + c] = (h / sigma[t] as f64) as f32;
                in_table[t * m * m + c] = (g / sigma[t] as f64) as f32;
            }
        }
        Ok(Self {
            grid: m,
            sigma,
            out_table,
            in_table,
            spectrum: svd.s.to_vec(),
        })
    }

    /// Terms `K`.
    pub fn terms(&self) -> usize {
        self.sigma.len()
    }

    /// The kept singular values `σ_k`, descending.
    pub fn sigma(&self) -> &[f32] {
        &self.sigma
    }

    /// The relative solid-angle L2 error of the tabulated BRDF truncated to `terms` terms:
    /// `sqrt(Σ_{k ≥ terms} σ_k² / Σ_k σ_k²)` over the whole spectrum (any `terms`, not only the
    /// kept ones).
    pub fn truncation_error(&self, terms: usize) -> f64 {
        let total: f64 = self.spectrum.iter().map(|s| s * s).sum();
        let tail: f64 = self.spectrum.iter().skip(terms).map(|s| s * s).sum();
        if total > 0.0 {
            (tail / total).sqrt()
        } else {
            0.0
        }
    }

    /// `h_k(ωo)` for every term (local frame; zero below the horizon) into `out` (`K` values).
    pub fn out_factors(&self, wo: Vec3, out: &mut [f32]) {
        self.lookup(&self.out_table, wo, out);
    }

    /// `g_k(ωi)` for every term (local frame; zero below the horizon) into `out` (`K` values).
    pub fn in_factors(&self, wi: Vec3, out: &mut [f32]) {
        self.lookup(&self.in_table, wi, out);
    }

    /// The factored BRDF `Σ_k σ_k h_k(ωo) g_k(ωi)`.
    pub fn eval(&self, wi: Vec3, wo: Vec3) -> f32 {
        let k = self.terms();
        let (mut h, mut g) = (vec![0.0; k], vec![0.0; k]);
        self.out_factors(wo, &mut h);
        self.in_factors(wi, &mut g);
        (0..k).map(|t| self.sigma[t] * h[t] * g[t]).sum()
    }

    /// Outgoing radiance towards `wo` (local frame) of a point whose lit transport terms are
    /// `coefficients[k · channels + c] = T_k · L_c`: `Σ_k σ_k h_k(ωo) T_k · L_c` into `out`
    /// (`channels` values).
    pub fn shade(&self, wo: Vec3, coefficients: &[f32], out: &mut [f32]) {
        let channels = out.len();
        let mut h = [0.0f32; 32];
        let k = self.terms().min(h.len());
        self.out_factors(wo, &mut h[..k]);
        out.fill(0.0);
        for t in 0..k {
            let s = self.sigma[t] * h[t];
            for (o, c) in out.iter_mut().zip(&coefficients[t * channels..]) {
                *o += s * c;
            }
        }
    }

    /// Bilinear lookup of every term's table at a local direction.
    fn lookup(&self, table: &[f32], dir: Vec3, out: &mut [f32]) {
        out.fill(0.0);
        if dir.z <= 0.0 {
            return;
        }
        let m = self.grid;
        let (u, v) = paraboloid_coordinates(dir);
        let coordinate = |x: f32| ((x + 1.0) * 0.5 * m as f32 - 0.5).clamp(0.0, (m - 1) as f32);
        let (x, y) = (coordinate(u), coordinate(v));
        let (x0, y0) = (x.floor() as usize, y.floor() as usize);
        let (x1, y1) = ((x0 + 1).min(m - 1), (y0 + 1).min(m - 1));
        let (fx, fy) = (x - x0 as f32, y - y0 as f32);
        let corners = [
            (y0 * m + x0, (1.0 - fx) * (1.0 - fy)),
            (y0 * m + x1, fx * (1.0 - fy)),
            (y1 * m + x0, (1.0 - fx) * fy),
            (y1 * m + x1, fx * fy),
        ];
        for (t, o) in out.iter_mut().enumerate().take(self.terms()) {
            let plane = &table[t * m * m..(t + 1) * m * m];
            *o = corners.iter().map(|&(c, w)| w * plane[c]).sum();
        }
    }
}

/// Paraboloid coordinates of the centre of cell `c` of an `m × m` grid.
fn cell_centre(m: usize, c: usize) -> (f32, f32) {
    let centre = |i: usize| (2.0 * i as f32 + 1.0) / m as f32 - 1.0;
    (centre(c % m), centre(c / m))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn blinn(wi: Vec3, wo: Vec3) -> f32 {
        let h = (wi + wo).normalize_or_zero();
        12.0 / (2.0 * std::f32::consts::PI) * h.z.max(0.0).powi(10)
    }

    #[test]
    fn paraboloid_round_trip() {
        for (u, v) in [(0.0, 0.0), (0.3, -0.5), (-0.7, 0.1)] {
            let d = paraboloid_direction(u, v);
            assert!((d.length() - 1.0).abs() < 1e-6);
            let (a, b) = paraboloid_coordinates(d);
            assert!((a - u).abs() < 1e-6 && (b - v).abs() < 1e-6);
        }
    }

    #[test]
    fn a_rank_two_brdf_is_reproduced_at_two_terms() {
        // ρ = a(ωi) b(ωo) + c(ωi) d(ωo): rank 2, so two terms are exact at the cell centres.
        let brdf = |wi: Vec3, wo: Vec3| {
            (1.0 + wi.x) * (0.5 + wo.z * wo.z) + wi.z * wi.z * (0.2 + wo.y).abs()
        };
        let config = FactorisationConfig { grid: 12, terms: 2 };
        let f = BrdfFactorisation::fit(&brdf, &config).unwrap();
        assert!(f.truncation_error(2) < 1e-6, "{}", f.truncation_error(2));
        assert!(f.truncation_error(1) > 1e-3);
        let m = config.grid;
        let mut worst = 0.0f32;
        for o in 0..m * m {
            for i in 0..m * m {
                let ((uo, vo), (ui, vi)) = (cell_centre(m, o), cell_centre(m, i));
                if uo * uo + vo * vo >= 1.0 || ui * ui + vi * vi >= 1.0 {
                    continue;
                }
                let (wo, wi) = (paraboloid_direction(uo, vo), paraboloid_direction(ui, vi));
                worst = worst.max((f.eval(wi, wo) - brdf(wi, wo)).abs());
            }
        }
        assert!(worst < 1e-4, "{worst}");
    }

    #[test]
    fn error_falls_with_terms() {
        let f =
            BrdfFactorisation::fit(&blinn, &FactorisationConfig { grid: 16, terms: 8 }).unwrap();
        let errors: Vec<f64> = (1..=8).map(|k| f.truncation_error(k)).collect();
        assert!(errors.windows(2).all(|w| w[1] <= w[0]), "{errors:?}");
        assert!(errors[7] < errors[0]);
        // Below the horizon nothing is reflected.
        assert_eq!(f.eval(Vec3::new(0.0, 0.6, -0.8), Vec3::Z), 0.0);
    }

    #[test]
    fn shade_is_the_factored_product() {
        let f = BrdfFactorisation::fit(&blinn, &FactorisationConfig { grid: 8, terms: 3 }).unwrap();
        let wo = Vec3::new(0.2, -0.3, 0.9).normalize();
        let wi = Vec3::new(-0.1, 0.4, 0.8).normalize();
        let mut g = [0.0; 3];
        f.in_factors(wi, &mut g);
        // One light of unit radiance from ωi: T_k · L = g_k(ωi).
        let mut out = [0.0f32; 1];
        f.shade(wo, &g, &mut out);
        assert!((out[0] - f.eval(wi, wo)).abs() < 1e-6 * f.eval(wi, wo).abs().max(1.0));
    }

    #[test]
    fn a_camera_path_under_converged_lighting_is_the_direct_product() {
        use crate::{
            Approximator, BandStrategy, CubemapLayout, Policy, Relighter, SparseTransport,
            Weighting,
        };
        // Two points × K = 3 transport rows over a 6 × 2 × 2 map, relit incrementally until
        // the static lighting has converged, then shaded along a camera path: every view
        // equals `Σ_k σ_k h_k(ωo) T_k · L` computed directly, with no lighting work.
        let f = BrdfFactorisation::fit(&blinn, &FactorisationConfig { grid: 8, terms: 3 }).unwrap();
        let (k, n) = (3, 24);
        let rows: Vec<f32> = (0..2 * k * n)
            .map(|i| ((i * 37 % 11) as f32 - 5.0) * 0.1)
            .collect();
        let oracle =
            prt_core::DenseOracle::new(Array2::from_shape_vec((2 * k, n), rows).unwrap(), 1)
                .unwrap();
        let transport = SparseTransport::from_oracle(&oracle, n, &prt_core::NoProgress).unwrap();
        let dense = transport.to_dense();
        let layout = CubemapLayout::new(2).unwrap();
        let light: Vec<f32> = (0..3 * n).map(|i| (i % 7) as f32 * 0.3 - 0.4).collect();
        let policy = Policy::PerBand(BandStrategy::L1Test);
        let mut approx = Approximator::for_cubemap(&layout, 3, Weighting::Area, 5, policy).unwrap();
        let mut engine = Relighter::new(transport, 3, layout.band_count()).unwrap();
        for _ in 0..20 {
            engine.apply(approx.step(&light).unwrap()).unwrap();
        }
        assert_eq!(approx.approximation(), &light[..]);
        let lit = engine.image();
        for step in 0..6 {
            let wo = Vec3::new(0.1 * step as f32 - 0.3, 0.2, 0.8).normalize();
            assert!(approx.step(&light).unwrap().terms.is_empty());
            for point in 0..2 {
                let mut shaded = [0.0f32; 3];
                f.shade(wo, &lit[point * k * 3..(point + 1) * k * 3], &mut shaded);
                let mut h = [0.0; 3];
                f.out_factors(wo, &mut h);
                for (c, s) in shaded.iter().enumerate() {
                    let direct: f32 = (0..k)
                        .map(|t| {
                            let row = &dense[(point * k + t) * n..(point * k + t + 1) * n];
                            let tl: f32 = row.iter().zip(&light[c * n..]).map(|(a, b)| a * b).sum();
                            f.sigma()[t] * h[t] * tl
                        })
                        .sum();
                    assert!(
                        (s - direct).abs() <= 1e-5 * direct.abs().max(1.0),
                        "{s} {direct}"
                    );
                }
            }
        }
    }

    #[test]
    fn rejects_bad_configs() {
        let zero = FactorisationConfig { grid: 4, terms: 0 };
        assert!(BrdfFactorisation::fit(&blinn, &zero).is_err());
        let many = FactorisationConfig { grid: 2, terms: 9 };
        assert!(BrdfFactorisation::fit(&blinn, &many).is_err());
        let nan = |_: Vec3, _: Vec3| f32::NAN;
        assert!(BrdfFactorisation::fit(&nan, &FactorisationConfig { grid: 4, terms: 1 }).is_err());
    }
}
