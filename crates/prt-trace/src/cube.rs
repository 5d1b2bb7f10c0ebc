//! Shadow rays from a surface point towards the texels of a cube map of distant light: the
//! directional sampling under per-pixel and per-vertex wavelet transport (Ng, Ramamoorthi and
//! Hanrahan 2003), where a transport row has one entry per lighting texel.
//!
//! Texels follow `prt-sphere`'s cube conventions and `prt-wavelet`'s planar order: faces +X, −X,
//! +Y, −Y, +Z, −Z ([`prt_sphere::envmap::cube_to_direction`]), texel `face · n² + y · n + x`
//! with face coordinate `a` from the column `x` and `b` from the row `y`. Each texel is split
//! into `samples × samples` equal sub-rectangles of its face; a sub-sample's direction is the
//! sub-rectangle's centre and its weight the sub-rectangle's exact solid angle, so the weights of
//! a texel sum to the texel's solid angle and those of the whole map to 4π.

use glam::Vec3;
use prt_sphere::envmap::{cube_rect_solid_angle, cube_to_direction};

use crate::{RayTracer, TraceError};

/// Sub-sample directions and solid angles of every texel of a `6 × size × size` cube map.
#[derive(Debug, Clone, PartialEq)]
pub struct CubeRays {
    size: usize,
    samples: usize,
    /// `samples²` entries per texel, texel-major.
    directions: Vec<Vec3>,
    solid_angles: Vec<f32>,
}

impl CubeRays {
    /// The largest `size × samples` (sub-samples along a face edge): 2048 gives 25 million
    /// rays per point, far beyond any transport row prt builds.
    pub const MAX_SUBDIVISION: usize = 2048;

    /// Sub-samples of a cube map with `size × size` faces, `samples × samples` per texel.
    ///
    /// Errors: [`TraceError::InvalidOption`] for a zero size or sample count, or
    /// `size × samples` above [`Self::MAX_SUBDIVISION`].
    pub fn new(size: usize, samples: usize) -> Result<Self, TraceError> {
        let fine = size.saturating_mul(samples);
        if size == 0 || samples == 0 || fine > Self::MAX_SUBDIVISION {
            return Err(TraceError::InvalidOption {
                what: "cube rays",
                why: format!(
                    "{size} × {size} faces with {samples} × {samples} samples per texel; \
                     both must be at least 1 and size × samples at most {}",
                    Self::MAX_SUBDIVISION
                ),
            });
        }
        let per_texel = samples * samples;
        let count = 6 * size * size * per_texel;
        let mut directions = Vec::with_capacity(count);
        let mut solid_angles = Vec::with_capacity(count);
        let edge = |i: usize| 2.0 * i as f64 / fine as f64 - 1.0;
        for face in 0..6 {
            for y in 0..size {
                for x in 0..size {
                    for sy in 0..samples {
                        let fy = y * samples + sy;
                        for sx in 0..samples {
                            let fx = x * samples + sx;
                            let a = 0.5 * (edge(fx) + edge(fx + 1));
                            let b = 0.5 * (edge(fy) + edge(fy + 1));
                            directions.push(cube_to_direction(face, a, b));
                            solid_angles.push(cube_rect_solid_angle(
                                edge(fx),
                                edge(fx + 1),
                                edge(fy),
                                edge(fy + 1),
                            ) as f32);
                        }
                    }
                }
            }
        }
        Ok(Self {
            size,
            samples,
            directions,
            solid_angles,
        })
    }

    /// Texels along a face edge.
    pub fn size(&self) -> usize {
        self.size
    }

    /// Sub-samples along a texel edge.
    pub fn samples(&self) -> usize {
        self.samples
    }

    /// Texels of the whole map, `6 · size²`: the length of a transport row.
    pub fn texels(&self) -> usize {
        6 * self.size * self.size
    }

    /// Calls `visit(texel, direction, solid_angle)` for every sub-sample direction `ω` above
    /// the surface (`normal · ω > 0`) whose shadow ray from `position + offset · normal` reaches
    /// the distant light unoccluded. `normal` must be unit length and face the side being lit;
    /// `offset` (a small fraction of the scene size) keeps the ray off its own surface.
    /// Directions are visited in texel order.
    pub fn trace(
        &self,
        tracer: &RayTracer,
        position: Vec3,
        normal: Vec3,
        offset: f32,
        mut visit: impl FnMut(usize, Vec3, f32),
    ) {
        let origin = position + normal * offset;
        let per_texel = self.samples * self.samples;
        for (k, (&dir, &omega)) in self.directions.iter().zip(&self.solid_angles).enumerate() {
            if normal.dot(dir) > 0.0 && !tracer.occluded(origin, dir, 0.0, f32::INFINITY) {
                visit(k / per_texel, dir, omega);
            }
        }
    }

