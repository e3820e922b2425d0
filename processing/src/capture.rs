//! Reading captures: a 16-bit (or 8-bit) RGB TIFF or a camera raw file, plus its JSON
//! sidecar of the same stem (`x.tiff` → `x.json`).
//!
//! Pixel values are kept as the file's integer counts (RGB interleaved, row-major)
//! together with the black and white levels that apply to them; [`Frame::signal`]
//! gives the normalised signal (count − black)/(white − black). Raw Bayer data are
//! turned into RGB by 2×2 superpixels (half resolution): R and B as recorded, G the
//! mean of the two greens.
//!
//! Hostile files are expected: before any decoder allocates, the image size a file
//! claims is checked against [`max_pixels`] and against the file's own size (see
//! processing/src/capture.md, "Limits"), and a decoder that panics becomes a
//! [`CaptureError::Image`]. A program may have the files decoded elsewhere (in a child
//! process that can die of a file without taking the program along) by installing a
//! [`Decoder`]; [`wire`] is the protocol of such a child. Without one, files are
//! decoded in this process.
#![doc = include_str!("capture.md")]

mod tiff_ifd;
pub mod wire;

use std::fs;
use std::ops::Range;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::OnceLock;

use gonio_files::input::{open_input, read_input, read_input_to_string, MAX_SMALL_FILE_BYTES};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::guard;

/// Pixels a capture may have unless [`set_max_pixels`] says otherwise (100 megapixels;
/// a 16-bit RGB frame of that size takes 600 MB).
pub const DEFAULT_MAX_PIXELS: u64 = 100_000_000;
static MAX_PIXELS: AtomicU64 = AtomicU64::new(DEFAULT_MAX_PIXELS);
/// Largest ratio of decoded to stored pixel bytes a compressed TIFF may claim
/// (deflate's own limit is 1032:1).
const MAX_COMPRESSION_RATIO: u64 = 1032;
/// A camera raw file spends at least one bit per pixel of its largest image.
const RAW_PIXELS_PER_BYTE: u64 = 8;
/// Most samples per pixel a camera raw's directory may state (a mosaic has 1, a linear
/// DNG 3 or 4); rawler sizes per-sample levels by it before reading any pixel.
const MAX_RAW_SAMPLES: u64 = 4;
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
fn max_file_bytes() -> u64 {
    max_pixels()
        .saturating_mul(8)
        .saturating_add(FILE_OVERHEAD_BYTES)
}

/// How pixel counts relate to exposure.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Response {
    /// Counts proportional to exposure (raw data, linear TIFF).
    #[default]
    Linear,
    /// An unknown monotonic camera response (developed images): needs response recovery.
    Nonlinear,
}

/// The JSON sidecar of a capture (docs/ARCHITECTURE.md, "File formats"). Unknown keys are ignored.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Sidecar {
    /// Exposure time in seconds.
    pub shutter_s: f64,
    /// ISO speed; `null` where the body has no ISO setting (taken as 100). Written as
    /// an integer when it is whole (`"iso":100`), as cameras report it.
    #[serde(serialize_with = "serialize_iso")]
    pub iso: Option<f64>,
    /// Light-arm angle θL in degrees.
    pub theta_l: f64,
    pub camera: String,
    /// Capture time, RFC 3339.
    pub time: String,
    /// Black level in file counts, overriding the file's own.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub black_level: Option<f64>,
    /// White (clipping) level in file counts, overriding the file's own.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub white_level: Option<f64>,
    #[serde(default)]
    pub response: Response,
    /// How many of the 16 bits of a TIFF value carry signal, at its top: an N-bit
    /// sensor count is stored times 2^(16−N) (docs/ARCHITECTURE.md, "File formats").
    /// Informative; the levels above are in stored units.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub significant_bits: Option<u32>,
    /// Lens aperture as an f-number N (f/N), informative; checked when present.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub aperture: Option<f64>,
    /// Image width in pixels as stored in the file, checked when present.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub width: Option<u32>,
    /// Image height in pixels as stored in the file, checked when present.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub height: Option<u32>,
}

fn serialize_iso<S: serde::Serializer>(iso: &Option<f64>, s: S) -> Result<S::Ok, S::Error> {
    match iso {
        Some(v) if v.fract() == 0.0 && (0.0..=u32::MAX as f64).contains(v) => {
            s.serialize_u32(*v as u32)
        }
        Some(v) => s.serialize_f64(*v),
        None => s.serialize_none(),
    }
}

impl Sidecar {
    /// Relative exposure H = shutter_s · ISO/100 (seconds at ISO 100).
    pub fn exposure(&self) -> f64 {
        self.shutter_s * self.iso.unwrap_or(100.0) / 100.0
    }

