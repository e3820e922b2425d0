//! Where the offline commands write their results. A regular file (or a new path) is
//! written to a temporary file beside it and renamed over it, so a reader never sees
//! half of it; anything else (a device such as `/dev/null`, a FIFO) is written in place.
//! On failure only the temporary is removed: a path the command did not create is
//! never removed.

use std::fs;
use std::path::Path;

use anyhow::{anyhow, bail};
use gonio_drivers::atomic_file::write_atomically_with;

/// Writes `path` through `write`, which gets the path to write to.
pub fn write_output<E: std::fmt::Display>(
    path: &Path,
    write: impl FnOnce(&Path) -> Result<(), E>,
) -> anyhow::Result<()> {
    let failed = |reason: String| anyhow!("writing {}: {reason}", path.display());
    match fs::metadata(path) {
        Ok(meta) if meta.is_dir() => bail!("writing {}: it is a directory", path.display()),
        Ok(meta) if !meta.is_file() => return write(path).map_err(|e| failed(e.to_string())),
        _ => {}
    }
    // A link to a regular file: replace the file it names, not the link.
    let target = fs::canonicalize(path).unwrap_or_else(|_| path.to_path_buf());
    write_atomically_with(&target, write).map_err(|e| failed(e.to_string()))
}
