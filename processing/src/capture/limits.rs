//! Limits on what a capture file may claim (docs/ARCHITECTURE.md, "Limits"): the largest
//! pixel count, the largest file, and the check of a claimed image size against both,
//! made before any decoder allocates. Sizes in pixels and bytes.

use std::path::Path;
use std::sync::atomic::{AtomicU64, Ordering};

use gonio_files::input::open_input;

use super::error::{image_error, CaptureError};

/// Pixels a capture may have unless [`set_max_pixels`] says otherwise.
pub const DEFAULT_MAX_PIXELS: u64 = gonio_files::input::DEFAULT_MAX_FRAME_PIXELS;
static MAX_PIXELS: AtomicU64 = AtomicU64::new(DEFAULT_MAX_PIXELS);
/// Largest ratio of decoded to stored pixel bytes a compressed TIFF may claim
/// (deflate's own limit is 1032:1).
pub(super) const MAX_COMPRESSION_RATIO: u64 = 1032;
/// A camera raw file spends at least one bit per pixel of its largest image.
pub(super) const RAW_PIXELS_PER_BYTE: u64 = 8;
/// Most samples per pixel a camera raw's directory may state (a mosaic has 1, a linear
/// DNG 3 or 4); rawler sizes per-sample levels by it before reading any pixel.
pub(super) const MAX_RAW_SAMPLES: u64 = 4;
/// Bytes a file may have beyond its pixel data (previews, metadata).
const FILE_OVERHEAD_BYTES: u64 = 64 << 20;

/// Sets the largest number of pixels (width × height as stored in the file) a capture
/// may claim, for every later read in this process.
pub fn set_max_pixels(pixels: u64) {
    MAX_PIXELS.store(pixels.max(1), Ordering::Relaxed);
}

/// The largest number of pixels a capture may claim.
pub fn max_pixels() -> u64 {
    MAX_PIXELS.load(Ordering::Relaxed)
}

/// Largest capture file read at all: 8 bytes per allowed pixel plus overhead.
pub(super) fn max_file_bytes() -> u64 {
    max_pixels()
        .saturating_mul(8)
        .saturating_add(FILE_OVERHEAD_BYTES)
}

/// The length of the capture file at `path`: a regular file (a device or FIFO is
/// refused unopened) no larger than a capture of [`max_pixels`] needs.
pub(super) fn checked_len(path: &Path) -> Result<u64, CaptureError> {
    let file_len = match open_input(path, u64::MAX).and_then(|file| file.metadata()) {
        Ok(meta) => meta.len(),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            return Err(image_error(path, "no such file"))
        }
        Err(e) => return Err(image_error(path, e)),
    };
    if file_len > max_file_bytes() {
        return Err(too_large(
            path,
            format!(
                "{file_len} bytes is more than a capture of at most {} pixels needs",
                max_pixels()
            ),
        ));
    }
    Ok(file_len)
}

pub(super) fn too_large(path: &Path, reason: String) -> CaptureError {
    CaptureError::TooLarge {
        path: path.to_path_buf(),
        reason,
    }
}

/// An image size as a file claims it.
pub(super) struct Stored {
    pub(super) width: u64,
    pub(super) height: u64,
    /// Samples per pixel.
    pub(super) samples: u64,
    /// Bits per sample.
    pub(super) bits: u64,
}

/// Checks a claimed image size against [`max_pixels`] and the file's length: its pixel
/// bytes may exceed the file's at most `ratio` times (1 for uncompressed data).
pub(super) fn check_claim(
    path: &Path,
    file_len: u64,
    stored: Stored,
    ratio: u64,
) -> Result<(), CaptureError> {
    let Stored {
        width,
        height,
        samples,
        bits,
    } = stored;
    if width == 0 || height == 0 {
        return Err(CaptureError::Layout {
            path: path.to_path_buf(),
            reason: format!("{width}×{height} pixels: empty image"),
        });
    }
    let pixels = width.saturating_mul(height);
    if pixels > max_pixels() {
        return Err(too_large(
            path,
            format!(
                "{width}×{height} pixels is more than the {} allowed (max_frame_pixels)",
                max_pixels()
            ),
        ));
    }
    let bytes = pixels
        .saturating_mul(samples.max(1))
        .saturating_mul(bits.max(1))
        / 8;
    if bytes > file_len.saturating_mul(ratio) {
        return Err(too_large(
            path,
            format!(
                "{width}×{height} pixels of {samples}×{bits} bits need {bytes} bytes, but the \
                 file has only {file_len}{}",
                if ratio > 1 { " (even compressed)" } else { "" }
            ),
        ));
    }
    Ok(())
}
