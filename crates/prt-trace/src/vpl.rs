//! The many-light scene side: virtual point lights by particle tracing, a pinhole view with a
//! G-buffer of gather points, and the pixel × light matrix as a [`MatrixOracle`].
//!
//! Instant radiosity (Keller 1997) as used by matrix row-column sampling (Hašan et al. 2007):
//! particles leave the emitters carrying `Φ / (N p)` of their power, and every surface they
//! reach stores a VPL with the *reflected* flux `ρ Φ`; the particle continues along a
//! cosine-distributed direction with that flux. A VPL radiates as a Lambertian emitter of flux
//! `Φ_j` (radiant intensity `Φ_j cos θ / π`), so element `(i, j)` is
//!
//! `ρ_i/π · Φ_j/π · max(0, n_i·ω) · max(0, -n_j·ω) / max(d², c²) · V(x_i, y_j)`
//!
//! with `ω = (y_j - x_i)/d`, the clamp distance `c` bounding the `1/d²` singularity, and `V` a
//! shadow ray. (Hašan's notes fold the second `1/π` into the VPL's flux; here the stored flux is
//! the physical one, so the emitter VPLs sum to the emitters' power.)
//!
//! Sun, sky and glTF directional lights have no position, so particle tracing can only leave
//! VPLs where they first hit (their *indirect* light). Their *direct* light enters the matrix as
//! [`DirectionalLight`] columns ([`directional_lights`], [`VplOracle::with_directional`]), as
//! Hašan et al. 2007 do for their sun-and-sky scenes: the sun one light, the sky many
//! directions, each of element `ρ_i/π · E_j · max(0, n_i·(−d_j)) · V(x_i, −d_j)`.

use std::f32::consts::{PI, TAU};
use std::sync::atomic::{AtomicU64, Ordering};

use glam::Vec3;
use prt_core::{Aabb, CoreError, MatrixOracle, Progress};
use prt_manylight::{GatherGeometry, SliceOracle, VisibilityOracle};
use rayon::prelude::*;

use crate::camera::{GBuffer, GatherPoint};
use crate::sampling::{cosine_hemisphere, hash_seed};
use crate::scene::LightKind;
use crate::{RayTracer, Scene, TraceError};

/// A virtual point light: an oriented point that radiates its flux like a Lambertian emitter.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Vpl {
    /// World-space position.
    pub position: Vec3,
    /// Unit normal of the side it radiates from (zero for an isotropic point light's VPL).
    pub normal: Vec3,
    /// Radiated flux (linear RGB).
    pub flux: Vec3,
    /// Diffuse albedo of the surface it lies on (zero for punctual lights).
    pub albedo: Vec3,
    /// Number of bounces before it (0: on an emitter).
    pub bounce: u32,
}

/// Sun and sky that light scenes without emitters or punctual lights: a sun at infinity and a
/// sky of one radiance over the upper hemisphere, what VPL emission and the sky's directional
/// lights sample. ([`prt_sphere::SunSky`] is an analytic sky with a gradient and a ground for SH
/// lighting of bakes.)
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SunAndUniformSky {
    /// Unit direction the sunlight travels (from the sun into the scene).
    pub sun_direction: Vec3,
    /// Irradiance on a surface facing the sun (linear RGB).
    pub sun_irradiance: Vec3,
    /// Constant radiance of the upper (+Y) sky hemisphere (linear RGB).
    pub sky_radiance: Vec3,
}

impl Default for SunAndUniformSky {
    fn default() -> Self {
        Self {
            sun_direction: Vec3::new(0.3, -1.0, 0.2).normalize(),
            sun_irradiance: Vec3::new(3.0, 2.9, 2.6),
            sky_radiance: Vec3::new(0.15, 0.2, 0.3),
        }
    }
}

/// A light at infinity: parallel light travelling along `direction` with irradiance `irradiance`
/// on a surface facing it. One column of the [`VplOracle`] matrix (direct sun or sky light).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DirectionalLight {
    /// Unit direction the light travels (from the light into the scene).
    pub direction: Vec3,
    /// Irradiance on a surface facing the light (linear RGB).
    pub irradiance: Vec3,
}

