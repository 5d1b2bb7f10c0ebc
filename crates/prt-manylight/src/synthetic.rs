use std::sync::atomic::{AtomicU64, Ordering};

use prt_core::{CoreError, MatrixOracle};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

use crate::{GatherGeometry, SliceOracle, VisibilityOracle};

/// A procedural pixels × lights matrix with the structure of a virtual-point-light matrix, for
/// tests and benchmarks without a ray tracer: non-negative RGB elements, columns that cluster
/// (lights on the same wall light the image alike), a few very bright lights, lights that reach
/// no pixel (zero columns), and hard shadows.
///
/// The scene is the unit box. Pixel `i = x + width · y` is a point of the floor (`y = 0`,
/// normal +Y) at `((x + ½)/width, 0, (y + ½)/height)` with a checkerboard albedo. The lights are
/// oriented point lights: about 0.1% (at least 4) bright ones just below the ceiling facing
/// down (the "primary" lights), the rest dim and coloured on the left (red), right (green), back
/// and ceiling (white) walls, and 10% on the floor itself, which reach no pixel. A sphere of
/// radius 0.18 at `(0.5, 0.3, 0.5)` (movable with [`SyntheticVplOracle::with_occluder`]) casts
/// shadows. Element `(i, j)` is
/// `albedo_i / π · Φ_j · cos θ_i cos θ_j / max(d², 0.01) · V(i, j)`.
#[derive(Debug)]
pub struct SyntheticVplOracle {
    width: usize,
    height: usize,
    lights: Vec<Light>,
    occluder: [f32; 3],
    evaluated: AtomicU64,
}

#[derive(Debug, Clone, Copy)]
struct Light {
    position: [f32; 3],
    normal: [f32; 3],
    flux: [f32; 3],
}

const OCCLUDER_CENTRE: [f32; 3] = [0.5, 0.3, 0.5];
const OCCLUDER_RADIUS: f32 = 0.18;
/// Lower bound of the squared distance: the usual VPL clamp against the 1/d² singularity.
const MIN_DISTANCE_SQ: f32 = 0.01;

impl SyntheticVplOracle {
    /// A `width × height` image lit by `lights` lights placed with `seed`.
    pub fn new(width: usize, height: usize, lights: usize, seed: u64) -> Self {
        let mut rng = Pcg64Mcg::seed_from_u64(seed);
        let bright = if lights == 0 {
            0
        } else {
            (lights / 1000).max(4).min(lights)
        };
        let dim = lights - bright;
        let mut list = Vec::with_capacity(lights);
        for _ in 0..bright {
            let (u, v): (f32, f32) = (rng.random(), rng.random());
            let flux = 2.0 / bright as f32;
            list.push(Light {
                position: [0.35 + 0.3 * u, 0.98, 0.35 + 0.3 * v],
                normal: [0.0, -1.0, 0.0],
                flux: [flux, 0.9 * flux, 0.75 * flux],
            });
        }
        let share = 6.0 / dim.max(1) as f32;
        for _ in 0..dim {
            let (u, v): (f32, f32) = (rng.random(), rng.random());
            let light = match rng.random_range(0..10u32) {
                0..=2 => Light {
                    position: [0.0, v, u],
                    normal: [1.0, 0.0, 0.0],
                    flux: [share, 0.15 * share, 0.1 * share],
                },
                3..=5 => Light {
                    position: [1.0, v, u],
                    normal: [-1.0, 0.0, 0.0],
                    flux: [0.1 * share, share, 0.15 * share],
                },
                6..=7 => Light {
                    position: [u, v, 1.0],
                    normal: [0.0, 0.0, -1.0],
                    flux: [0.8 * share; 3],
                },
                8 => Light {
                    position: [u, 1.0, v],
                    normal: [0.0, -1.0, 0.0],
                    flux: [0.8 * share; 3],
                },
                _ => Light {
                    position: [u, 0.0, v],
                    normal: [0.0, 1.0, 0.0],
                    flux: [0.8 * share; 3],
                },
            };
            list.push(light);
        }
        Self {
            width,
            height,
            lights: list,
            occluder: OCCLUDER_CENTRE,
            evaluated: AtomicU64::new(0),
        }
    }