    /// Checks every value against its physical range (docs/ARCHITECTURE.md, "File
    /// formats"), and θL against the `theta_l_<θL>` directory `image` is in, if it is
    /// in one. `path` is the sidecar's.
    fn validate(&self, path: &Path, image: &Path) -> Result<(), CaptureError> {
        let bad = |field: &'static str, reason: String| CaptureError::InvalidSidecar {
            path: path.to_path_buf(),
            field,
            reason,
        };
        let (shortest, longest) = SHUTTER_RANGE_S;
        if !(self.shutter_s.is_finite() && (shortest..=longest).contains(&self.shutter_s)) {
            return Err(bad(
                "shutter_s",
                format!(
                    "{} is not an exposure time in [{shortest:e}, {longest}] s",
                    self.shutter_s
                ),
            ));
        }
        if let Some(iso) = self.iso {
            let (lowest, highest) = ISO_RANGE;
            if !(iso.is_finite() && (lowest..=highest).contains(&iso)) {
                return Err(bad(
                    "iso",
                    format!("{iso} is not an ISO speed in [{lowest}, {highest}]"),
                ));
            }
        }
        if !(self.theta_l.is_finite() && self.theta_l.abs() <= 180.0) {
            return Err(bad(
                "theta_l",
                format!("{} is not an angle in [-180, 180] degrees", self.theta_l),
            ));
        }
        if let Some((dir, theta_l)) = theta_l_directory(image) {
            if (self.theta_l - theta_l).abs() > THETA_DIR_TOLERANCE_DEG {
                return Err(bad(
                    "theta_l",
                    format!("{} but the frame is in {dir}/ (θL {theta_l})", self.theta_l),
                ));
            }
        }
        if let Some(n) = self.aperture {
            let (widest, narrowest) = APERTURE_RANGE;
            if !(n.is_finite() && (widest..=narrowest).contains(&n)) {
                return Err(bad(
                    "aperture",
                    format!("{n} is not an f-number in [{widest}, {narrowest}]"),
                ));
            }
        }
        if let Some(bits) = self.significant_bits {
            if !(1..=16).contains(&bits) {
                return Err(bad(
                    "significant_bits",
                    format!("{bits} is not a bit count in 1..=16"),
                ));
            }
        }
        for (field, level) in [
            ("black_level", self.black_level),
            ("white_level", self.white_level),
        ] {
            if let Some(v) = level {
                if !(v.is_finite() && (0.0..=MAX_COUNT).contains(&v)) {
                    return Err(bad(
                        field,
                        format!("{v} is not a count in [0, {MAX_COUNT}]"),
                    ));
                }
            }
        }
        Ok(())
    }
}

/// Exposure times a sidecar may state, seconds: a microsecond to an hour.
pub const SHUTTER_RANGE_S: (f64, f64) = (1e-6, 3600.0);
/// ISO speeds a sidecar may state.
pub const ISO_RANGE: (f64, f64) = (25.0, 409_600.0);
/// f-numbers a sidecar may state: from the limit of a lens in air (f/0.5) to a
/// pinhole's (f/1024).
pub const APERTURE_RANGE: (f64, f64) = (0.5, 1024.0);
/// Largest count a sidecar level may state (16-bit files).
const MAX_COUNT: f64 = u16::MAX as f64;
/// How far a sidecar's θL may be from its directory's name, written to 0.1°.
pub(crate) const THETA_DIR_TOLERANCE_DEG: f64 = 0.05 + 1e-6;

/// The name of the `theta_l_<θL>` directory `image` is in, and its θL.
pub(crate) fn theta_l_directory(image: &Path) -> Option<(String, f64)> {
    let dir = image.parent()?.file_name()?.to_str()?;
    let theta_l = dir
        .strip_prefix("theta_l_")?
        .parse::<f64>()
        .ok()
        .filter(|t| t.is_finite())?;
    Some((dir.to_owned(), theta_l))
}

/// Errors reading a capture.
#[derive(Debug, Error)]
pub enum CaptureError {
    #[error("{image}: sidecar {sidecar} is missing")]
    MissingSidecar { image: PathBuf, sidecar: PathBuf },
    #[error("{path}: cannot read sidecar: {error}")]
    SidecarIo {
        path: PathBuf,
        error: std::io::Error,
    },
    #[error("{path}: invalid sidecar JSON: {error}")]
    SidecarJson {
        path: PathBuf,
        error: serde_json::Error,
    },
    #[error("{path}: sidecar field '{field}': {reason}")]
    InvalidSidecar {
        path: PathBuf,
        field: &'static str,
        reason: String,
    },
    #[error("{path}: cannot decode image: {reason}")]
    Image { path: PathBuf, reason: String },
    #[error("{path}: unsupported image layout: {reason}")]
    Layout { path: PathBuf, reason: String },
    #[error("{path}: refused: {reason}")]
    TooLarge { path: PathBuf, reason: String },
    #[error("{path}: unsupported file type (expected .tif, .tiff{raw})", raw = if cfg!(feature = "raw") { " or a camera raw file" } else { "; camera raw support is not built in" })]
    UnsupportedFormat { path: PathBuf },
}

