//! Helpers shared by prt-bake's integration tests.

use std::path::PathBuf;
use std::sync::atomic::{AtomicUsize, Ordering};

use prt_texture::Encoding;

/// Every encoding of a container's arrays (RGB9E5 stores non-negative RGB only).
#[allow(dead_code)] // used by the container tests only
pub const ENCODINGS: [Encoding; 6] = [
    Encoding::F32,
    Encoding::F16,
    Encoding::Unorm8,
    Encoding::Unorm16,
    Encoding::Snorm8,
    Encoding::Snorm16,
];

/// A fresh empty folder under the system's temp folder, named after `test` and this process.
pub fn scratch(test: &str) -> PathBuf {
    static NEXT: AtomicUsize = AtomicUsize::new(0);
    let dir = std::env::temp_dir().join(format!(
        "prt-bake-{test}-{}-{}",
        std::process::id(),
        NEXT.fetch_add(1, Ordering::Relaxed)
    ));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}
