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

/// A file written over time, seeks included, under a temporary name in its folder; it appears
/// under its own name only when [`AtomicFile::commit`] succeeds, and dropped uncommitted it
/// leaves nothing behind (for writers that cannot produce the content in one closure).
#[derive(Debug)]
pub(crate) struct AtomicFile {
    path: PathBuf,
    tmp: PathBuf,
    file: Option<fs::File>,
}

impl AtomicFile {
    /// Creates (or truncates) the temporary file for `path`.
    pub(crate) fn open(path: &Path) -> Result<Self, TextureError> {
        let tmp = temporary_name(path);
        let file = fs::File::create(&tmp).map_err(|e| TextureError::io(path, e))?;
        Ok(Self {
            path: path.to_path_buf(),
            tmp,
            file: Some(file),
        })
    }

    /// The file's final name.
    pub(crate) fn path(&self) -> &Path {
        &self.path
    }

    /// The open temporary file; an error once committed.
    pub(crate) fn file(&mut self) -> Result<&mut fs::File, TextureError> {
        self.file.as_mut().ok_or_else(Self::committed)
    }

    /// Flushes the file to disk and renames it over its final name; on failure the temporary
    /// file is removed.
    pub(crate) fn commit(mut self) -> Result<(), TextureError> {
        let file = self.file.take().ok_or_else(Self::committed)?;
        let result = file.sync_all().and_then(|()| {
            drop(file);
            fs::rename(&self.tmp, &self.path)
        });
        result.map_err(|e| {
            let _ = fs::remove_file(&self.tmp);
            TextureError::io(&self.path, e)
        })
    }

    fn committed() -> TextureError {
        TextureError::invalid("atomic file", "already committed")
    }
}

impl Drop for AtomicFile {
    fn drop(&mut self) {
        if self.file.take().is_some() {
            let _ = fs::remove_file(&self.tmp);
        }
    }
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

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::{Seek, SeekFrom, Write};

    fn scratch(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("prt-atomic-{name}-{}", std::process::id()));
        let _ = fs::remove_dir_all(&dir);
        fs::create_dir_all(&dir).unwrap();
        dir
    }

    #[test]
    fn an_atomic_file_appears_only_on_commit_and_leaves_nothing_when_dropped() {
        let dir = scratch("file");
        let path = dir.join("out.bin");
        fs::write(&path, b"old").unwrap();
        let mut out = AtomicFile::open(&path).unwrap();
        out.file().unwrap().write_all(b"abcdef").unwrap();
        out.file().unwrap().seek(SeekFrom::Start(1)).unwrap();
        out.file().unwrap().write_all(b"X").unwrap();
        assert_eq!(fs::read(&path).unwrap(), b"old");
        out.commit().unwrap();
        assert_eq!(fs::read(&path).unwrap(), b"aXcdef");

        let mut dropped = AtomicFile::open(&path).unwrap();
        dropped.file().unwrap().write_all(b"half").unwrap();
        drop(dropped);
        assert_eq!(fs::read(&path).unwrap(), b"aXcdef");
        let names: Vec<_> = fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names, vec![std::ffi::OsString::from("out.bin")]);
        fs::remove_dir_all(&dir).unwrap();
    }
}
