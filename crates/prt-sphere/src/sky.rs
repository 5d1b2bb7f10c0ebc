//! Distant lighting as order-3 SH per colour channel: what lights a transfer volume.

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

/// SH projection (prt's basis, indices 0, 2, 6; the others are 0) of the indicator of the
/// upper hemisphere `ω_y > 0`: `√π`, `√(3π)/2`, 0. The lower hemisphere's has the sign of index
/// 2 flipped.
const UPPER_HEMISPHERE: [f64; 3] = [1.772_453_850_905_516, 1.534_990_061_919_732_5, 0.0];
/// SH projection (indices 0, 2, 6) of `max(ω_y, 0)`: `√π/2`, `√(π/3)`, `√(5π)/8`.
const CLAMPED_UP: [f64; 3] = [
    0.886_226_925_452_758,
    1.023_326_707_946_488_5,
    0.495_415_912_200_751_7,
];

/// The analytic outdoor sky of [`Sky::sun_sky`]: a sun, a sky gradient and a lit ground.
///
/// Radiance, per colour channel (directions in prt's frame, +Y up):
///
/// * sun: a directional light of irradiance `sun` (on a surface facing it) from the direction
///   `s = (cos e · sin a, sin e, cos e · cos a)` (elevation `e` above the horizon, azimuth `a`
///   from +Z towards +X), projected exactly: `E_sun · Y_j(s)`;
/// * sky, upper hemisphere: `horizon + (zenith − horizon) · ω_y`;
/// * ground, lower hemisphere: the constant radiance of a Lambertian ground of albedo
///   `ground_albedo` lit by the sun and the sky, `albedo · (E_sun · max(sin e, 0) + π ·
///   horizon + 2π/3 · (zenith − horizon)) / π`.
///
/// Each term is projected on SH of order 3 in closed form, so the result is deterministic and
/// exact for the order-3 band limit (the sun and the hemisphere edge ring, as any order-3 SH).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SunSky {
    /// Sun elevation above the horizon, degrees.
    pub elevation_deg: f32,
    /// Sun azimuth, degrees from +Z towards +X.
    pub azimuth_deg: f32,
    /// Sun irradiance on a surface facing it, RGB.
    pub sun: [f32; 3],
    /// Sky radiance straight up, RGB.
    pub zenith: [f32; 3],
    /// Sky radiance at the horizon, RGB.
    pub horizon: [f32; 3],
    /// Albedo of the ground that fills the lower hemisphere (0..=1).
    pub ground_albedo: f32,
}

impl Default for SunSky {
    /// A sun 45° up in the +Z direction of irradiance 3 (slightly warm), a blue sky of zenith
    /// radiance (0.25, 0.4, 0.8) and horizon (0.6, 0.7, 0.85), ground albedo 0.2.
    fn default() -> Self {
        SunSky {
            elevation_deg: 45.0,
            azimuth_deg: 0.0,
            sun: [3.0, 2.85, 2.6],
            zenith: [0.25, 0.4, 0.8],
            horizon: [0.6, 0.7, 0.85],
            ground_albedo: 0.2,
        }
    }
}

impl SunSky {
    /// Unit direction towards the sun.
    pub fn sun_direction(&self) -> Vec3 {
        let (e, a) = (
            f64::from(self.elevation_deg).to_radians(),
            f64::from(self.azimuth_deg).to_radians(),
        );
        glam::DVec3::new(e.cos() * a.sin(), e.sin(), e.cos() * a.cos()).as_vec3()
    }
}

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

    /// The analytic sun and sky of `params` (formula on [`SunSky`]). Non-finite parameters,
    /// negative radiance or irradiance, or an albedo outside 0..=1 are errors.
    pub fn sun_sky(params: &SunSky) -> Result<Sky, SphereError> {
        let scalars = [
            params.elevation_deg,
            params.azimuth_deg,
            params.ground_albedo,
        ];
        let colours = [params.sun, params.zenith, params.horizon].concat();
        SphereError::check_finite("sun-sky parameter", &[&scalars[..], &colours].concat())?;
        if let Some(i) = colours.iter().position(|&v| v < 0.0) {
            return Err(SphereError::invalid(
                "sun-sky colour",
                format!("value {} at index {i} is negative", colours[i]),
            ));
        }
        if !(0.0..=1.0).contains(&params.ground_albedo) {
            return Err(SphereError::invalid(
                "ground albedo",
                format!("{} (must be within 0..=1)", params.ground_albedo),
            ));
        }
        let s = params.sun_direction();
        let mut y = [0.0f64; SKY_SH];
        crate::eval_sh_f64(3, s.as_dvec3(), &mut y);
        let cos_zenith = f64::from(s.y).max(0.0);
        let mut sh = [[0.0f32; SKY_SH]; 3];
        for c in 0..3 {
            let (sun, zenith, horizon) = (
                f64::from(params.sun[c]),
                f64::from(params.zenith[c]),
                f64::from(params.horizon[c]),
            );
            let ground_irradiance = sun * cos_zenith
                + std::f64::consts::PI * horizon
                + 2.0 * std::f64::consts::FRAC_PI_3 * (zenith - horizon);
            let ground = f64::from(params.ground_albedo) * ground_irradiance / std::f64::consts::PI;
            let mut coefficients: [f64; SKY_SH] = y.map(|yj| sun * yj);
            for (k, &j) in [0usize, 2, 6].iter().enumerate() {
                let lower = if j == 2 { -1.0 } else { 1.0 } * UPPER_HEMISPHERE[k];
                coefficients[j] += horizon * UPPER_HEMISPHERE[k]
                    + (zenith - horizon) * CLAMPED_UP[k]
                    + ground * lower;
            }
            sh[c] = coefficients.map(|v| v as f32);
        }
        Sky::from_coefficients(sh)
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
