//! Lightmap bases and encoders: what a texel stores and how its samples become coefficients.

use std::f64::consts::{LN_2, TAU};

use glam::Vec3;
use ndarray::Array2;
use prt_core::SphericalBasis;
use prt_sphere::{AmbientDiceSrbf, SgBasis, ShBasis};

use crate::LightmapError;

/// What each texel stores, in its tangent frame (+Y the surface normal, X and Z the
/// orthonormal pair of Duff et al. 2017, glam's `Vec3::any_orthonormal_pair`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LightmapBasis {
    /// `lobes` spherical Gaussians on a Fibonacci spiral over the upper hemisphere, sharpness
    /// `lobes · ln 2` (neighbouring lobes cross near half their peak).
    Sg {
        /// Number of lobes.
        lobes: usize,
    },
    /// Real spherical harmonics of order `order` (bands `0..order`, `order²` functions; the
    /// `sh:N` of `prt encode`).
    Sh {
        /// The order (number of bands).
        order: usize,
    },
    /// Ambient dice, SRBF variant (12 functions; Iwanicki and Sloan 2017).
    AmbientDice,
    /// Irradiance at the texel's normal only (RGB, no directional data): the Monte Carlo
    /// estimate `2π/W Σ w L cos θ`; the encoder does not apply.
    Irradiance,
}

impl LightmapBasis {
    /// Parses `sg:N`, `sh:N`, `ambient-dice` or `irradiance`.
    pub fn parse(text: &str) -> Result<Self, LightmapError> {
        let bad = || {
            LightmapError::invalid(
                "basis",
                format!("{text:?}: expected sg:N, sh:N, ambient-dice or irradiance"),
            )
        };
        let number = |s: &str| s.parse::<usize>().map_err(|_| bad());
        let basis = match text.split_once(':') {
            Some(("sg", n)) => LightmapBasis::Sg { lobes: number(n)? },
            Some(("sh", n)) => LightmapBasis::Sh { order: number(n)? },
            None if text == "ambient-dice" => LightmapBasis::AmbientDice,
            None if text == "irradiance" => LightmapBasis::Irradiance,
            _ => return Err(bad()),
        };
        basis.validate()?;
        Ok(basis)
    }

    fn validate(&self) -> Result<(), LightmapError> {
        match *self {
            LightmapBasis::Sg { lobes } if !(1..=64).contains(&lobes) => Err(
                LightmapError::invalid("SG lobes", format!("{lobes} (1..=64)")),
            ),
            LightmapBasis::Sh { order } if !(1..=8).contains(&order) => Err(
                LightmapError::invalid("SH order", format!("{order} (1..=8)")),
            ),
            _ => Ok(()),
        }
    }

    /// Number of basis functions (0 for [`LightmapBasis::Irradiance`]).
    pub fn len(&self) -> usize {
        match *self {
            LightmapBasis::Sg { lobes } => lobes,
            LightmapBasis::Sh { order } => order * order,
            LightmapBasis::AmbientDice => 12,
            LightmapBasis::Irradiance => 0,
        }
    }

    /// Whether the basis has no functions ([`LightmapBasis::Irradiance`]).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The name `parse` reads.
    pub fn label(&self) -> String {
        match *self {
            LightmapBasis::Sg { lobes } => format!("sg:{lobes}"),
            LightmapBasis::Sh { order } => format!("sh:{order}"),
            LightmapBasis::AmbientDice => "ambient-dice".into(),
            LightmapBasis::Irradiance => "irradiance".into(),
        }
    }

    /// The lobe axes and sharpness of [`LightmapBasis::Sg`] (tangent frame), for shaders.
    pub fn sg_lobes(lobes: usize) -> (Vec<Vec3>, f32) {
        let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
        let axes = (0..lobes)
            .map(|i| {
                let y = 1.0 - (i as f64 + 0.5) / lobes as f64;
                let r = (1.0 - y * y).max(0.0).sqrt();
                let phi = golden * i as f64;
                Vec3::new((r * phi.cos()) as f32, y as f32, (r * phi.sin()) as f32)
            })
            .collect();
        (axes, (lobes as f64 * LN_2) as f32)
    }

    pub(crate) fn functions(&self) -> Result<Option<Box<dyn SphericalBasis>>, LightmapError> {
        self.validate()?;
        Ok(match *self {
            LightmapBasis::Sg { lobes } => {
                let (axes, sharpness) = Self::sg_lobes(lobes);
                Some(Box::new(SgBasis::new(
                    axes,
                    vec![sharpness; lobes],
                    self.label(),
                )?))
            }
            LightmapBasis::Sh { order } => Some(Box::new(ShBasis::new(order)?)),
            LightmapBasis::AmbientDice => Some(Box::new(AmbientDiceSrbf)),
            LightmapBasis::Irradiance => None,
        })
    }
}

