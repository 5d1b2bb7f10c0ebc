//! Incident radiance at a texel: a path tracer over prt-trace's scene and ray tracer.

use std::f32::consts::{PI, TAU};

use glam::Vec3;
use prt_trace::manylight::SunAndUniformSky;
use prt_trace::scene::LightKind;
use prt_trace::{Hit, RayTracer, Scene};

/// Sobol' dimensions of the texel ray: its direction.
const TEXEL_DIMS: u32 = 2;
/// Sobol' dimensions per bounce: emitter choice (1), point on it (2), cosine direction (2).
const BOUNCE_DIMS: u32 = 5;
/// Most diffuse bounces (the Sobol' tables have 256 dimensions).
pub(crate) const MAX_BOUNCES: u32 = (256 - TEXEL_DIMS) / BOUNCE_DIMS;

/// The light of a bake: the scene's emitters and punctual lights, and optionally a sun and sky.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Lighting {
    /// A sun (a directional light: texels add it in closed form, as the punctual lights) and a
    /// constant sky over the upper (+Y) hemisphere; `None` for the scene's own lights only.
    pub sun_sky: Option<SunAndUniformSky>,
}

impl Lighting {
    /// The scene's lights, plus [`SunAndUniformSky::default`] when it has no emitter and no
    /// punctual light (the rule of [`prt_trace::manylight::trace_vpls`]).
    pub fn for_scene(scene: &Scene) -> Self {
        let emits = (0..scene.triangles().len())
            .any(|t| scene.material_of(t).emissive.max_element() > 0.0)
            || !scene.lights().is_empty();
        Self {
            sun_sky: (!emits).then(SunAndUniformSky::default),
        }
    }
}

/// One radiance sample of a texel.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Sample {
    /// Direction in the texel's tangent frame (+Y the normal).
    pub local: Vec3,
    /// Incident radiance (RGB).
    pub radiance: Vec3,
}

pub(crate) struct Transport<'a> {
    scene: &'a Scene,
    tracer: &'a RayTracer,
    lighting: Lighting,
    bounces: u32,
    eps: f32,
    /// Emissive triangles and the cumulative distribution over their power.
    emitters: Vec<(usize, f32)>,
    emitter_total: f32,
}

fn luminance(c: Vec3) -> f32 {
    c.dot(Vec3::new(0.2126, 0.7152, 0.0722))
}

fn area(t: &[Vec3; 3]) -> f32 {
    0.5 * (t[1] - t[0]).cross(t[2] - t[0]).length()
}

impl<'a> Transport<'a> {
    pub fn new(scene: &'a Scene, tracer: &'a RayTracer, lighting: Lighting, bounces: u32) -> Self {
        let mut emitters = Vec::new();
        let mut acc = 0.0;
        for (t, tri) in scene.triangles().iter().enumerate() {
            let power = luminance(scene.material_of(t).emissive) * area(tri);
            if power > 0.0 && power.is_finite() {
                acc += power;
                emitters.push((t, acc));
            }
        }
        let extent = scene.bounds().map_or(1.0, |b| (b.max - b.min).length());
        Self {
            scene,
            tracer,
            lighting,
            bounces,
            eps: 1e-4 * extent.max(1e-3),
            emitters,
            emitter_total: acc,
        }
    }

    /// Whether any light is a delta in direction (the sun, `KHR_lights_punctual` lights): see
    /// [`Self::texel_deltas`].
    pub fn has_delta_lights(&self) -> bool {
        !self.scene.lights().is_empty() || self.sun().is_some()
    }

    /// The sun: direction towards it and its irradiance, if it shines.
    fn sun(&self) -> Option<(Vec3, Vec3)> {
        self.lighting
            .sun_sky
            .filter(|s| s.sun_irradiance.max_element() > 0.0)
            .map(|s| (-s.sun_direction.normalize_or(Vec3::NEG_Y), s.sun_irradiance))
    }

    /// The sun and the punctual lights that reach `point` above the horizon of `normal`
    /// unoccluded, as [`Self::punctual_direct`] gives them: the lights a texel's hemisphere
    /// samples cannot find (the sun's 0.27° disk would be found by one sample in 10⁵, with
    /// 10⁵ times the sky's radiance, which the progressive encoders cannot average out).
    pub(crate) fn texel_deltas(
        &self,
        point: Vec3,
        normal: Vec3,
        mut arrive: impl FnMut(Vec3, Vec3),
    ) {
        if let Some((towards, irradiance)) = self.sun()
            && normal.dot(towards) > 0.0
            && !self
                .tracer
                .occluded(point + normal * self.eps, towards, 0.0, f32::INFINITY)
        {
            arrive(towards, irradiance);
        }
        self.punctual_direct(point, normal, arrive);
    }

