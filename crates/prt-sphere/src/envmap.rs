//! Environment maps: lat-long (equirectangular) RGB f32 maps and cubemaps, lookups by
//! direction, exact texel solid angles, conversions and SH projection.
//!
//! Lat-long mapping (conventions.md): texel `(x, y)` of a `W × H` map is sampled at its
//! centre, `u = (x + ½)/W`, `v = (y + ½)/H`, `θ = 2πu`, `φ = πv`,
//! `dir = (sin φ sin θ, cos φ, −sin φ cos θ)`; the top row is up (+Y).
//!
//! Cubemaps: faces +X, −X, +Y, −Y, +Z, −Z (KTX2/Vulkan order), per-face `(s, t)` as in the
//! Vulkan specification's cube map face selection table, texel centres.
use glam::{DVec3, Vec3};

use crate::SphereError;
use crate::sh::{eval_sh, sh_len};

const PI: f64 = std::f64::consts::PI;

/// A lat-long RGB map, row-major from the top row, 3 f32 per texel.
#[derive(Debug, Clone, PartialEq)]
pub struct LatLongMap {
    width: usize,
    height: usize,
    data: Vec<f32>,
}

impl LatLongMap {
    /// A map of `width × height` texels from `data` (`3 · width · height` values). Errors: zero
    /// size, wrong length, a non-finite texel value (named by its flat index into `data`).
    pub fn new(width: usize, height: usize, data: Vec<f32>) -> Result<Self, SphereError> {
        if width == 0 || height == 0 {
            return Err(SphereError::invalid(
                "map size",
                format!("{width} × {height}"),
            ));
        }
        let expected = width
            .checked_mul(height)
            .and_then(|n| n.checked_mul(3))
            .ok_or_else(|| {
                SphereError::invalid("map size", format!("{width} × {height} overflows"))
            })?;
        if data.len() != expected {
            return Err(SphereError::LengthMismatch {
                what: "texel data",
                expected,
                got: data.len(),
            });
        }
        SphereError::check_finite("texel", &data)?;
        Ok(Self {
            width,
            height,
            data,
        })
    }

    /// A map whose texel at `(x, y)` is `f(dir of texel centre)`.
    pub fn from_fn(
        width: usize,
        height: usize,
        mut f: impl FnMut(Vec3) -> Vec3,
    ) -> Result<Self, SphereError> {
        let mut data = Vec::with_capacity(width * height * 3);
        for y in 0..height {
            for x in 0..width {
                data.extend_from_slice(&f(texel_direction(x, y, width, height)).to_array());
            }
        }
        Self::new(width, height, data)
    }

    /// Width in texels.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Height in texels.
    pub fn height(&self) -> usize {
        self.height
    }

    /// The texel data (RGB interleaved, row-major from the top).
    pub fn data(&self) -> &[f32] {
        &self.data
    }

    /// Texel `(x, y)`.
    pub fn texel(&self, x: usize, y: usize) -> Vec3 {
        let i = 3 * (y * self.width + x);
        Vec3::new(self.data[i], self.data[i + 1], self.data[i + 2])
    }

    /// Direction of the centre of texel `(x, y)`.
    pub fn direction(&self, x: usize, y: usize) -> Vec3 {
        texel_direction(x, y, self.width, self.height)
    }

    /// Exact solid angle of any texel of row `y`: `(2π/W) (cos(πy/H) − cos(π(y+1)/H))`.
    /// The solid angles of all texels sum to 4π.
    pub fn texel_solid_angle(&self, y: usize) -> f64 {
        let h = self.height as f64;
        2.0 * PI / self.width as f64 * ((PI * y as f64 / h).cos() - (PI * (y + 1) as f64 / h).cos())
    }

    /// The value of the texel containing `dir` (non-unit directions are normalised).
    pub fn nearest(&self, dir: Vec3) -> Vec3 {
        let (u, v) = direction_to_uv(dir);
        let x =
            ((u * self.width as f64).floor() as isize).clamp(0, self.width as isize - 1) as usize;
        let y =
            ((v * self.height as f64).floor() as isize).clamp(0, self.height as isize - 1) as usize;
        self.texel(x, y)
    }

    /// Bilinear interpolation between texel centres, wrapping in longitude and clamping at the
    /// poles.
    pub fn bilinear(&self, dir: Vec3) -> Vec3 {
        let (u, v) = direction_to_uv(dir);
        let fx = u * self.width as f64 - 0.5;
        let fy = (v * self.height as f64 - 0.5).clamp(0.0, (self.height - 1) as f64);
        let x0 = fx.floor();
        let y0 = fy.floor();
        let (tx, ty) = ((fx - x0) as f32, (fy - y0) as f32);
        let w = self.width as isize;
        let xa = (x0 as isize).rem_euclid(w) as usize;
        let xb = (x0 as isize + 1).rem_euclid(w) as usize;
        let ya = y0 as usize;
        let yb = (ya + 1).min(self.height - 1);
        let top = self.texel(xa, ya).lerp(self.texel(xb, ya), tx);
        let bottom = self.texel(xa, yb).lerp(self.texel(xb, yb), tx);
        top.lerp(bottom, ty)
    }