/// One capture: integer counts, their black and white levels, and the sidecar.
#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    pub path: PathBuf,
    pub sidecar: Sidecar,
    pub width: usize,
    pub height: usize,
    /// Counts, RGB interleaved, row-major: `data[3 * (y * width + x) + c]`.
    pub data: Vec<u16>,
    /// Black level in counts.
    pub black_level: f64,
    /// White (clipping) level in counts, above `black_level`.
    pub white_level: f64,
}

/// Extensions read as TIFF; every other extension is tried as camera raw.
const TIFF_EXTENSIONS: [&str; 2] = ["tif", "tiff"];
/// Camera raw extensions recognised when scanning directories.
pub const RAW_EXTENSIONS: [&str; 10] = [
    "nef", "nrw", "cr2", "cr3", "arw", "dng", "orf", "rw2", "raf", "pef",
];

/// Whether `path` has a capture extension (TIFF or camera raw, case-insensitive).
pub fn is_capture_path(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase())
        .is_some_and(|e| {
            TIFF_EXTENSIONS.contains(&e.as_str()) || RAW_EXTENSIONS.contains(&e.as_str())
        })
}

/// The sidecar path of an image: same stem, `.json`.
pub fn sidecar_path(image: &Path) -> PathBuf {
    image.with_extension("json")
}

/// Reads and validates the sidecar of `image`.
pub fn read_sidecar(image: &Path) -> Result<Sidecar, CaptureError> {
    let path = sidecar_path(image);
    let text = match read_input_to_string(&path, MAX_SMALL_FILE_BYTES) {
        Ok(text) => text,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            return Err(CaptureError::MissingSidecar {
                image: image.to_path_buf(),
                sidecar: path,
            })
        }
        Err(error) => return Err(CaptureError::SidecarIo { path, error }),
    };
    let sidecar: Sidecar =
        serde_json::from_str(&text).map_err(|error| CaptureError::SidecarJson {
            path: path.clone(),
            error,
        })?;
    sidecar.validate(&path, image)?;
    Ok(sidecar)
}

/// Writes a 16-bit RGB TIFF of `counts` (RGB interleaved, row-major) and its sidecar.
pub fn write_tiff_capture(
    path: &Path,
    width: u32,
    height: u32,
    counts: &[u16],
    sidecar: &Sidecar,
) -> Result<(), CaptureError> {
    let image = image::ImageBuffer::<image::Rgb<u16>, &[u16]>::from_raw(width, height, counts)
        .ok_or_else(|| CaptureError::Layout {
            path: path.to_path_buf(),
            reason: format!("{} values for {width}×{height} RGB", counts.len()),
        })?;
    image
        .save_with_format(path, image::ImageFormat::Tiff)
        .map_err(|e| image_error(path, e))?;
    let json = serde_json::to_string_pretty(sidecar).map_err(|e| image_error(path, e))?;
    let side = sidecar_path(path);
    fs::write(&side, json).map_err(|error| CaptureError::SidecarIo { path: side, error })
}

/// Where the image of a capture is decoded, when not in this process (see [`set_decoder`]).
pub trait Decoder: Send + Sync {
    /// Decodes the image at `path` as [`Frame::read_rows`] does: `select(width,
    /// height)` gets the image's size and returns the rows to keep, or `None` to stop
    /// (then the result is `Ok(None)`). A decoder that cannot finish fails with a
    /// one-line [`CaptureError`] naming `path`.
    fn decode(
        &self,
        path: &Path,
        select: &mut dyn FnMut(usize, usize) -> Option<Vec<Range<usize>>>,
    ) -> Result<Option<Decoded>, CaptureError>;
}

static DECODER: OnceLock<Box<dyn Decoder>> = OnceLock::new();

/// Has every later read of this process decode its image through `decoder`; returns
/// `false` (and changes nothing) if a decoder was installed before.
pub fn set_decoder(decoder: Box<dyn Decoder>) -> bool {
    DECODER.set(decoder).is_ok()
}

/// Decoded image contents before the sidecar is applied: the rows selected, as
/// counts. Built by a decoder; read by [`Frame::read_rows`].
#[derive(Debug, Clone, PartialEq)]
pub struct Decoded {
    width: usize,
    height: usize,
    /// Width and height as stored in the file (sensor size for raw).
    stored: (usize, usize),
    data: Vec<u16>,
    black_level: f64,
    white_level: f64,
    /// Largest count the file's bit depth can hold.
    max_count: f64,
}

impl Frame {
    /// Reads an image and its sidecar; sidecar levels override the file's own.
    pub fn read(path: &Path) -> Result<Frame, CaptureError> {
        Self::read_rows(path, |_, height| {
            Ok::<_, CaptureError>(std::iter::once(0..height).collect())
        })
    }

    /// Reads several captures in parallel, in the order given.
    pub fn read_all(paths: &[PathBuf]) -> Result<Vec<Frame>, CaptureError> {
        paths.par_iter().map(|path| Frame::read(path)).collect()
    }

