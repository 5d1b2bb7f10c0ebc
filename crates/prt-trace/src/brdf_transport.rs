//! Per-pixel light transport against the bins of an editable half-angle BRDF curve, for BRDF
//! editing under fixed view and lighting (Ben-Artzi, Overbeck and Ramamoorthi, "Real-time BRDF
//! editing in complex lighting", SIGGRAPH 2006).
//!
//! The surface seen through pixel `p` (position `x`, normal `n`, direction to the eye `v`,
//! albedo `a`) has the BRDF `ρ(ω, v) = a/π + f(θ_h) / (4 max(n·ω, n·v))`, with `θ_h` the angle
//! between `n` and the half vector `normalize(ω + v)` and `f` a curve of `bins` constant bins
//! over `θ_h ∈ [0, π/2)` (bin `b` covers `[b, b+1) · π / (2 bins)`, the bins whose centres
//! `prt_wavelet::brdf::beckmann_curve` samples). The denominator is Ashikhmin and Shirley's
//! `4 (h·ω) max(n·ω, n·v)` without the `h·ω` factor: bounded at grazing angles, and a
//! distribution `f` normalised over projected half-vector area reflects about its integral.
//! Under distant lighting `L` (a cube map) the pixel's radiance is
//! `I_p = D_p + Σ_b T_p[b] f[b]`: a diffuse part `D_p = a/π ∫ L V (n·ω) dω` and a glossy part
//! linear in the curve, with the transport
//! `T_p[b] = Σ_{ω : θ_h(ω, v) in bin b} L(ω) V(ω) (n·ω) / (4 max(n·ω, n·v)) dω`
//! summed over [`CubeRays`] sub-samples. Lighting is RGB, so `T_p` is RGB; the glossy lobe is
//! not tinted by the albedo (a dielectric's highlight has the light's colour).

use glam::Vec3;
use prt_core::Progress;
use rayon::prelude::*;

use crate::camera::GBuffer;
use crate::cube::CubeRays;
use crate::{RayTracer, TraceError};

/// Options of [`trace_half_angle_transport`].
#[derive(Debug, Clone, PartialEq)]
pub struct HalfAngleOptions {
    /// Bins of the curve over `θ_h ∈ [0, π/2)`.
    pub bins: usize,
    /// Shadow-ray offset along the normal, in scene units (a small fraction of the scene size).
    pub offset: f32,
}

impl Default for HalfAngleOptions {
    fn default() -> Self {
        Self {
            bins: 256,
            offset: 1e-4,
        }
    }
}

/// The traced transport of every pixel of a G-buffer; pixels without a gather point are zero.
#[derive(Debug, Clone, PartialEq)]
pub struct HalfAngleTransport {
    /// Pixels (width × height of the G-buffer).
    pub pixels: usize,
    /// Curve bins.
    pub bins: usize,
    /// `glossy[(p · 3 + c) · bins + b] = T_p[b]` in channel `c`.
    pub glossy: Vec<f32>,
    /// `diffuse[p · 3 + c] = D_p` in channel `c`.
    pub diffuse: Vec<f32>,
}

impl HalfAngleTransport {
    /// Bytes of a transport of `pixels` pixels and `bins` bins (f32 storage).
    pub fn bytes(pixels: usize, bins: usize) -> usize {
        pixels * 3 * (bins + 1) * size_of::<f32>()
    }

    /// The image `I_p = D_p + Σ_b T_p[b] curve[b]`, pixel-major RGB, accumulated in f64.
    /// Errors if `curve` does not have [`Self::bins`] samples.
    pub fn image(&self, curve: &[f32]) -> Result<Vec<f32>, TraceError> {
        if curve.len() != self.bins {
            return Err(TraceError::InvalidOption {
                what: "BRDF curve",
                why: format!("{} samples for {} bins", curve.len(), self.bins),
            });
        }
        Ok(self
            .glossy
            .chunks_exact(self.bins)
            .zip(&self.diffuse)
            .map(|(row, &d)| {
                let glossy: f64 = row
                    .iter()
                    .zip(curve)
                    .map(|(&t, &f)| t as f64 * f as f64)
                    .sum();
                (d as f64 + glossy) as f32
            })
            .collect())
    }
}

/// The bin of a half-angle `θ_h` (radians) among `bins` bins over `[0, π/2)`, clamped.
pub fn half_angle_bin(theta_h: f32, bins: usize) -> usize {
    ((theta_h / std::f32::consts::FRAC_PI_2 * bins as f32).max(0.0) as usize).min(bins - 1)
}

