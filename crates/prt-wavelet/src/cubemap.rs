//! Lat-long and cube-map lighting, and the cube map's Haar wavelet coefficient vector.
//!
//! Conventions (docs/conventions.md): a lat-long pixel `(x, y)` of a `W × H` map is the direction
//! `θ = 2π (x + ½)/W`, `φ = π (y + ½)/H`, `d = (sin φ sin θ, cos φ, −sin φ cos θ)`; cube faces
//! are ordered +X, −X, +Y, −Y, +Z, −Z with the Vulkan per-face `(s, t)` orientation, texels
//! sampled at their centres, and texel solid angles computed exactly.
//!
//! This is a deliberately minimal conversion (bilinear lat-long lookup at texel centres), kept
//! here until `prt-sphere`'s environment maps are available; its only job is to feed the
//! wavelet experiments with realistic lighting.

use glam::Vec3;

use crate::WaveletError;
use crate::haar::{band_of_2d, forward_2d, inverse_2d};

/// A lat-long (equirectangular) environment map, `channels` values per pixel, row-major,
/// channel-interleaved (the layout image decoders produce).
#[derive(Debug, Clone, PartialEq)]
pub struct LatLong {
    width: usize,
    height: usize,
    channels: usize,
    data: Vec<f32>,
}

impl LatLong {
    /// Wraps pixel data; errors on a size mismatch, zero dimensions or a non-finite value.
    pub fn new(
        width: usize,
        height: usize,
        channels: usize,
        data: Vec<f32>,
    ) -> Result<Self, WaveletError> {
        if width == 0 || height == 0 || channels == 0 {
            return Err(WaveletError::Invalid {
                what: "lat-long map",
                why: format!("dimensions {width} x {height} x {channels} must be non-zero"),
            });
        }
        WaveletError::check_len("lat-long pixels", width * height * channels, data.len())?;
        WaveletError::check_finite("lat-long pixels", &data)?;
        Ok(Self {
            width,
            height,
            channels,
            data,
        })
    }

    /// Width in pixels.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Height in pixels.
    pub fn height(&self) -> usize {
        self.height
    }

    /// Values per pixel.
    pub fn channels(&self) -> usize {
        self.channels
    }

    /// The pixel data (row-major, channel-interleaved).
    pub fn data(&self) -> &[f32] {
        &self.data
    }

    /// Bilinear lookup of direction `dir` after rotating the map by `angle` radians about +Y
    /// (the map's content moves towards increasing θ), wrapping in longitude and clamping in
    /// latitude; writes `channels` values.
    pub fn sample_rotated(&self, dir: Vec3, angle: f32, out: &mut [f32]) {
        let d = dir.normalize_or(Vec3::Y);
        let theta = d.x.atan2(-d.z) - angle;
        let phi = d.y.clamp(-1.0, 1.0).acos();
        let u = theta.rem_euclid(std::f32::consts::TAU) / std::f32::consts::TAU;
        let v = phi / std::f32::consts::PI;
        let fx = u * self.width as f32 - 0.5;
        let fy = (v * self.height as f32 - 0.5).clamp(0.0, (self.height - 1) as f32);
        let (x0, y0) = (fx.floor(), fy.floor());
        let (tx, ty) = (fx - x0, fy - y0);
        let w = self.width as isize;
        let xa = (x0 as isize).rem_euclid(w) as usize;
        let xb = (x0 as isize + 1).rem_euclid(w) as usize;
        let ya = y0 as usize;
        let yb = (ya + 1).min(self.height - 1);
        let c = self.channels;
        for (ch, o) in out.iter_mut().enumerate().take(c) {
            let p = |x: usize, y: usize| self.data[(y * self.width + x) * c + ch];
            let top = p(xa, ya) * (1.0 - tx) + p(xb, ya) * tx;
            let bottom = p(xa, yb) * (1.0 - tx) + p(xb, yb) * tx;
            *o = top * (1.0 - ty) + bottom * ty;
        }
    }
}

