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

mod decoded;
mod error;
mod limits;
mod raw;
mod sidecar;
mod tiff;
mod tiff_ifd;
pub mod wire;

use std::ops::Range;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use rayon::prelude::*;

use crate::guard;
use limits::checked_len;
use raw::decode_raw;
use tiff::{decode_tiff, decode_tiff_rows, TIFF_EXTENSIONS};

pub use decoded::Decoded;
use error::image_error;
pub use error::CaptureError;
pub use limits::{max_pixels, set_max_pixels, DEFAULT_MAX_PIXELS};
pub use raw::RAW_EXTENSIONS;
pub use sidecar::{
    read_sidecar, sidecar_path, Response, Sidecar, APERTURE_RANGE, ISO_RANGE, SHUTTER_RANGE_S,
};
pub(crate) use sidecar::{theta_l_directory, THETA_DIR_TOLERANCE_DEG};
pub use tiff::write_tiff_capture;

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

/// Whether `path` has a capture extension (TIFF or camera raw, case-insensitive).
pub fn is_capture_path(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase())
        .is_some_and(|e| {
            TIFF_EXTENSIONS.contains(&e.as_str()) || RAW_EXTENSIONS.contains(&e.as_str())
        })
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
        let decoded = Decoded::whole(width, height, data, max_count);
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
            // The level the sidecar states is the one at fault (the black level if both).
            return Err(
                if sidecar.black_level.is_none() && sidecar.white_level.is_some() {
                    bad(
                        "white_level",
                        format!("{white_level} is not above the black level {black_level}"),
                    )
                } else {
                    bad(
                        "black_level",
                        format!("{black_level} is not below the white level {white_level}"),
                    )
                },
            );
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