/// The direct light of the scene's lights at infinity as [`DirectionalLight`]s: its glTF
/// directional lights (irradiance = colour × intensity), and, for a scene with neither emissive
/// triangles nor punctual lights (the case where [`trace_vpls`] uses `sun_sky`), the sun as one
/// light and the sky as `sky_directions` lights. Sky directions are stratified over the upper
/// (+Y) hemisphere in equal solid angles (a grid in `cos θ` and `φ`, each cell's centre); each
/// carries `L · 2π / K`, so a horizontal surface open to the sky receives `π L`, the exact
/// irradiance, up to the grid's quadrature error. Emissive triangles and point lights need no
/// entry (their direct light is the emitter VPLs); a zero sun or sky gives no light for it.
///
/// Errors: [`TraceError::EmptyScene`] for a scene without triangles, [`TraceError::InvalidOption`]
/// for a non-finite `sun_sky`.
pub fn directional_lights(
    scene: &Scene,
    sun_sky: &SunAndUniformSky,
    sky_directions: usize,
) -> Result<Vec<DirectionalLight>, TraceError> {
    let bounds = scene.bounds().ok_or(TraceError::EmptyScene)?;
    let finite = sun_sky.sun_direction.is_finite()
        && sun_sky.sun_irradiance.is_finite()
        && sun_sky.sky_radiance.is_finite();
    if !finite {
        return Err(TraceError::InvalidOption {
            what: "sun and sky",
            why: format!("{sun_sky:?} is not finite"),
        });
    }
    // The sun and sky light the scene exactly when `trace_vpls` falls back to them: no emissive
    // triangle and no punctual light among its sources.
    let uses_sun_sky = sources(scene, &bounds, sun_sky)
        .iter()
        .all(|s| !matches!(s, Source::Triangle { .. }))
        && !scene.lights().iter().any(|l| {
            let intensity = l.color * l.intensity;
            intensity.is_finite() && intensity.max_element() > 0.0
        });
    let mut out: Vec<DirectionalLight> = scene
        .lights()
        .iter()
        .filter(|l| matches!(l.kind, LightKind::Directional))
        .map(|l| DirectionalLight {
            direction: l.direction.normalize_or(Vec3::NEG_Y),
            irradiance: l.color * l.intensity,
        })
        .filter(|l| l.irradiance.is_finite() && l.irradiance.max_element() > 0.0)
        .collect();
    if !uses_sun_sky {
        return Ok(out);
    }
    if sun_sky.sun_irradiance.max_element() > 0.0 {
        out.push(DirectionalLight {
            direction: sun_sky.sun_direction.normalize_or(Vec3::NEG_Y),
            irradiance: sun_sky.sun_irradiance,
        });
    }
    if sun_sky.sky_radiance.max_element() > 0.0 && sky_directions > 0 {
        // A near-square grid: `rings` bands of equal height in cos θ, `sectors` in φ.
        let rings = ((sky_directions as f64 / 2.0).sqrt().round() as usize).max(1);
        let sectors = sky_directions.div_ceil(rings);
        let count = rings * sectors;
        let irradiance = sun_sky.sky_radiance * (TAU / count as f32);
        for r in 0..rings {
            let cos_theta = (r as f32 + 0.5) / rings as f32;
            let sin_theta = (1.0 - cos_theta * cos_theta).max(0.0).sqrt();
            for k in 0..sectors {
                let phi = TAU * (k as f32 + 0.5) / sectors as f32;
                let from = Vec3::new(sin_theta * phi.cos(), cos_theta, sin_theta * phi.sin());
                out.push(DirectionalLight {
                    direction: -from,
                    irradiance,
                });
            }
        }
    }
    Ok(out)
}

/// Options of [`trace_vpls`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VplOptions {
    /// Number of particles (light paths) emitted; each yields up to `max_bounces + 1` VPLs.
    pub particles: usize,
    /// Surface hits a particle may make after leaving its source (0: emitter VPLs only).
    pub max_bounces: u32,
    /// Seed: the same seed gives the same VPLs on any thread count.
    pub seed: u64,
    /// Light used when the scene has neither emissive triangles nor punctual lights.
    pub sun_sky: SunAndUniformSky,
}

impl Default for VplOptions {
    fn default() -> Self {
        Self {
            particles: 10_000,
            max_bounces: 2,
            seed: 0,
            sun_sky: SunAndUniformSky::default(),
        }
    }
}

/// One light source with its total power (linear RGB).
#[derive(Debug, Clone, Copy)]
enum Source {
    /// An emissive triangle radiating from its front face.
    Triangle { index: usize, power: Vec3 },
    /// A point or spot light (cone half-angle `cos_outer`, -1 for a point light).
    Point {
        position: Vec3,
        direction: Vec3,
        cos_outer: f32,
        power: Vec3,
    },
    /// Parallel light of direction `direction` crossing the scene's bounding sphere.
    Directional { direction: Vec3, power: Vec3 },
    /// A constant upper-hemisphere sky crossing the scene's bounding sphere.
    Sky { power: Vec3 },
}

impl Source {
    fn power(&self) -> Vec3 {
        match *self {
            Source::Triangle { power, .. }
            | Source::Point { power, .. }
            | Source::Directional { power, .. }
            | Source::Sky { power } => power,
        }
    }
}

