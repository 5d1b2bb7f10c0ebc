//! Irradiance that is never negative: SH ringing and reconstruction error removed per voxel
//! before an engine sees it.

use glam::Vec3;
use prt_trace::LitVolume;
use prt_trace::expert::CLAMPED_COSINE;
use prt_trace::sh::{SH9, sh9};

use crate::ExportError;

/// A volume whose irradiance is non-negative in every test direction, and how many voxel
/// channels were changed to make it so.
#[derive(Debug, Clone, PartialEq)]
pub struct NonNegative {
    /// The volume; voxels that needed no change are bit-identical.
    pub volume: LitVolume,
    /// Voxel colour channels whose bands 1–2 were scaled down.
    pub scaled: usize,
    /// Voxel colour channels whose mean irradiance was not positive, set to zero.
    pub zeroed: usize,
}

/// Directions in which [`remove_negative_light`] checks the irradiance: the six axes (the
/// ambient cube's sides), the eight cube diagonals and a spherical Fibonacci set of 242.
pub fn test_directions() -> Vec<Vec3> {
    let mut out = vec![Vec3::X, -Vec3::X, Vec3::Y, -Vec3::Y, Vec3::Z, -Vec3::Z];
    for corner in 0..8 {
        let s = |bit: usize| if corner >> bit & 1 == 1 { 1.0 } else { -1.0 };
        out.push(Vec3::new(s(0), s(1), s(2)).normalize());
    }
    let n = 242;
    let golden = std::f32::consts::PI * (3.0 - 5f32.sqrt());
    for i in 0..n {
        let y = 1.0 - (i as f32 + 0.5) * 2.0 / n as f32;
        let r = (1.0 - y * y).max(0.0).sqrt();
        let phi = golden * i as f32;
        out.push(Vec3::new(r * phi.cos(), y, r * phi.sin()));
    }
    out
}

/// Makes every voxel's irradiance non-negative (a windowing of the SH, as deringing does):
/// per voxel and colour channel, `E(n) = E₀ + r(n)` splits into the constant band-0 term and
/// the rest; where `min r < −E₀` over [`test_directions`], bands 1 and 2 are scaled by
/// `E₀ / −min r` (less 10⁻⁵ of it), which keeps the mean and the dominant direction and lifts the minimum to 0;
/// a channel with `E₀ ≤ 0` has no light to keep and is zeroed. Validity is unchanged.
pub fn remove_negative_light(volume: &LitVolume) -> Result<NonNegative, ExportError> {
    volume.check()?;
    // Irradiance is Σ_j A_j Y_j(n) c_j (Ramamoorthi & Hanrahan): one row of A_j Y_j per
    // direction, so each check is a dot product.
    let rows: Vec<[f32; SH9]> = test_directions()
        .into_iter()
        .map(|n| {
            let y = sh9(n);
            std::array::from_fn(|j| CLAMPED_COSINE[j] * y[j])
        })
        .collect();
    let mut out = volume.clone();
    let (mut scaled, mut zeroed) = (0, 0);
    for l in &mut out.radiance {
        for channel in l.iter_mut() {
            let e0 = rows[0][0] * channel[0];
            let rest_min = rows
                .iter()
                .map(|row| (1..SH9).map(|j| row[j] * channel[j]).sum::<f32>())
                .fold(f32::INFINITY, f32::min);
            if e0 <= 0.0 {
                if channel.iter().any(|&c| c != 0.0) {
                    *channel = [0.0; SH9];
                    zeroed += 1;
                }
            } else if rest_min < -e0 {
                // A hair below the exact factor, so that rounding leaves no tiny negatives.
                let s = e0 / -rest_min * (1.0 - 1e-5);
                channel[1..].iter_mut().for_each(|c| *c *= s);
                scaled += 1;
            }
        }
    }
    Ok(NonNegative {
        volume: out,
        scaled,
        zeroed,
    })
}