/// The direction through the centre of texel `(x, y)` of cube face `face` (Vulkan orientation).
pub fn texel_direction(size: usize, face: usize, x: usize, y: usize) -> Vec3 {
    let a = 2.0 * (x as f32 + 0.5) / size as f32 - 1.0;
    let b = 2.0 * (y as f32 + 0.5) / size as f32 - 1.0;
    face_direction(face, a, b).normalize()
}

/// The (unnormalised) direction of face coordinates `(a, b) ∈ [−1, 1]²` (s and t mapped to
/// [−1, 1]) on face `face`: the inverse of the Vulkan major-axis selection table.
fn face_direction(face: usize, a: f32, b: f32) -> Vec3 {
    match face {
        0 => Vec3::new(1.0, -b, -a),
        1 => Vec3::new(-1.0, -b, a),
        2 => Vec3::new(a, 1.0, b),
        3 => Vec3::new(a, -1.0, -b),
        4 => Vec3::new(a, -b, 1.0),
        _ => Vec3::new(-a, -b, -1.0),
    }
}

/// Exact solid angle of the face rectangle `[a0, a1] × [b0, b1]` (face coordinates in [−1, 1]).
fn rect_solid_angle(a0: f64, a1: f64, b0: f64, b1: f64) -> f64 {
    let f = |a: f64, b: f64| (a * b).atan2((a * a + b * b + 1.0).sqrt());
    f(a1, b1) - f(a0, b1) - f(a1, b0) + f(a0, b0)
}

/// Exact solid angles of the texels of one channel plane (`6 × size × size`, face-major,
/// row-major); they sum to 4π.
pub fn texel_solid_angles(size: usize) -> Vec<f32> {
    let face = face_solid_angles(size, 1);
    let mut out = Vec::with_capacity(6 * size * size);
    for _ in 0..6 {
        out.extend(face.iter().map(|&w| w as f32));
    }
    out
}

/// Solid angles of the `(size/block)²` blocks of `block × block` texels of one face.
fn face_solid_angles(size: usize, block: usize) -> Vec<f64> {
    let n = size / block;
    let edge = |i: usize| 2.0 * (i * block) as f64 / size as f64 - 1.0;
    let mut out = Vec::with_capacity(n * n);
    for y in 0..n {
        for x in 0..n {
            out.push(rect_solid_angle(edge(x), edge(x + 1), edge(y), edge(y + 1)));
        }
    }
    out
}

/// A cube map of `channels` planes, each `6 × size × size` (face-major, row-major): the planar
/// layout that the wavelet transform and the approximations work on.
#[derive(Debug, Clone, PartialEq)]
pub struct Cubemap {
    size: usize,
    channels: usize,
    data: Vec<f32>,
}

impl Cubemap {
    /// Wraps planar data (`[channel][face][y][x]`). Errors: `size` not a power of two, zero
    /// channels, a length mismatch, or a non-finite texel (named by face, texel and channel).
    pub fn new(size: usize, channels: usize, data: Vec<f32>) -> Result<Self, WaveletError> {
        WaveletError::check_pow2("cube face side", size, 1)?;
        if channels == 0 {
            return Err(WaveletError::Invalid {
                what: "channels",
                why: "must be at least 1".into(),
            });
        }
        WaveletError::check_len("cubemap data", channels * 6 * size * size, data.len())?;
        if let Some(i) = data.iter().position(|v| !v.is_finite()) {
            let plane = 6 * size * size;
            let (channel, rest) = (i / plane, i % plane);
            let (face, texel) = (rest / (size * size), rest % (size * size));
            return Err(WaveletError::NonFiniteTexel {
                face,
                x: texel % size,
                y: texel / size,
                channel,
            });
        }
        Ok(Self {
            size,
            channels,
            data,
        })
    }