/// How a texel's samples become coefficients.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Encoder {
    /// Progressive least squares (Roughton 2020; the paper's configuration).
    Plsq,
    /// Progressive least squares with every coefficient clamped to `>= 0` after its update
    /// (Roughton's non-negative variant: no negative lobes, so no negative light).
    PlsqNonNegative,
    /// Least squares over the samples so far (normal equations accumulated per texel, f64).
    LeastSquares,
    /// Non-negative least squares over the samples so far (same accumulators).
    Nnls,
    /// Monte Carlo projection through the exact Gram matrix: `G c = 2π/W Σ w L B`.
    Naive,
}

impl Encoder {
    /// Parses `plsq`, `plsq-nonneg`, `ls`, `nnls` or `naive`.
    pub fn parse(text: &str) -> Result<Self, LightmapError> {
        Ok(match text {
            "plsq" => Encoder::Plsq,
            "plsq-nonneg" => Encoder::PlsqNonNegative,
            "ls" => Encoder::LeastSquares,
            "nnls" => Encoder::Nnls,
            "naive" => Encoder::Naive,
            _ => {
                return Err(LightmapError::invalid(
                    "encoder",
                    format!("{text:?}: expected plsq, plsq-nonneg, ls, nnls or naive"),
                ));
            }
        })
    }

    /// The name `parse` reads.
    pub fn label(&self) -> &'static str {
        match self {
            Encoder::Plsq => "plsq",
            Encoder::PlsqNonNegative => "plsq-nonneg",
            Encoder::LeastSquares => "ls",
            Encoder::Nnls => "nnls",
            Encoder::Naive => "naive",
        }
    }
}

/// Visits the cells of a 128 × 256 midpoint rule in `cos θ` and `φ` over the upper hemisphere
/// (y up): `visit(cos θ, the basis at the cell's centre, the cell's solid angle)`.
pub(crate) fn for_each_hemisphere_cell(
    basis: &dyn SphericalBasis,
    mut visit: impl FnMut(f64, &[f32], f64),
) {
    let (rings, sectors) = (128, 256);
    let mut b = vec![0.0f32; basis.len()];
    let cell = TAU / (rings * sectors) as f64;
    for r in 0..rings {
        let y = (r as f64 + 0.5) / rings as f64;
        let s = (1.0 - y * y).sqrt();
        for k in 0..sectors {
            let phi = TAU * (k as f64 + 0.5) / sectors as f64;
            basis.eval(
                Vec3::new((s * phi.cos()) as f32, y as f32, (s * phi.sin()) as f32),
                &mut b,
            );
            visit(y, &b, cell);
        }
    }
}

/// `∫ B_i(ω) max(ω_y, 0) dω` per function (the irradiance at the normal of each function), by
/// [`for_each_hemisphere_cell`].
pub(crate) fn cosine_weights(basis: &dyn SphericalBasis) -> Vec<f32> {
    let mut out = vec![0.0f64; basis.len()];
    for_each_hemisphere_cell(basis, |y, b, cell| {
        for (o, v) in out.iter_mut().zip(b) {
            *o += f64::from(*v) * y * cell;
        }
    });
    out.into_iter().map(|v| v as f32).collect()
}

/// The inverse of the Gram matrix (for the naive projection).
pub(crate) fn gram_inverse(basis: &dyn SphericalBasis) -> Result<Array2<f64>, LightmapError> {
    let g = basis.gram();
    let k = g.nrows();
    prt_linalg::cholesky_solve(g.view(), Array2::eye(k).view(), 0.0)
        .map_err(|e| LightmapError::invalid("basis", format!("singular Gram matrix: {e}")))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip() {
        for text in ["sg:9", "sh:3", "ambient-dice", "irradiance"] {
            assert_eq!(LightmapBasis::parse(text).unwrap().label(), text);
        }
        for text in ["plsq", "plsq-nonneg", "ls", "nnls", "naive"] {
            assert_eq!(Encoder::parse(text).unwrap().label(), text);
        }
        assert!(LightmapBasis::parse("sg:0").is_err());
        assert!(LightmapBasis::parse("sh:0").is_err());
        assert!(LightmapBasis::parse("sh:x").is_err());
        assert!(Encoder::parse("fast").is_err());
    }

    /// The constant SH function's cosine weight is `π Y_0 = π / (2√π)`.
    #[test]
    fn cosine_weights_match_the_clamped_cosine() {
        let basis = LightmapBasis::Sh { order: 2 }.functions().unwrap().unwrap();
        let w = cosine_weights(basis.as_ref());
        let expected = std::f32::consts::PI * 0.282_094_8;
        assert!((w[0] - expected).abs() < 1e-4 * expected, "{w:?}");
        // Y_1^0 = 0.488603 y: ∫ y² over the hemisphere = 2π/3.
        assert!((w[2] - 0.488_603 * std::f32::consts::TAU / 3.0).abs() < 1e-4);
    }
}
