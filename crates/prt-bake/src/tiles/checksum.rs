//! The 64-bit FNV-1a hash of the tiles: the scene's hash in the plan and the checksum of each
//! tile file's payload.

/// A running 64-bit FNV-1a hash (offset basis `0xcbf29ce484222325`, prime `0x100000001b3`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Fnv1a64(u64);

impl Default for Fnv1a64 {
    fn default() -> Self {
        Fnv1a64(0xcbf2_9ce4_8422_2325)
    }
}

impl Fnv1a64 {
    /// Feeds `bytes`.
    pub(crate) fn update(&mut self, bytes: &[u8]) {
        let mut hash = self.0;
        for &b in bytes {
            hash = (hash ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3);
        }
        self.0 = hash;
    }

    /// `fnv1a64:HEX` (16 lowercase hex digits), the form the plan and the tiles record.
    pub(crate) fn label(&self) -> String {
        format!("fnv1a64:{:016x}", self.0)
    }

    /// The label of `bytes`.
    pub(crate) fn of(bytes: &[u8]) -> String {
        let mut hash = Fnv1a64::default();
        hash.update(bytes);
        hash.label()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn known_values() {
        // The reference vectors of the FNV specification.
        assert_eq!(Fnv1a64::of(b""), "fnv1a64:cbf29ce484222325");
        assert_eq!(Fnv1a64::of(b"a"), "fnv1a64:af63dc4c8601ec8c");
        assert_eq!(Fnv1a64::of(b"foobar"), "fnv1a64:85944171f73967e8");
        let mut split = Fnv1a64::default();
        split.update(b"foo");
        split.update(b"bar");
        assert_eq!(split.label(), Fnv1a64::of(b"foobar"));
    }
}