/// Traces the diffuse and half-angle-binned glossy transport of every pixel of `gbuffer`
/// (viewed from `eye`) under the RGB cube-map lighting `lighting` (planar,
/// `lighting[c · texels + t]` in [`CubeRays`]' texel order), in parallel over pixels.
/// Each pixel accumulates in f64 in texel order, so the result is the same on any thread count.
///
/// Errors: [`TraceError::InvalidOption`] for zero bins, a lighting buffer that is not
/// `3 × rays.texels()` long, or a non-finite or negative texel (named); cancellation through
/// `progress` (which counts pixels).
pub fn trace_half_angle_transport(
    tracer: &RayTracer,
    gbuffer: &GBuffer,
    eye: Vec3,
    rays: &CubeRays,
    lighting: &[f32],
    options: &HalfAngleOptions,
    progress: &dyn Progress,
) -> Result<HalfAngleTransport, TraceError> {
    let bins = options.bins;
    let texels = rays.texels();
    if bins == 0 || lighting.len() != 3 * texels {
        return Err(TraceError::InvalidOption {
            what: "half-angle transport",
            why: format!(
                "{bins} bins and {} lighting values for 3 × {texels} texels",
                lighting.len()
            ),
        });
    }
    if let Some(i) = lighting.iter().position(|v| !(v.is_finite() && *v >= 0.0)) {
        return Err(TraceError::InvalidOption {
            what: "lighting",
            why: format!(
                "texel {} of channel {} is {} (must be finite and non-negative)",
                i % texels,
                i / texels,
                lighting[i]
            ),
        });
    }
    let pixels = gbuffer.points.len();
    progress.set_len(pixels as u64);
    let rows: Vec<(Vec<f32>, [f32; 3])> = gbuffer
        .points
        .par_iter()
        .map_init(
            || vec![[0.0f64; 3]; bins],
            |acc, point| {
                progress.check()?;
                let mut glossy = vec![0.0f32; 3 * bins];
                let mut diffuse = [0.0f32; 3];
                if let Some(g) = point {
                    acc.fill([0.0; 3]);
                    let mut irradiance = [0.0f64; 3];
                    let v = (eye - g.position).normalize_or_zero();
                    let n_v = g.normal.dot(v).max(0.0);
                    rays.trace(
                        tracer,
                        g.position,
                        g.normal,
                        options.offset,
                        |t, dir, omega| {
                            let n_w = g.normal.dot(dir);
                            let light =
                                [lighting[t], lighting[texels + t], lighting[2 * texels + t]];
                            let cos_weight = (n_w * omega) as f64;
                            let h = (dir + v).normalize_or_zero();
                            let theta_h = g.normal.dot(h).clamp(-1.0, 1.0).acos();
                            let glossy_weight = cos_weight / (4.0 * n_w.max(n_v) as f64);
                            let bin = &mut acc[half_angle_bin(theta_h, bins)];
                            for c in 0..3 {
                                irradiance[c] += cos_weight * light[c] as f64;
                                bin[c] += glossy_weight * light[c] as f64;
                            }
                        },
                    );
                    for c in 0..3 {
                        diffuse[c] =
                            (irradiance[c] * g.albedo[c] as f64 * std::f64::consts::FRAC_1_PI)
                                as f32;
                        for (b, a) in acc.iter().enumerate() {
                            glossy[c * bins + b] = a[c] as f32;
                        }
                    }
                }
                progress.inc(1);
                Ok((glossy, diffuse))
            },
        )
        .collect::<Result<_, TraceError>>()?;
    let mut glossy = Vec::with_capacity(pixels * 3 * bins);
    let mut diffuse = Vec::with_capacity(pixels * 3);
    for (g, d) in rows {
        glossy.extend_from_slice(&g);
        diffuse.extend_from_slice(&d);
    }
    Ok(HalfAngleTransport {
        pixels,
        bins,
        glossy,
        diffuse,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Scene;
    use crate::camera::GatherPoint;
    use prt_core::NoProgress;

    fn single_point(normal: Vec3) -> GBuffer {
        GBuffer {
            width: 1,
            height: 1,
            points: vec![Some(GatherPoint {
                position: Vec3::ZERO,
                normal,
                albedo: Vec3::new(0.5, 0.25, 1.0),
                emission: Vec3::ZERO,
            })],
        }
    }

    #[test]
    fn constant_light_on_an_open_point_reflects_the_albedo() {
        let tracer = RayTracer::new(&[]);
        let rays = CubeRays::new(8, 2).unwrap();
        let lighting = vec![1.0; 3 * rays.texels()];
        let options = HalfAngleOptions::default();
        let transport = trace_half_angle_transport(
            &tracer,
            &single_point(Vec3::Y),
            Vec3::new(0.3, 1.0, 0.1),
            &rays,
            &lighting,
            &options,
            &NoProgress,
        )
        .unwrap();
        // D = a/π · ∫ cos = a (up to the sub-samples straddling the horizon).
        for (d, a) in transport.diffuse.iter().zip([0.5, 0.25, 1.0]) {
            assert!((d - a).abs() < 0.01 * a, "{d} vs {a}");
        }
        // A constant curve: ∫ cos / (4 max(n·ω, n·v)) dω lies between π/4 (n·v = 1) and π/2,
        // less the horizon sub-samples.
        let total: f32 = transport.glossy[..options.bins].iter().sum();
        let quarter_pi = std::f32::consts::FRAC_PI_4;
        assert!(
            (0.99 * quarter_pi..2.0 * quarter_pi).contains(&total),
            "{total}"
        );
        // RGB rows are equal under white light; the image is D + Σ T f.
        assert_eq!(transport.glossy[..256], transport.glossy[256..512]);
        let image = transport.image(&vec![2.0; 256]).unwrap();
        assert!((image[0] - (transport.diffuse[0] + 2.0 * total)).abs() < 1e-5);
        assert!(transport.image(&[1.0; 3]).is_err());
    }

    #[test]
    fn mirror_direction_lands_in_the_first_bins() {
        // One lit texel straight above a point seen from straight above: θ_h ≈ 0.
        let tracer = RayTracer::new(&[]);
        let rays = CubeRays::new(4, 2).unwrap();
        let n2 = 16;
        let mut lighting = vec![0.0; 3 * rays.texels()];
        for c in 0..3 {
            for t in [5, 6, 9, 10] {
                lighting[c * rays.texels() + 2 * n2 + t] = 1.0;
            }
        }
        let transport = trace_half_angle_transport(
            &tracer,
            &single_point(Vec3::Y),
            Vec3::new(0.0, 5.0, 0.0),
            &rays,
            &lighting,
            &HalfAngleOptions {
                bins: 16,
                offset: 1e-4,
            },
            &NoProgress,
        )
        .unwrap();
        let row = &transport.glossy[..16];
        // The four centre texels of +Y span about ±27° around the normal: θ_h < 14°, bins 0..3.
        assert!(row[..3].iter().sum::<f32>() > 0.0);
        assert!(row[3..].iter().all(|&v| v == 0.0), "{row:?}");
    }

    #[test]
    fn rejects_bad_lighting_and_is_cancellable() {
        let scene = Scene::cornell_box();
        let tracer = RayTracer::new(scene.triangles());
        let rays = CubeRays::new(2, 1).unwrap();
        let gbuffer = single_point(Vec3::Y);
        let options = HalfAngleOptions::default();
        let mut lighting = vec![1.0; 3 * rays.texels()];
        let run = |l: &[f32]| {
            trace_half_angle_transport(&tracer, &gbuffer, Vec3::Y, &rays, l, &options, &NoProgress)
        };
        assert!(run(&lighting).is_ok());
        let cancelled = prt_core::AtomicProgress::new();
        cancelled.cancel();
        let result = trace_half_angle_transport(
            &tracer,
            &gbuffer,
            Vec3::Y,
            &rays,
            &lighting,
            &options,
            &cancelled,
        );
        assert!(result.is_err_and(|e| e.is_cancelled()));
        assert!(run(&lighting[1..]).is_err());
        lighting[30] = f32::NAN;
        let err = run(&lighting).unwrap_err().to_string();
        assert!(err.contains("texel 6 of channel 1"), "{err}");
    }

    #[test]
    fn bins_clamp_at_both_ends() {
        assert_eq!(half_angle_bin(0.0, 256), 0);
        assert_eq!(half_angle_bin(-0.1, 256), 0);
        assert_eq!(half_angle_bin(std::f32::consts::FRAC_PI_2, 256), 255);
        assert_eq!(half_angle_bin(std::f32::consts::FRAC_PI_4, 256), 128);
    }
}