    /// Reads only some rows of a capture: `select(width, height)` gets the capture's
    /// size (after superpixels for raw) and returns row ranges, which are stacked in
    /// that order into the frame. Striped 16-bit RGB TIFFs decode only the strips that
    /// hold those rows; other files are decoded whole and cut.
    pub fn read_rows<E: From<CaptureError>>(
        path: &Path,
        select: impl FnOnce(usize, usize) -> Result<Vec<Range<usize>>, E>,
    ) -> Result<Frame, E> {
        // A file of another kind is named as such, not as one whose sidecar is missing.
        if !is_capture_path(path) {
            return Err(CaptureError::UnsupportedFormat {
                path: path.to_path_buf(),
            }
            .into());
        }
        let file_len = checked_len(path)?;
        let sidecar = read_sidecar(path)?;
        let decoded = match DECODER.get() {
            None => decode_here(path, file_len, select)?,
            Some(decoder) => {
                let mut select = Some(select);
                let mut declined = None;
                let result = decoder.decode(path, &mut |width, height| match select.take()?(
                    width, height,
                ) {
                    Ok(bands) => Some(bands),
                    Err(e) => {
                        declined = Some(e);
                        None
                    }
                });
                match (result, declined) {
                    (_, Some(e)) => return Err(e),
                    (Ok(Some(decoded)), None) => decoded,
                    (Ok(None), None) => {
                        return Err(image_error(path, "the decoder stopped without an image").into())
                    }
                    (Err(e), None) => return Err(e.into()),
                }
            }
        };
        Ok(Self::assemble(path, sidecar, decoded)?)
    }

    /// Builds a frame from counts already in memory (RGB interleaved), checking sizes
    /// and levels. `max_count` is the largest count the source bit depth can hold.
    pub fn from_counts(
        path: PathBuf,
        sidecar: Sidecar,
        width: usize,
        height: usize,
        data: Vec<u16>,
        max_count: f64,
    ) -> Result<Frame, CaptureError> {
        if data.len() != width * height * 3 {
            return Err(CaptureError::Layout {
                path,
                reason: format!("{} values for {width}×{height} RGB", data.len()),
            });
        }
        let decoded = Decoded {
            width,
            height,
            stored: (width, height),
            data,
            black_level: 0.0,
            white_level: max_count,
            max_count,
        };
        Self::assemble(&path, sidecar, decoded)
    }

    fn assemble(path: &Path, sidecar: Sidecar, decoded: Decoded) -> Result<Frame, CaptureError> {
        let sidecar_file = sidecar_path(path);
        let bad = |field: &'static str, reason: String| CaptureError::InvalidSidecar {
            path: sidecar_file.clone(),
            field,
            reason,
        };
        let (stored_w, stored_h) = decoded.stored;
        if let Some(w) = sidecar.width {
            if w as usize != stored_w {
                return Err(bad(
                    "width",
                    format!("{w} but the image is {stored_w} wide"),
                ));
            }
        }
        if let Some(h) = sidecar.height {
            if h as usize != stored_h {
                return Err(bad(
                    "height",
                    format!("{h} but the image is {stored_h} high"),
                ));
            }
        }
        let black_level = sidecar.black_level.unwrap_or(decoded.black_level);
        let white_level = sidecar.white_level.unwrap_or(decoded.white_level);
        if white_level > decoded.max_count {
            return Err(bad(
                "white_level",
                format!(
                    "{white_level} exceeds the file's largest count {}",
                    decoded.max_count
                ),
            ));
        }
        if black_level >= white_level {
            return Err(bad(
                "black_level",
                format!("{black_level} is not below the white level {white_level}"),
            ));
        }
        if decoded.width == 0 || decoded.height == 0 {
            return Err(CaptureError::Layout {
                path: path.to_path_buf(),
                reason: "empty image".into(),
            });
        }
        Ok(Frame {
            path: path.to_path_buf(),
            sidecar,
            width: decoded.width,
            height: decoded.height,
            data: decoded.data,
            black_level,
            white_level,
        })
    }

    /// Normalised signal (count − black)/(white − black) of pixel (x, y), channel c.
    /// 0 is black, 1 is clipping; noise can make it slightly negative.
    pub fn signal(&self, x: usize, y: usize, c: usize) -> f64 {
        let count = f64::from(self.data[3 * (y * self.width + x) + c]);
        (count - self.black_level) / (self.white_level - self.black_level)
    }
}

