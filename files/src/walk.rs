//! Every regular file below a directory, visited by handle: each directory is opened
//! relative to its parent's open descriptor and listed through it, each file opened
//! relative to its directory's descriptor, none with a link followed (`O_NOFOLLOW`), a
//! file never blocking on open (a FIFO swapped in is opened non-blocking and skipped).
//! What is visited is the file opened: nothing is checked by path and opened by path
//! again, so a directory or a file swapped for a link (to `/etc`, say) while the walk
//! runs is skipped, never followed. Links, FIFOs, sockets and devices are skipped.

use std::ffi::{CStr, CString, OsStr, OsString};
use std::fs::{File, Metadata, OpenOptions};
use std::io;
use std::os::fd::{AsRawFd, FromRawFd, OwnedFd};
use std::os::unix::ffi::{OsStrExt, OsStringExt};
use std::os::unix::fs::OpenOptionsExt;
use std::path::{Path, PathBuf};

use crate::beneath::READ_FLAGS;

/// Most directories nested below the one walked that are visited (deeper ones are
/// skipped): a bound on the descriptors one walk holds open.
pub const MAX_DEPTH: usize = 32;

/// Visits every regular file below `dir` whose every path component `keep` accepts, in
/// byte order of their names, directory by directory (see the module). `visit` gets
/// the path relative to `dir`, the open file and its metadata (of the descriptor); its
/// error ends the walk. An entry that vanishes or changes kind meanwhile is skipped.
pub fn walk_beneath(
    dir: &Path,
    keep: &dyn Fn(&OsStr) -> bool,
    visit: &mut dyn FnMut(&Path, File, Metadata) -> io::Result<()>,
) -> io::Result<()> {
    let base = OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_DIRECTORY | libc::O_CLOEXEC)
        .open(dir)?;
    walk(&base, &mut PathBuf::new(), 0, keep, visit)
}

fn walk(
    dir: &File,
    relative: &mut PathBuf,
    depth: usize,
    keep: &dyn Fn(&OsStr) -> bool,
    visit: &mut dyn FnMut(&Path, File, Metadata) -> io::Result<()>,
) -> io::Result<()> {
    for name in names(dir)? {
        if !keep(&name) {
            continue;
        }
        let Ok(c_name) = CString::new(name.as_bytes()) else {
            continue;
        };
        match kind_at(dir, &c_name) {
            Some(libc::S_IFDIR) if depth < MAX_DEPTH => {
                let flags = libc::O_RDONLY | libc::O_DIRECTORY | libc::O_NOFOLLOW | libc::O_CLOEXEC;
                let Ok(sub) = open_at(dir, &c_name, flags) else {
                    continue;
                };
                relative.push(&name);
                let walked = walk(&sub, relative, depth + 1, keep, visit);
                relative.pop();
                walked?;
            }
            Some(libc::S_IFREG) => {
                let Ok(file) = open_at(dir, &c_name, READ_FLAGS) else {
                    continue;
                };
                // The kind of what was opened: the name may name something else now.
                let Ok(meta) = file.metadata() else {
                    continue;
                };
                if !meta.file_type().is_file() {
                    continue;
                }
                relative.push(&name);
                let visited = visit(relative, file, meta);
                relative.pop();
                visited?;
            }
            _ => {}
        }
    }
    Ok(())
}

/// The names in directory `dir` but `.` and `..`, sorted by bytes.
fn names(dir: &File) -> io::Result<Vec<OsString>> {
    // SAFETY: duplicating a valid descriptor; the copy is owned by the stream below.
    let copy = unsafe { libc::fcntl(dir.as_raw_fd(), libc::F_DUPFD_CLOEXEC, 0) };
    if copy < 0 {
        return Err(io::Error::last_os_error());
    }
    // SAFETY: `copy` is a fresh directory descriptor; on success the stream owns it.
    let stream = unsafe { libc::fdopendir(copy) };
    if stream.is_null() {
        let err = io::Error::last_os_error();
        // SAFETY: `copy` was not taken by the stream.
        drop(unsafe { OwnedFd::from_raw_fd(copy) });
        return Err(err);
    }
    let mut names = Vec::new();
    // SAFETY: `stream` is a valid directory stream until `closedir` below; each entry's
    // name is a NUL-terminated string valid until the next `readdir`, copied at once.
    unsafe {
        libc::rewinddir(stream);
        loop {
            let entry = libc::readdir(stream);
            if entry.is_null() {
                break;
            }
            let name = CStr::from_ptr((*entry).d_name.as_ptr()).to_bytes();
            if name != b"." && name != b".." {
                names.push(OsString::from_vec(name.to_vec()));
            }
        }
        libc::closedir(stream);
    }
    names.sort();
    Ok(names)
}