    /// The offset that keeps ray origins off surfaces (1e-4 of the scene's diagonal).
    pub fn eps(&self) -> f32 {
        self.eps
    }

    /// One sample of the texel at `position` with unit `normal`; `u(dim)` gives the sample's
    /// Sobol' coordinates.
    pub fn sample(&self, position: Vec3, normal: Vec3, u: &dyn Fn(u32) -> f32) -> Sample {
        let (tangent, bitangent) = tangent_frame(normal);
        let to_world = |l: Vec3| tangent * l.x + normal * l.y + bitangent * l.z;
        let to_local = |d: Vec3| Vec3::new(d.dot(tangent), d.dot(normal), d.dot(bitangent));
        let cos_theta = u(0);
        let sin_theta = (1.0 - cos_theta * cos_theta).max(0.0).sqrt();
        let phi = TAU * u(1);
        let dir = to_world(Vec3::new(
            sin_theta * phi.cos(),
            cos_theta,
            sin_theta * phi.sin(),
        ));
        let origin = position + normal * self.eps;
        let radiance = self.radiance(origin, dir, u);
        Sample {
            local: to_local(dir).normalize(),
            radiance,
        }
    }

    /// Radiance arriving at `origin` from `dir` (emission and sky seen directly, and up to
    /// `bounces` diffuse reflections with next-event estimation; the sun and punctual lights
    /// only after a bounce, see [`Self::texel_deltas`]).
    fn radiance(&self, mut origin: Vec3, mut dir: Vec3, u: &dyn Fn(u32) -> f32) -> Vec3 {
        let mut total = Vec3::ZERO;
        let mut throughput = Vec3::ONE;
        for depth in 0..=self.bounces {
            let Some(hit) = self.tracer.closest_hit(origin, dir, 0.0, f32::INFINITY) else {
                total += throughput * self.sky(dir);
                break;
            };
            let material = self.scene.material_of(hit.triangle as usize);
            if !hit.front_face && !material.double_sided {
                break;
            }
            // Emitters hit after a bounce are counted by next-event estimation instead.
            if depth == 0 && hit.front_face {
                total += material.emissive;
            }
            if depth == self.bounces {
                break;
            }
            throughput *= material.albedo;
            if throughput.max_element() <= 0.0 {
                break;
            }
            let normal = facing_normal(&hit);
            let point = origin + dir * hit.t + normal * self.eps;
            let base = TEXEL_DIMS + BOUNCE_DIMS * depth;
            total += throughput * self.direct_irradiance(point, normal, |d| u(base + d)) / PI;
            dir = cosine_hemisphere(normal, u(base + 3), u(base + 4));
            origin = point;
        }
        total
    }

    fn sky(&self, dir: Vec3) -> Vec3 {
        match self.lighting.sun_sky {
            Some(s) if dir.y > 0.0 => s.sky_radiance,
            _ => Vec3::ZERO,
        }
    }

