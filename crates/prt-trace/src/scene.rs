//! Scenes as flat world-space triangle lists with per-triangle materials, and their parts
//! (materials, punctual lights, glTF cameras): use it to build a scene or read what one holds.

use glam::{Mat4, Vec2, Vec3};
use prt_core::Aabb;

use crate::TraceError;

/// A diffuse material as the baker sees it.
#[derive(Debug, Clone, PartialEq)]
pub struct Material {
    /// Name from the file (or the built-in scene).
    pub name: String,
    /// Diffuse reflectance (linear RGB) used for the bounce: the base colour factor times the
    /// texture's mean, or times the scene's default albedo when a texture was not decoded.
    pub albedo: Vec3,
    /// Emitted radiance (linear RGB): emissive factor times `KHR_materials_emissive_strength`.
    /// Not used by the sky-transfer baker (emission is not sky light), kept for renderers.
    pub emissive: Vec3,
    /// Whether both faces reflect light. A single-sided surface is black from behind.
    pub double_sided: bool,
}

impl Material {
    /// A double-sided, non-emissive diffuse material.
    pub fn diffuse(name: &str, albedo: Vec3) -> Self {
        Self {
            name: name.to_owned(),
            albedo,
            emissive: Vec3::ZERO,
            double_sided: true,
        }
    }
}

/// A `KHR_lights_punctual` light placed in world space.
#[derive(Debug, Clone, PartialEq)]
pub struct PunctualLight {
    /// Name, if any.
    pub name: Option<String>,
    /// Kind of light.
    pub kind: LightKind,
    /// Linear RGB colour.
    pub color: Vec3,
    /// Intensity (candela for point and spot, lux for directional).
    pub intensity: f32,
    /// Range, if given.
    pub range: Option<f32>,
    /// World-space position (the node's translation).
    pub position: Vec3,
    /// World-space direction the light points to (the node's -Z axis).
    pub direction: Vec3,
}

/// Kinds of punctual light.
#[derive(Debug, Clone, Copy, PartialEq)]
#[non_exhaustive]
pub enum LightKind {
    /// A directional light.
    Directional,
    /// A point light.
    Point,
    /// A spot light with its cone angles (radians).
    Spot {
        /// Inner cone angle.
        inner_cone_angle: f32,
        /// Outer cone angle.
        outer_cone_angle: f32,
    },
}

/// A perspective camera placed in world space (orthographic cameras are skipped with a warning).
#[derive(Debug, Clone, PartialEq)]
pub struct Camera {
    /// Name, if any.
    pub name: Option<String>,
    /// Camera-to-world transform (the camera looks down its local -Z, +Y up).
    pub to_world: Mat4,
    /// Vertical field of view (radians).
    pub yfov: f32,
    /// Aspect ratio, if given.
    pub aspect_ratio: Option<f32>,
    /// Near plane distance.
    pub znear: f32,
}

/// A built-in part: name, albedo, vertices, triangle indices.
type Part<'a> = (&'a str, Vec3, &'a [[f32; 3]], &'a [u32]);

/// A scene: world-space triangles, one material index per triangle, lights, cameras.
///
/// Construction drops degenerate triangles (zero area, counted in
/// [`Scene::degenerate_dropped`]) and rejects non-finite positions with a typed error.
#[derive(Debug, Clone, Default)]
pub struct Scene {
    triangles: Vec<[Vec3; 3]>,
    material_ids: Vec<u32>,
    materials: Vec<Material>,
    lights: Vec<PunctualLight>,
    cameras: Vec<Camera>,
    degenerate_dropped: usize,
    warnings: Vec<String>,
    lightmap_uvs: Option<Vec<[Vec2; 3]>>,
}

