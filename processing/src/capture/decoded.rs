//! Decoded image contents before the sidecar is applied, and the selection of rows from
//! them. Counts RGB interleaved, row-major.

use std::ops::Range;
use std::path::Path;

use super::error::CaptureError;

/// Decoded image contents before the sidecar is applied: the rows selected, as
/// counts. Built by a decoder; read by [`Frame::read_rows`](super::Frame::read_rows).
#[derive(Debug, Clone, PartialEq)]
pub struct Decoded {
    pub(super) width: usize,
    pub(super) height: usize,
    /// Width and height as stored in the file (sensor size for raw).
    pub(super) stored: (usize, usize),
    pub(super) data: Vec<u16>,
    pub(super) black_level: f64,
    pub(super) white_level: f64,
    /// Largest count the file's bit depth can hold.
    pub(super) max_count: f64,
}

impl Decoded {
    /// A whole `width`×`height` image of counts as stored, black at 0 and clipping at
    /// `max_count`, the largest count of its bit depth.
    pub(super) fn whole(width: usize, height: usize, data: Vec<u16>, max_count: f64) -> Self {
        Decoded {
            width,
            height,
            stored: (width, height),
            data,
            black_level: 0.0,
            white_level: max_count,
            max_count,
        }
    }

    /// The given row ranges of the image, stacked.
    pub(super) fn rows(self, path: &Path, bands: &[Range<usize>]) -> Result<Decoded, CaptureError> {
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

pub(super) fn check_bands(
    path: &Path,
    bands: &[Range<usize>],
    height: usize,
) -> Result<(), CaptureError> {
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