fn luminance(c: Vec3) -> f64 {
    f64::from(0.2126 * c.x + 0.7152 * c.y + 0.0722 * c.z)
}

fn triangle_area(t: &[Vec3; 3]) -> f32 {
    0.5 * (t[1] - t[0]).cross(t[2] - t[0]).length()
}

/// Uniform in `[0, 1)` from `(seed, particle, dimension)`: a pure function, so particles can be
/// traced in any order on any number of threads.
fn uniform(seed: u64, particle: u64, dim: u64) -> f32 {
    (hash_seed(seed, particle, dim) >> 8) as f32 * (1.0 / 16_777_216.0)
}

fn uniform_sphere(u1: f32, u2: f32) -> Vec3 {
    let z = 1.0 - 2.0 * u1;
    let r = (1.0 - z * z).max(0.0).sqrt();
    Vec3::new(r * (TAU * u2).cos(), z, r * (TAU * u2).sin())
}

/// The scene's light sources: emissive triangles (front face, power `π A L_e`), punctual lights
/// (point `4π I`, spot `2π (1 - cos outer) I`, directional `E π R²` over the bounding sphere of
/// radius `R`), or, when there are none, the sun and sky of `sun_sky`.
fn sources(scene: &Scene, bounds: &Aabb, sun_sky: &SunAndUniformSky) -> Vec<Source> {
    let radius = 0.5 * (bounds.max - bounds.min).length();
    let disk = PI * radius * radius;
    let mut out = Vec::new();
    for (index, t) in scene.triangles().iter().enumerate() {
        let e = scene.material_of(index).emissive;
        if e.max_element() > 0.0 && e.is_finite() {
            out.push(Source::Triangle {
                index,
                power: e * (PI * triangle_area(t)),
            });
        }
    }
    for l in scene.lights() {
        let intensity = l.color * l.intensity;
        if !intensity.is_finite() || intensity.max_element() <= 0.0 {
            continue;
        }
        let direction = l.direction.normalize_or(Vec3::NEG_Y);
        out.push(match l.kind {
            LightKind::Directional => Source::Directional {
                direction,
                power: intensity * disk,
            },
            LightKind::Spot {
                outer_cone_angle, ..
            } => {
                let cos_outer = outer_cone_angle.cos();
                Source::Point {
                    position: l.position,
                    direction,
                    cos_outer,
                    power: intensity * (TAU * (1.0 - cos_outer)),
                }
            }
            _ => Source::Point {
                position: l.position,
                direction,
                cos_outer: -1.0,
                power: intensity * (4.0 * PI),
            },
        });
    }
    if out.is_empty() {
        let d = sun_sky.sun_direction.normalize_or(Vec3::NEG_Y);
        if sun_sky.sun_irradiance.max_element() > 0.0 {
            out.push(Source::Directional {
                direction: d,
                power: sun_sky.sun_irradiance * disk,
            });
        }
        if sun_sky.sky_radiance.max_element() > 0.0 {
            // Radiance L over the upper hemisphere through a disk of area πR² facing each ω.
            out.push(Source::Sky {
                power: sun_sky.sky_radiance * (disk * TAU),
            });
        }
    }
    out
}

/// Total power of the light sources [`trace_vpls`] emits from (linear RGB), for energy checks.
///
/// Errors: [`TraceError::EmptyScene`] for a scene without triangles.
pub fn emitted_power(scene: &Scene, sun_sky: &SunAndUniformSky) -> Result<Vec3, TraceError> {
    let bounds = scene.bounds().ok_or(TraceError::EmptyScene)?;
    Ok(sources(scene, &bounds, sun_sky)
        .iter()
        .map(Source::power)
        .sum())
}