    /// Builds a cube map from six faces in image layout (`[y][x][channel]`, interleaved), in the
    /// order +X, −X, +Y, −Y, +Z, −Z. Errors: not six faces, a face of the wrong length (the
    /// "face" length mismatch names the expected `size² × channels`), a side that is not a power
    /// of two, or a non-finite texel.
    pub fn from_faces(
        size: usize,
        channels: usize,
        faces: &[&[f32]],
    ) -> Result<Self, WaveletError> {
        WaveletError::check_len("cube faces", 6, faces.len())?;
        WaveletError::check_pow2("cube face side", size, 1)?;
        for face in faces {
            WaveletError::check_len("cube face", size * size * channels, face.len())?;
        }
        let plane = 6 * size * size;
        let mut data = vec![0.0; channels * plane];
        for (f, face) in faces.iter().enumerate() {
            for (t, texel) in face.chunks_exact(channels.max(1)).enumerate() {
                for (c, &v) in texel.iter().enumerate() {
                    data[c * plane + f * size * size + t] = v;
                }
            }
        }
        Self::new(size, channels, data)
    }

    /// Resamples a lat-long map rotated by `angle` radians about +Y (bilinear at texel centres).
    pub fn from_lat_long(map: &LatLong, size: usize, angle: f32) -> Result<Self, WaveletError> {
        WaveletError::check_pow2("cube face side", size, 1)?;
        let channels = map.channels();
        let plane = 6 * size * size;
        let mut data = vec![0.0; channels * plane];
        let mut texel = vec![0.0; channels];
        for face in 0..6 {
            for y in 0..size {
                for x in 0..size {
                    map.sample_rotated(texel_direction(size, face, x, y), angle, &mut texel);
                    let i = (face * size + y) * size + x;
                    for (c, &v) in texel.iter().enumerate() {
                        data[c * plane + i] = v;
                    }
                }
            }
        }
        Self::new(size, channels, data)
    }

    /// Face side length.
    pub fn size(&self) -> usize {
        self.size
    }

    /// Number of channel planes.
    pub fn channels(&self) -> usize {
        self.channels
    }

    /// Texels (or coefficients) per channel plane: `6 × size²`.
    pub fn plane_len(&self) -> usize {
        6 * self.size * self.size
    }

    /// The planar data.
    pub fn data(&self) -> &[f32] {
        &self.data
    }

    /// Consumes the map and returns its planar data.
    pub fn into_data(self) -> Vec<f32> {
        self.data
    }
}

/// Where every coefficient of a cube map's Haar wavelet vector sits: its band (wavelet level:
/// 0 = the six scaling coefficients, then `1 ..= log2(size)` from coarse to fine) and its
/// area weight.
///
/// The area weight of coefficient `i` is `Σ_t |ψ_i(t)| Ω(t)` over the texels `t` of its support,
/// `Ω` the exact texel solid angle: the L1 norm of the basis function on the sphere. Dropping a
/// coefficient `c` therefore changes the area-weighted L1 error `Σ_t Ω(t) |ΔL(t)|` by at most
/// `|c| × weight`, which is why selecting by `|c| × weight` (Ng et al. 2003's area weighting)
/// targets that error.
#[derive(Debug, Clone, PartialEq)]
pub struct CubemapLayout {
    size: usize,
    bands: Vec<u8>,
    area_weights: Vec<f32>,
}

