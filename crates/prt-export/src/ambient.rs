//! Ambient cubes (Valve's HL2 basis, as Bevy samples them) from incident-radiance SH.

use std::sync::OnceLock;

use glam::Vec3;
use prt_sphere::eval_sh_f64;

use prt_trace::lit::RadianceSh;

/// Side order of an ambient cube: +X, -X, +Y, -Y, +Z, -Z (prt_texture's `AMBIENT_CUBE_SIDES`).
pub const SIDES: [Vec3; 6] = [
    Vec3::X,
    Vec3::NEG_X,
    Vec3::Y,
    Vec3::NEG_Y,
    Vec3::Z,
    Vec3::NEG_Z,
];

/// Six RGB values, one per side in the order of [`SIDES`].
pub type AmbientCubeColours = [[f32; 3]; 6];

/// How the six sides of an ambient cube are chosen to reproduce `E(n) / π` (irradiance over π,
/// the radiance a white Lambertian surface reflects: what Bevy multiplies by the diffuse colour).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum AmbientCubeFit {
    /// Each side is `E(±axis) / π`: exact in the six axis directions, error elsewhere at most
    /// [`ambient_cube_error_bound`].
    #[default]
    Axes,
    /// The six values minimising `∫ |blend(n) − E(n)/π|² dn` over the sphere (Bevy's blend,
    /// [`ambient_cube_blend`]): a lower mean error, not exact on the axes.
    LeastSquares,
}

/// `E(n)/π` of radiance SH `l` (zonal factors 1, 2/3, 1/4), per channel, in f64.
fn irradiance_over_pi(l: &RadianceSh, n: Vec3) -> [f64; 3] {
    let mut y = [0.0f64; 9];
    eval_sh_f64(3, n.as_dvec3(), &mut y);
    let band = [
        1.0,
        2.0 / 3.0,
        2.0 / 3.0,
        2.0 / 3.0,
        0.25,
        0.25,
        0.25,
        0.25,
        0.25,
    ];
    l.map(|ch| (0..9).map(|j| band[j] * f64::from(ch[j]) * y[j]).sum())
}

/// The ambient cube of radiance SH `l` by `fit`. Sides can come out negative where the SH
/// itself rings below zero; writers clamp them.
pub fn ambient_cube(l: &RadianceSh, fit: AmbientCubeFit) -> AmbientCubeColours {
    match fit {
        AmbientCubeFit::Axes => SIDES.map(|d| irradiance_over_pi(l, d).map(|v| v as f32)),
        AmbientCubeFit::LeastSquares => {
            let m = least_squares_matrix();
            std::array::from_fn(|side| {
                std::array::from_fn(|c| {
                    (0..9).map(|j| m[side][j] * f64::from(l[c][j])).sum::<f64>() as f32
                })
            })
        }
    }
}

/// Bevy's ambient-cube blend (bevy_pbr's `irradiance_volume_light`, without the intensity):
/// `Σ_a n_a² · side(a, sign n_a)`, the negative side where `n_a < 0`.
pub fn ambient_cube_blend(cube: &AmbientCubeColours, n: Vec3) -> Vec3 {
    let side = |axis: usize| {
        let s = if n[axis] < 0.0 {
            2 * axis + 1
        } else {
            2 * axis
        };
        Vec3::from_array(cube[s])
    };
    side(0) * n.x * n.x + side(1) * n.y * n.y + side(2) * n.z * n.z
}

/// A bound, per channel, on `|blend(n) − E(n)/π|` over all unit `n` for the
/// [`AmbientCubeFit::Axes`] cube of `l` with negative sides clamped to 0.
///
/// Write `E/π = c + d·n + nᵀQn`. The blend reproduces `c`, the diagonal of `Q` and `d` on the
/// axes; what it misses is `Σ_a d_a n_a (|n_a| − 1)`, at most `¼ Σ_a |d_a|`, and the off-diagonal
/// part `nᵀ Q_off n`, at most `‖Q_off‖_F`. Clamping adds at most the largest clamped amount.
pub fn ambient_cube_error_bound(l: &RadianceSh) -> [f32; 3] {
    let f = |n: Vec3| irradiance_over_pi(l, n.normalize());
    let axes = [Vec3::X, Vec3::Y, Vec3::Z];
    let cube = ambient_cube(l, AmbientCubeFit::Axes);
    std::array::from_fn(|c| {
        let linear: f64 = axes.iter().map(|&a| 0.5 * (f(a)[c] - f(-a)[c]).abs()).sum();
        let mut off = 0.0f64;
        for i in 0..3 {
            for k in i + 1..3 {
                let (a, b) = (axes[i], axes[k]);
                let q = 0.25 * (f(a + b)[c] + f(-a - b)[c] - f(a - b)[c] - f(b - a)[c]);
                off += 2.0 * q * q;
            }
        }
        let clamped = cube.iter().map(|s| (-s[c]).max(0.0)).fold(0.0f32, f32::max);
        (0.25 * linear + off.sqrt()) as f32 + clamped
    })
}