/// Traces `options.particles` particles from the scene's emitters and returns the VPLs they
/// leave, in particle order (so a seed gives identical VPLs on any thread count).
///
/// Emitter VPLs (bounce 0) lie on emissive triangles and point lights; their fluxes sum to the
/// emitted power in expectation (exactly for a single emitter). Directional and sky light have no
/// position and a spot's cone is not a Lambertian or isotropic lobe, so they give no bounce-0
/// VPL: their first surface hit is the first VPL, which carries their indirect light. The direct
/// light of lights at infinity is added to the oracle as columns of its own
/// ([`directional_lights`], [`VplOracle::with_directional`]). A particle that hits the back of a
/// single-sided surface or leaves the scene stops.
///
/// Errors: [`TraceError::EmptyScene`] without triangles, [`TraceError::InvalidOption`] for zero
/// particles or a scene with no light at all (zero sun and sky and no emitters),
/// [`TraceError::Core`] when cancelled.
pub fn trace_vpls(
    scene: &Scene,
    tracer: &RayTracer,
    options: &VplOptions,
    progress: &dyn Progress,
) -> Result<Vec<Vpl>, TraceError> {
    let bounds = scene.bounds().ok_or(TraceError::EmptyScene)?;
    if options.particles == 0 {
        return Err(TraceError::InvalidOption {
            what: "particles",
            why: "zero particles".into(),
        });
    }
    let sources = sources(scene, &bounds, &options.sun_sky);
    let weights: Vec<f64> = sources.iter().map(|s| luminance(s.power())).collect();
    let total: f64 = weights.iter().sum();
    if !(total > 0.0 && total.is_finite()) {
        return Err(TraceError::InvalidOption {
            what: "light sources",
            why: format!("total emitted luminance is {total}"),
        });
    }
    let mut cdf = Vec::with_capacity(weights.len());
    let mut acc = 0.0;
    for w in &weights {
        acc += w / total;
        cdf.push(acc);
    }
    let centre = 0.5 * (bounds.min + bounds.max);
    let radius = (0.5 * (bounds.max - bounds.min).length()).max(1e-6);
    let eps = 1e-4 * 2.0 * radius;
    let n = options.particles;
    let tracer_ctx = ParticleContext {
        scene,
        tracer,
        sources: &sources,
        probabilities: &weights,
        total,
        cdf: &cdf,
        centre,
        radius,
        eps,
        particles: n as f32,
        options,
    };
    progress.set_len(n as u64);
    const CHUNK: usize = 1024;
    let chunks: Result<Vec<Vec<Vpl>>, TraceError> = (0..n.div_ceil(CHUNK))
        .into_par_iter()
        .map(|c| {
            progress.check()?;
            let mut out = Vec::new();
            let end = ((c + 1) * CHUNK).min(n);
            for k in c * CHUNK..end {
                tracer_ctx.trace(k as u64, &mut out);
            }
            progress.inc((end - c * CHUNK) as u64);
            Ok(out)
        })
        .collect();
    Ok(chunks?.into_iter().flatten().collect())
}

struct ParticleContext<'a> {
    scene: &'a Scene,
    tracer: &'a RayTracer,
    sources: &'a [Source],
    probabilities: &'a [f64],
    total: f64,
    cdf: &'a [f64],
    centre: Vec3,
    radius: f32,
    eps: f32,
    particles: f32,
    options: &'a VplOptions,
}

impl ParticleContext<'_> {
    fn trace(&self, k: u64, out: &mut Vec<Vpl>) {
        let seed = self.options.seed;
        let u = |dim: u64| uniform(seed, k, dim);
        let pick = f64::from(u(0));
        let s = self
            .cdf
            .partition_point(|&c| c <= pick)
            .min(self.sources.len() - 1);
        let p = self.probabilities[s] / self.total;
        let flux = self.sources[s].power() / (self.particles * p as f32);
        let (origin, dir) = match self.sources[s] {
            Source::Triangle { index, .. } => {
                let t = &self.scene.triangles()[index];
                let (mut b1, mut b2) = (u(1), u(2));
                if b1 + b2 > 1.0 {
                    (b1, b2) = (1.0 - b1, 1.0 - b2);
                }
                let pos = t[0] + b1 * (t[1] - t[0]) + b2 * (t[2] - t[0]);
                let normal = (t[1] - t[0]).cross(t[2] - t[0]).normalize();
                let material = self.scene.material_of(index);
                out.push(Vpl {
                    position: pos,
                    normal,
                    flux,
                    albedo: material.albedo,
                    bounce: 0,
                });
                (
                    pos + normal * self.eps,
                    cosine_hemisphere(normal, u(3), u(4)),
                )
            }
            Source::Point {
                position,
                direction,
                cos_outer,
                ..
            } => {
                // Uniform in the cone (the whole sphere for a point light).
                let z = 1.0 - u(3) * (1.0 - cos_outer);
                let r = (1.0 - z * z).max(0.0).sqrt();
                let (a, b) = direction.any_orthonormal_pair();
                let phi = TAU * u(4);
                let dir = (a * (r * phi.cos()) + b * (r * phi.sin()) + direction * z).normalize();
                // An isotropic point VPL represents a point light exactly; a spot's cone is not
                // representable by one, so spots only seed bounces.
                if cos_outer <= -1.0 {
                    out.push(Vpl {
                        position,
                        normal: Vec3::ZERO,
                        flux,
                        albedo: Vec3::ZERO,
                        bounce: 0,
                    });
                }
                (position, dir)
            }
            Source::Directional { direction, .. } => {
                (self.disk_origin(direction, u(3), u(4)), direction)
            }
            Source::Sky { .. } => {
                // Uniform over the upper hemisphere of directions the sky light comes from.
                let from = uniform_sphere(u(1), u(2));
                let dir = -Vec3::new(from.x, from.y.abs(), from.z);
                (self.disk_origin(dir, u(3), u(4)), dir)
            }
        };
        self.bounce(origin, dir, flux, k, out);
    }

    /// A uniform point on the disk of the bounding sphere's radius facing `dir`, behind the sphere.
    fn disk_origin(&self, dir: Vec3, u1: f32, u2: f32) -> Vec3 {
        let (a, b) = dir.any_orthonormal_pair();
        let r = self.radius * u1.sqrt();
        let phi = TAU * u2;
        self.centre - dir * (1.01 * self.radius) + a * (r * phi.cos()) + b * (r * phi.sin())
    }

    fn bounce(&self, mut origin: Vec3, mut dir: Vec3, mut flux: Vec3, k: u64, out: &mut Vec<Vpl>) {
        let seed = self.options.seed;
        for b in 0..self.options.max_bounces {
            let Some(hit) = self.tracer.closest_hit(origin, dir, 0.0, f32::INFINITY) else {
                return;
            };
            let material = self.scene.material_of(hit.triangle as usize);
            if !hit.front_face && !material.double_sided {
                return;
            }
            let normal = if hit.front_face {
                hit.normal
            } else {
                -hit.normal
            };
            let position = origin + dir * hit.t;
            flux *= material.albedo;
            if flux.max_element() <= 0.0 {
                return;
            }
            out.push(Vpl {
                position,
                normal,
                flux,
                albedo: material.albedo,
                bounce: b + 1,
            });
            let dim = 5 + 2 * u64::from(b);
            origin = position + normal * self.eps;
            dir = cosine_hemisphere(normal, uniform(seed, k, dim), uniform(seed, k, dim + 1));
        }
    }
}