/// Whether a triangle has (numerically) zero area relative to its size.
pub(crate) fn is_degenerate(t: &[Vec3; 3]) -> bool {
    let e1 = t[1] - t[0];
    let e2 = t[2] - t[0];
    let area2 = e1.cross(e2).length();
    let scale = e1
        .length_squared()
        .max(e2.length_squared())
        .max((t[2] - t[1]).length_squared());
    // Written so that a NaN area also counts as degenerate.
    area2.partial_cmp(&(1e-10 * scale)) != Some(std::cmp::Ordering::Greater)
}

impl Scene {
    /// A scene from triangles and their material indices.
    ///
    /// Errors: a non-finite position ([`TraceError::NonFinitePosition`] naming the triangle), a
    /// length mismatch or a material index out of range ([`TraceError::InvalidOption`]).
    /// Degenerate triangles are dropped and counted.
    pub fn from_triangles(
        triangles: Vec<[Vec3; 3]>,
        material_ids: Vec<u32>,
        materials: Vec<Material>,
    ) -> Result<Self, TraceError> {
        let mut scene = Self {
            materials,
            ..Self::default()
        };
        if material_ids.len() != triangles.len() {
            return Err(TraceError::InvalidOption {
                what: "material ids",
                why: format!(
                    "{} ids for {} triangles",
                    material_ids.len(),
                    triangles.len()
                ),
            });
        }
        for (i, (t, m)) in triangles.into_iter().zip(material_ids).enumerate() {
            if m as usize >= scene.materials.len() {
                return Err(TraceError::InvalidOption {
                    what: "material ids",
                    why: format!(
                        "triangle {i} uses material {m} of {}",
                        scene.materials.len()
                    ),
                });
            }
            scene.push_triangle(t, m, "triangles", i)?;
        }
        Ok(scene)
    }

    /// Adds one triangle (dropping it if degenerate).
    pub(crate) fn push_triangle(
        &mut self,
        t: [Vec3; 3],
        material: u32,
        what: &str,
        index: usize,
    ) -> Result<(), TraceError> {
        if !t.iter().all(|v| v.is_finite()) {
            return Err(TraceError::NonFinitePosition {
                what: what.to_owned(),
                triangle: index,
            });
        }
        if is_degenerate(&t) {
            self.degenerate_dropped += 1;
        } else {
            self.triangles.push(t);
            self.material_ids.push(material);
        }
        Ok(())
    }

    pub(crate) fn push_material(&mut self, m: Material) -> u32 {
        self.materials.push(m);
        (self.materials.len() - 1) as u32
    }

    pub(crate) fn push_light(&mut self, l: PunctualLight) {
        self.lights.push(l);
    }

    pub(crate) fn push_camera(&mut self, c: Camera) {
        self.cameras.push(c);
    }

    pub(crate) fn warn(&mut self, w: String) {
        self.warnings.push(w);
    }

    /// The empty scene: no triangles (open sky everywhere).
    pub fn empty() -> Self {
        Self::default()
    }