    /// SH projection of the map by exact texel solid angles at texel centres (f64 sums):
    /// `c_i = Σ_texels L(texel) Y_i(centre) Ω(texel)`. Returns `order²` rows of 3 channels.
    pub fn project_sh(&self, order: usize) -> Result<Vec<f32>, SphereError> {
        crate::ShBasis::new(order)?;
        let n = sh_len(order);
        let mut acc = vec![0.0f64; n * 3];
        let mut y = vec![0.0f32; n];
        for ty in 0..self.height {
            let omega = self.texel_solid_angle(ty);
            for tx in 0..self.width {
                eval_sh(order, self.direction(tx, ty), &mut y);
                let l = self.texel(tx, ty);
                for i in 0..n {
                    let w = y[i] as f64 * omega;
                    acc[3 * i] += w * l.x as f64;
                    acc[3 * i + 1] += w * l.y as f64;
                    acc[3 * i + 2] += w * l.z as f64;
                }
            }
        }
        Ok(acc.into_iter().map(|a| a as f32).collect())
    }

    /// Resamples to a cubemap of `size × size` faces (bilinear lookups at cube texel centres).
    pub fn to_cubemap(&self, size: usize) -> Result<CubeMap, SphereError> {
        CubeMap::from_fn(size, |d| self.bilinear(d))
    }
}

/// Direction of the centre of texel `(x, y)` of a `w × h` lat-long map.
pub fn texel_direction(x: usize, y: usize, w: usize, h: usize) -> Vec3 {
    let u = (x as f64 + 0.5) / w as f64;
    let v = (y as f64 + 0.5) / h as f64;
    uv_to_direction(u, v)
}

/// Lat-long `(u, v)` in `[0, 1]²` to a unit direction.
pub fn uv_to_direction(u: f64, v: f64) -> Vec3 {
    let theta = 2.0 * PI * u;
    let phi = PI * v;
    DVec3::new(phi.sin() * theta.sin(), phi.cos(), -phi.sin() * theta.cos()).as_vec3()
}

/// A direction to lat-long `(u, v)`, `u` in `[0, 1)`, `v` in `[0, 1]`. Non-unit directions are
/// normalised; the zero vector maps to `(0, 0)`.
pub fn direction_to_uv(dir: Vec3) -> (f64, f64) {
    let d = dir.as_dvec3().normalize_or_zero();
    if d == DVec3::ZERO {
        return (0.0, 0.0);
    }
    let phi = d.y.clamp(-1.0, 1.0).acos();
    let theta = d.x.atan2(-d.z);
    let u = (theta / (2.0 * PI)).rem_euclid(1.0);
    (if u >= 1.0 { 0.0 } else { u }, phi / PI)
}

/// A cubemap of six `size × size` RGB f32 faces in the order +X, −X, +Y, −Y, +Z, −Z.
#[derive(Debug, Clone, PartialEq)]
pub struct CubeMap {
    size: usize,
    data: Vec<f32>,
}

impl CubeMap {
    /// From face data (`6 · size² · 3` values, face-major, rows from t = 0). Errors as
    /// [`LatLongMap::new`].
    pub fn new(size: usize, data: Vec<f32>) -> Result<Self, SphereError> {
        if size == 0 {
            return Err(SphereError::invalid("cubemap size", "0"));
        }
        let expected = 18 * size * size;
        if data.len() != expected {
            return Err(SphereError::LengthMismatch {
                what: "cubemap data",
                expected,
                got: data.len(),
            });
        }
        SphereError::check_finite("texel", &data)?;
        Ok(Self { size, data })
    }

    /// A cubemap whose texels are `f(dir of texel centre)`.
    pub fn from_fn(size: usize, mut f: impl FnMut(Vec3) -> Vec3) -> Result<Self, SphereError> {
        let mut data = Vec::with_capacity(18 * size * size);
        for face in 0..6 {
            for t in 0..size {
                for s in 0..size {
                    data.extend_from_slice(&f(cube_texel_direction(face, s, t, size)).to_array());
                }
            }
        }
        Self::new(size, data)
    }

    /// Face size in texels.
    pub fn size(&self) -> usize {
        self.size
    }

    /// Texel `(s, t)` of `face`.
    pub fn texel(&self, face: usize, s: usize, t: usize) -> Vec3 {
        let i = 3 * ((face * self.size + t) * self.size + s);
        Vec3::new(self.data[i], self.data[i + 1], self.data[i + 2])
    }

    /// The texel data.
    pub fn data(&self) -> &[f32] {
        &self.data
    }

