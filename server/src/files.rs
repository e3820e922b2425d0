//! Durable file writes and safe paths inside the data directory.

use std::ffi::OsStr;
use std::fs;
use std::io;
use std::os::unix::ffi::OsStrExt;
use std::os::unix::fs::MetadataExt;
use std::path::{Component, Path, PathBuf};

use gonio_files::output::partial_writer;
pub use gonio_files::output::{is_partial, AtomicWriteError};
use gonio_files::output::{write_atomically, write_atomically_with};

/// Writes `bytes` to `path` atomically (see `gonio_files::output`), creating the
/// directory first.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    fs::create_dir_all(parent(path))?;
    write_atomically(path, bytes)
}

/// Runs `write` on a temporary path beside `path`, then fsyncs and renames it into
/// place (for writers that take a path, such as image encoders), creating the
/// directory first.
pub fn write_atomic_with<E>(
    path: &Path,
    write: impl FnOnce(&Path) -> Result<(), E>,
) -> Result<(), AtomicWriteError<E>> {
    fs::create_dir_all(parent(path))?;
    write_atomically_with(path, write)
}

fn parent(path: &Path) -> &Path {
    path.parent().unwrap_or(Path::new("."))
}

/// Whose temporaries [`remove_partials`] leaves in place.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Writers {
    /// Those of every running process: a write in flight, ours included.
    Running,
    /// Those of every running process but this one, which has written nothing yet (at
    /// start, an earlier daemon with the same process id left them).
    RunningOthers,
}

/// Removes the temporary files of atomic writes under `dir`, recursively, except those
/// whose writer (the process id in their name) `keep` says is still writing; a
/// temporary that names no writer is removed. Returns how many it removed.
pub fn remove_partials(dir: &Path, keep: Writers) -> std::io::Result<usize> {
    let mut removed = 0;
    let Ok(entries) = fs::read_dir(dir) else {
        return Ok(0);
    };
    for entry in entries {
        let entry = entry?;
        let path = entry.path();
        let name = entry.file_name();
        let name = name.to_string_lossy();
        if entry.file_type()?.is_dir() {
            removed += remove_partials(&path, keep)?;
        } else if is_partial(&name) && !partial_writer(&name).is_some_and(|pid| keep.has(pid)) {
            match fs::remove_file(&path) {
                Ok(()) => removed += 1,
                // Its writer renamed or removed it meanwhile.
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
                Err(e) => return Err(e),
            }
        }
    }
    Ok(removed)
}

impl Writers {
    /// Whether process `pid` is one of these writers.
    fn has(self, pid: u32) -> bool {
        let ours = pid == std::process::id();
        match self {
            Writers::Running => ours || process_exists(pid),
            Writers::RunningOthers => !ours && process_exists(pid),
        }
    }
}

/// Whether a process `pid` exists (signal 0: nothing is sent).
fn process_exists(pid: u32) -> bool {
    let Ok(pid) = libc::pid_t::try_from(pid) else {
        return false;
    };
    if pid <= 0 {
        return false;
    }
    // SAFETY: kill with signal 0 sends nothing; it only checks that the process exists.
    let found = unsafe { libc::kill(pid, 0) } == 0;
    found || std::io::Error::last_os_error().raw_os_error() == Some(libc::EPERM)
}

/// Joins a relative, user-supplied path under `base`, refusing anything that could
/// leave it (`..`, absolute paths) and hidden components.
pub fn safe_join(base: &Path, relative: &str) -> Option<PathBuf> {
    let rel = Path::new(relative);
    let mut out = base.to_path_buf();
    let mut any = false;
    for component in rel.components() {
        match component {
            Component::Normal(part) if is_visible(part) => {
                out.push(part);
                any = true;
            }
            _ => return None,
        }
    }
    any.then_some(out)
}

/// Whether a client may see a directory entry of this name: not hidden (dot files,
/// the temporaries of atomic writes).
fn is_visible(name: &OsStr) -> bool {
    !name.as_bytes().starts_with(b".")
}

/// Whether a client may read this open file: a regular file with one link. A file
/// with more is also elsewhere, maybe outside the scan (a hard link to DATA/token).
fn is_own_file(meta: &fs::Metadata) -> bool {
    meta.file_type().is_file() && meta.nlink() == 1
}

/// Opens a file under `base` for reading by a client: `relative` must be a path
/// [`safe_join`] accepts, and is opened by handle relative to `base`
/// (`gonio_files::beneath`): no link followed at any component, regular files with
/// one link only, never blocking on a FIFO.
pub fn open_under(base: &Path, relative: &str) -> Option<fs::File> {
    safe_join(base, relative)?;
    let file = gonio_files::beneath::open_beneath(base, Path::new(relative)).ok()?;
    is_own_file(&file.metadata().ok()?).then_some(file)
}