/// The length of the capture file at `path`: a regular file (a device or FIFO is
/// refused unopened) no larger than a capture of [`max_pixels`] needs.
fn checked_len(path: &Path) -> Result<u64, CaptureError> {
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

/// Decodes the image at `path` (`file_len` bytes) in this process, keeping the rows
/// `select` returns; a decoder's panic becomes the error.
fn decode_here<E: From<CaptureError>>(
    path: &Path,
    file_len: u64,
    select: impl FnOnce(usize, usize) -> Result<Vec<Range<usize>>, E>,
) -> Result<Decoded, E> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase())
        .unwrap_or_default();
    let decode = || -> Result<Decoded, E> {
        if TIFF_EXTENSIONS.contains(&ext.as_str()) {
            match decode_tiff_rows(path, file_len, select)? {
                Ok(decoded) => Ok(decoded),
                Err(select) => {
                    let full = decode_tiff(path)?;
                    let bands = select(full.width, full.height)?;
                    Ok(full.rows(path, &bands)?)
                }
            }
        } else {
            let full = decode_raw(path)?;
            let bands = select(full.width, full.height)?;
            Ok(full.rows(path, &bands)?)
        }
    };
    guard::catch(decode).unwrap_or_else(|panic| {
        Err(CaptureError::Image {
            path: path.to_path_buf(),
            reason: format!("the decoder failed on malformed data ({panic})"),
        }
        .into())
    })
}

impl Decoded {
    /// The given row ranges of the image, stacked.
    fn rows(self, path: &Path, bands: &[Range<usize>]) -> Result<Decoded, CaptureError> {
        if let [band] = bands {
            if *band == (0..self.height) {
                return Ok(self);
            }
        }
        check_bands(path, bands, self.height)?;
        let row_len = 3 * self.width;
        let mut data = Vec::with_capacity(bands.iter().map(|b| b.len()).sum::<usize>() * row_len);
        for band in bands {
            data.extend_from_slice(&self.data[band.start * row_len..band.end * row_len]);
        }
        Ok(Decoded {
            height: data.len() / row_len,
            data,
            ..self
        })
    }
}

fn check_bands(path: &Path, bands: &[Range<usize>], height: usize) -> Result<(), CaptureError> {
    match bands.iter().find(|b| b.start >= b.end || b.end > height) {
        Some(band) => Err(CaptureError::Layout {
            path: path.to_path_buf(),
            reason: format!("rows {band:?} are empty or outside the {height}-row image"),
        }),
        None if bands.is_empty() => Err(CaptureError::Layout {
            path: path.to_path_buf(),
            reason: "no rows selected".into(),
        }),
        None => Ok(()),
    }
}

/// The tiff crate's own buffer limits, sized for the largest allowed capture.
fn tiff_limits() -> tiff::decoder::Limits {
    let mut limits = tiff::decoder::Limits::default();
    let frame_bytes = usize::try_from(max_pixels().saturating_mul(8)).unwrap_or(usize::MAX);
    limits.decoding_buffer_size = frame_bytes;
    limits.intermediate_buffer_size = frame_bytes;
    limits
}

fn too_large(path: &Path, reason: String) -> CaptureError {
    CaptureError::TooLarge {
        path: path.to_path_buf(),
        reason,
    }
}

/// An image size as a file claims it.
struct Stored {
    width: u64,
    height: u64,
    /// Samples per pixel.
    samples: u64,
    /// Bits per sample.
    bits: u64,
}