/// The kind (`S_IFMT` bits) of `name` in `dir`, the link itself for a link.
fn kind_at(dir: &File, name: &CStr) -> Option<libc::mode_t> {
    // SAFETY: `stat` is plain data, written by the call.
    let mut stat: libc::stat = unsafe { std::mem::zeroed() };
    // SAFETY: a valid descriptor, a NUL-terminated name and a `stat` to fill.
    let done = unsafe {
        libc::fstatat(
            dir.as_raw_fd(),
            name.as_ptr(),
            &mut stat,
            libc::AT_SYMLINK_NOFOLLOW,
        )
    };
    (done == 0).then_some(stat.st_mode & libc::S_IFMT)
}

/// `openat(dir, name, flags)`.
fn open_at(dir: &File, name: &CStr, flags: libc::c_int) -> io::Result<File> {
    // SAFETY: a valid directory descriptor and a NUL-terminated name.
    let fd = unsafe { libc::openat(dir.as_raw_fd(), name.as_ptr(), flags) };
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

    fn visited(dir: &Path) -> Vec<(Vec<u8>, String)> {
        let mut out = Vec::new();
        walk_beneath(
            dir,
            &|name| !name.as_bytes().starts_with(b"."),
            &mut |rel, mut file, _| {
                let mut text = String::new();
                file.read_to_string(&mut text)?;
                out.push((rel.as_os_str().as_bytes().to_vec(), text));
                Ok(())
            },
        )
        .unwrap();
        out
    }

    #[test]
    fn regular_files_only_with_every_name_and_no_link_followed() {
        let dir = tempfile::tempdir().unwrap();
        let (base, outside) = (dir.path().join("scan"), dir.path().join("etc"));
        fs::create_dir_all(base.join("theta_l_-20.0")).unwrap();
        fs::create_dir_all(&outside).unwrap();
        fs::write(outside.join("passwd"), "root").unwrap();
        fs::write(base.join("theta_l_-20.0/exp_00.tiff"), "frame").unwrap();
        fs::write(base.join(".hidden"), "no").unwrap();
        let odd = OsStr::from_bytes(b"odd \"name\"\n\xff");
        fs::write(base.join(odd), "odd").unwrap();
        symlink(&outside, base.join("linked")).unwrap();
        symlink(outside.join("passwd"), base.join("passwd")).unwrap();
        mkfifo(&base.join("fifo"));
        let mut expected = vec![
            (odd.as_bytes().to_vec(), "odd".to_owned()),
            (b"theta_l_-20.0/exp_00.tiff".to_vec(), "frame".to_owned()),
        ];
        expected.sort();
        assert_eq!(visited(&base), expected);
    }

    #[test]
    fn directories_deeper_than_the_bound_are_skipped() {
        let dir = tempfile::tempdir().unwrap();
        let mut deep = dir.path().to_path_buf();
        for _ in 0..=MAX_DEPTH + 1 {
            deep.push("d");
            fs::create_dir(&deep).unwrap();
            fs::write(deep.join("f"), "x").unwrap();
        }
        assert_eq!(visited(dir.path()).len(), MAX_DEPTH);
    }

    /// A directory swapped for a link to outside while walked, many times: nothing
    /// outside is ever visited.
    #[test]
    fn a_directory_swapped_for_a_link_is_never_followed() {
        let dir = tempfile::tempdir().unwrap();
        let (base, outside) = (dir.path().join("scan"), dir.path().join("etc"));
        fs::create_dir_all(base.join("dir")).unwrap();
        fs::create_dir_all(&outside).unwrap();
        fs::write(base.join("dir/passwd"), "inside").unwrap();
        fs::write(outside.join("passwd"), "outside").unwrap();
        symlink(&outside, base.join("link")).unwrap();
        let stop = AtomicBool::new(false);
        std::thread::scope(|scope| {
            scope.spawn(|| {
                let (dir, link, spare) = (base.join("dir"), base.join("link"), base.join("spare"));
                while !stop.load(Ordering::Relaxed) {
                    let _ = fs::rename(&dir, &spare);
                    let _ = fs::rename(&link, &dir);
                    let _ = fs::rename(&spare, &link);
                }
            });
            let (mut inside, mut outside) = (0, 0);
            for _ in 0..5_000 {
                for (_, text) in visited(&base) {
                    if text == "inside" {
                        inside += 1;
                    } else {
                        outside += 1;
                    }
                }
            }
            stop.store(true, Ordering::Relaxed);
            assert_eq!(outside, 0, "a file outside the directory was visited");
            assert!(inside > 0, "the race never let the file inside be visited");
        });
    }
}
