//! The ambient cube (Valve, McTaggart 2004) and ambient dice (Iwanicki & Sloan, "Ambient Dice",
//! EGSR 2017), SRBF variant.
use glam::Vec3;
use ndarray::Array2;
use prt_core::SphericalBasis;

use crate::sampling::sphere_quadrature;

/// Six clamped cos² lobes on ±X, ±Y, ±Z: `B_{±a}(v) = max(0, ±v_a)²`. They sum to 1 everywhere.
/// Order: +X, −X, +Y, −Y, +Z, −Z.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct AmbientCube;

impl SphericalBasis for AmbientCube {
    fn len(&self) -> usize {
        6
    }

    fn eval(&self, dir: Vec3, out: &mut [f32]) {
        let c = dir.to_array();
        for a in 0..3 {
            let v = c[a];
            out[2 * a] = if v > 0.0 { v * v } else { 0.0 };
            out[2 * a + 1] = if v < 0.0 { v * v } else { 0.0 };
        }
    }

    /// Exact: `∫_{x>0} x⁴ = 2π/5`, `∫_{x>0,y>0} x² y² = π/15`, opposite lobes do not overlap.
    fn gram(&self) -> Array2<f64> {
        use std::f64::consts::PI;
        Array2::from_shape_fn((6, 6), |(i, j)| {
            if i == j {
                2.0 * PI / 5.0
            } else if i / 2 == j / 2 {
                0.0
            } else {
                PI / 15.0
            }
        })
    }

    fn name(&self) -> String {
        "ambient cube (6)".into()
    }
}

/// Ambient dice, SRBF variant: 12 lobes on the icosahedron's vertices. For each of the six
/// vertex pairs `±a_k`, `d = v·a_k` selects the lobe on the side of `v` and weighs it
/// `0.7 (d²/2) + 0.3 (5/6) d⁴` (Iwanicki & Sloan 2017, §4; the weights as in Probulator's
/// `AmbientDice::srbfWeights`). Lobe `2k` is `+a_k`, `2k + 1` is `−a_k`; the axes `a_k` are
/// Probulator's `(1,t,0), (−1,t,0), (0,1,t), (0,−1,t), (t,0,1), (t,0,−1)`, `t = 1/φ`.
///
/// The Gram matrix is a 256 × 512 Gauss-Legendre product quadrature (the lobes have a kink on
/// a great circle, so it is accurate to about 1e-6 relative, not exact).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct AmbientDiceSrbf;

impl AmbientDiceSrbf {
    /// The six (normalised) vertex axes.
    pub fn axes() -> [Vec3; 6] {
        let t = 0.618_034_f32;
        [
            Vec3::new(1.0, t, 0.0).normalize(),
            Vec3::new(-1.0, t, 0.0).normalize(),
            Vec3::new(0.0, 1.0, t).normalize(),
            Vec3::new(0.0, -1.0, t).normalize(),
            Vec3::new(t, 0.0, 1.0).normalize(),
            Vec3::new(t, 0.0, -1.0).normalize(),
        ]
    }
}

impl SphericalBasis for AmbientDiceSrbf {
    fn len(&self) -> usize {
        12
    }

    fn eval(&self, dir: Vec3, out: &mut [f32]) {
        let out = &mut out[..12];
        out.fill(0.0);
        for (k, a) in Self::axes().iter().enumerate() {
            let d = dir.dot(*a);
            let c2 = d * d;
            let w = 0.7 * (0.5 * c2) + 0.3 * (5.0 / 6.0 * c2 * c2);
            out[if d > 0.0 { 2 * k } else { 2 * k + 1 }] = w;
        }
    }

    fn gram(&self) -> Array2<f64> {
        quadrature_gram(self, 256)
    }

    fn name(&self) -> String {
        "ambient dice SRBF (12)".into()
    }
}

/// Gram matrix of any basis by a product Gauss-Legendre quadrature with `n` polar nodes.
pub fn quadrature_gram(basis: &dyn SphericalBasis, n: usize) -> Array2<f64> {
    let k = basis.len();
    let (dirs, weights) = sphere_quadrature(n);
    let mut g = Array2::<f64>::zeros((k, k));
    let mut b = vec![0.0f32; k];
    for (d, w) in dirs.iter().zip(&weights) {
        basis.eval(*d, &mut b);
        for i in 0..k {
            if b[i] == 0.0 {
                continue;
            }
            let wi = w * b[i] as f64;
            for j in i..k {
                g[[i, j]] += wi * b[j] as f64;
            }
        }
    }
    for i in 0..k {
        for j in 0..i {
            g[[i, j]] = g[[j, i]];
        }
    }
    g
}
