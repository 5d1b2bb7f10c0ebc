//! Cube-map lighting from lat-long maps, and the cube map's Haar wavelet coefficient vector.
//!
//! Conventions (docs/conventions.md): lat-long maps and cube-face directions are `prt-sphere`'s
//! ([`LatLongMap`], [`prt_sphere::envmap::cube_to_direction`]): faces +X, −X, +Y, −Y, +Z, −Z with the
//! Vulkan per-face `(s, t)` orientation, texel solid angles computed exactly.
//!
//! The conversion is `prt-sphere`'s lookups (bilinear in the lat-long map, Vulkan face
//! directions), but **area-averaged** rather than point-sampled: each cube texel is the
//! solid-angle-weighted mean of `n × n` bilinear lookups at the centres of its sub-texels
//! ([`Cubemap::from_lat_long`]). `prt-sphere`'s `LatLongMap::to_cubemap` samples once at the
//! texel centre, which is right for smooth maps but aliases small bright sources: a light
//! smaller than a cube texel is seen only while a texel centre falls near it, so under rotation
//! its energy in the cube map blinks (probulator_grace rotating at 1°/frame on 64 × 64 faces:
//! total radiant energy between 4.4 and 10.9 across frames with one sample per texel, between
//! 7.18 and 7.27 with 8 × 8). That flicker is temporal incoherence that the real lighting does
//! not have, and it is exactly what incremental updates cannot follow.

use glam::{DVec3, Quat};
use prt_sphere::LatLongMap;
use prt_sphere::envmap::{cube_rect_solid_angle, cube_to_direction};

use crate::WaveletError;
use crate::haar::{band_of_2d, forward_2d, inverse_2d};

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
            out.push(cube_rect_solid_angle(
                edge(x),
                edge(x + 1),
                edge(y),
                edge(y + 1),
            ));
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

    /// Sub-texel samples per side that [`Self::from_lat_long`] needs for a lat-long map `width`
    /// texels wide on `size × size` faces: about four lookups per lat-long texel along the
    /// equator (a cube texel spans about `width / (4 size)` lat-long texels there, and fewer
    /// towards the poles, where lat-long texels narrow and a small light is missed or caught
    /// depending on its phase), at least 4 × 4 and at most 16 × 16 per cube texel. Two lookups
    /// per texel left probulator_grace on 32 × 32 faces with resampling noise of 30-40% of its
    /// frame-to-frame change under a 1°/frame rotation (the `wavelet_resample` bench).
    pub fn default_samples(width: usize, size: usize) -> usize {
        width.div_ceil(size.max(1)).clamp(4, 16)
    }

    /// Resamples an RGB lat-long map rotated by `angle` radians about +Y (the content moves
    /// towards increasing longitude θ: the result at direction `d` is the map at `R_y(angle) d`)
    /// onto `size × size` faces, as planar RGB. Each texel is the solid-angle-weighted mean of
    /// `samples × samples` bilinear lookups at its sub-texel centres (see the module docs for
    /// why not one). Errors: `size` not a power of two, `samples` zero or `angle` not finite.
    pub fn from_lat_long(
        map: &LatLongMap,
        size: usize,
        angle: f32,
        samples: usize,
    ) -> Result<Self, WaveletError> {
        WaveletError::check_pow2("cube face side", size, 1)?;
        if samples == 0 || !angle.is_finite() {
            return Err(WaveletError::Invalid {
                what: "lat-long resampling",
                why: format!("{samples} samples per side at angle {angle}"),
            });
        }
        let rotation = Quat::from_rotation_y(angle);
        let fine = size * samples;
        let sub_weights = face_solid_angles(fine, 1);
        let plane = 6 * size * size;
        let mut data = vec![0.0; 3 * plane];
        let texel_weights = face_solid_angles(size, 1);
        let mut sum = vec![DVec3::ZERO; size * size];
        for face in 0..6 {
            sum.fill(DVec3::ZERO);
            for fy in 0..fine {
                let b = 2.0 * (fy as f64 + 0.5) / fine as f64 - 1.0;
                for fx in 0..fine {
                    let a = 2.0 * (fx as f64 + 0.5) / fine as f64 - 1.0;
                    let value = map.bilinear(rotation * cube_to_direction(face, a, b));
                    sum[(fy / samples) * size + fx / samples] +=
                        value.as_dvec3() * sub_weights[fy * fine + fx];
                }
            }
            for (t, (s, w)) in sum.iter().zip(&texel_weights).enumerate() {
                let mean = *s / *w;
                for (c, v) in mean.to_array().into_iter().enumerate() {
                    data[c * plane + face * size * size + t] = v as f32;
                }
            }
        }
        Self::new(size, 3, data)
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

    /// Finer still: wavelet level × face × spatial tile, the face cut into `tiles × tiles`
    /// squares and a coefficient assigned to the tile holding its support (coefficients whose
    /// support spans several tiles, at the coarse levels, form one band per level and face).
    /// Bands are numbered consecutively in (level, face, tile) order. A moving light then
    /// forces only the bands around it to be replaced while the rest of its level stays
    /// incremental. `tiles = 1` gives [`Self::level_face_bands`]. Errors: `tiles` zero, not a
    /// power of two, larger than the face, or more than 256 bands.
    pub fn level_face_tile_bands(&self, tiles: usize) -> Result<Vec<u8>, WaveletError> {
        WaveletError::check_pow2("tiles per face side", tiles, 1)?;
        if tiles > self.size {
            return Err(WaveletError::Invalid {
                what: "tiles per face side",
                why: format!("{tiles} > face side {}", self.size),
            });
        }
        let face_len = self.size * self.size;
        let keys: Vec<usize> = (0..self.len())
            .map(|i| {
                let (face, r) = (i / face_len, i % face_len);
                let (x, y) = (r % self.size, r / self.size);
                let level = self.bands[i] as usize;
                // Detail blocks of level j are s × s; block (bx, by) covers face tile
                // (bx, by) · tiles / s when s >= tiles.
                let s = if level == 0 { 1 } else { 1 << (level - 1) };
                let tile = if s >= tiles {
                    let (bx, by) = (x % s, y % s);
                    (by * tiles / s) * tiles + bx * tiles / s
                } else {
                    0
                };
                (level * 6 + face) * tiles * tiles + tile
            })
            .collect();
        let mut present = keys.clone();
        present.sort_unstable();
        present.dedup();
        if present.len() > 256 {
            return Err(WaveletError::Invalid {
                what: "tiles per face side",
                why: format!("{} bands do not fit in u8", present.len()),
            });
        }
        Ok(keys
            .iter()
            .map(|k| present.binary_search(k).unwrap_or(0) as u8)
            .collect())
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