/// Visits, by handle, every file below `base` that [`open_under`] would open (and some
/// whose names are not UTF-8, which no client can name): `visit` gets its path
/// relative to `base`, the open file and its metadata (`gonio_files::walk`).
pub fn servable_files(
    base: &Path,
    visit: &mut dyn FnMut(&Path, fs::File, fs::Metadata) -> io::Result<()>,
) -> io::Result<()> {
    gonio_files::walk::walk_beneath(base, &is_visible, &mut |relative, file, meta| {
        if is_own_file(&meta) {
            visit(relative, file, meta)
        } else {
            Ok(())
        }
    })
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

/// `message` with every path under `dirs` (most specific first) made relative to it,
/// so that an answer shows no path of the server (`theta_l_-20.0/exp_00.json`, not
/// `/srv/gonio-data/scans/3/theta_l_-20.0/exp_00.json`).
pub fn without_server_paths(message: &str, dirs: &[&Path]) -> String {
    dirs.iter().fold(message.to_owned(), |message, dir| {
        let dir = dir.display().to_string();
        message.replace(&format!("{dir}/"), "").replace(&dir, ".")
    })
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
    fn open_under_serves_plain_files_only() {
        let dir = tempfile::tempdir().unwrap();
        let base = dir.path();
        fs::create_dir_all(base.join("sub")).unwrap();
        fs::write(base.join("sub/ok.csv"), b"ok").unwrap();
        fs::write(base.join("sub/.x.1.partial"), b"half").unwrap();
        std::os::unix::fs::symlink(base.join("sub/ok.csv"), base.join("link.csv")).unwrap();
        fs::write(base.join("token"), b"secret").unwrap();
        fs::hard_link(base.join("token"), base.join("sub/hard.csv")).unwrap();
        assert!(open_under(base, "sub/ok.csv").is_some());
        for bad in [
            "sub/hard.csv",
            "token",
            "link.csv",
            "sub",
            "sub/.x.1.partial",
            "sub/../sub/ok.csv",
            "missing",
        ] {
            assert!(open_under(base, bad).is_none(), "{bad}");
        }
    }

    #[test]
    fn the_files_visited_are_those_open_under_opens() {
        let dir = tempfile::tempdir().unwrap();
        let base = dir.path();
        fs::create_dir_all(base.join("sub")).unwrap();
        fs::create_dir_all(base.join(".hidden")).unwrap();
        fs::write(base.join("sub/ok.csv"), b"ok").unwrap();
        fs::write(base.join(".hidden/x.csv"), b"x").unwrap();
        fs::write(base.join("sub/.x.1.partial"), b"half").unwrap();
        fs::write(base.join("token"), b"secret").unwrap();
        fs::hard_link(base.join("token"), base.join("sub/hard.csv")).unwrap();
        std::os::unix::fs::symlink(base.join("sub"), base.join("linked")).unwrap();
        let mut visited = Vec::new();
        servable_files(base, &mut |relative, _, _| {
            visited.push(relative.to_str().unwrap().to_owned());
            Ok(())
        })
        .unwrap();
        assert_eq!(visited, ["sub/ok.csv"]);
        for name in [
            "sub/ok.csv",
            "sub/hard.csv",
            "token",
            ".hidden/x.csv",
            "linked/ok.csv",
        ] {
            assert_eq!(
                open_under(base, name).is_some(),
                visited.iter().any(|v| v == name),
                "{name}"
            );
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
        assert_eq!(remove_partials(&dir, Writers::Running).unwrap(), 1);
        let names: Vec<_> = fs::read_dir(dir.join("sub")).unwrap().collect();
        assert_eq!(names.len(), 1);
        fs::remove_dir_all(dir).unwrap();
    }

    #[test]
    fn only_the_temporaries_of_writers_gone_are_removed() {
        let dir = tempfile::tempdir().unwrap();
        let sub = dir.path().join("theta_l_-20.0");
        fs::create_dir_all(&sub).unwrap();
        // A process that has ended: its id is free until reused.
        let mut child = std::process::Command::new("true").spawn().unwrap();
        let gone = child.id();
        child.wait().unwrap();
        let ours = std::process::id();
        // The parent of this test: a process that is running.
        let running = std::os::unix::process::parent_id();
        let name = |pid: u32| format!(".exp_00.tiff.{pid}.0.partial");
        for pid in [gone, ours, running] {
            fs::write(sub.join(name(pid)), b"half").unwrap();
        }
        fs::write(sub.join(".study.tmp.partial"), b"half").unwrap();
        fs::write(sub.join("exp_00.tiff"), b"whole").unwrap();
        let left = || {
            let mut names: Vec<String> = fs::read_dir(&sub)
                .unwrap()
                .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
                .collect();
            names.sort();
            names
        };
        // A scan that ended while this process writes into it keeps that write.
        assert_eq!(remove_partials(dir.path(), Writers::Running).unwrap(), 2);
        let mut expected = vec![name(ours), name(running), "exp_00.tiff".to_owned()];
        expected.sort();
        assert_eq!(left(), expected);
        // At start, this process has written nothing: a temporary with its id is an
        // earlier daemon's.
        assert_eq!(
            remove_partials(dir.path(), Writers::RunningOthers).unwrap(),
            1
        );
        let mut expected = vec![name(running), "exp_00.tiff".to_owned()];
        expected.sort();
        assert_eq!(left(), expected);
    }
    #[test]
    fn messages_show_paths_relative_to_the_scan_or_data_directory() {
        let (scan, data) = (Path::new("/srv/data/scans/3"), Path::new("/srv/data"));
        let message = "/srv/data/scans/3/theta_l_-20.0/exp_00.json: sidecar field 'iso'; \
                       writing /srv/data/setup.json; reading /srv/data/scans/3";
        assert_eq!(
            without_server_paths(message, &[scan, data]),
            "theta_l_-20.0/exp_00.json: sidecar field 'iso'; writing setup.json; reading ."
        );
    }
}
