//! Free space as a state (docs/ARCHITECTURE.md, "Daemon"): what a step will write,
//! the free space of the data directory's filesystem, and whether an error means the
//! disk is full. A step runs only while its output fits above the reserve kept for the
//! journal; otherwise its scan waits ("disk full: N GB free, M GB needed"). Another
//! process may still fill the disk: the journal then writes into space held for it, a
//! preallocated file it deletes when it finds the disk full ([`JOURNAL_RESERVE_FILE`]).

use std::io;
use std::path::{Path, PathBuf};

use gonio_files::input::{read_input_to_string, MAX_SMALL_FILE_BYTES};
use gonio_processing::geometry::Setup;

use super::plan::{ScanPlan, Step};

/// Pixels a frame is taken to have when the scan's setup does not say (24 MP).
const DEFAULT_PIXELS: u64 = 24_000_000;
/// Frames an automatic bracket is taken to have before metering chose it.
const AUTO_BRACKET_FRAMES: u64 = 8;
/// Bytes of a capture beyond its 16-bit RGB pixels (file structure, sidecar).
const FRAME_OVERHEAD_BYTES: u64 = 1 << 20;
/// Outputs of the steps that write tables and fits (samples, extraction, fits).
const SMALL_OUTPUT_BYTES: u64 = 16 << 20;

/// The file that holds space for the journal, beside the database in the data
/// directory: its blocks are allocated, so other writers cannot take them. The store
/// deletes it when a write of the journal finds the disk full, and writes again.
pub const JOURNAL_RESERVE_FILE: &str = "journal.reserve";

/// The journal's reserve file of the database at `db`.
pub fn journal_reserve_path(db: &Path) -> PathBuf {
    db.with_file_name(JOURNAL_RESERVE_FILE)
}

/// Where the free space is read from.
#[derive(Debug, Clone)]
pub struct Probe {
    /// The data directory, whose filesystem is measured.
    pub dir: PathBuf,
    /// Space that must stay free beyond any step's output, bytes (`[storage]
    /// reserve_bytes`: the journal must always be able to write).
    pub reserve_bytes: u64,
    /// A file holding the free space in bytes, read instead of the filesystem (the
    /// emulator's test hook for a disk that fills up and empties).
    pub emulated: Option<PathBuf>,
    /// Size of the journal's reserve file ([`JOURNAL_RESERVE_FILE`]), bytes; 0 for none.
    pub journal_reserve_bytes: u64,
}

impl Probe {
    /// Free bytes for an unprivileged writer on the data directory's filesystem.
    pub fn free_bytes(&self) -> io::Result<u64> {
        if let Some(path) = &self.emulated {
            let text = read_input_to_string(path, MAX_SMALL_FILE_BYTES)?;
            return text.trim().parse().map_err(|e| {
                io::Error::new(
                    io::ErrorKind::InvalidData,
                    format!("{}: not a byte count: {e}", path.display()),
                )
            });
        }
        statvfs_free(&self.dir)
    }

    /// `Ok` when `need` bytes fit above the reserve, else the reason the step waits.
    /// A filesystem that cannot be measured does not stop a step (its writes report
    /// their own errors).
    pub fn check(&self, need: u64) -> Result<(), String> {
        let Ok(free) = self.free_bytes() else {
            return Ok(());
        };
        let needed = need.saturating_add(self.reserve_bytes);
        if free >= needed {
            Ok(())
        } else {
            Err(disk_full(free, needed))
        }
    }

    /// Makes the journal's reserve file in the data directory when it is missing or
    /// not whole (the store deleted it when the disk was full) and the free space holds
    /// it above [`Probe::reserve_bytes`]; returns whether it made it. One `stat` when
    /// the file is in place.
    pub fn keep_journal_reserve(&self) -> io::Result<bool> {
        let bytes = self.journal_reserve_bytes;
        let path = self.dir.join(JOURNAL_RESERVE_FILE);
        if bytes == 0 || std::fs::metadata(&path).is_ok_and(|m| m.len() == bytes) {
            return Ok(false);
        }
        let held = std::fs::metadata(&path).map_or(0, |m| m.len());
        if self.free_bytes()?.saturating_add(held) < bytes.saturating_add(self.reserve_bytes) {
            return Ok(false);
        }
        allocate(&path, bytes).inspect_err(|_| {
            let _ = std::fs::remove_file(&path);
        })?;
        Ok(true)
    }

    /// The reason a step waits after a write found the disk full, `need` bytes to go.
    pub fn full_reason(&self, need: u64) -> String {
        let needed = need.saturating_add(self.reserve_bytes);
        disk_full(self.free_bytes().unwrap_or(0), needed)
    }
}

