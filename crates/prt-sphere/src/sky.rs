//! Distant lighting as order-3 SH per colour channel: what relights a transfer volume.

use glam::{Mat3, Vec3};

use crate::{LatLongMap, ShRotation, SphereError, eval_sh};

/// SH coefficients of order 3 (bands 0–2).
pub const SKY_SH: usize = 9;

/// Distant radiance `L(ω)` as real SH of order 3 (prt's SH convention, +Y up), one 9-vector per
/// colour channel: `L_c(ω) = Σ_j sh[c][j] Y_j(ω)`.
///
/// Transfer volumes and MBD bases are linear in it; lighting a bake means multiplying their
/// 9×9 transfer blocks by these vectors.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sky {
    /// Coefficients per channel: `sh[c][j]`, c = R, G, B.
    pub sh: [[f32; SKY_SH]; 3],
}

/// `√(4π)`: the SH coefficient `∫ Y_0^0` of a constant 1.
const SQRT_4PI: f32 = 3.544_907_7;
/// `√(4π/3)`: the SH coefficient `∫ ω_y Y_1^0` of the function `ω_y`.
const SQRT_4PI_3: f32 = 2.046_653_4;

impl Default for Sky {
    /// prt's default sky, used wherever no sky is given (bake report, exports, renders):
    /// `L(ω) = c · (1 + 0.6 ω_y)` with `c = (0.9, 1.0, 1.2)`, a bluish sky brighter overhead.
    fn default() -> Self {
        Sky {
            sh: [0.9f32, 1.0, 1.2].map(|c| {
                let mut s = [0.0; SKY_SH];
                s[0] = c * SQRT_4PI;
                s[2] = 0.6 * c * SQRT_4PI_3;
                s
            }),
        }
    }
}

impl Sky {
    /// A sky of the same radiance `rgb` in every direction.
    pub fn constant(rgb: [f32; 3]) -> Sky {
        Sky {
            sh: rgb.map(|c| {
                let mut s = [0.0; SKY_SH];
                s[0] = c * SQRT_4PI;
                s
            }),
        }
    }

    /// The SH projection of a lat-long environment map (exact texel solid angles, f64 sums).
    pub fn from_latlong(map: &LatLongMap) -> Result<Sky, SphereError> {
        let rows = map.project_sh(3)?;
        let mut sh = [[0.0; SKY_SH]; 3];
        for (j, row) in rows.chunks_exact(3).enumerate() {
            for c in 0..3 {
                sh[c][j] = row[c];
            }
        }
        Sky::from_coefficients(sh)
    }

    /// A sky from coefficients; NaN or infinite values are an error naming the channel and
    /// coefficient (`index = channel · 9 + j`).
    pub fn from_coefficients(sh: [[f32; SKY_SH]; 3]) -> Result<Sky, SphereError> {
        SphereError::check_finite("sky SH coefficient", sh.as_flattened())?;
        Ok(Sky { sh })
    }

    /// This sky turned by the rotation `r`: the rotated sky's radiance towards `r ω` is this
    /// sky's towards `ω`. `r` must be a rotation (orthonormal, determinant +1).
    pub fn rotated(&self, r: Mat3) -> Result<Sky, SphereError> {
        let rotation = ShRotation::new(3, r)?;
        let mut sh = self.sh;
        for channel in &mut sh {
            rotation.apply(channel, 1)?;
        }
        Ok(Sky { sh })
    }

    /// This sky turned by `degrees` about +Y (counter-clockwise seen from above).
    pub fn rotated_about_y(&self, degrees: f32) -> Sky {
        let r = Mat3::from_rotation_y(degrees.to_radians());
        self.rotated(r)
            .expect("a rotation about Y is orthonormal with determinant +1")
    }

    /// Radiance (RGB) towards the unit direction `dir`.
    pub fn radiance(&self, dir: Vec3) -> Vec3 {
        let mut y = [0.0f32; SKY_SH];
        eval_sh(3, dir, &mut y);
        let channel = |s: &[f32; SKY_SH]| -> f32 {
            s.iter()
                .zip(&y)
                .map(|(&a, &b)| f64::from(a) * f64::from(b))
                .sum::<f64>() as f32
        };
        Vec3::new(
            channel(&self.sh[0]),
            channel(&self.sh[1]),
            channel(&self.sh[2]),
        )
    }
}