impl CubemapLayout {
    /// The layout of `size × size` faces (`size` a power of two).
    pub fn new(size: usize) -> Result<Self, WaveletError> {
        WaveletError::check_pow2("cube face side", size, 1)?;
        let levels = size.trailing_zeros() as usize;
        let mut face_bands = vec![0u8; size * size];
        let mut face_weights = vec![0.0f32; size * size];
        // Band-0 scaling function: 1/size on every texel of the face.
        face_weights[0] = (face_solid_angles(size, size)[0] / size as f64) as f32;
        for j in 1..=levels {
            let s = 1usize << (j - 1); // detail blocks of band j are s × s
            let block = size / s; // support side in texels; |ψ| = 1/block on it
            let support = face_solid_angles(size, block);
            for (qx, qy) in [(s, 0), (0, s), (s, s)] {
                for by in 0..s {
                    for bx in 0..s {
                        let i = (qy + by) * size + qx + bx;
                        face_bands[i] = j as u8;
                        face_weights[i] = (support[by * s + bx] / block as f64) as f32;
                    }
                }
            }
        }
        let mut bands = Vec::with_capacity(6 * size * size);
        let mut area_weights = Vec::with_capacity(6 * size * size);
        // The solid angle of a face rectangle does not depend on the face's orientation.
        for _ in 0..6 {
            bands.extend_from_slice(&face_bands);
            area_weights.extend_from_slice(&face_weights);
        }
        Ok(Self {
            size,
            bands,
            area_weights,
        })
    }

    /// Face side length.
    pub fn size(&self) -> usize {
        self.size
    }

    /// Coefficients per channel plane (`6 × size²`).
    pub fn len(&self) -> usize {
        self.bands.len()
    }

    /// Always false: a cube map has at least six coefficients.
    pub fn is_empty(&self) -> bool {
        self.bands.is_empty()
    }

    /// Number of bands: `log2(size) + 1`.
    pub fn band_count(&self) -> usize {
        self.size.trailing_zeros() as usize + 1
    }

    /// Band of every coefficient.
    pub fn bands(&self) -> &[u8] {
        &self.bands
    }

    /// Area weight of every coefficient.
    pub fn area_weights(&self) -> &[f32] {
        &self.area_weights
    }

    /// Band of the coefficient at `(x, y)` of any face.
    pub fn band_at(&self, x: usize, y: usize) -> usize {
        band_of_2d(x, y)
    }

    /// Finer bands: wavelet level × face (`6 × level + face`, `6 × band_count()` bands), so that
    /// a per-band update policy can treat the faces of one level differently (under rotation
    /// about +Y the ±Y faces spin in place while the side faces translate).
    pub fn level_face_bands(&self) -> Vec<u8> {
        let face_len = self.size * self.size;
        self.bands
            .iter()
            .enumerate()
            .map(|(i, &b)| 6 * b + (i / face_len) as u8)
            .collect()
    }
}

/// The Haar wavelet transform of whole cube maps: every face of every channel plane is
/// transformed with the 2D non-standard decomposition, giving one coefficient vector in the
/// same planar layout as the texels. Holds its scratch buffer so transforms do not allocate.
#[derive(Debug, Clone)]
pub struct CubemapHaar {
    size: usize,
    scratch: Vec<f32>,
}

impl CubemapHaar {
    /// A transform for `size × size` faces.
    pub fn new(size: usize) -> Result<Self, WaveletError> {
        WaveletError::check_pow2("cube face side", size, 1)?;
        Ok(Self {
            size,
            scratch: vec![0.0; size * size],
        })
    }

    /// Forward transform of planar data (any whole number of `6 × size²` planes) in place.
    pub fn forward(&mut self, data: &mut [f32]) -> Result<(), WaveletError> {
        self.check(data)?;
        let n = self.size;
        for face in data.chunks_exact_mut(n * n) {
            forward_2d(face, n, &mut self.scratch);
        }
        Ok(())
    }

    /// Inverse transform in place.
    pub fn inverse(&mut self, data: &mut [f32]) -> Result<(), WaveletError> {
        self.check(data)?;
        let n = self.size;
        for face in data.chunks_exact_mut(n * n) {
            inverse_2d(face, n, &mut self.scratch);
        }
        Ok(())
    }

    fn check(&self, data: &[f32]) -> Result<(), WaveletError> {
        let plane = 6 * self.size * self.size;
        if data.is_empty() || !data.len().is_multiple_of(plane) {
            return Err(WaveletError::LengthMismatch {
                what: "cubemap planes (a non-zero multiple of 6 x size^2)",
                expected: plane * (data.len() / plane).max(1),
                got: data.len(),
            });
        }
        Ok(())
    }
}