    /// The same image and lights with the occluding sphere moved to `centre`: the frames of an
    /// animation (a moving object) share their lights, as tensor clustering expects.
    pub fn with_occluder(self, centre: [f32; 3]) -> Self {
        Self {
            occluder: centre,
            ..self
        }
    }

    /// Resets the element counter.
    pub fn reset_count(&self) {
        self.evaluated.store(0, Ordering::Relaxed);
    }

    /// Light `j` after checking both indices.
    fn checked(&self, i: usize, j: usize) -> Result<&Light, CoreError> {
        if i >= self.rows() {
            return Err(CoreError::OutOfRange {
                what: "oracle row",
                index: i,
                len: self.rows(),
            });
        }
        self.lights.get(j).ok_or(CoreError::OutOfRange {
            what: "oracle column",
            index: j,
            len: self.cols(),
        })
    }

    /// Position and albedo of pixel `i`.
    fn pixel(&self, i: usize) -> ([f32; 3], [f32; 3]) {
        let (x, y) = (i % self.width, i / self.width);
        let p = [
            (x as f32 + 0.5) / self.width as f32,
            0.0,
            (y as f32 + 0.5) / self.height as f32,
        ];
        let checker = ((p[0] * 8.0) as usize + (p[2] * 8.0) as usize).is_multiple_of(2);
        let albedo = if checker {
            [0.8, 0.8, 0.8]
        } else {
            [0.6, 0.5, 0.4]
        };
        (p, albedo)
    }

    /// The element `(pixel, light)` into `out` (3 channels).
    #[inline]
    fn element(&self, p: [f32; 3], albedo: [f32; 3], light: &Light, out: &mut [f32]) {
        if Self::shading(p, albedo, light, out) && self.occluded(p, Self::to_light(p, light)) {
            out.fill(0.0);
        }
    }

    fn to_light(p: [f32; 3], light: &Light) -> [f32; 3] {
        [
            light.position[0] - p[0],
            light.position[1] - p[1],
            light.position[2] - p[2],
        ]
    }

    /// The unshadowed element into `out`; whether it is non-zero.
    #[inline]
    fn shading(p: [f32; 3], albedo: [f32; 3], light: &Light, out: &mut [f32]) -> bool {
        let w = Self::to_light(p, light);
        // The receiver's normal is +Y, so cos θ_i = w.y / d.
        let d2 = w[0] * w[0] + w[1] * w[1] + w[2] * w[2];
        let cos_light = -(light.normal[0] * w[0] + light.normal[1] * w[1] + light.normal[2] * w[2]);
        if w[1] <= 0.0 || cos_light <= 0.0 || d2 <= 0.0 {
            out.fill(0.0);
            return false;
        }
        let g = w[1] * cos_light / (d2 * d2.max(MIN_DISTANCE_SQ));
        for c in 0..3 {
            out[c] = albedo[c] * std::f32::consts::FRAC_1_PI * light.flux[c] * g;
        }
        true
    }

    /// Whether the segment `p → p + w` passes through the occluding sphere.
    #[inline]
    fn occluded(&self, p: [f32; 3], w: [f32; 3]) -> bool {
        let o = [
            p[0] - self.occluder[0],
            p[1] - self.occluder[1],
            p[2] - self.occluder[2],
        ];
        let ww = w[0] * w[0] + w[1] * w[1] + w[2] * w[2];
        let t = (-(o[0] * w[0] + o[1] * w[1] + o[2] * w[2]) / ww).clamp(0.0, 1.0);
        let q = [o[0] + t * w[0], o[1] + t * w[1], o[2] + t * w[2]];
        q[0] * q[0] + q[1] * q[1] + q[2] * q[2] < OCCLUDER_RADIUS * OCCLUDER_RADIUS
    }
}

impl MatrixOracle for SyntheticVplOracle {
    fn rows(&self) -> usize {
        self.width * self.height
    }

