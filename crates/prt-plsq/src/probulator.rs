//! Probulator's error definition and lat-long frames, so that fits can be compared with the
//! figures Probulator (kayru/Probulator, and Roughton's fork troughton/Probulator) publishes.
//!
//! **Radiance RMSE** ([`radiance_rmse`]): reconstruct the fit at every texel centre of the
//! lat-long map, take the squared error per channel averaged over R, G and B, average that over
//! the texels *without* solid-angle weighting (every texel counts the same, so the poles are
//! over-represented, as in Probulator), and return the square root. SH and ambient dice fits
//! are clamped at 0 before the comparison in Probulator; SG fits are not.
//!
//! **Frames** ([`LatLongFrame`]): prt's conventions.md addresses a lat-long map by
//! `θ = 2πu`, `dir = (sin φ sin θ, cos φ, −sin φ cos θ)`. kayru/Probulator uses
//! `u = ½ + atan2(x, −z) / 2π`, i.e. `θ = π(2u − 1)`: prt's frame turned by π about +Y,
//! `(x, y, z) ↦ (−x, y, −z)`. So a direction `d` in which Probulator samples or places a lobe
//! reads the texel prt finds at `(−d.x, d.y, −d.z)`. Probulator's Halton sample directions,
//! spiral lobes and ambient dice vertices are defined in its own frame, so reproducing its
//! numbers means fitting in [`LatLongFrame::Probulator`]; for any other use the conventions
//! frame is the right one. troughton/Probulator is Z up ([`LatLongFrame::ProbulatorZUp`]).
use glam::Vec3;
use prt_core::SphericalBasis;
use prt_sphere::LatLongMap;

use crate::PlsqError;

/// The frame in which basis directions are expressed relative to a lat-long map.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[non_exhaustive]
pub enum LatLongFrame {
    /// prt's conventions.md (the frame of [`LatLongMap::direction`] and
    /// [`LatLongMap::nearest`]).
    #[default]
    Conventions,
    /// kayru/Probulator, Y up: the conventions frame turned by π about +Y.
    Probulator,
    /// troughton/Probulator, Z up: `u = ½ + atan2(x, −y) / 2π`, `v = acos(z) / π`.
    ProbulatorZUp,
}

impl LatLongFrame {
    /// The direction in this frame of a direction `d` of the conventions frame.
    pub fn from_conventions(self, d: Vec3) -> Vec3 {
        match self {
            LatLongFrame::Conventions => d,
            LatLongFrame::Probulator => Vec3::new(-d.x, d.y, -d.z),
            LatLongFrame::ProbulatorZUp => Vec3::new(-d.x, -d.z, d.y),
        }
    }

    /// The direction in the conventions frame of a direction `d` of this frame (the inverse
    /// of [`LatLongFrame::from_conventions`]).
    pub fn to_conventions(self, d: Vec3) -> Vec3 {
        match self {
            LatLongFrame::Conventions => d,
            LatLongFrame::Probulator => Vec3::new(-d.x, d.y, -d.z),
            LatLongFrame::ProbulatorZUp => Vec3::new(-d.x, d.z, -d.y),
        }
    }
}

/// RGB values of the texels nearest to `dirs` (directions in `frame`), 3 per direction: the
/// fit input of Probulator ("nearest texel").
pub fn sample_nearest(map: &LatLongMap, dirs: &[Vec3], frame: LatLongFrame) -> Vec<f32> {
    dirs.iter()
        .flat_map(|d| map.nearest(frame.to_conventions(*d)).to_array())
        .collect()
}

/// Probulator's radiance RMSE of a fit against the map it was fitted to (see the module docs):
/// `sqrt(mean over texel centres of mean over RGB of (fit − texel)²)`, unweighted by solid
/// angle, with the fit clamped at 0 when `clamp_negative` (Probulator clamps SH and ambient
/// dice, not SG). `coefficients` are `basis.len()` rows of RGB; basis directions are in
/// `frame`. Accumulated in f64.
///
/// Errors: a coefficient count other than `3 · basis.len()`, a non-finite coefficient (named
/// by index). An HDR texel of `1e6` is fine; the map itself is finite by construction.
pub fn radiance_rmse<B: SphericalBasis + ?Sized>(
    map: &LatLongMap,
    basis: &B,
    coefficients: &[f32],
    clamp_negative: bool,
    frame: LatLongFrame,
) -> Result<f64, PlsqError> {
    let k = basis.len();
    if coefficients.len() != 3 * k {
        return Err(PlsqError::LengthMismatch {
            what: "RGB coefficients",
            expected: 3 * k,
            got: coefficients.len(),
        });
    }
    PlsqError::check_finite("coefficient", coefficients)?;
    let mut b = vec![0.0f32; k];
    let mut sum = 0.0f64;
    for y in 0..map.height() {
        for x in 0..map.width() {
            basis.eval(frame.from_conventions(map.direction(x, y)), &mut b);
            let truth = map.texel(x, y).to_array();
            let mut texel = 0.0f64;
            for c in 0..3 {
                let mut v = 0.0f32;
                for i in 0..k {
                    v += b[i] * coefficients[3 * i + c];
                }
                if clamp_negative {
                    v = v.max(0.0);
                }
                texel += (v as f64 - truth[c] as f64).powi(2);
            }
            sum += texel / 3.0;
        }
    }
    Ok((sum / (map.width() * map.height()) as f64).sqrt())
}