/// One column's light: a VPL or a light at infinity.
#[derive(Debug, Clone, Copy)]
enum Light<'a> {
    Point(&'a Vpl),
    Directional(&'a DirectionalLight),
}

/// The pixel × VPL matrix (3 channels, RGB) of a G-buffer lit by VPLs, evaluated on demand with
/// shadow rays: element `(i, j) = ρ_i/π · Φ_j/π · max(0, n_i·ω) max(0, -n_j·ω) / max(d², c²) · V`
/// (an isotropic point-light VPL uses `1/4` for the second cosine, i.e. intensity `Φ/4π`).
/// After the VPLs come the [`DirectionalLight`] columns of [`VplOracle::with_directional`]
/// (none by default): `ρ_i/π · E_j · max(0, n_i·(−d_j)) · V`, the shadow ray leaving the scene.
/// Pixels without a gather point are zero rows. The matrix holds only light arriving through
/// VPLs: an emitter's own radiance seen directly by a pixel is not in it (add it to the image).
/// `eval_row` and `eval_col` run over rayon; every
/// element they return, and every element of [`VplOracle::reference_image`], is counted.
///
/// ```
/// use prt_core::{MatrixOracle, NoProgress};
/// use prt_trace::manylight::{VplOptions, VplOracle, trace_vpls};
/// use prt_trace::camera::{GBuffer, PinholeView};
/// use prt_trace::{RayTracer, Scene};
///
/// let scene = Scene::cornell_box();
/// let tracer = RayTracer::new(scene.triangles());
/// let options = VplOptions { particles: 200, max_bounces: 1, seed: 1, ..Default::default() };
/// let vpls = trace_vpls(&scene, &tracer, &options, &NoProgress)?;
/// let view = PinholeView::for_scene(&scene)?;
/// let gbuffer = GBuffer::render(&scene, &tracer, &view, 8, 8)?;
/// let oracle = VplOracle::new(&tracer, &gbuffer, &vpls, 0.1, 1e-4)?;
/// let mut column = vec![0.0; 3 * oracle.rows()];
/// oracle.eval_col(0, &mut column)?;
/// let image = oracle.reference_image(&NoProgress)?;
/// assert_eq!(image.len(), 3 * 64);
/// assert_eq!(oracle.elements_evaluated(), 64 + 64 * vpls.len() as u64);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
#[derive(Debug)]
pub struct VplOracle<'a> {
    tracer: &'a RayTracer,
    gather: &'a [Option<GatherPoint>],
    vpls: &'a [Vpl],
    directional: &'a [DirectionalLight],
    clamp2: f32,
    eps: f32,
    evaluated: AtomicU64,
}

