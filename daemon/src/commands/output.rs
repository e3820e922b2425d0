//! Where the offline commands write their results: through
//! `gonio_files::output::write_atomically_with`, so a regular file (or a new path) is
//! written to a temporary file beside it and renamed over it, a device (`/dev/null`) or
//! a FIFO is written in place, a directory is refused; on failure only the temporary is
//! removed. A command that writes a directory of results through a writer it does not
//! control (`gonio study`) writes them into a temporary directory first, then each file
//! into place as above.

use std::fs;
use std::path::{Path, PathBuf};

use anyhow::{anyhow, Context};
use gonio_files::output::{write_atomically_with, AtomicWriteError};

use crate::interrupt::RemoveOnInterrupt;

/// Writes `path` through `write`, which gets the path to write to.
pub fn write_output<E: std::fmt::Display>(
    path: &Path,
    write: impl FnOnce(&Path) -> Result<(), E>,
) -> anyhow::Result<()> {
    write_atomically_with(path, write).map_err(|err| {
        let reason = match err {
            AtomicWriteError::Write(err) => err.to_string(),
            AtomicWriteError::Io(err) => err.to_string(),
        };
        anyhow!("writing {}: {reason}", path.display())
    })
}

/// Writes files into directory `out` (created if missing) through `write`, which gets a
/// fresh temporary directory inside `out` and returns the paths it wrote there; each is
/// then moved into place by [`write_output`]. The temporary directory is removed
/// whatever happens (on Ctrl-C too). Returns the paths in `out`.
pub fn write_output_files(
    out: &Path,
    write: impl FnOnce(&Path) -> anyhow::Result<Vec<PathBuf>>,
) -> anyhow::Result<Vec<PathBuf>> {
    fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let (work, _removed_on_interrupt) = RemoveOnInterrupt::tempdir_in(
        tempfile::Builder::new()
            .prefix(".gonio-output-")
            .suffix(".partial"),
        out,
    )
    .with_context(|| format!("creating a temporary directory in {}", out.display()))?;
    let written = write(work.path())?;
    written
        .iter()
        .map(|path| {
            let name = path.strip_prefix(work.path()).with_context(|| {
                format!("{} was written outside {}", path.display(), out.display())
            })?;
            let target = out.join(name);
            if let Some(parent) = target.parent() {
                fs::create_dir_all(parent)
                    .with_context(|| format!("creating {}", parent.display()))?;
            }
            write_output(&target, |temp| fs::rename(path, temp))?;
            Ok(target)
        })
        .collect()
}
