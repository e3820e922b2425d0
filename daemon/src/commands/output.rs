//! Where the offline commands write their results: through
//! `gonio_files::output::write_atomically_with`, so a regular file (or a new path) is
//! written to a temporary file beside it and renamed over it, a device (`/dev/null`) or
//! a FIFO is written in place, a directory is refused; on failure only the temporary is
//! removed. A command that writes a directory of results through a writer it does not
//! control (`gonio study`) writes them into a temporary directory first, then each file
//! into place as above. No command writes over a file it reads ([`refuse_overwriting`]).

use std::fs;
use std::os::unix::fs::MetadataExt;
use std::path::{Component, Path, PathBuf};

use anyhow::{anyhow, bail, Context};
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

/// The files of a scan directory that the commands reading the scan read: these at its
/// top, and everything in its θL directories (`theta_l_<θL>/`: frames and sidecars).
const SCAN_FILES: [&str; 4] = ["setup.json", "plan.json", "truth.json", "reference.csv"];

/// The (device, inode) of an existing file, following links.
fn identity(path: &Path) -> Option<(u64, u64)> {
    fs::metadata(path).ok().map(|m| (m.dev(), m.ino()))
}

/// Whether `path` (existing) is a file that a command reading scan directory `dir` reads.
fn read_from_scan(path: &Path, dir: &Path) -> bool {
    let (Ok(path), Ok(dir)) = (path.canonicalize(), dir.canonicalize()) else {
        return false;
    };
    let Ok(inside) = path.strip_prefix(&dir) else {
        return false;
    };
    let parts: Vec<&std::ffi::OsStr> = inside
        .components()
        .filter_map(|c| match c {
            Component::Normal(name) => Some(name),
            _ => None,
        })
        .collect();
    match parts.as_slice() {
        [name] => SCAN_FILES.iter().any(|f| name == f),
        [first, ..] => first.to_string_lossy().starts_with("theta_l_"),
        [] => false,
    }
}

/// The results of a scan directory that `report` and `colour` read: samples.csv and the
/// fit JSONs (`fit-*.json`) at its top.
pub fn scan_results(dir: &Path) -> Vec<PathBuf> {
    let Ok(entries) = fs::read_dir(dir) else {
        return Vec::new();
    };
    entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.file_name().and_then(|n| n.to_str()).is_some_and(|n| {
                n == "samples.csv" || (n.starts_with("fit-") && n.ends_with(".json"))
            })
        })
        .collect()
}

/// Refuses to write `out` when it is one of the command's input `files` (the same file
/// by any name) or a file of one of its input scan directories `scans`
/// ([`SCAN_FILES`], anything in a θL directory): the result would replace what it was
/// made from.
pub fn refuse_overwriting(out: &Path, files: &[PathBuf], scans: &[&Path]) -> anyhow::Result<()> {
    let Some(target) = identity(out) else {
        // Nothing there yet: nothing to lose.
        return Ok(());
    };
    if let Some(input) = files.iter().find(|f| identity(f) == Some(target)) {
        bail!(
            "--out {} is the input {}: writing it would replace the input (choose another output path)",
            out.display(),
            input.display()
        );
    }
    if let Some(scan) = scans.iter().find(|dir| read_from_scan(out, dir)) {
        bail!(
            "--out {} is a file of the scan {} (its setup, plan, truth, reference or captures): writing it would replace the scan's data (choose another output path)",
            out.display(),
            scan.display()
        );
    }
    Ok(())
}
