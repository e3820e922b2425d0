//! TIFF captures: writing a 16-bit RGB TIFF and its sidecar, and reading 8- or 16-bit
//! RGB(A) TIFFs, only the strips holding the selected rows where the layout allows
//! (chunky, striped, 16-bit RGB), with the claimed size checked first.

use std::fs;
use std::ops::Range;
use std::path::Path;

use gonio_files::input::open_input;
use rayon::prelude::*;

use super::decoded::{check_bands, Decoded};
use super::error::{image_error, CaptureError};
use super::limits::{check_claim, max_file_bytes, max_pixels, Stored, MAX_COMPRESSION_RATIO};
use super::sidecar::{sidecar_path, Sidecar};

/// Extensions read as TIFF; every other extension is tried as camera raw.
pub(super) const TIFF_EXTENSIONS: [&str; 2] = ["tif", "tiff"];

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

/// The tiff crate's own buffer limits, sized for the largest allowed capture.
fn tiff_limits() -> tiff::decoder::Limits {
    let mut limits = tiff::decoder::Limits::default();
    let frame_bytes = usize::try_from(max_pixels().saturating_mul(8)).unwrap_or(usize::MAX);
    limits.decoding_buffer_size = frame_bytes;
    limits.intermediate_buffer_size = frame_bytes;
    limits
}

/// Decodes only the strips holding the selected rows of a chunky, striped, 16-bit RGB
/// TIFF, the rows split in contiguous parts decoded in parallel (a decoder per part).
/// `Ok(Err(select))` hands the selector back when the file has another layout.
pub(super) fn decode_tiff_rows<
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

pub(super) fn decode_tiff(path: &Path) -> Result<Decoded, CaptureError> {
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
    Ok(Decoded::whole(width, height, data, max_count))
}

fn drop_alpha<T: Copy>(rgba: &[T]) -> Vec<T> {
    rgba.chunks_exact(4)
        .flat_map(|p| [p[0], p[1], p[2]])
        .collect()
}

fn widen(values: &[u8]) -> Vec<u16> {
    values.iter().map(|&v| u16::from(v)).collect()
}
