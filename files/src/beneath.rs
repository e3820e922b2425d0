//! Opening a file that a client names below a directory, by handle: every component
//! is resolved relative to the directory's open descriptor, none may be a symbolic
//! link or `..`, only a regular file is returned, and opening never blocks (a FIFO is
//! opened non-blocking, then refused). Nothing is checked by path and then opened by
//! path again, so swapping a directory for a link meanwhile gains nothing.
//!
//! Where the kernel has `openat2` (Linux 5.6) it resolves the whole path at once with
//! `RESOLVE_BENEATH | RESOLVE_NO_SYMLINKS`; elsewhere (an older kernel, a sandbox that
//! filters the call) each component is opened with `openat` and `O_NOFOLLOW` from the
//! one before.
#![doc = include_str!("beneath.md")]

use std::ffi::CString;
use std::fs::{File, OpenOptions};
use std::io;
use std::os::fd::{AsRawFd, FromRawFd, OwnedFd};
use std::os::unix::fs::OpenOptionsExt;
use std::path::{Component, Path};

use crate::input::check_kind;

/// Flags of the final open: read only, never following a link, never blocking.
pub(crate) const READ_FLAGS: libc::c_int =
    libc::O_RDONLY | libc::O_NOFOLLOW | libc::O_NONBLOCK | libc::O_NOCTTY | libc::O_CLOEXEC;

/// Opens the regular file `relative` (plain names only) below directory `dir` (see the
/// module). `dir` itself is opened as given.
pub fn open_beneath(dir: &Path, relative: &Path) -> io::Result<File> {
    let names = names(relative)?;
    let base = OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_DIRECTORY | libc::O_CLOEXEC)
        .open(dir)?;
    let file = match open_resolved_beneath(&base, relative) {
        Err(err) if matches!(err.raw_os_error(), Some(libc::ENOSYS | libc::EPERM)) => {
            open_by_components(&base, &names)?
        }
        opened => opened?,
    };
    check_kind(&file.metadata()?)?;
    Ok(file)
}

/// The components of `relative` as C strings: plain names, at least one.
fn names(relative: &Path) -> io::Result<Vec<CString>> {
    let refused = || {
        io::Error::new(
            io::ErrorKind::InvalidInput,
            format!(
                "{}: only plain names below the directory",
                relative.display()
            ),
        )
    };
    let names = relative
        .components()
        .map(|component| match component {
            Component::Normal(name) => CString::new(name.as_encoded_bytes()).map_err(|_| refused()),
            _ => Err(refused()),
        })
        .collect::<io::Result<Vec<_>>>()?;
    if names.is_empty() {
        return Err(refused());
    }
    Ok(names)
}

/// `openat2(base, relative, RESOLVE_BENEATH | RESOLVE_NO_SYMLINKS)`.
#[cfg(target_os = "linux")]
fn open_resolved_beneath(base: &File, relative: &Path) -> io::Result<File> {
    let path = CString::new(relative.as_os_str().as_encoded_bytes())
        .map_err(|_| io::Error::from(io::ErrorKind::InvalidInput))?;
    // SAFETY: `open_how` is plain data (non-exhaustive, so built zeroed); every field
    // the call reads is set below.
    let mut how: libc::open_how = unsafe { std::mem::zeroed() };
    how.flags = READ_FLAGS as u64;
    how.resolve = libc::RESOLVE_BENEATH | libc::RESOLVE_NO_SYMLINKS | libc::RESOLVE_NO_MAGICLINKS;
    // SAFETY: a valid directory descriptor, a NUL-terminated path and an `open_how` of
    // the size passed, all alive for the call.
    let fd = unsafe {
        libc::syscall(
            libc::SYS_openat2,
            base.as_raw_fd(),
            path.as_ptr(),
            &how as *const libc::open_how,
            std::mem::size_of::<libc::open_how>(),
        )
    };
    owned(fd as libc::c_int)
}

#[cfg(not(target_os = "linux"))]
fn open_resolved_beneath(_: &File, _: &Path) -> io::Result<File> {
    Err(io::Error::from_raw_os_error(libc::ENOSYS))
}

/// Walks `names` from `base`: each directory with `O_PATH | O_DIRECTORY |
/// O_NOFOLLOW` (a link is not a directory), the last with [`READ_FLAGS`].
fn open_by_components(base: &File, names: &[CString]) -> io::Result<File> {
    let (last, dirs) = names.split_last().expect("at least one name");
    let mut held: Option<File> = None;
    for name in dirs {
        let at = held.as_ref().unwrap_or(base).as_raw_fd();
        // SAFETY: a valid directory descriptor and a NUL-terminated name.
        let fd = unsafe {
            libc::openat(
                at,
                name.as_ptr(),
                libc::O_PATH | libc::O_DIRECTORY | libc::O_NOFOLLOW | libc::O_CLOEXEC,
            )
        };
        held = Some(owned(fd)?);
    }
    let at = held.as_ref().unwrap_or(base).as_raw_fd();
    // SAFETY: as above.
    owned(unsafe { libc::openat(at, last.as_ptr(), READ_FLAGS) })
}