    /// The Cornell box of `../shared/scenes/cornell_box` (Morgan McGuire's "CornellBox-Original",
    /// Y up, floor at y = 0, ceiling at 1.99, open towards +Z; 32 triangles, 8 materials with the
    /// file's colours; the light is a quad just below the ceiling with emissive (1, 1, 1)).
    pub fn cornell_box() -> Self {
        let white = Vec3::new(0.725, 0.71, 0.68);
        let quad = [0u32, 1, 2, 0, 2, 3];
        // The file's two boxes differ only in the first quad's diagonal.
        let short_box = [
            0u32, 1, 2, 3, 0, 2, 4, 5, 6, 4, 6, 7, 8, 9, 10, 8, 10, 11, 12, 13, 14, 12, 14, 15, 16,
            17, 18, 16, 18, 19,
        ];
        let mut tall_box = short_box;
        tall_box[..6].copy_from_slice(&quad);
        #[rustfmt::skip]
        let parts: [Part<'_>; 8] = [
            ("floor", white, &[[1.0, 0.0, 0.99], [1.0, 0.0, -1.04], [-0.99, 0.0, -1.04], [-1.01, 0.0, 0.99]], &quad),
            ("ceiling", white, &[[-1.02, 1.99, 0.99], [-1.02, 1.99, -1.04], [1.0, 1.99, -1.04], [1.0, 1.99, 0.99]], &quad),
            ("backWall", white, &[[1.0, 0.0, -1.04], [1.0, 1.99, -1.04], [-1.02, 1.99, -1.04], [-0.99, 0.0, -1.04]], &quad),
            ("rightWall", Vec3::new(0.14, 0.45, 0.091), &[[1.0, 1.99, 0.99], [1.0, 1.99, -1.04], [1.0, 0.0, -1.04], [1.0, 0.0, 0.99]], &quad),
            ("leftWall", Vec3::new(0.63, 0.065, 0.05), &[[-1.01, 0.0, 0.99], [-0.99, 0.0, -1.04], [-1.02, 1.99, -1.04], [-1.02, 1.99, 0.99]], &quad),
            ("shortBox", white, &[
                [0.7, 0.6, 0.17], [0.13, 0.6, 0.0], [-0.05, 0.6, 0.57], [0.53, 0.6, 0.75],
                [-0.05, 0.6, 0.57], [0.13, 0.6, 0.0], [0.13, 0.0, 0.0], [-0.05, 0.0, 0.57],
                [0.53, 0.6, 0.75], [-0.05, 0.6, 0.57], [-0.05, 0.0, 0.57], [0.53, 0.0, 0.75],
                [0.7, 0.0, 0.17], [0.13, 0.0, 0.0], [0.13, 0.6, 0.0], [0.7, 0.6, 0.17],
                [0.53, 0.0, 0.75], [0.7, 0.0, 0.17], [0.7, 0.6, 0.17], [0.53, 0.6, 0.75],
            ], &short_box),
            ("tallBox", white, &[
                [0.04, 1.2, -0.09], [-0.14, 1.2, -0.67], [-0.71, 1.2, -0.49], [-0.53, 1.2, 0.09],
                [-0.53, 1.2, 0.09], [-0.71, 1.2, -0.49], [-0.71, 0.0, -0.49], [-0.53, 0.0, 0.09],
                [-0.71, 1.2, -0.49], [-0.14, 1.2, -0.67], [-0.14, 0.0, -0.67], [-0.71, 0.0, -0.49],
                [0.04, 0.0, -0.09], [-0.14, 0.0, -0.67], [-0.14, 1.2, -0.67], [0.04, 1.2, -0.09],
                [-0.53, 0.0, 0.09], [0.04, 0.0, -0.09], [0.04, 1.2, -0.09], [-0.53, 1.2, 0.09],
            ], &tall_box),
            ("Light", Vec3::ONE, &[[-0.24, 1.98, 0.16], [-0.24, 1.98, -0.22], [0.23, 1.98, -0.22], [0.23, 1.98, 0.16]], &quad),
        ];
        let mut scene = Self::default();
        for (name, albedo, verts, indices) in parts {
            let mut material = Material::diffuse(name, albedo);
            if name == "Light" {
                material.emissive = Vec3::ONE;
            }
            let m = scene.push_material(material);
            for (k, tri) in indices.chunks_exact(3).enumerate() {
                let t = [0, 1, 2].map(|c| Vec3::from_array(verts[tri[c] as usize]));
                // Built-in data is finite by construction.
                if scene.push_triangle(t, m, name, k).is_err() {
                    unreachable!("built-in Cornell box has finite positions");
                }
            }
        }
        scene
    }