impl<'a> VplOracle<'a> {
    /// An oracle over `gbuffer`'s pixels and `vpls`, with clamp distance `clamp` (the `1/d²`
    /// falloff is capped at `1/clamp²`) and shadow-ray offset `eps` along both normals.
    ///
    /// Errors: zero pixels or zero VPLs ([`CoreError::Empty`]); a non-finite or negative clamp
    /// or eps ([`CoreError::Invalid`]); a non-finite VPL or gather point ([`CoreError::NonFinite`]
    /// with its index).
    pub fn new(
        tracer: &'a RayTracer,
        gbuffer: &'a GBuffer,
        vpls: &'a [Vpl],
        clamp: f32,
        eps: f32,
    ) -> Result<Self, CoreError> {
        if gbuffer.points.is_empty() {
            return Err(CoreError::Empty { what: "pixels" });
        }
        if vpls.is_empty() {
            return Err(CoreError::Empty { what: "VPLs" });
        }
        if !(clamp.is_finite() && clamp >= 0.0 && eps.is_finite() && eps >= 0.0) {
            return Err(CoreError::Invalid {
                what: "oracle clamp or eps",
                why: format!("clamp {clamp}, eps {eps}"),
            });
        }
        let bad_vpl = vpls
            .iter()
            .position(|v| !(v.position.is_finite() && v.normal.is_finite() && v.flux.is_finite()));
        if let Some(index) = bad_vpl {
            return Err(CoreError::NonFinite { what: "VPL", index });
        }
        let bad_point = gbuffer.points.iter().position(|g| {
            g.is_some_and(|g| {
                !(g.position.is_finite() && g.normal.is_finite() && g.albedo.is_finite())
            })
        });
        if let Some(index) = bad_point {
            return Err(CoreError::NonFinite {
                what: "gather point",
                index,
            });
        }
        Ok(Self {
            tracer,
            gather: &gbuffer.points,
            vpls,
            directional: &[],
            clamp2: clamp * clamp,
            eps,
            evaluated: AtomicU64::new(0),
        })
    }

    /// The same oracle with the direct light of `lights` as extra columns after the VPLs
    /// (column `vpls.len() + k` is `lights[k]`), replacing any set before; see
    /// [`directional_lights`].
    ///
    /// Errors: a non-finite light or a zero direction ([`CoreError::NonFinite`] with its index).
    pub fn with_directional(self, lights: &'a [DirectionalLight]) -> Result<Self, CoreError> {
        let bad = lights.iter().position(|l| {
            !(l.direction.is_finite() && l.irradiance.is_finite() && l.direction != Vec3::ZERO)
        });
        if let Some(index) = bad {
            return Err(CoreError::NonFinite {
                what: "directional light",
                index,
            });
        }
        Ok(Self {
            directional: lights,
            ..self
        })
    }

    /// Number of VPL columns (the directional columns follow them).
    pub fn vpl_count(&self) -> usize {
        self.vpls.len()
    }

    /// Resets the element counter.
    pub fn reset_count(&self) {
        self.evaluated.store(0, Ordering::Relaxed);
    }

    /// The RGB contribution of VPL `j` to pixel `i` (not counted by the element counter):
    /// [`VplOracle::shading`] times [`VplOracle::visible`], the shadow ray traced only where the
    /// shading is non-zero.
    ///
    /// Errors: an index out of range ([`CoreError::OutOfRange`]), a non-finite result.
    pub fn element(&self, i: usize, j: usize) -> Result<Vec3, CoreError> {
        let shading = self.shading(i, j)?;
        if shading == Vec3::ZERO || self.visible(i, j)? {
            Ok(shading)
        } else {
            Ok(Vec3::ZERO)
        }
    }

    /// The unshadowed contribution of VPL `j` to pixel `i`: the element without its visibility
    /// term (no shadow ray; not counted).
    ///
    /// Errors: an index out of range ([`CoreError::OutOfRange`]), a non-finite result.
    pub fn shading(&self, i: usize, j: usize) -> Result<Vec3, CoreError> {
        let (g, light) = self.pair(i, j)?;
        let Some(g) = g else {
            return Ok(Vec3::ZERO);
        };
        let v = match light {
            Light::Point(v) => v,
            Light::Directional(l) => {
                let cos_i = -g.normal.dot(l.direction.normalize());
                if cos_i <= 0.0 {
                    return Ok(Vec3::ZERO);
                }
                return self.finite(i, j, g.albedo * l.irradiance * (cos_i / PI));
            }
        };
        let to = v.position - g.position;
        let d2 = to.length_squared();
        if d2 <= 0.0 {
            return Ok(Vec3::ZERO);
        }
        let w = to / d2.sqrt();
        let cos_i = g.normal.dot(w);
        // An isotropic (punctual) VPL has a zero normal and radiates Φ/(4π) in every direction.
        let cos_j = if v.normal == Vec3::ZERO {
            0.25
        } else {
            -v.normal.dot(w)
        };
        if cos_i <= 0.0 || cos_j <= 0.0 || g.albedo == Vec3::ZERO {
            return Ok(Vec3::ZERO);
        }
        let value = g.albedo * v.flux * (cos_i * cos_j / (PI * PI * d2.max(self.clamp2)));
        self.finite(i, j, value)
    }