    /// The diffuse transport row of a point: `row[t] = (1/π) ∫_texel V(ω) max(0, n · ω) dω`,
    /// so that a white Lambertian surface under lighting `L` reflects `Σ_t row[t] L[t]`. The
    /// row sums to at most 1 (an unoccluded point under unit light). `row` must hold
    /// [`Self::texels`] entries; it is overwritten.
    pub fn diffuse_row(
        &self,
        tracer: &RayTracer,
        position: Vec3,
        normal: Vec3,
        offset: f32,
        row: &mut [f32],
    ) {
        assert_eq!(row.len(), self.texels(), "transport row length");
        row.fill(0.0);
        self.trace(tracer, position, normal, offset, |t, dir, omega| {
            row[t] += normal.dot(dir) * omega * std::f32::consts::FRAC_1_PI;
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use prt_sphere::envmap::direction_to_cube;

    #[test]
    fn weights_sum_to_the_sphere() {
        for (size, samples) in [(1, 1), (4, 3), (16, 1)] {
            let rays = CubeRays::new(size, samples).unwrap();
            let total: f64 = rays.solid_angles.iter().map(|&w| w as f64).sum();
            assert!((total - 4.0 * std::f64::consts::PI).abs() < 1e-5, "{total}");
        }
    }

    #[test]
    fn rejects_empty_and_huge_maps() {
        assert!(CubeRays::new(0, 1).is_err());
        assert!(CubeRays::new(4, 0).is_err());
        assert!(CubeRays::new(1024, 4).is_err());
        assert!(CubeRays::new(usize::MAX, 2).is_err());
    }

    #[test]
    fn unoccluded_diffuse_row_integrates_the_cosine() {
        let tracer = RayTracer::new(&[]);
        let rays = CubeRays::new(8, 4).unwrap();
        let mut row = vec![0.0; rays.texels()];
        let normal = Vec3::new(0.3, 0.9, -0.2).normalize();
        rays.diffuse_row(&tracer, Vec3::ZERO, normal, 1e-4, &mut row);
        let total: f32 = row.iter().sum();
        // Only the sub-samples straddling the horizon are misweighted.
        assert!((total - 1.0).abs() < 1e-2, "{total}");
        assert!(row.iter().all(|&v| v >= 0.0));
    }

    #[test]
    fn a_roof_blocks_the_sky() {
        let roof = [
            [
                Vec3::new(-10.0, 1.0, -10.0),
                Vec3::new(10.0, 1.0, -10.0),
                Vec3::new(10.0, 1.0, 10.0),
            ],
            [
                Vec3::new(-10.0, 1.0, -10.0),
                Vec3::new(10.0, 1.0, 10.0),
                Vec3::new(-10.0, 1.0, 10.0),
            ],
        ];
        let tracer = RayTracer::new(&roof);
        let rays = CubeRays::new(8, 2).unwrap();
        let mut row = vec![0.0; rays.texels()];
        rays.diffuse_row(&tracer, Vec3::ZERO, Vec3::Y, 1e-4, &mut row);
        let total: f32 = row.iter().sum();
        // The roof subtends all but a thin band at the horizon.
        assert!(total > 0.0 && total < 0.02, "{total}");
        // Nothing comes through the +Y face.
        let n2 = 64;
        assert!(row[2 * n2..3 * n2].iter().all(|&v| v == 0.0));
    }

    proptest! {
        #[test]
        fn every_sub_sample_lies_in_its_texel(size in 1usize..9, samples in 1usize..4) {
            let rays = CubeRays::new(size, samples).unwrap();
            let per_texel = samples * samples;
            for (k, &dir) in rays.directions.iter().enumerate() {
                let texel = k / per_texel;
                let (face, s, t) = direction_to_cube(dir);
                let x = ((s * size as f64) as usize).min(size - 1);
                let y = ((t * size as f64) as usize).min(size - 1);
                prop_assert_eq!(face * size * size + y * size + x, texel);
            }
        }
    }
}