    /// A square ground plane `y = 0` of half-size `half_size` centred at the origin, front face
    /// up, diffuse `albedo`, under open sky.
    pub fn ground_plane(half_size: f32, albedo: Vec3) -> Self {
        let h = half_size;
        let v = [
            Vec3::new(-h, 0.0, -h),
            Vec3::new(-h, 0.0, h),
            Vec3::new(h, 0.0, h),
            Vec3::new(h, 0.0, -h),
        ];
        let mut scene = Self::default();
        let m = scene.push_material(Material {
            double_sided: false,
            ..Material::diffuse("ground", albedo)
        });
        for (k, t) in [[v[0], v[1], v[2]], [v[0], v[2], v[3]]]
            .into_iter()
            .enumerate()
        {
            if scene.push_triangle(t, m, "ground", k).is_err() {
                unreachable!("finite built-in plane");
            }
        }
        scene
    }

    /// A closed axis-aligned box `[-half, half]³` with inward-facing front faces (12 triangles),
    /// single-sided, diffuse `albedo`: no sky light reaches its inside.
    pub fn closed_box(half: f32, albedo: Vec3) -> Self {
        let mut scene = Self::default();
        let m = scene.push_material(Material {
            double_sided: false,
            ..Material::diffuse("box", albedo)
        });
        scene.push_box(Vec3::splat(-half), Vec3::splat(half), true, m, "box");
        scene
    }

    /// Two 1 × 1 × 1 rooms side by side along x, `x ∈ [−1, −wall/2]` and `[wall/2, 1]` (y up
    /// from the floor at 0, z in [0, 1]), separated by a solid wall of thickness `wall`
    /// (`0 < wall < 1`) at x = 0. The room at x < 0 is open to the sky above; the one at x > 0
    /// is roofed but for a skylight strip 0.2 wide along its far wall (x ∈ [0.8, 1]), so it is
    /// dim. Single-sided grey (albedo 0.5) surfaces facing into the rooms, the wall a closed
    /// box: the test scene for light leaking through a thin wall.
    pub fn thin_wall_rooms(wall: f32) -> Self {
        let mut scene = Self::default();
        let m = scene.push_material(Material {
            double_sided: false,
            ..Material::diffuse("rooms", Vec3::splat(0.5))
        });
        let h = 0.5 * wall;
        let mut k = 0;
        // A rectangle spanned by `u` and `w` from `corner`, front face towards `facing`.
        let mut quad = |scene: &mut Self, corner: Vec3, u: Vec3, w: Vec3, facing: Vec3| {
            let q = [corner, corner + u, corner + u + w, corner + w];
            for t in [[q[0], q[1], q[2]], [q[0], q[2], q[3]]] {
                let t = if (t[1] - t[0]).cross(t[2] - t[0]).dot(facing) > 0.0 {
                    t
                } else {
                    [t[0], t[2], t[1]]
                };
                if scene.push_triangle(t, m, "rooms", k).is_err() {
                    unreachable!("the built-in rooms have finite corners");
                }
                k += 1;
            }
        };
        let (x, y, z) = (Vec3::X, Vec3::Y, Vec3::Z);
        // Floor, the outer walls at x = ±1, and the long walls at z = 0 and z = 1.
        quad(&mut scene, Vec3::new(-1.0, 0.0, 0.0), 2.0 * x, z, y);
        quad(&mut scene, Vec3::new(-1.0, 0.0, 0.0), y, z, x);
        quad(&mut scene, Vec3::new(1.0, 0.0, 0.0), y, z, -x);
        quad(&mut scene, Vec3::new(-1.0, 0.0, 0.0), 2.0 * x, y, z);
        quad(&mut scene, Vec3::new(-1.0, 0.0, 1.0), 2.0 * x, y, -z);
        // The dark room's roof, short of the skylight.
        quad(&mut scene, Vec3::new(h, 1.0, 0.0), (0.8 - h) * x, z, -y);
        scene.push_box(
            Vec3::new(-h, 0.0, 0.0),
            Vec3::new(h, 1.0, 1.0),
            false,
            m,
            "wall",
        );
        scene
    }