    fn finite(&self, i: usize, j: usize, value: Vec3) -> Result<Vec3, CoreError> {
        if value.is_finite() {
            Ok(value)
        } else {
            Err(CoreError::NonFinite {
                what: "VPL oracle element",
                index: i * self.cols() + j,
            })
        }
    }

    /// Whether VPL `j` is visible from pixel `i`'s gather point (one shadow ray between the
    /// points offset by `eps` along their normals; false for a pixel without a gather point).
    ///
    /// Errors: an index out of range ([`CoreError::OutOfRange`]).
    pub fn visible(&self, i: usize, j: usize) -> Result<bool, CoreError> {
        let (g, light) = self.pair(i, j)?;
        let Some(g) = g else {
            return Ok(false);
        };
        let from = g.position + g.normal * self.eps;
        let v = match light {
            Light::Point(v) => v,
            Light::Directional(l) => {
                let towards = -l.direction.normalize();
                return Ok(!self.tracer.occluded(from, towards, 0.0, f32::INFINITY));
            }
        };
        let target = v.position + v.normal * self.eps;
        let seg = target - from;
        let len = seg.length();
        Ok(!(len > self.eps && self.tracer.occluded(from, seg / len, 0.0, len - self.eps)))
    }

    fn pair(&self, i: usize, j: usize) -> Result<(&Option<GatherPoint>, Light<'_>), CoreError> {
        let g = self.gather.get(i).ok_or(CoreError::OutOfRange {
            what: "oracle row",
            index: i,
            len: self.gather.len(),
        })?;
        let light = match self.vpls.get(j) {
            Some(v) => Light::Point(v),
            None => Light::Directional(self.directional.get(j - self.vpls.len()).ok_or(
                CoreError::OutOfRange {
                    what: "oracle column",
                    index: j,
                    len: self.cols(),
                },
            )?),
        };
        Ok((g, light))
    }

    /// The brute-force image: every element, parallel over pixels, summed per pixel in f64 in
    /// VPL order (identical on any thread count); `rows × 3` floats, RGB. Counts every element.
    ///
    /// Errors: a non-finite element, or [`CoreError::Cancelled`] through `progress`.
    pub fn reference_image(&self, progress: &dyn Progress) -> Result<Vec<f32>, CoreError> {
        progress.set_len(self.gather.len() as u64);
        let pixels: Result<Vec<[f32; 3]>, CoreError> = (0..self.gather.len())
            .into_par_iter()
            .map(|i| {
                progress.check()?;
                let mut sum = [0f64; 3];
                for j in 0..self.cols() {
                    let e = self.element(i, j)?;
                    for (s, c) in sum.iter_mut().zip(e.to_array()) {
                        *s += f64::from(c);
                    }
                }
                progress.inc(1);
                Ok(sum.map(|s| s as f32))
            })
            .collect();
        self.evaluated
            .fetch_add((self.gather.len() * self.cols()) as u64, Ordering::Relaxed);
        Ok(pixels?.into_iter().flatten().collect())
    }

    /// A fingerprint of everything an element depends on except the geometry behind the shadow
    /// rays: gather points, VPLs, directional lights, clamp and offset (FNV-1a over their bits).
    pub fn fingerprint(&self) -> u64 {
        let mut h = 0xcbf2_9ce4_8422_2325u64;
        let mut eat = |x: f32| {
            for b in x.to_bits().to_le_bytes() {
                h = (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3);
            }
        };
        eat(self.clamp2);
        eat(self.eps);
        for g in self.gather {
            match g {
                Some(g) => [g.position, g.normal, g.albedo]
                    .iter()
                    .flat_map(|v| v.to_array())
                    .for_each(&mut eat),
                None => eat(f32::NAN),
            }
        }
        for v in self.vpls {
            [v.position, v.normal, v.flux]
                .iter()
                .flat_map(|v| v.to_array())
                .for_each(&mut eat);
        }
        for l in self.directional {
            [l.direction, l.irradiance]
                .iter()
                .flat_map(|v| v.to_array())
                .for_each(&mut eat);
        }
        h
    }