/// The 6 × 9 matrix taking radiance SH to the least-squares ambient cube of `E/π`, computed
/// once: `G⁻¹ P` with `G` the Gram matrix of the blend's six functions `n_a² [±n_a > 0]` and
/// `P_ij = ∫ φ_i (E/π of Y_j)` by midpoint quadrature over each side's hemisphere (exact to
/// ~1e-8: the integrands are polynomials of degree 4).
fn least_squares_matrix() -> &'static [[f64; 9]; 6] {
    static MATRIX: OnceLock<[[f64; 9]; 6]> = OnceLock::new();
    MATRIX.get_or_init(|| {
        const STEPS_T: usize = 1024;
        const STEPS_PHI: usize = 64;
        let band = [
            1.0,
            2.0 / 3.0,
            2.0 / 3.0,
            2.0 / 3.0,
            0.25,
            0.25,
            0.25,
            0.25,
            0.25,
        ];
        let mut p = [[0.0f64; 9]; 6];
        for (side, row) in p.iter_mut().enumerate() {
            let axis = side / 2;
            let sign = if side % 2 == 0 { 1.0 } else { -1.0 };
            let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
            let dt = 1.0 / STEPS_T as f64;
            let dphi = std::f64::consts::TAU / STEPS_PHI as f64;
            for it in 0..STEPS_T {
                let t = (it as f64 + 0.5) * dt;
                let s = (1.0 - t * t).sqrt();
                for ip in 0..STEPS_PHI {
                    let phi = (ip as f64 + 0.5) * dphi;
                    let mut n = [0.0f64; 3];
                    n[axis] = sign * t;
                    n[u] = s * phi.cos();
                    n[v] = s * phi.sin();
                    let mut y = [0.0f64; 9];
                    eval_sh_f64(3, glam::DVec3::from_array(n), &mut y);
                    let w = t * t * dt * dphi;
                    for j in 0..9 {
                        row[j] += w * band[j] * y[j];
                    }
                }
            }
        }
        // Gram matrix: ∫ n_a⁴ over a hemisphere = 2π/5; opposite sides of one axis never
        // overlap; sides of different axes share a quarter sphere: ∫ n_a² n_b² = π/15.
        let mut g = [[0.0f64; 6]; 6];
        for i in 0..6 {
            for k in 0..6 {
                g[i][k] = if i == k {
                    2.0 * std::f64::consts::PI / 5.0
                } else if i / 2 == k / 2 {
                    0.0
                } else {
                    std::f64::consts::PI / 15.0
                };
            }
        }
        solve_6(g, p)
    })
}

/// `G⁻¹ P` by Gauss-Jordan elimination with partial pivoting (G is symmetric positive
/// definite and well conditioned).
fn solve_6(mut g: [[f64; 6]; 6], mut p: [[f64; 9]; 6]) -> [[f64; 9]; 6] {
    for col in 0..6 {
        let pivot = (col..6)
            .max_by(|&a, &b| g[a][col].abs().total_cmp(&g[b][col].abs()))
            .unwrap_or(col);
        g.swap(col, pivot);
        p.swap(col, pivot);
        let d = g[col][col];
        for k in 0..6 {
            g[col][k] /= d;
        }
        for j in 0..9 {
            p[col][j] /= d;
        }
        for row in 0..6 {
            if row != col {
                let f = g[row][col];
                for k in 0..6 {
                    g[row][k] -= f * g[col][k];
                }
                for j in 0..9 {
                    p[row][j] -= f * p[col][j];
                }
            }
        }
    }
    p
}
