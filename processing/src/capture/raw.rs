//! Camera raw captures (through rawler, with the `raw` feature): the claimed sizes
//! checked before rawler allocates, and Bayer mosaics turned into RGB by 2×2
//! superpixels (half resolution).

use std::path::Path;

#[cfg(feature = "raw")]
use gonio_files::input::read_input;

use super::decoded::Decoded;
#[cfg(feature = "raw")]
use super::error::image_error;
use super::error::CaptureError;
#[cfg(feature = "raw")]
use super::limits::{
    check_claim, max_file_bytes, too_large, Stored, MAX_RAW_SAMPLES, RAW_PIXELS_PER_BYTE,
};
#[cfg(feature = "raw")]
use super::tiff_ifd;

/// Camera raw extensions recognised when scanning directories.
pub const RAW_EXTENSIONS: [&str; 10] = [
    "nef", "nrw", "cr2", "cr3", "arw", "dng", "orf", "rw2", "raf", "pef",
];

#[cfg(not(feature = "raw"))]
pub(super) fn decode_raw(path: &Path) -> Result<Decoded, CaptureError> {
    Err(CaptureError::UnsupportedFormat {
        path: path.to_path_buf(),
    })
}

#[cfg(feature = "raw")]
pub(super) fn decode_raw(path: &Path) -> Result<Decoded, CaptureError> {
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