/// Checks a claimed image size against [`max_pixels`] and the file's length: its pixel
/// bytes may exceed the file's at most `ratio` times (1 for uncompressed data).
fn check_claim(path: &Path, file_len: u64, stored: Stored, ratio: u64) -> Result<(), CaptureError> {
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

/// Decodes only the strips holding the selected rows of a chunky, striped, 16-bit RGB
/// TIFF, the rows split in contiguous parts decoded in parallel (a decoder per part).
/// `Ok(Err(select))` hands the selector back when the file has another layout.
fn decode_tiff_rows<
    E: From<CaptureError>,
    S: FnOnce(usize, usize) -> Result<Vec<Range<usize>>, E>,
>(
    path: &Path,
    file_len: u64,
    select: S,
) -> Result<Result<Decoded, S>, E> {
    use tiff::decoder::ChunkType;
    use tiff::tags::{CompressionMethod, PlanarConfiguration, Tag};
    use tiff::ColorType;
    let Ok(mut decoder) = open_tiff(path) else {
        // Let the full decoder report what is wrong with the file.
        return Ok(Err(select));
    };
    let (width, height) = decoder.dimensions().map_err(|e| image_error(path, e))?;
    // Check the claimed size before anything is allocated for it.
    let (samples, bits) = match decoder.colortype() {
        Ok(ColorType::Gray(b)) => (1, b),
        Ok(ColorType::GrayA(b)) => (2, b),
        Ok(ColorType::RGB(b)) => (3, b),
        Ok(ColorType::RGBA(b) | ColorType::CMYK(b)) => (4, b),
        _ => (4, 16),
    };
    let compressed = decoder
        .find_tag_unsigned::<u16>(Tag::Compression)
        .map_err(|e| image_error(path, e))?
        .is_some_and(|c| c != CompressionMethod::None.to_u16());
    check_claim(
        path,
        file_len,
        Stored {
            width: u64::from(width),
            height: u64::from(height),
            samples,
            bits: u64::from(bits),
        },
        if compressed { MAX_COMPRESSION_RATIO } else { 1 },
    )?;
    let (width, height) = (width as usize, height as usize);
    let chunky = decoder
        .find_tag_unsigned::<u16>(Tag::PlanarConfiguration)
        .map_err(|e| image_error(path, e))?
        .is_none_or(|v| v == PlanarConfiguration::Chunky.to_u16());
    let rgb16 = matches!(decoder.colortype(), Ok(ColorType::RGB(16)));
    if !(chunky && rgb16 && decoder.get_chunk_type() == ChunkType::Strip) {
        return Ok(Err(select));
    }
    let rows_per_strip = decoder
        .find_tag_unsigned::<u32>(Tag::RowsPerStrip)
        .map_err(|e| image_error(path, e))?
        .map_or(height, |r| (r as usize).clamp(1, height.max(1)));
    let bands = select(width, height)?;
    check_bands(path, &bands, height)?;
    let rows: Vec<usize> = bands.iter().flat_map(Range::clone).collect();
    let row_len = 3 * width;
    let mut data = vec![0u16; rows.len() * row_len];
    let per_part = rows.len().div_ceil(rayon::current_num_threads().max(1));
    data.par_chunks_mut(per_part * row_len)
        .zip(rows.par_chunks(per_part))
        .try_for_each(|(out, rows)| {
            let mut decoder = open_tiff(path).map_err(|e| image_error(path, e))?;
            decode_strip_rows(&mut decoder, path, rows, rows_per_strip, out)
        })?;
    Ok(Ok(Decoded {
        width,
        height: rows.len(),
        stored: (width, height),
        data,
        black_level: 0.0,
        white_level: f64::from(u16::MAX),
        max_count: f64::from(u16::MAX),
    }))
}

type TiffDecoder = tiff::decoder::Decoder<std::io::BufReader<fs::File>>;

/// A TIFF decoder on `path` with [`tiff_limits`].
fn open_tiff(path: &Path) -> Result<TiffDecoder, tiff::TiffError> {
    let file = open_input(path, max_file_bytes())?;
    Ok(tiff::decoder::Decoder::new(std::io::BufReader::new(file))?.with_limits(tiff_limits()))
}

/// The error of an image `path` that cannot be read or written, for `reason` (on one
/// line: rawler's messages may span several).
fn image_error(path: &Path, reason: impl std::fmt::Display) -> CaptureError {
    CaptureError::Image {
        path: path.to_path_buf(),
        reason: guard::one_line(&reason.to_string()),
    }
}

/// Decodes `rows` of a chunky 16-bit RGB TIFF striped `rows_per_strip` rows at a time
/// into `out`, a row after another; a strip is decoded once for its consecutive rows.
fn decode_strip_rows(
    decoder: &mut TiffDecoder,
    path: &Path,
    rows: &[usize],
    rows_per_strip: usize,
    out: &mut [u16],
) -> Result<(), CaptureError> {
    use tiff::decoder::DecodingResult;
    let row_len = out.len() / rows.len().max(1);
    let mut cached: Option<(usize, Vec<u16>)> = None;
    for (&row, line) in rows.iter().zip(out.chunks_exact_mut(row_len)) {
        let strip = row / rows_per_strip;
        if cached.as_ref().is_none_or(|(index, _)| *index != strip) {
            let values = match decoder
                .read_chunk(strip as u32)
                .map_err(|e| image_error(path, e))?
            {
                DecodingResult::U16(values) => values,
                _ => {
                    return Err(CaptureError::Layout {
                        path: path.to_path_buf(),
                        reason: "strip is not 16-bit".into(),
                    })
                }
            };
            cached = Some((strip, values));
        }
        let values = cached.as_ref().map_or(&[][..], |(_, v)| v.as_slice());
        let start = (row - strip * rows_per_strip) * row_len;
        let values = values
            .get(start..start + row_len)
            .ok_or_else(|| CaptureError::Layout {
                path: path.to_path_buf(),
                reason: format!("strip {strip} is too short for row {row}"),
            })?;
        line.copy_from_slice(values);
    }
    Ok(())
}

fn decode_tiff(path: &Path) -> Result<Decoded, CaptureError> {
    use image::DynamicImage;
    let file = open_input(path, max_file_bytes()).map_err(|e| image_error(path, e))?;
    let mut reader = image::ImageReader::new(std::io::BufReader::new(file))
        .with_guessed_format()
        .map_err(|e| image_error(path, e))?;
    let mut limits = image::Limits::default();
    // Room for the decoded image (at most 4 channels of 16 bits) and its conversion.
    limits.max_alloc = Some(max_pixels().saturating_mul(16));
    reader.limits(limits);
    let image = reader.decode().map_err(|e| image_error(path, e))?;
    let (width, height) = (image.width() as usize, image.height() as usize);
    let (data, max_count) = match image {
        DynamicImage::ImageRgb16(img) => (img.into_raw(), f64::from(u16::MAX)),
        DynamicImage::ImageRgba16(img) => (drop_alpha(&img.into_raw()), f64::from(u16::MAX)),
        DynamicImage::ImageRgb8(img) => (widen(&img.into_raw()), f64::from(u8::MAX)),
        DynamicImage::ImageRgba8(img) => (widen(&drop_alpha(&img.into_raw())), f64::from(u8::MAX)),
        other => {
            return Err(CaptureError::Layout {
                path: path.to_path_buf(),
                reason: format!("{:?} pixels; expected 8- or 16-bit RGB", other.color()),
            })
        }
    };
    Ok(Decoded {
        width,
        height,
        stored: (width, height),
        data,
        black_level: 0.0,
        white_level: max_count,
        max_count,
    })
}

fn drop_alpha<T: Copy>(rgba: &[T]) -> Vec<T> {
    rgba.chunks_exact(4)
        .flat_map(|p| [p[0], p[1], p[2]])
        .collect()
}

fn widen(values: &[u8]) -> Vec<u16> {
    values.iter().map(|&v| u16::from(v)).collect()
}

#[cfg(not(feature = "raw"))]
fn decode_raw(path: &Path) -> Result<Decoded, CaptureError> {
    Err(CaptureError::UnsupportedFormat {
        path: path.to_path_buf(),
    })
}

#[cfg(feature = "raw")]
fn decode_raw(path: &Path) -> Result<Decoded, CaptureError> {
    use rawler::rawimage::{RawImageData, RawPhotometricInterpretation};
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase())
        .unwrap_or_default();
    if !RAW_EXTENSIONS.contains(&ext.as_str()) {
        return Err(CaptureError::UnsupportedFormat {
            path: path.to_path_buf(),
        });
    }
    let layout = |reason: String| CaptureError::Layout {
        path: path.to_path_buf(),
        reason,
    };
    let bytes = read_input(path, max_file_bytes()).map_err(|e| image_error(path, e))?;
    // Only the containers of the formats above reach rawler: TIFF-structured files
    // (checked below), CR3 (ISO BMFF) and RAF. rawler's other readers (JPEG/Exif, MRW,
    // X3F, CRW…) are for formats not listed, and some allocate or spin on a damaged file;
    // a CRW heap starts "II" too and still reaches its reader, as CR3 boxes reach theirs
    // unchecked: `gonio` decodes in a child whose limits bound them.
    let tiff = bytes.starts_with(b"II") || bytes.starts_with(b"MM");
    let bmff = bytes.get(4..8) == Some(&b"ftyp"[..]);
    let raf = bytes.starts_with(b"FUJIFILM");
    if !(tiff || bmff || raf) {
        return Err(CaptureError::Image {
            path: path.to_path_buf(),
            reason: "not a TIFF-based, CR3 or RAF camera raw file".into(),
        });
    }
    // The largest image and the largest entry the file's directories claim, checked
    // before rawler allocates for them.
    if let Some(claim) = tiff_ifd::largest_claim(&bytes) {
        let file_len = bytes.len() as u64;
        if let Some(offset) = claim.revisited {
            return Err(CaptureError::Layout {
                path: path.to_path_buf(),
                reason: format!("the TIFF directory at offset {offset} is reached twice (a loop)"),
            });
        }
        if claim.max_samples > MAX_RAW_SAMPLES {
            return Err(CaptureError::Layout {
                path: path.to_path_buf(),
                reason: format!(
                    "a TIFF directory gives {} samples per pixel; a camera raw has at most \
                     {MAX_RAW_SAMPLES}",
                    claim.max_samples
                ),
            });
        }
        let (entry_bytes, tag) = claim.largest_entry;
        if entry_bytes > file_len {
            return Err(too_large(
                path,
                format!(
                    "TIFF tag {tag} claims {entry_bytes} bytes of values, but the file has \
                     only {file_len}"
                ),
            ));
        }
        check_claim(
            path,
            file_len,
            Stored {
                width: claim.width.max(1),
                height: claim.height.max(1),
                samples: claim.samples,
                bits: 1,
            },
            RAW_PIXELS_PER_BYTE,
        )?;
    }
    let source = rawler::rawsource::RawSource::new_from_slice(&bytes);
    let raw = rawler::decode(&source, &rawler::decoders::RawDecodeParams::default())
        .map_err(|e| image_error(path, e))?;
    drop(bytes);
    let RawImageData::Integer(counts) = &raw.data else {
        return Err(layout("floating-point raw data".into()));
    };
    if counts.len() < raw.width.saturating_mul(raw.height).saturating_mul(raw.cpp) {
        return Err(layout(format!(
            "{} values for {}×{}×{}",
            counts.len(),
            raw.width,
            raw.height,
            raw.cpp
        )));
    }
    let black = raw.blacklevel.as_bayer_array();
    let black_level = f64::from(black.iter().sum::<f32>() / 4.0);
    let white_level = raw
        .whitelevel
        .0
        .iter()
        .copied()
        .min()
        .map_or(f64::from(u16::MAX), f64::from);
    let stored = (raw.width, raw.height);
    let area = raw
        .crop_area
        .or(raw.active_area)
        .map_or((0, 0, raw.width, raw.height), |r| {
            (r.p.x, r.p.y, r.d.w, r.d.h)
        });
    let (x0, y0, w, h) = area;
    if x0.saturating_add(w) > raw.width || y0.saturating_add(h) > raw.height {
        return Err(layout(format!(
            "crop {w}×{h} at ({x0}, {y0}) leaves the {}×{} sensor",
            raw.width, raw.height
        )));
    }
    let (data, width, height) = match (&raw.photometric, raw.cpp) {
        (RawPhotometricInterpretation::Cfa(config), 1) => {
            superpixels(counts, raw.width, area, |row, col| {
                config.cfa.color_at(row, col)
            })
            .map_err(layout)?
        }
        (_, 3) => {
            let mut data = Vec::with_capacity(w * h * 3);
            for y in y0..y0 + h {
                let start = 3 * (y * raw.width + x0);
                data.extend_from_slice(&counts[start..start + 3 * w]);
            }
            (data, w, h)
        }
        (_, cpp) => return Err(layout(format!("{cpp} components per pixel"))),
    };
    Ok(Decoded {
        width,
        height,
        stored,
        data,
        black_level,
        white_level,
        max_count: f64::from(u16::MAX),
    })
}

