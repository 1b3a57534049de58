//! Where a shot's files live: the local file system ([`LocalFiles`]) or an object store
//! (`s3://`, `gs://`, `az://`; the command line provides that implementation, since it needs
//! an async runtime this layer does not know). Both write whole-or-nothing: a reader never
//! sees half an object under its real name.
//!
//! Paths name files the same way in both: an object is `s3://bucket/key/of/it.exr`, held
//! as a [`Path`] whose parent is its "directory" (`s3://bucket/key/of`).

use super::{read_raw, read_raw_exr_bytes, FileType, IoError, RawImage};
use std::path::{Path, PathBuf};

/// A place files are read from and written to.
pub trait Storage: Send + Sync {
    /// Whether paths are local files (read with `std::fs`, so every file type and symbolic
    /// link works as elsewhere in this crate).
    fn is_local(&self) -> bool;
    /// The contents of `path`, or `None` when there is no such file.
    fn get(&self, path: &Path) -> Result<Option<Vec<u8>>, IoError>;
    /// Writes `bytes` to `path` whole or not at all, replacing what was there.
    fn put(&self, path: &Path, bytes: &[u8]) -> Result<(), IoError>;
    /// The files directly in `dir` (not in its subdirectories), as full paths.
    fn list(&self, dir: &Path) -> Result<Vec<PathBuf>, IoError>;
    /// Removes `path`; no such file is not an error.
    fn delete(&self, path: &Path) -> Result<(), IoError>;
    /// The files directly in `dir`, each with a stamp of its contents read without reading
    /// them: size and modification time (and an object store's ETag). A file rewritten
    /// gets another stamp.
    fn stamps(&self, dir: &Path) -> Result<Vec<(PathBuf, String)>, IoError>;
}

/// The local file system: writes go to a hidden name beside the file
/// ([`super::partial_path`]) and are renamed into place.
#[derive(Clone, Copy, Debug, Default)]
pub struct LocalFiles;

impl Storage for LocalFiles {
    fn is_local(&self) -> bool {
        true
    }

    fn get(&self, path: &Path) -> Result<Option<Vec<u8>>, IoError> {
        match std::fs::read(path) {
            Ok(b) => Ok(Some(b)),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
            Err(e) => Err(IoError::os(path, e)),
        }
    }

    fn put(&self, path: &Path, bytes: &[u8]) -> Result<(), IoError> {
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).map_err(|e| IoError::os(dir, e))?;
        }
        let (mut file, tmp) = super::output::create_partial(path)?;
        std::io::Write::write_all(&mut file, bytes).map_err(|e| IoError::os(&tmp, e))?;
        drop(file);
        std::fs::rename(&tmp, path).map_err(|e| IoError::os(path, e))
    }

    fn list(&self, dir: &Path) -> Result<Vec<PathBuf>, IoError> {
        let dir = if dir.as_os_str().is_empty() {
            Path::new(".")
        } else {
            dir
        };
        Ok(std::fs::read_dir(dir)
            .map_err(|e| IoError::os(dir, e))?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.is_file())
            .collect())
    }

    fn delete(&self, path: &Path) -> Result<(), IoError> {
        match std::fs::remove_file(path) {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => Err(IoError::os(path, e)),
            _ => Ok(()),
        }
    }

    fn stamps(&self, dir: &Path) -> Result<Vec<(PathBuf, String)>, IoError> {
        self.list(dir)?
            .into_iter()
            .map(|p| {
                // Through links, as the frames are read.
                let m = std::fs::metadata(&p).map_err(|e| IoError::os(&p, e))?;
                let modified = m
                    .modified()
                    .ok()
                    .and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok())
                    .map_or(0, |d| d.as_nanos());
                Ok((p, format!("{} bytes, modified {modified} ns", m.len())))
            })
            .collect()
    }
}

/// Decodes the image at `path` in `storage`: any supported type from local files, OpenEXR
/// from an object store.
pub fn read_raw_in(storage: &dyn Storage, path: &Path) -> Result<RawImage, IoError> {
    if storage.is_local() {
        return read_raw(path);
    }
    if FileType::of(path) != Some(FileType::Exr) {
        return Err(IoError::Argument(format!(
            "{}: only OpenEXR frames are read from an object store",
            path.display()
        )));
    }
    let bytes = storage.get(path)?.ok_or_else(|| {
        IoError::os(
            path,
            std::io::Error::new(std::io::ErrorKind::NotFound, "no such object"),
        )
    })?;
    read_raw_exr_bytes(&bytes, path)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn local_files_write_whole_and_list_only_files() {
        let dir = tempfile::tempdir().unwrap();
        let s = LocalFiles;
        let p = dir.path().join("a/b.bin");
        assert_eq!(s.get(&p).unwrap(), None);
        s.put(&p, b"one").unwrap();
        s.put(&p, b"two").unwrap();
        assert_eq!(s.get(&p).unwrap().as_deref(), Some(&b"two"[..]));
        std::fs::create_dir(dir.path().join("a/sub")).unwrap();
        assert_eq!(s.list(&dir.path().join("a")).unwrap(), vec![p.clone()]);
        let stamp = |s: &LocalFiles| s.stamps(&dir.path().join("a")).unwrap();
        let before = stamp(&s);
        assert_eq!(before.len(), 1);
        assert!(before[0].1.starts_with("3 bytes"), "{before:?}");
        s.put(&p, b"three").unwrap();
        assert_ne!(stamp(&s), before, "a rewritten file is stamped anew");
        s.delete(&p).unwrap();
        s.delete(&p).unwrap();
        assert_eq!(s.get(&p).unwrap(), None);
    }

    #[cfg(unix)]
    #[test]
    fn a_planted_link_at_the_partial_name_is_not_followed() {
        let dir = tempfile::tempdir().unwrap();
        let victim = dir.path().join("victim.txt");
        std::fs::write(&victim, b"precious").unwrap();
        let p = dir.path().join("out.bin");
        std::os::unix::fs::symlink(&victim, super::super::partial_path(&p)).unwrap();
        LocalFiles.put(&p, b"new").unwrap();
        assert_eq!(std::fs::read(&victim).unwrap(), b"precious");
        assert_eq!(std::fs::read(&p).unwrap(), b"new");
        assert!(!super::super::partial_path(&p).exists());
    }
}
