use crate::TextureError;

/// Bounds that a reader enforces on untrusted input before it allocates anything.
///
/// Every reader of this crate checks each dimension, count and byte size that a file announces
/// against these limits (and against the real length of the input) before allocating, so a
/// malicious header cannot make it allocate gigabytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Limits {
    /// Largest accepted width, height or depth, in texels.
    pub max_dimension: u32,
    /// Largest accepted number of array layers (cubemap faces not included).
    pub max_layers: u32,
    /// Largest accepted number of mip levels.
    pub max_levels: u32,
    /// Largest number of bytes a reader may allocate for decoded data.
    pub max_bytes: u64,
}

impl Default for Limits {
    /// 16384 texels per side, 2048 layers, 16 levels, 1 GiB of decoded data.
    fn default() -> Self {
        Limits {
            max_dimension: 16384,
            max_layers: 2048,
            max_levels: 16,
            max_bytes: 1 << 30,
        }
    }
}

impl Limits {
    /// Limits suitable for fuzzing and tests: 4096 texels, 64 layers, 16 levels, 64 MiB.
    pub fn small() -> Self {
        Limits {
            max_dimension: 4096,
            max_layers: 64,
            max_levels: 16,
            max_bytes: 64 << 20,
        }
    }

    pub(crate) fn check_dimension(
        &self,
        what: &'static str,
        value: u64,
    ) -> Result<(), TextureError> {
        check_at_most(what, value, u64::from(self.max_dimension))
    }

    pub(crate) fn check_bytes(&self, what: &'static str, value: u64) -> Result<(), TextureError> {
        check_at_most(what, value, self.max_bytes)
    }
}

pub(crate) fn check_at_most(
    what: &'static str,
    value: u64,
    limit: u64,
) -> Result<(), TextureError> {
    if value > limit {
        Err(TextureError::TooLarge { what, value, limit })
    } else {
        Ok(())
    }
}

/// Product of sizes with overflow reported as a `TooLarge` error.
pub(crate) fn checked_product(what: &'static str, factors: &[u64]) -> Result<u64, TextureError> {
    factors.iter().try_fold(1u64, |acc, &f| {
        acc.checked_mul(f).ok_or(TextureError::TooLarge {
            what,
            value: u64::MAX,
            limit: u64::MAX,
        })
    })
}
