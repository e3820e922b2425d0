//! The captures of a scan directory: every image with a capture extension below it,
//! in plain directories; a θL folder (`theta_l_…`) or a capture that is a symbolic link
//! is refused, never followed.

use std::fs;
use std::path::{Path, PathBuf};

use crate::capture;

/// Why the captures could not be found.
#[derive(Debug)]
pub(super) enum FindError {
    /// A directory could not be listed.
    Walk {
        path: PathBuf,
        error: std::io::Error,
    },
    /// A θL folder or a capture is a symbolic link.
    Link { path: PathBuf },
}

/// Whether the entry at `path` of type `kind` is a symbolic link named as a θL folder
/// (`theta_l_…`) or a capture: refused, never followed.
pub(crate) fn refused_link(path: &Path, kind: &fs::FileType) -> bool {
    let named_like_capture = capture::is_capture_path(path)
        || path
            .file_name()
            .is_some_and(|n| n.as_encoded_bytes().starts_with(b"theta_l_"));
    kind.is_symlink() && named_like_capture
}

/// Adds the capture images below `dir` to `out` (see the module).
pub(super) fn find_captures(dir: &Path, out: &mut Vec<PathBuf>) -> Result<(), FindError> {
    let walk_error = |error| FindError::Walk {
        path: dir.to_path_buf(),
        error,
    };
    for entry in fs::read_dir(dir).map_err(walk_error)? {
        let entry = entry.map_err(walk_error)?;
        let path = entry.path();
        let kind = entry.file_type().map_err(walk_error)?;
        if refused_link(&path, &kind) {
            return Err(FindError::Link { path });
        }
        if kind.is_dir() {
            find_captures(&path, out)?;
        } else if kind.is_file() && capture::is_capture_path(&path) {
            out.push(path);
        }
    }
    Ok(())
}
