use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};

use crate::TextureError;

/// Writes `bytes` to `path` without ever leaving a half-written file under that name.
///
/// The data goes to a temporary file in the same folder (so the rename cannot cross file
/// systems), is flushed to disk, and is then renamed over `path`. On failure the temporary file
/// is removed and the previous content of `path`, if any, is untouched.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), TextureError> {
    write_atomic_with(path, |file| file.write_all(bytes))
}

/// Like [`write_atomic`], with the content produced by a closure writing into the open file.
pub fn write_atomic_with(
    path: &Path,
    produce: impl FnOnce(&mut fs::File) -> std::io::Result<()>,
) -> Result<(), TextureError> {
    let tmp = temporary_name(path);
    let result = (|| {
        let mut file = fs::File::create(&tmp)?;
        produce(&mut file)?;
        file.sync_all()?;
        drop(file);
        fs::rename(&tmp, path)
    })();
    if let Err(e) = result {
        // The temporary may not exist (creation failed); nothing more to do in that case.
        let _ = fs::remove_file(&tmp);
        return Err(TextureError::io(path, e));
    }
    Ok(())
}

pub(crate) fn temporary_name(path: &Path) -> PathBuf {
    let mut name = path
        .file_name()
        .map(|n| n.to_os_string())
        .unwrap_or_else(|| "out".into());
    name.push(format!(".tmp{}", std::process::id()));
    path.with_file_name(name)
}

/// Reads a whole file, refusing files larger than `max_bytes` before reading them.
pub(crate) fn read_limited(path: &Path, max_bytes: u64) -> Result<Vec<u8>, TextureError> {
    let meta = fs::metadata(path).map_err(|e| TextureError::io(path, e))?;
    crate::limits::check_at_most("file size", meta.len(), max_bytes)?;
    fs::read(path).map_err(|e| TextureError::io(path, e))
}