/// Makes `path` a file of `bytes` allocated bytes (posix_fallocate: blocks taken, not a
/// sparse file), synced.
fn allocate(path: &Path, bytes: u64) -> io::Result<()> {
    use std::os::fd::AsRawFd;
    use std::os::unix::fs::OpenOptionsExt;
    let file = std::fs::OpenOptions::new()
        .write(true)
        .create(true)
        .truncate(true)
        .mode(0o600)
        .open(path)?;
    let len =
        libc::off_t::try_from(bytes).map_err(|e| io::Error::new(io::ErrorKind::InvalidInput, e))?;
    // SAFETY: posix_fallocate only allocates blocks of the open descriptor it is given;
    // it reports errors through its return value.
    let err = unsafe { libc::posix_fallocate(file.as_raw_fd(), 0, len) };
    if err != 0 {
        return Err(io::Error::from_raw_os_error(err));
    }
    file.sync_all()
}

/// "disk full: N GB free, M GB needed".
fn disk_full(free: u64, needed: u64) -> String {
    format!(
        "disk full: {:.2} GB free, {:.2} GB needed",
        free as f64 / 1e9,
        needed as f64 / 1e9
    )
}

/// Whether a scan's reason says it waits for disk space.
pub fn is_disk_wait(reason: &str) -> bool {
    reason.starts_with("disk full:")
}

// The widths of `fsblkcnt_t` and `c_ulong` vary with the target (u64 on this one).
#[allow(clippy::useless_conversion)]
fn statvfs_free(dir: &Path) -> io::Result<u64> {
    use std::os::unix::ffi::OsStrExt;
    let path = std::ffi::CString::new(dir.as_os_str().as_bytes())
        .map_err(|e| io::Error::new(io::ErrorKind::InvalidInput, e))?;
    // SAFETY: statvfs is a plain C struct, all-zero is a valid value, and the call
    // only fills it from a NUL-terminated path we own.
    let mut stat: libc::statvfs = unsafe { std::mem::zeroed() };
    // SAFETY: as above.
    if unsafe { libc::statvfs(path.as_ptr(), &mut stat) } != 0 {
        return Err(io::Error::last_os_error());
    }
    Ok(u64::from(stat.f_bavail).saturating_mul(u64::from(stat.f_frsize)))
}

/// Pixels of the frames of a scan with `setup` (image width × height).
pub fn frame_pixels(setup: Option<&Setup>) -> u64 {
    setup.map_or(DEFAULT_PIXELS, |s| {
        u64::from(s.image_width).saturating_mul(u64::from(s.image_height))
    })
}

/// Bytes a capture of `pixels` may take: 16-bit RGB, uncompressed.
fn frame_bytes(pixels: u64) -> u64 {
    pixels
        .saturating_mul(6)
        .saturating_add(FRAME_OVERHEAD_BYTES)
}

/// Bytes an HDR map of `pixels` may take: float32 RGB, uncompressed.
fn map_bytes(pixels: u64) -> u64 {
    pixels
        .saturating_mul(12)
        .saturating_add(FRAME_OVERHEAD_BYTES)
}

/// Bytes `step` of a scan planned as `plan`, with frames of `pixels`, will write: before
/// a move to a new θL its whole bracket and its map, a frame per capture, a map per HDR
/// merge.
pub fn step_need(step: &Step, plan: &ScanPlan, pixels: u64) -> u64 {
    match step {
        Step::Home => 0,
        Step::Move { .. } => {
            let frames = if plan.auto_bracket {
                AUTO_BRACKET_FRAMES
            } else {
                plan.shutter_s.len() as u64
            };
            frames
                .saturating_mul(frame_bytes(pixels))
                .saturating_add(map_bytes(pixels))
        }
        Step::Meter { .. } | Step::Capture { .. } => frame_bytes(pixels),
        Step::Hdr { .. } => map_bytes(pixels),
        Step::Samples { .. } | Step::Extract | Step::Fit { .. } => SMALL_OUTPUT_BYTES,
    }
}

/// Whether an error's message says a write found the disk (or the quota) full.
pub fn says_disk_full(message: &str) -> bool {
    [
        "No space left on device",
        "Disk quota exceeded",
        "database or disk is full",
    ]
    .iter()
    .any(|m| message.contains(m))
}

