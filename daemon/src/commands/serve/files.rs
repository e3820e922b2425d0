//! Durable file writes and safe paths inside the data directory.

use std::fs::{self, File};
use std::io::Write;
use std::path::{Component, Path, PathBuf};

/// Writes `bytes` to `path` atomically: a temporary file beside it, fsync, rename,
/// then fsync of the directory. A reader never sees a partial file.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let dir = path.parent().unwrap_or(Path::new("."));
    fs::create_dir_all(dir)?;
    let tmp = temp_path(path);
    {
        let mut file = File::create(&tmp)?;
        file.write_all(bytes)?;
        file.sync_all()?;
    }
    fs::rename(&tmp, path)?;
    File::open(dir)?.sync_all()
}

/// Runs `write` on a temporary path beside `path`, then fsyncs and renames it into
/// place (for writers that take a path, such as image encoders).
pub fn write_atomic_with<E>(
    path: &Path,
    write: impl FnOnce(&Path) -> Result<(), E>,
) -> Result<(), AtomicError<E>> {
    let dir = path.parent().unwrap_or(Path::new("."));
    fs::create_dir_all(dir).map_err(AtomicError::Io)?;
    let tmp = temp_path(path);
    if let Err(err) = write(&tmp) {
        let _ = fs::remove_file(&tmp);
        return Err(AtomicError::Write(err));
    }
    File::open(&tmp)
        .and_then(|f| f.sync_all())
        .and_then(|()| fs::rename(&tmp, path))
        .and_then(|()| File::open(dir)?.sync_all())
        .map_err(AtomicError::Io)
}

/// Failure of [`write_atomic_with`]: the writer's own error or the file system's.
#[derive(Debug, thiserror::Error)]
pub enum AtomicError<E> {
    #[error("{0}")]
    Write(E),
    #[error("I/O: {0}")]
    Io(std::io::Error),
}

/// The temporary sibling of `path`: same directory, hidden, named like the device
/// drivers' temporaries (`.<name>.<pid>.partial`).
fn temp_path(path: &Path) -> PathBuf {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    path.with_file_name(format!(".{name}.{}.partial", std::process::id()))
}

/// Whether `name` is a leftover temporary file of an atomic write (ours or a
/// driver's).
pub fn is_partial(name: &str) -> bool {
    name.starts_with('.') && name.ends_with(".partial")
}

/// Removes leftover temporary files under `dir` (after a crash), recursively.
pub fn remove_partials(dir: &Path) -> std::io::Result<usize> {
    let mut removed = 0;
    let Ok(entries) = fs::read_dir(dir) else {
        return Ok(0);
    };
    for entry in entries {
        let entry = entry?;
        let path = entry.path();
        if entry.file_type()?.is_dir() {
            removed += remove_partials(&path)?;
        } else if is_partial(&entry.file_name().to_string_lossy()) {
            fs::remove_file(&path)?;
            removed += 1;
        }
    }
    Ok(removed)
}

/// Joins a relative, user-supplied path under `base`, refusing anything that could
/// leave it (`..`, absolute paths, hidden components).
pub fn safe_join(base: &Path, relative: &str) -> Option<PathBuf> {
    let rel = Path::new(relative);
    let mut out = base.to_path_buf();
    let mut any = false;
    for component in rel.components() {
        match component {
            Component::Normal(part) if !part.to_string_lossy().starts_with('.') => {
                out.push(part);
                any = true;
            }
            _ => return None,
        }
    }
    any.then_some(out)
}

/// Whether `name` is a safe single path component for a sample: 1–64 characters of
/// ASCII letters, digits, `-`, `_` and `.`, not starting with `.`.
pub fn is_safe_name(name: &str) -> bool {
    !name.is_empty()
        && name.len() <= 64
        && !name.starts_with('.')
        && name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.'))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn safe_join_stays_inside() {
        let base = Path::new("/data/scans/1");
        assert_eq!(
            safe_join(base, "theta_l_-20.0/exp_00.tiff"),
            Some(base.join("theta_l_-20.0/exp_00.tiff"))
        );
        for bad in [
            "../x",
            "/etc/passwd",
            "a/../../b",
            "",
            ".hidden",
            "a/.x.1.partial",
        ] {
            assert_eq!(safe_join(base, bad), None, "{bad}");
        }
    }

    #[test]
    fn sample_names_are_single_safe_components() {
        assert!(is_safe_name("gold-2024_a.1"));
        for bad in ["", ".", "..", "a/b", "a b", "é", &"x".repeat(65)] {
            assert!(!is_safe_name(bad), "{bad}");
        }
    }

    #[test]
    fn atomic_write_leaves_no_partial() {
        let dir = std::env::temp_dir().join(format!("gonio-files-{}", std::process::id()));
        let _ = fs::remove_dir_all(&dir);
        let path = dir.join("sub/x.json");
        write_atomic(&path, b"{}").unwrap();
        assert_eq!(fs::read(&path).unwrap(), b"{}");
        fs::write(dir.join("sub/.y.tiff.1.partial"), b"half").unwrap();
        assert_eq!(remove_partials(&dir).unwrap(), 1);
        let names: Vec<_> = fs::read_dir(dir.join("sub")).unwrap().collect();
        assert_eq!(names.len(), 1);
        fs::remove_dir_all(dir).unwrap();
    }
}