    fn cols(&self) -> usize {
        self.lights.len()
    }

    fn channels(&self) -> usize {
        3
    }

    fn eval_row(&self, i: usize, out: &mut [f32]) -> Result<(), CoreError> {
        if i >= self.rows() {
            return Err(CoreError::OutOfRange {
                what: "oracle row",
                index: i,
                len: self.rows(),
            });
        }
        if out.len() != self.cols() * 3 {
            return Err(CoreError::LengthMismatch {
                what: "oracle row output",
                expected: self.cols() * 3,
                got: out.len(),
            });
        }
        let (p, albedo) = self.pixel(i);
        for (light, element) in self.lights.iter().zip(out.chunks_exact_mut(3)) {
            self.element(p, albedo, light, element);
        }
        self.evaluated
            .fetch_add(self.cols() as u64, Ordering::Relaxed);
        Ok(())
    }

    fn eval_col(&self, j: usize, out: &mut [f32]) -> Result<(), CoreError> {
        let Some(light) = self.lights.get(j) else {
            return Err(CoreError::OutOfRange {
                what: "oracle column",
                index: j,
                len: self.cols(),
            });
        };
        if out.len() != self.rows() * 3 {
            return Err(CoreError::LengthMismatch {
                what: "oracle column output",
                expected: self.rows() * 3,
                got: out.len(),
            });
        }
        for (i, element) in out.chunks_exact_mut(3).enumerate() {
            let (p, albedo) = self.pixel(i);
            self.element(p, albedo, light, element);
        }
        self.evaluated
            .fetch_add(self.rows() as u64, Ordering::Relaxed);
        Ok(())
    }

    fn elements_evaluated(&self) -> u64 {
        self.evaluated.load(Ordering::Relaxed)
    }
}

impl VisibilityOracle for SyntheticVplOracle {
    fn shading(&self, i: usize, j: usize, out: &mut [f32]) -> Result<(), CoreError> {
        let light = self.checked(i, j)?;
        if out.len() != 3 {
            return Err(CoreError::LengthMismatch {
                what: "shading output",
                expected: 3,
                got: out.len(),
            });
        }
        let (p, albedo) = self.pixel(i);
        Self::shading(p, albedo, light, out);
        Ok(())
    }

    fn visibility(&self, i: usize, j: usize) -> Result<f32, CoreError> {
        let light = self.checked(i, j)?;
        let (p, _) = self.pixel(i);
        Ok(if self.occluded(p, Self::to_light(p, light)) {
            0.0
        } else {
            1.0
        })
    }
}

impl SliceOracle for SyntheticVplOracle {
    /// Evaluates only the requested rows (counting `rows.len()` elements).
    fn eval_col_rows(&self, j: usize, rows: &[usize], out: &mut [f32]) -> Result<(), CoreError> {
        let Some(light) = self.lights.get(j) else {
            return Err(CoreError::OutOfRange {
                what: "oracle column",
                index: j,
                len: self.cols(),
            });
        };
        if let Some(&bad) = rows.iter().find(|&&i| i >= self.rows()) {
            return Err(CoreError::OutOfRange {
                what: "oracle row",
                index: bad,
                len: self.rows(),
            });
        }
        if out.len() != rows.len() * 3 {
            return Err(CoreError::LengthMismatch {
                what: "oracle column rows output",
                expected: rows.len() * 3,
                got: out.len(),
            });
        }
        for (&i, element) in rows.iter().zip(out.chunks_exact_mut(3)) {
            let (p, albedo) = self.pixel(i);
            self.element(p, albedo, light, element);
        }
        self.evaluated
            .fetch_add(rows.len() as u64, Ordering::Relaxed);
        Ok(())
    }

    /// The floor point of pixel `i`, normal +Y.
    fn gather_point(&self, i: usize) -> Option<GatherGeometry> {
        (i < self.rows()).then(|| GatherGeometry {
            position: self.pixel(i).0,
            normal: [0.0, 1.0, 0.0],
        })
    }
}