/// Whether `err` is a full disk or quota.
pub fn is_disk_full(err: &io::Error) -> bool {
    matches!(
        err.kind(),
        io::ErrorKind::StorageFull | io::ErrorKind::QuotaExceeded
    ) || matches!(err.raw_os_error(), Some(libc::ENOSPC | libc::EDQUOT))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plan(shutter_s: &[f64], auto_bracket: bool) -> ScanPlan {
        ScanPlan {
            sample: "gold".into(),
            theta_l: vec![-20.0],
            shutter_s: shutter_s.to_vec(),
            auto_bracket,
        }
    }

    #[test]
    fn a_move_needs_its_bracket_and_map_a_capture_its_frame() {
        let pixels = 1000;
        let fixed = plan(&[0.1, 0.01, 0.001], false);
        let frame = 6000 + FRAME_OVERHEAD_BYTES;
        let map = 12_000 + FRAME_OVERHEAD_BYTES;
        let step = Step::Move { theta_l: -20.0 };
        assert_eq!(step_need(&step, &fixed, pixels), 3 * frame + map);
        let auto = plan(&[], true);
        assert_eq!(
            step_need(&step, &auto, pixels),
            AUTO_BRACKET_FRAMES * frame + map
        );
        let capture = Step::Capture {
            theta_l: -20.0,
            index: 0,
            shutter_s: 0.1,
        };
        assert_eq!(step_need(&capture, &fixed, pixels), frame);
        assert_eq!(
            step_need(&Step::Hdr { theta_l: -20.0 }, &fixed, pixels),
            map
        );
        assert_eq!(step_need(&Step::Home, &fixed, pixels), 0);
        assert_eq!(frame_pixels(None), DEFAULT_PIXELS);
    }

    #[test]
    fn a_step_waits_when_its_output_does_not_fit_above_the_reserve() {
        let dir = tempfile::tempdir().unwrap();
        let free = dir.path().join("free");
        let probe = Probe {
            dir: dir.path().to_path_buf(),
            reserve_bytes: 64 << 20,
            emulated: Some(free.clone()),
            journal_reserve_bytes: 0,
        };
        std::fs::write(&free, "1000000000").unwrap();
        assert_eq!(probe.check(900_000_000), Ok(()));
        assert_eq!(
            probe.check(950_000_000),
            Err("disk full: 1.00 GB free, 1.02 GB needed".into())
        );
        assert!(is_disk_wait(&probe.check(u64::MAX).unwrap_err()));
        // Nothing measurable: the step goes on.
        std::fs::write(&free, "lots").unwrap();
        assert!(probe.free_bytes().is_err());
        assert_eq!(probe.check(u64::MAX), Ok(()));
        // The real filesystem answers.
        let real = Probe {
            emulated: None,
            ..probe
        };
        assert!(real.free_bytes().unwrap() > 0);
    }

    #[test]
    fn the_journal_reserve_is_made_again_once_it_fits_above_the_reserve() {
        let dir = tempfile::tempdir().unwrap();
        let free = dir.path().join("free");
        let probe = Probe {
            dir: dir.path().to_path_buf(),
            reserve_bytes: 1000,
            emulated: Some(free.clone()),
            journal_reserve_bytes: 4096,
        };
        let reserve = journal_reserve_path(&dir.path().join("gonio.sqlite"));
        assert_eq!(reserve, dir.path().join(JOURNAL_RESERVE_FILE));
        // Not above the reserve: not made.
        std::fs::write(&free, "5095").unwrap();
        assert!(!probe.keep_journal_reserve().unwrap());
        assert!(!reserve.exists());
        std::fs::write(&free, "5096").unwrap();
        assert!(probe.keep_journal_reserve().unwrap());
        assert_eq!(std::fs::metadata(&reserve).unwrap().len(), 4096);
        // In place: left alone; cut short: made whole.
        assert!(!probe.keep_journal_reserve().unwrap());
        std::fs::write(&reserve, b"short").unwrap();
        assert!(probe.keep_journal_reserve().unwrap());
        assert_eq!(std::fs::metadata(&reserve).unwrap().len(), 4096);
        let none = Probe {
            journal_reserve_bytes: 0,
            ..probe
        };
        std::fs::remove_file(&reserve).unwrap();
        assert!(!none.keep_journal_reserve().unwrap());
        assert!(!reserve.exists());
    }

    #[test]
    fn full_disks_are_told_from_other_errors() {
        assert!(is_disk_full(&io::Error::from_raw_os_error(libc::ENOSPC)));
        assert!(is_disk_full(&io::Error::from_raw_os_error(libc::EDQUOT)));
        assert!(!is_disk_full(&io::Error::from_raw_os_error(libc::EIO)));
        let message = format!(
            "camera capture θL -20.0° exp_00: I/O error: {}",
            io::Error::from_raw_os_error(libc::ENOSPC)
        );
        assert!(says_disk_full(&message), "{message}");
        assert!(!says_disk_full("camera capture: USB transfer failed"));
    }
}