    /// The value of the texel containing `dir`.
    pub fn nearest(&self, dir: Vec3) -> Vec3 {
        let (face, s, t) = direction_to_cube(dir);
        let n = self.size as f64;
        let si = ((s * n).floor() as isize).clamp(0, self.size as isize - 1) as usize;
        let ti = ((t * n).floor() as isize).clamp(0, self.size as isize - 1) as usize;
        self.texel(face, si, ti)
    }

    /// Bilinear interpolation inside the face containing `dir` (clamped at face edges).
    pub fn bilinear(&self, dir: Vec3) -> Vec3 {
        let (face, s, t) = direction_to_cube(dir);
        let n = self.size as f64;
        let fs = (s * n - 0.5).clamp(0.0, n - 1.0);
        let ft = (t * n - 0.5).clamp(0.0, n - 1.0);
        let (s0, t0) = (fs.floor() as usize, ft.floor() as usize);
        let (s1, t1) = ((s0 + 1).min(self.size - 1), (t0 + 1).min(self.size - 1));
        let (a, b) = ((fs - s0 as f64) as f32, (ft - t0 as f64) as f32);
        let top = self.texel(face, s0, t0).lerp(self.texel(face, s1, t0), a);
        let bottom = self.texel(face, s0, t1).lerp(self.texel(face, s1, t1), a);
        top.lerp(bottom, b)
    }

    /// Exact solid angle of texel `(s, t)` of any face (the same on every face).
    pub fn texel_solid_angle(&self, s: usize, t: usize) -> f64 {
        let n = self.size as f64;
        let (x0, x1) = (2.0 * s as f64 / n - 1.0, 2.0 * (s + 1) as f64 / n - 1.0);
        let (y0, y1) = (2.0 * t as f64 / n - 1.0, 2.0 * (t + 1) as f64 / n - 1.0);
        cube_rect_solid_angle(x0, x1, y0, y1)
    }

    /// Resamples to a lat-long map (bilinear lookups at lat-long texel centres).
    pub fn to_latlong(&self, width: usize, height: usize) -> Result<LatLongMap, SphereError> {
        LatLongMap::from_fn(width, height, |d| self.bilinear(d))
    }
}

/// Direction of the centre of texel `(s, t)` of `face` of a cubemap with `size × size` faces.
pub fn cube_texel_direction(face: usize, s: usize, t: usize, size: usize) -> Vec3 {
    let a = 2.0 * (s as f64 + 0.5) / size as f64 - 1.0;
    let b = 2.0 * (t as f64 + 0.5) / size as f64 - 1.0;
    cube_to_direction(face, a, b)
}

/// Exact solid angle of the rectangle `[a0, a1] × [b0, b1]` of a cube face (face coordinates
/// in `[−1, 1]`, any face).
pub fn cube_rect_solid_angle(a0: f64, a1: f64, b0: f64, b1: f64) -> f64 {
    let f = |a: f64, b: f64| (a * b).atan2((a * a + b * b + 1.0).sqrt());
    f(a1, b1) - f(a0, b1) - f(a1, b0) + f(a0, b0)
}

/// Face-local coordinates `sc/|ma|, tc/|ma|` in `[−1, 1]` of `face` to a unit direction (inverse
/// of the Vulkan face selection table).
pub fn cube_to_direction(face: usize, a: f64, b: f64) -> Vec3 {
    let d = match face {
        0 => DVec3::new(1.0, -b, -a),
        1 => DVec3::new(-1.0, -b, a),
        2 => DVec3::new(a, 1.0, b),
        3 => DVec3::new(a, -1.0, -b),
        4 => DVec3::new(a, -b, 1.0),
        _ => DVec3::new(-a, -b, -1.0),
    };
    d.normalize().as_vec3()
}

/// The face and `(s, t)` in `[0, 1]²` of `dir` (Vulkan face selection; ties go to X, then Y).
pub fn direction_to_cube(dir: Vec3) -> (usize, f64, f64) {
    let d = dir.as_dvec3();
    let (ax, ay, az) = (d.x.abs(), d.y.abs(), d.z.abs());
    let (face, sc, tc, ma) = if ax >= ay && ax >= az {
        if d.x >= 0.0 {
            (0, -d.z, -d.y, ax)
        } else {
            (1, d.z, -d.y, ax)
        }
    } else if ay >= az {
        if d.y >= 0.0 {
            (2, d.x, d.z, ay)
        } else {
            (3, d.x, -d.z, ay)
        }
    } else if d.z >= 0.0 {
        (4, d.x, -d.y, az)
    } else {
        (5, -d.x, -d.y, az)
    };
    if ma == 0.0 {
        return (0, 0.5, 0.5);
    }
    (face, 0.5 * (sc / ma + 1.0), 0.5 * (tc / ma + 1.0))
}