    /// The light of every `KHR_lights_punctual` light that reaches `point` above the horizon of
    /// `normal` unoccluded (shadow rays leave from one ray offset above `point`): `arrive(towards, irradiance)` with the unit direction towards the
    /// light and the irradiance on a surface facing it. These are deltas in direction, which no
    /// hemisphere sample finds, so texels add them in closed form (`crate::punctual`) and
    /// bounces by next-event estimation.
    ///
    /// Conventions of the extension: point and spot intensity in candela (`I / d²`), spot cones
    /// with its smooth falloff (the square of a linear ramp in the cosine from the outer to the
    /// inner cone), `range` with its recommended window `clamp(1 − (d / range)⁴, 0, 1)`;
    /// directional lights in lux.
    pub(crate) fn punctual_direct(
        &self,
        point: Vec3,
        normal: Vec3,
        mut arrive: impl FnMut(Vec3, Vec3),
    ) {
        let origin = point + normal * self.eps;
        for light in self.scene.lights() {
            let intensity = light.color * light.intensity;
            if !intensity.is_finite() || intensity.max_element() <= 0.0 {
                continue;
            }
            let spot = match light.kind {
                LightKind::Directional => {
                    let towards = -light.direction.normalize_or(Vec3::NEG_Z);
                    if normal.dot(towards) > 0.0
                        && !self.tracer.occluded(origin, towards, 0.0, f32::INFINITY)
                    {
                        arrive(towards, intensity);
                    }
                    continue;
                }
                LightKind::Point => None,
                LightKind::Spot {
                    inner_cone_angle,
                    outer_cone_angle,
                } => Some((inner_cone_angle.cos(), outer_cone_angle.cos())),
                _ => continue,
            };
            let d = light.position - point;
            let dist2 = d.length_squared();
            if dist2 <= 0.0 {
                continue;
            }
            let dist = dist2.sqrt();
            let towards = d / dist;
            if normal.dot(towards) <= 0.0 {
                continue;
            }
            let cone = spot.map_or(1.0, |(cos_inner, cos_outer)| {
                let c = (-towards).dot(light.direction.normalize_or(Vec3::NEG_Z));
                let ramp = ((c - cos_outer) / (cos_inner - cos_outer).max(1e-3)).clamp(0.0, 1.0);
                ramp * ramp
            });
            let window = light
                .range
                .map_or(1.0, |r| (1.0 - (dist / r).powi(4)).clamp(0.0, 1.0));
            if cone * window > 0.0
                && !self
                    .tracer
                    .occluded(origin, towards, 0.0, dist * (1.0 - 1e-4))
            {
                arrive(towards, intensity * (cone * window / dist2));
            }
        }
    }

    /// Irradiance at `point` (normal `normal`) from the sun, one emissive triangle chosen by
    /// power, and every punctual light, with shadow rays.
    fn direct_irradiance(&self, point: Vec3, normal: Vec3, u: impl Fn(u32) -> f32) -> Vec3 {
        let mut e = Vec3::ZERO;
        if let Some(s) = self.lighting.sun_sky {
            let towards = -s.sun_direction.normalize_or(Vec3::NEG_Y);
            let cos = normal.dot(towards);
            if cos > 0.0 && !self.tracer.occluded(point, towards, 0.0, f32::INFINITY) {
                e += s.sun_irradiance * cos;
            }
        }
        self.punctual_direct(point, normal, |towards, arriving| {
            e += arriving * normal.dot(towards);
        });
        if self.emitter_total > 0.0 {
            let pick = u(0) * self.emitter_total;
            let k = self
                .emitters
                .partition_point(|&(_, c)| c <= pick)
                .min(self.emitters.len() - 1);
            let t = self.emitters[k].0;
            let p_pick = (self.emitters[k].1 - if k > 0 { self.emitters[k - 1].1 } else { 0.0 })
                / self.emitter_total;
            let tri = &self.scene.triangles()[t];
            let (mut b1, mut b2) = (u(1), u(2));
            if b1 + b2 > 1.0 {
                (b1, b2) = (1.0 - b1, 1.0 - b2);
            }
            let y = tri[0] + (tri[1] - tri[0]) * b1 + (tri[2] - tri[0]) * b2;
            let light_normal = (tri[1] - tri[0]).cross(tri[2] - tri[0]).normalize_or_zero();
            let d = y - point;
            let dist2 = d.length_squared();
            if dist2 > 0.0 {
                let dist = dist2.sqrt();
                let towards = d / dist;
                let (cos_x, cos_y) = (normal.dot(towards), -light_normal.dot(towards));
                if cos_x > 0.0
                    && cos_y > 0.0
                    && !self
                        .tracer
                        .occluded(point, towards, 0.0, dist * (1.0 - 1e-3))
                {
                    let emission = self.scene.material_of(t).emissive;
                    e += emission * (cos_x * cos_y / dist2 * area(tri) / p_pick);
                }
            }
        }
        e
    }
}

/// The tangent and bitangent of a texel's frame (+Y the normal), in which its coefficients lie.
pub(crate) fn tangent_frame(normal: Vec3) -> (Vec3, Vec3) {
    normal.any_orthonormal_pair()
}

fn facing_normal(hit: &Hit) -> Vec3 {
    if hit.front_face {
        hit.normal
    } else {
        -hit.normal
    }
}

/// Cosine-weighted direction about `n` (pdf `cos θ / π`).
fn cosine_hemisphere(n: Vec3, u1: f32, u2: f32) -> Vec3 {
    let r = u1.sqrt();
    let phi = TAU * u2;
    let (t, b) = n.any_orthonormal_pair();
    (t * (r * phi.cos()) + b * (r * phi.sin()) + n * (1.0 - u1).max(0.0).sqrt()).normalize()
}
