//! Lighting sequences for the incremental experiments (Overbeck's rotating and blending maps).

use prt_sphere::LatLongMap;

use crate::WaveletError;
use crate::cubemap::Cubemap;

/// An environment map rotating about +Y at `speed` radians per frame until `stop_frame`, then
/// static: frame `t` is the map rotated by `speed × min(t, stop_frame)`, area-averaged onto the
/// cube faces ([`Cubemap::from_lat_long`]).
#[derive(Debug, Clone)]
pub struct Rotation {
    map: LatLongMap,
    size: usize,
    samples: usize,
    speed: f32,
    stop_frame: usize,
}

impl Rotation {
    /// A rotation of `map` resampled to `size × size` cube faces with
    /// [`Cubemap::default_samples`] sub-texel samples. Errors if `size` is not a power of two or
    /// `speed` is not finite.
    pub fn new(
        map: LatLongMap,
        size: usize,
        speed: f32,
        stop_frame: usize,
    ) -> Result<Self, WaveletError> {
        WaveletError::check_pow2("cube face side", size, 1)?;
        if !speed.is_finite() {
            return Err(WaveletError::Invalid {
                what: "rotation speed",
                why: format!("{speed} is not finite"),
            });
        }
        Ok(Self {
            samples: Cubemap::default_samples(map.width(), size),
            map,
            size,
            speed,
            stop_frame,
        })
    }

    /// The same rotation resampled with `samples × samples` lookups per cube texel (1 = a single
    /// point sample at the texel centre, which aliases small bright sources). Errors if
    /// `samples` is zero.
    pub fn with_samples(mut self, samples: usize) -> Result<Self, WaveletError> {
        if samples == 0 {
            return Err(WaveletError::Invalid {
                what: "samples per texel side",
                why: "must be at least 1".into(),
            });
        }
        self.samples = samples;
        Ok(self)
    }

    /// Sub-texel samples per side.
    pub fn samples(&self) -> usize {
        self.samples
    }

    /// The rotation angle of frame `t`.
    pub fn angle(&self, t: usize) -> f32 {
        self.speed * t.min(self.stop_frame) as f32
    }

    /// The frame at which the rotation stops.
    pub fn stop_frame(&self) -> usize {
        self.stop_frame
    }

    /// The cube map of frame `t`.
    pub fn frame(&self, t: usize) -> Result<Cubemap, WaveletError> {
        Cubemap::from_lat_long(&self.map, self.size, self.angle(t), self.samples)
    }
}

/// A linear blend from cube map `from` (frame 0) to `to` (frame `frames − 1`), then `to`.
#[derive(Debug, Clone)]
pub struct Interpolation {
    from: Cubemap,
    to: Cubemap,
    frames: usize,
}

impl Interpolation {
    /// A blend over `frames` frames (at least 2) between maps of equal size and channels.
    pub fn new(from: Cubemap, to: Cubemap, frames: usize) -> Result<Self, WaveletError> {
        WaveletError::check_len("blend target", from.data().len(), to.data().len())?;
        WaveletError::check_len("blend target face side", from.size(), to.size())?;
        if frames < 2 {
            return Err(WaveletError::Invalid {
                what: "blend frames",
                why: format!("{frames} < 2"),
            });
        }
        Ok(Self { from, to, frames })
    }

    /// The blend weight of frame `t` (0 at the start, 1 from frame `frames − 1` on).
    pub fn weight(&self, t: usize) -> f32 {
        (t.min(self.frames - 1)) as f32 / (self.frames - 1) as f32
    }

    /// The cube map of frame `t`.
    pub fn frame(&self, t: usize) -> Result<Cubemap, WaveletError> {
        let s = self.weight(t);
        let data = self
            .from
            .data()
            .iter()
            .zip(self.to.data())
            .map(|(a, b)| a + s * (b - a))
            .collect();
        Cubemap::new(self.from.size(), self.from.channels(), data)
    }
}