    /// [`VplOracle::reference_image`] cached in the file `path`: read back when the file holds an
    /// image of this oracle's shape and [`VplOracle::fingerprint`] (then nothing is evaluated or
    /// counted), else computed and written. The geometry is not fingerprinted: use one file per
    /// scene.
    ///
    /// Errors: [`TraceError::Write`] when the file cannot be written, those of `reference_image`.
    pub fn reference_image_cached(
        &self,
        path: &std::path::Path,
        progress: &dyn Progress,
    ) -> Result<Vec<f32>, TraceError> {
        let header = [
            u64::from_le_bytes(*b"PRTVPLR1"),
            self.gather.len() as u64,
            self.cols() as u64,
            self.fingerprint(),
        ];
        let expected_len = 32 + 12 * self.gather.len();
        if let Ok(bytes) = std::fs::read(path) {
            let matches = bytes.len() == expected_len
                && bytes
                    .chunks_exact(8)
                    .zip(header)
                    .all(|(b, h)| b == h.to_le_bytes());
            if matches {
                return Ok(bytes[32..]
                    .chunks_exact(4)
                    .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                    .collect());
            }
        }
        let image = self.reference_image(progress)?;
        let mut bytes = Vec::with_capacity(expected_len);
        header
            .iter()
            .for_each(|h| bytes.extend_from_slice(&h.to_le_bytes()));
        image
            .iter()
            .for_each(|v| bytes.extend_from_slice(&v.to_le_bytes()));
        // Write-then-rename: an interrupted write never leaves a truncated cache behind.
        prt_texture::write_atomic(path, &bytes).map_err(|source| TraceError::Write {
            path: path.to_owned(),
            source,
        })?;
        Ok(image)
    }
}

impl MatrixOracle for VplOracle<'_> {
    fn rows(&self) -> usize {
        self.gather.len()
    }

    fn cols(&self) -> usize {
        self.vpls.len() + self.directional.len()
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
        if out.len() != 3 * self.cols() {
            return Err(CoreError::LengthMismatch {
                what: "oracle row output",
                expected: 3 * self.cols(),
                got: out.len(),
            });
        }
        out.par_chunks_mut(3)
            .with_min_len(256)
            .enumerate()
            .try_for_each(|(j, o)| {
                o.copy_from_slice(&self.element(i, j)?.to_array());
                Ok(())
            })?;
        self.evaluated
            .fetch_add(self.cols() as u64, Ordering::Relaxed);
        Ok(())
    }

    fn eval_col(&self, j: usize, out: &mut [f32]) -> Result<(), CoreError> {
        if j >= self.cols() {
            return Err(CoreError::OutOfRange {
                what: "oracle column",
                index: j,
                len: self.cols(),
            });
        }
        if out.len() != 3 * self.rows() {
            return Err(CoreError::LengthMismatch {
                what: "oracle column output",
                expected: 3 * self.rows(),
                got: out.len(),
            });
        }
        out.par_chunks_mut(3)
            .with_min_len(256)
            .enumerate()
            .try_for_each(|(i, o)| {
                o.copy_from_slice(&self.element(i, j)?.to_array());
                Ok(())
            })?;
        self.evaluated
            .fetch_add(self.rows() as u64, Ordering::Relaxed);
        Ok(())
    }

    fn elements_evaluated(&self) -> u64 {
        self.evaluated.load(Ordering::Relaxed)
    }
}

/// LightSlice reads columns on chosen rows and each pixel's geometry (its gather point).
impl SliceOracle for VplOracle<'_> {
    fn eval_col_rows(&self, j: usize, rows: &[usize], out: &mut [f32]) -> Result<(), CoreError> {
        out.par_chunks_mut(3)
            .zip(rows.par_iter())
            .with_min_len(64)
            .try_for_each(|(o, &i)| {
                o.copy_from_slice(&self.element(i, j)?.to_array());
                Ok(())
            })
    }

    fn gather_point(&self, i: usize) -> Option<GatherGeometry> {
        let g = self.gather.get(i).copied().flatten()?;
        Some(GatherGeometry {
            position: g.position.to_array(),
            normal: g.normal.to_array(),
        })
    }
}

/// Visibility clustering reads shading and visibility apart.
impl VisibilityOracle for VplOracle<'_> {
    fn shading(&self, i: usize, j: usize, out: &mut [f32]) -> Result<(), CoreError> {
        out.copy_from_slice(&VplOracle::shading(self, i, j)?.to_array());
        Ok(())
    }

    fn visibility(&self, i: usize, j: usize) -> Result<f32, CoreError> {
        Ok(if self.visible(i, j)? { 1.0 } else { 0.0 })
    }
}
