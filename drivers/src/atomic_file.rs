//! Writing a file so that readers see either nothing or all of it.
//!
//! The file is written to a hidden temporary sibling `.<name>.<pid>.partial`, fsynced,
//! renamed over the target, and the directory fsynced. After a crash only such
//! temporaries can be left behind ([`is_partial`] recognises them).

use std::fs::{self, File};
use std::io::{self, Write};
use std::path::{Path, PathBuf};

/// Failure of [`write_atomically_with`]: the writer's own error or the file system's.
#[derive(Debug, thiserror::Error)]
pub enum AtomicWriteError<E> {
    #[error("{0}")]
    Write(E),
    #[error("I/O: {0}")]
    Io(io::Error),
}

impl<E> From<io::Error> for AtomicWriteError<E> {
    fn from(error: io::Error) -> Self {
        AtomicWriteError::Io(error)
    }
}

/// Write `bytes` to `path` atomically. On error the temporary is removed.
pub fn write_atomically(path: &Path, bytes: &[u8]) -> io::Result<()> {
    write_atomically_with(path, |temp| {
        File::create(temp).and_then(|mut file| file.write_all(bytes))
    })
    .map_err(|err| match err {
        AtomicWriteError::Write(err) | AtomicWriteError::Io(err) => err,
    })
}

/// Run `write` on the temporary path beside `path` (for writers that take a path, such
/// as image encoders), then fsync and rename it into place. The parent directory must
/// exist. On error the temporary is removed.
pub fn write_atomically_with<E>(
    path: &Path,
    write: impl FnOnce(&Path) -> Result<(), E>,
) -> Result<(), AtomicWriteError<E>> {
    let temp = temp_path(path)?;
    let written = write(&temp)
        .map_err(AtomicWriteError::Write)
        .and_then(|()| {
            File::open(&temp)
                .and_then(|file| file.sync_all())
                .and_then(|()| fs::rename(&temp, path))
                .map_err(AtomicWriteError::Io)
        });
    if written.is_err() {
        let _ = fs::remove_file(&temp);
    }
    written?;
    // Persist the rename itself; not every filesystem supports syncing a directory.
    if let Ok(dir) = File::open(parent(path)) {
        let _ = dir.sync_all();
    }
    Ok(())
}

/// Whether a file name is a leftover temporary of an atomic write.
pub fn is_partial(name: &str) -> bool {
    name.starts_with('.') && name.ends_with(".partial")
}

fn parent(path: &Path) -> &Path {
    match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    }
}

fn temp_path(path: &Path) -> io::Result<PathBuf> {
    let name = path.file_name().ok_or_else(|| {
        io::Error::new(
            io::ErrorKind::InvalidInput,
            format!("{} is no file path", path.display()),
        )
    })?;
    Ok(parent(path).join(format!(
        ".{}.{}.partial",
        name.to_string_lossy(),
        std::process::id()
    )))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn replaces_the_file_and_leaves_no_temporary() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("frame.nef");
        write_atomically(&path, b"first").unwrap();
        write_atomically(&path, b"second").unwrap();
        assert_eq!(fs::read(&path).unwrap(), b"second");
        let names: Vec<_> = fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names, vec![std::ffi::OsString::from("frame.nef")]);
    }

    #[test]
    fn failure_leaves_nothing_behind() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("missing-dir").join("frame.nef");
        assert!(write_atomically(&path, b"x").is_err());
        assert!(write_atomically(Path::new("/"), b"x").is_err());
        assert_eq!(fs::read_dir(dir.path()).unwrap().count(), 0);
    }

    #[test]
    fn a_failing_writer_leaves_neither_file_nor_temporary() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("map.exr");
        let result = write_atomically_with(&path, |temp| {
            fs::write(temp, b"half").unwrap();
            Err("encoder failed")
        });
        assert!(matches!(
            result,
            Err(AtomicWriteError::Write("encoder failed"))
        ));
        assert_eq!(fs::read_dir(dir.path()).unwrap().count(), 0);
        assert!(is_partial(".map.exr.12.partial"));
        assert!(!is_partial("map.exr"));
    }
}
