//! Writing an output so that readers see either nothing or all of it, and never
//! replacing what is not a regular file.
//!
//! A regular file (or a path that does not exist yet) is written to a hidden temporary
//! sibling `.<name>.<pid>.<n>.partial`, a name no other writer (thread or process)
//! holds at the same time, fsynced, renamed over the target, and the directory fsynced.
//! A symbolic link to a regular file keeps its link: the file it names is replaced.
//! Whatever else exists at the path is never replaced: a device (`/dev/null`), a FIFO
//! or a socket is written in place, a directory is refused. After a crash only
//! temporaries can be left behind ([`is_partial`] recognises them).
#![doc = include_str!("output.md")]

use std::fs::{self, File, OpenOptions};
use std::io::{self, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

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

/// Write `bytes` to `path` as the module says. On error the temporary is removed.
pub fn write_atomically(path: &Path, bytes: &[u8]) -> io::Result<()> {
    write_atomically_with(path, |temp| {
        File::create(temp).and_then(|mut file| file.write_all(bytes))
    })
    .map_err(|err| match err {
        AtomicWriteError::Write(err) | AtomicWriteError::Io(err) => err,
    })
}

/// Run `write` on the path to write (for writers that take a path, such as image
/// encoders): a fresh temporary beside a regular `path`, then fsynced and renamed into
/// place; or `path` itself when it is a device, FIFO or socket. The parent directory
/// must exist. On error the temporary is removed; `path` never is.
pub fn write_atomically_with<E>(
    path: &Path,
    write: impl FnOnce(&Path) -> Result<(), E>,
) -> Result<(), AtomicWriteError<E>> {
    let target = match Target::of(path)? {
        Target::InPlace => return write(path).map_err(AtomicWriteError::Write),
        Target::Replace(target) => target,
    };
    let (temp, claimed) = create_beside(&target, |temp| {
        OpenOptions::new().write(true).create_new(true).open(temp)
    })?;
    drop(claimed);
    let written = write(&temp)
        .map_err(AtomicWriteError::Write)
        .and_then(|()| {
            File::open(&temp)
                .and_then(|file| file.sync_all())
                .and_then(|()| fs::rename(&temp, &target))
                .map_err(AtomicWriteError::Io)
        });
    if written.is_err() {
        let _ = fs::remove_file(&temp);
    }
    written?;
    // Persist the rename itself; not every filesystem supports syncing a directory.
    if let Ok(dir) = File::open(parent(&target)) {
        let _ = dir.sync_all();
    }
    Ok(())
}

/// Where an output goes.
enum Target {
    /// Write the path itself: it is a device, a FIFO or a socket.
    InPlace,
    /// Replace this regular file (or create it) through a temporary beside it.
    Replace(PathBuf),
}

impl Target {
    fn of(path: &Path) -> io::Result<Target> {
        match fs::metadata(path) {
            Ok(meta) if meta.is_dir() => Err(io::Error::new(
                io::ErrorKind::IsADirectory,
                "it is a directory",
            )),
            Ok(meta) if !meta.is_file() => Ok(Target::InPlace),
            Ok(_) if fs::symlink_metadata(path)?.file_type().is_symlink() => {
                Ok(Target::Replace(fs::canonicalize(path)?))
            }
            _ => Ok(Target::Replace(path.to_path_buf())),
        }
    }
}

/// Temporaries named by this process so far: with the process id, a name no other
/// writer uses at the same time.
static TEMPORARIES: AtomicU64 = AtomicU64::new(0);

/// Most names tried before giving up (each taken by a leftover of an earlier process
/// with the same id).
const NAME_ATTEMPTS: u32 = 1000;

/// Creates something at a fresh hidden temporary path beside `path`
/// (`.<name>.<pid>.<n>.partial`): `create` is called with candidate paths until it
/// succeeds or fails otherwise than with `AlreadyExists` (so it must refuse an existing
/// path: `create_new`, `symlink`). Returns the path and what `create` returned.
pub fn create_beside<T>(
    path: &Path,
    mut create: impl FnMut(&Path) -> io::Result<T>,
) -> io::Result<(PathBuf, T)> {
    let name = path.file_name().ok_or_else(|| {
        io::Error::new(
            io::ErrorKind::InvalidInput,
            format!("{} is no file path", path.display()),
        )
    })?;
    let dir = parent(path);
    for _ in 0..NAME_ATTEMPTS {
        let n = TEMPORARIES.fetch_add(1, Ordering::Relaxed);
        let temp = dir.join(format!(
            ".{}.{}.{n}.partial",
            name.to_string_lossy(),
            std::process::id()
        ));
        match create(&temp) {
            Err(err) if err.kind() == io::ErrorKind::AlreadyExists => continue,
            result => return result.map(|made| (temp, made)),
        }
    }
    Err(io::Error::new(
        io::ErrorKind::AlreadyExists,
        format!("no free temporary name beside {}", path.display()),
    ))
}

/// Whether a file name is a leftover temporary of an atomic write.
pub fn is_partial(name: &str) -> bool {
    name.starts_with('.') && name.ends_with(".partial")
}

/// The process id of the writer of a temporary named by [`create_beside`]
/// (`.<name>.<pid>.<n>.partial`); `None` for any other name.
pub fn partial_writer(name: &str) -> Option<u32> {
    let stem = name.strip_prefix('.')?.strip_suffix(".partial")?;
    let mut parts = stem.rsplitn(3, '.');
    parts.next()?.parse::<u64>().ok()?;
    let pid = parts.next()?.parse().ok()?;
    parts.next().filter(|target| !target.is_empty())?;
    Some(pid)
}

fn parent(path: &Path) -> &Path {
    match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Read;
    use std::os::unix::fs::{FileTypeExt, OpenOptionsExt};

    fn names(dir: &Path) -> Vec<std::ffi::OsString> {
        let mut names: Vec<_> = fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        names.sort();
        names
    }

    #[test]
    fn replaces_the_file_and_leaves_no_temporary() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("frame.nef");
        write_atomically(&path, b"first").unwrap();
        write_atomically(&path, b"second").unwrap();
        assert_eq!(fs::read(&path).unwrap(), b"second");
        assert_eq!(
            names(dir.path()),
            vec![std::ffi::OsString::from("frame.nef")]
        );
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
        assert!(is_partial(".map.exr.12.3.partial"));
        assert!(!is_partial("map.exr"));
        assert_eq!(partial_writer(".map.exr.12.3.partial"), Some(12));
        assert_eq!(partial_writer(".x.12.3.partial"), Some(12));
        for other in [
            ".tmpAbC.partial",
            ".12.3.partial",
            "map.exr",
            ".x.y.3.partial",
        ] {
            assert_eq!(partial_writer(other), None, "{other}");
        }
    }

    #[test]
    fn a_temporary_names_its_writer() {
        let dir = tempfile::tempdir().unwrap();
        let (temp, ()) = create_beside(&dir.path().join("exp_00.tiff"), |_| Ok(())).unwrap();
        let name = temp.file_name().unwrap().to_string_lossy().into_owned();
        assert!(is_partial(&name), "{name}");
        assert_eq!(partial_writer(&name), Some(std::process::id()));
    }

    #[test]
    fn writers_of_one_path_on_many_threads_never_share_a_temporary() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("setup.json");
        std::thread::scope(|scope| {
            for t in 0..6u8 {
                let path = &path;
                scope.spawn(move || {
                    for i in 0..100u8 {
                        let text = [t, i].repeat(512);
                        write_atomically(path, &text).unwrap();
                    }
                });
            }
        });
        // Whole: one writer's last text, never a mix.
        let text = fs::read(&path).unwrap();
        assert_eq!(text.len(), 1024);
        assert_eq!(text[1], 99);
        assert!(text.chunks(2).all(|pair| pair == &text[..2]));
        assert_eq!(
            names(dir.path()),
            vec![std::ffi::OsString::from("setup.json")]
        );
    }

    #[test]
    fn a_fifo_is_written_in_place_and_a_directory_refused() {
        let dir = tempfile::tempdir().unwrap();
        let fifo = dir.path().join("out.fifo");
        crate::mkfifo(&fifo);
        // The reading end, opened first and non-blocking: the write finds its reader.
        let mut reader = OpenOptions::new()
            .read(true)
            .custom_flags(libc::O_NONBLOCK)
            .open(&fifo)
            .unwrap();
        write_atomically(&fifo, b"through the pipe").unwrap();
        let mut got = Vec::new();
        let _ = reader.read_to_end(&mut got);
        assert_eq!(got, b"through the pipe");
        assert!(fs::symlink_metadata(&fifo).unwrap().file_type().is_fifo());
        assert_eq!(
            names(dir.path()),
            vec![std::ffi::OsString::from("out.fifo")]
        );

        let err = write_atomically(dir.path(), b"x").unwrap_err();
        assert_eq!(err.kind(), io::ErrorKind::IsADirectory);
    }

    #[test]
    fn a_character_device_is_written_in_place() {
        // A device node of our own with /dev/null's numbers (1, 3); the real one is
        // never touched.
        let dir = tempfile::tempdir().unwrap();
        let null = dir.path().join("null");
        let c_path = std::ffi::CString::new(null.as_os_str().as_encoded_bytes()).unwrap();
        // SAFETY: a valid NUL-terminated path.
        let made =
            unsafe { libc::mknod(c_path.as_ptr(), libc::S_IFCHR | 0o666, libc::makedev(1, 3)) };
        if made != 0 {
            eprintln!(
                "skipped: creating a character device needs root ({})",
                io::Error::last_os_error()
            );
            return;
        }
        write_atomically(&null, b"discarded").unwrap();
        write_atomically_with(&null, |p| fs::write(p, b"discarded")).unwrap();
        assert!(fs::symlink_metadata(&null)
            .unwrap()
            .file_type()
            .is_char_device());
        assert_eq!(names(dir.path()), vec![std::ffi::OsString::from("null")]);
    }

    #[test]
    fn a_link_to_a_file_keeps_its_link() {
        let dir = tempfile::tempdir().unwrap();
        let (file, link) = (dir.path().join("fit.json"), dir.path().join("latest.json"));
        fs::write(&file, b"old").unwrap();
        std::os::unix::fs::symlink(&file, &link).unwrap();
        write_atomically(&link, b"new").unwrap();
        assert!(fs::symlink_metadata(&link)
            .unwrap()
            .file_type()
            .is_symlink());
        assert_eq!(fs::read(&file).unwrap(), b"new");
    }
}