/// 2×2 superpixels of a Bayer mosaic inside `area` = (x0, y0, w, h): one RGB pixel per
/// block, R and B as recorded, G the mean of the two greens (rounded half up on even
/// blocks and half down on odd ones, so rounding adds no bias). `color_at(row, col)` is
/// the CFA colour (0 R, 1 G, 2 B) at absolute sensor coordinates.
#[cfg(any(feature = "raw", test))]
fn superpixels(
    counts: &[u16],
    stride: usize,
    area: (usize, usize, usize, usize),
    color_at: impl Fn(usize, usize) -> usize,
) -> Result<(Vec<u16>, usize, usize), String> {
    let (x0, y0, w, h) = area;
    let (out_w, out_h) = (w / 2, h / 2);
    let inside = x0.saturating_add(w) <= stride
        && stride
            .checked_mul(y0.saturating_add(h))
            .is_some_and(|n| n <= counts.len());
    if out_w == 0 || out_h == 0 || !inside {
        return Err(format!("raw area {w}×{h} is too small or outside the data"));
    }
    // The colours of the four positions of a block and where each one goes.
    let mut offsets = [[usize::MAX; 2]; 3];
    for (dy, dx) in [(0, 0), (0, 1), (1, 0), (1, 1)] {
        let color = color_at(y0 + dy, x0 + dx);
        let slot = offsets
            .get_mut(color)
            .ok_or_else(|| format!("CFA colour {color} is not R, G or B"))?;
        let position = dy * stride + dx;
        if slot[0] == usize::MAX {
            slot[0] = position;
        } else if slot[1] == usize::MAX {
            slot[1] = position;
        } else {
            return Err("CFA is not a 2×2 Bayer pattern".into());
        }
    }
    let [r, g, b] = offsets;
    if r[0] == usize::MAX || b[0] == usize::MAX || g[1] == usize::MAX {
        return Err("CFA is not a 2×2 Bayer pattern".into());
    }
    let mut data = Vec::with_capacity(out_w * out_h * 3);
    for by in 0..out_h {
        for bx in 0..out_w {
            let base = (y0 + 2 * by) * stride + x0 + 2 * bx;
            let greens = u32::from(counts[base + g[0]]) + u32::from(counts[base + g[1]]);
            let round = ((bx + by) & 1) as u32;
            data.extend_from_slice(&[
                counts[base + r[0]],
                ((greens + round) / 2) as u16,
                counts[base + b[0]],
            ]);
        }
    }
    Ok((data, out_w, out_h))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn superpixels_follow_the_cfa_pattern() {
        // RGGB mosaic 4×2: R=10, G=21/22, B=30 in the first block; second block +100.
        let counts = [10, 21, 110, 121, 22, 30, 122, 130];
        let rggb = |row: usize, col: usize| match (row % 2, col % 2) {
            (0, 0) => 0,
            (1, 1) => 2,
            _ => 1,
        };
        let (data, w, h) = superpixels(&counts, 4, (0, 0, 4, 2), rggb).unwrap();
        assert_eq!((w, h), (2, 1));
        // (21 + 22)/2 = 21.5: rounded down on block 0, up on block 1.
        assert_eq!(data, vec![10, 21, 30, 110, 122, 130]);
        // An offset area starting on a green pixel sees a GRBG block.
        let counts = [0, 20, 10, 0, 0, 30, 22, 0];
        let (data, _, _) = superpixels(&counts, 4, (1, 0, 2, 2), rggb).unwrap();
        assert_eq!(data, vec![10, 21, 30]);
    }

    #[test]
    fn superpixels_reject_non_bayer_patterns() {
        let counts = [0u16; 16];
        let all_green = |_: usize, _: usize| 1;
        assert!(superpixels(&counts, 4, (0, 0, 4, 4), all_green).is_err());
    }
}