    /// Adds the 12 triangles of the axis-aligned box `min`–`max` (finite, `min < max`), their
    /// winding normals pointing inwards or outwards.
    pub(crate) fn push_box(
        &mut self,
        min: Vec3,
        max: Vec3,
        inward: bool,
        material: u32,
        what: &str,
    ) {
        let (centre, half) = ((min + max) * 0.5, (max - min) * 0.5);
        let mut k = 0;
        for axis in 0..3 {
            for sign in [-1.0f32, 1.0] {
                // The face at `centre + sign * half` along `axis`, spanned by the other two axes.
                let unit = |i: usize| {
                    Vec3::from_array(std::array::from_fn(|j| f32::from(u8::from(i == j))))
                };
                let outward = unit(axis) * sign;
                let u = unit((axis + 1) % 3) * half[(axis + 1) % 3];
                let w = unit((axis + 2) % 3) * half[(axis + 2) % 3];
                let c = centre + outward * half[axis];
                let q = [c - u - w, c + u - w, c + u + w, c - u + w];
                let n = if inward { -outward } else { outward };
                for t in [[q[0], q[1], q[2]], [q[0], q[2], q[3]]] {
                    let t = if (t[1] - t[0]).cross(t[2] - t[0]).dot(n) > 0.0 {
                        t
                    } else {
                        [t[0], t[2], t[1]]
                    };
                    if self.push_triangle(t, material, what, k).is_err() {
                        unreachable!("a built-in box has finite corners");
                    }
                    k += 1;
                }
            }
        }
    }

    /// World-space triangles (degenerate ones already dropped).
    pub fn triangles(&self) -> &[[Vec3; 3]] {
        &self.triangles
    }

    /// Material index of each triangle.
    pub fn material_ids(&self) -> &[u32] {
        &self.material_ids
    }

    /// Materials.
    pub fn materials(&self) -> &[Material] {
        &self.materials
    }

    /// The material of triangle `t` (panics if `t` is out of range).
    pub fn material_of(&self, t: usize) -> &Material {
        &self.materials[self.material_ids[t] as usize]
    }

    /// Punctual lights (`KHR_lights_punctual`).
    pub fn lights(&self) -> &[PunctualLight] {
        &self.lights
    }

    /// Cameras.
    pub fn cameras(&self) -> &[Camera] {
        &self.cameras
    }

    /// The scene with `cameras` appended (for scenes rebuilt from triangles, e.g. a mesh file).
    pub fn with_cameras(mut self, cameras: impl IntoIterator<Item = Camera>) -> Self {
        self.cameras.extend(cameras);
        self
    }

    /// Number of degenerate triangles dropped while building the scene.
    pub fn degenerate_dropped(&self) -> usize {
        self.degenerate_dropped
    }

    /// Per triangle, its lightmap UVs (glTF `TEXCOORD_1`, 0..1, origin top-left) when every
    /// primitive of a loaded glTF has them; `None` otherwise and for built-in scenes.
    pub fn lightmap_uvs(&self) -> Option<&[[Vec2; 3]]> {
        self.lightmap_uvs.as_deref()
    }

    pub(crate) fn set_lightmap_uvs(&mut self, uvs: Vec<[Vec2; 3]>) {
        debug_assert_eq!(uvs.len(), self.triangles.len());
        self.lightmap_uvs = Some(uvs);
    }

    /// Non-fatal problems met while loading (unsupported required extensions, undecoded textures, ...).
    pub fn warnings(&self) -> &[String] {
        &self.warnings
    }

    /// Bounding box of all triangles, `None` for a scene without triangles.
    pub fn bounds(&self) -> Option<Aabb> {
        let first = self.triangles.first()?[0];
        let (lo, hi) = self
            .triangles
            .iter()
            .flatten()
            .fold((first, first), |(lo, hi), &v| (lo.min(v), hi.max(v)));
        Some(Aabb::new(lo, hi))
    }

    /// Replaces the albedo of every material (for tests and for scenes whose colours are unknown).
    pub fn set_uniform_albedo(&mut self, albedo: Vec3) {
        for m in &mut self.materials {
            m.albedo = albedo;
        }
    }
}