/// The file of a descriptor a call returned, or the call's error.
fn owned(fd: libc::c_int) -> io::Result<File> {
    if fd < 0 {
        return Err(io::Error::last_os_error());
    }
    // SAFETY: a fresh descriptor that nothing else owns.
    Ok(File::from(unsafe { OwnedFd::from_raw_fd(fd) }))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mkfifo;
    use std::fs;
    use std::io::Read;
    use std::os::unix::fs::symlink;
    use std::sync::atomic::{AtomicBool, Ordering};
    use std::time::Duration;

    /// Both ways of opening: `openat2` where the kernel has it, and component by
    /// component.
    fn both_ways(dir: &Path, relative: &str) -> [io::Result<File>; 2] {
        let base = File::open(dir).unwrap();
        let by_components = names(Path::new(relative))
            .and_then(|names| open_by_components(&base, &names))
            .and_then(|file| check_kind(&file.metadata()?).map(|()| file));
        [open_beneath(dir, Path::new(relative)), by_components]
    }

    fn read(file: io::Result<File>) -> io::Result<String> {
        let mut text = String::new();
        file?.read_to_string(&mut text)?;
        Ok(text)
    }

    #[test]
    fn only_regular_files_below_the_directory_without_links() {
        let dir = tempfile::tempdir().unwrap();
        let (base, outside) = (dir.path().join("scan"), dir.path().join("secret"));
        fs::create_dir_all(base.join("sub")).unwrap();
        fs::create_dir_all(&outside).unwrap();
        fs::write(outside.join("shadow"), b"secret").unwrap();
        fs::write(base.join("sub/ok.csv"), b"ok").unwrap();
        symlink(outside.join("shadow"), base.join("link.csv")).unwrap();
        symlink(&outside, base.join("linked-dir")).unwrap();
        symlink(base.join("sub/ok.csv"), base.join("inner-link.csv")).unwrap();
        symlink(base.join("sub"), base.join("inner-dir")).unwrap();
        mkfifo(&base.join("sub/fifo"));
        for opened in both_ways(&base, "sub/ok.csv") {
            assert_eq!(read(opened).unwrap(), "ok");
        }
        for bad in [
            "link.csv",
            "linked-dir/shadow",
            "inner-link.csv",
            "inner-dir/ok.csv",
            "sub",
            "sub/fifo",
            "missing",
            "../secret/shadow",
            "sub/../sub/ok.csv",
            "/etc/passwd",
            "",
        ] {
            for opened in both_ways(&base, bad) {
                assert!(opened.is_err(), "{bad} was opened");
            }
        }
    }

    #[test]
    fn a_fifo_is_refused_without_blocking() {
        let dir = tempfile::tempdir().unwrap();
        mkfifo(&dir.path().join("fifo"));
        let (tx, rx) = std::sync::mpsc::channel();
        let path = dir.path().to_path_buf();
        std::thread::spawn(move || {
            let _ = tx.send(both_ways(&path, "fifo").map(|r| r.is_err()));
        });
        let refused = rx.recv_timeout(Duration::from_secs(10));
        if refused.is_err() {
            // Unblock the opener before failing, so the test process can end.
            let _ = fs::write(dir.path().join("fifo"), b"");
        }
        assert_eq!(refused.expect("opening a FIFO blocked"), [true, true]);
    }

    /// A directory swapped with a link to outside while it is opened, many times: a
    /// check by path followed by an open by path serves the outside file now and then;
    /// opening by handle never does.
    #[test]
    fn a_directory_swapped_for_a_link_never_leads_outside() {
        let dir = tempfile::tempdir().unwrap();
        let (base, outside) = (dir.path().join("scan"), dir.path().join("etc"));
        fs::create_dir_all(base.join("dir")).unwrap();
        fs::create_dir_all(&outside).unwrap();
        fs::write(base.join("dir/passwd"), b"inside").unwrap();
        fs::write(outside.join("passwd"), b"outside").unwrap();
        symlink(&outside, base.join("link")).unwrap();
        let stop = AtomicBool::new(false);
        std::thread::scope(|scope| {
            scope.spawn(|| {
                // Swap `dir` and `link` (a directory and a link to outside) back and
                // forth by renames through a third name.
                let (dir, link, spare) = (base.join("dir"), base.join("link"), base.join("spare"));
                while !stop.load(Ordering::Relaxed) {
                    let _ = fs::rename(&dir, &spare);
                    let _ = fs::rename(&link, &dir);
                    let _ = fs::rename(&spare, &link);
                }
            });
            let (mut inside, mut outside) = (0, 0);
            for _ in 0..20_000 {
                for opened in both_ways(&base, "dir/passwd") {
                    match read(opened).as_deref() {
                        Ok("inside") => inside += 1,
                        Ok(_) => outside += 1,
                        Err(_) => {}
                    }
                }
            }
            stop.store(true, Ordering::Relaxed);
            assert_eq!(outside, 0, "a file outside the directory was served");
            assert!(inside > 0, "the race never let the file inside be read");
        });
    }
}
