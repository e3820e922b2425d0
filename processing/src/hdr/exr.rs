//! OpenEXR radiance maps: writing a map as float32 RGB with its merge's attributes (the
//! same map always the same bytes), and reading one back with its claimed size checked
//! first.

use std::io::Write;
use std::path::Path;

use rayon::prelude::*;

use super::error::HdrError;
use super::image::{HdrImage, SATURATED, UNDEREXPOSED};
use crate::capture;

impl HdrImage {
    /// Writes float32 RGB OpenEXR. Attributes: `exposure` 1 s and `isoSpeed` 100 (the
    /// units of the values), `capDate`, and `gonio.*` custom attributes with the merge
    /// method, θL, the frames' shutter times and ISOs, and the flagged pixel counts.
    /// RLE-compressed 64×64 tiles, which are laid out and compressed in parallel on
    /// the current thread pool. The attributes are in name order: the same map is the
    /// same bytes.
    pub fn write_exr(&self, path: &Path) -> Result<(), HdrError> {
        use exr::meta::attribute::{AttributeValue, ChannelDescription, SampleType, Text};
        use exr::meta::header::{Header, LayerAttributes};
        let exr_error = |reason: String| HdrError::Exr {
            path: path.to_path_buf(),
            reason,
        };
        let text = |s: &str| Text::new_or_none(s).unwrap_or_else(|| Text::from("?"));
        let list = |v: &[f64]| {
            v.iter()
                .map(|x| format!("{x}"))
                .collect::<Vec<_>>()
                .join(",")
        };
        let mut attributes = LayerAttributes::named("radiance");
        attributes.exposure = Some(1.0);
        attributes.iso_speed = Some(100.0);
        attributes.capture_date = Text::new_or_none(&self.info.time);
        attributes.owner = Text::new_or_none(&self.info.camera);
        attributes.software_name = Some(text("gonio"));
        let custom = [
            ("gonio.method", AttributeValue::Text(text(self.info.method))),
            ("gonio.thetaL", AttributeValue::F64(self.info.theta_l)),
            (
                "gonio.shutterS",
                AttributeValue::Text(text(&list(&self.info.shutter_s))),
            ),
            (
                "gonio.iso",
                AttributeValue::Text(text(&list(&self.info.iso))),
            ),
            (
                "gonio.units",
                AttributeValue::Text(text(match self.info.method {
                    "linear" => "normalised signal per second at ISO 100",
                    _ => "relative radiance, g(128) = 0",
                })),
            ),
            (
                "gonio.saturatedPixels",
                AttributeValue::I32(saturating_i32(self.count_flagged(SATURATED))),
            ),
            (
                "gonio.underexposedPixels",
                AttributeValue::I32(saturating_i32(self.count_flagged(UNDEREXPOSED))),
            ),
        ];
        for (name, value) in custom {
            attributes.other.insert(text(name), value);
        }
        // Channels in the file's (alphabetical) order, each with its offset in a pixel.
        const CHANNELS: [(&str, usize); 3] = [("B", 2), ("G", 1), ("R", 0)];
        let header = Header::new(
            text("radiance"),
            (self.width, self.height),
            CHANNELS
                .iter()
                .map(|(name, _)| ChannelDescription::named(*name, SampleType::F32))
                .collect(),
        )
        .with_attributes(attributes);
        // A tile's rows of interleaved RGB, top to bottom.
        let tile_rows = |block: &exr::block::BlockIndex| {
            let (x0, y0) = (block.pixel_position.x(), block.pixel_position.y());
            let (w, h) = (block.pixel_size.width(), block.pixel_size.height());
            (y0..y0 + h)
                .map(move |y| &self.rgb[3 * (y * self.width + x0)..3 * (y * self.width + x0 + w)])
        };
        // A tile's bytes: each of its rows, channel after channel, little-endian.
        let tile_bytes = |block: &exr::block::BlockIndex| {
            let mut data = Vec::with_capacity(block.pixel_size.area() * 4 * CHANNELS.len());
            for row in tile_rows(block) {
                for (_, offset) in CHANNELS {
                    for pixel in row.chunks_exact(3) {
                        data.extend_from_slice(&pixel[offset].to_le_bytes());
                    }
                }
            }
            data
        };
        let tile_is_zero =
            |block: &exr::block::BlockIndex| tile_rows(block).flatten().all(|v| v.to_bits() == 0);
        // Written through our own handle: on failure the path is left as it is (the
        // exr crate's `to_file` would remove it, whatever it was).
        let file = std::fs::File::create(path).map_err(|e| exr_error(e.to_string()))?;
        let mut out = std::io::BufWriter::new(file);
        exr::block::write(
            &mut out,
            std::iter::once(header).collect(),
            true,
            |meta, writer| {
                use exr::block::chunk::{
                    Chunk, CompressedBlock, CompressedTileBlock, TileCoordinates,
                };
                use exr::block::writer::ChunksWriter;
                use exr::block::UncompressedBlock;
                let blocks: Vec<_> =
                    exr::block::enumerate_ordered_header_block_indices(&meta.headers).collect();
                let tile_size = meta.headers[0].max_block_pixel_size();
                // Most of a map is black (0 radiance): a full tile of zeros is compressed
                // once, and its bytes stand for every other.
                let zero_tile = match blocks.iter().find(|(_, b)| b.pixel_size == tile_size) {
                    Some((_, block)) => {
                        let zeros = UncompressedBlock {
                            index: *block,
                            data: vec![0; tile_size.area() * 4 * CHANNELS.len()],
                        };
                        match zeros.compress_to_chunk(&meta.headers)?.compressed_block {
                            CompressedBlock::Tile(tile) => Some(tile.compressed_pixels_le),
                            _ => None,
                        }
                    }
                    None => None,
                };
                // The chunk of `block` when it is a full tile of zeros: the zero tile's
                // bytes at its coordinates.
                let zero_chunk = |block: &exr::block::BlockIndex| {
                    let zeros = zero_tile.as_ref()?;
                    (block.pixel_size == tile_size && tile_is_zero(block)).then(|| Chunk {
                        layer_index: block.layer,
                        compressed_block: CompressedBlock::Tile(CompressedTileBlock {
                            coordinates: TileCoordinates {
                                tile_index: block.pixel_position / tile_size,
                                level_index: block.level,
                            },
                            compressed_pixels_le: zeros.clone(),
                        }),
                    })
                };
                // A bounded number of compressed tiles in memory at once.
                for batch in blocks.chunks(EXR_TILES_PER_BATCH) {
                    let chunks = batch
                        .par_iter()
                        .map(|(index, block)| {
                            let chunk = match zero_chunk(block) {
                                Some(chunk) => chunk,
                                None => UncompressedBlock {
                                    index: *block,
                                    data: tile_bytes(block),
                                }
                                .compress_to_chunk(&meta.headers)?,
                            };
                            Ok((*index, chunk))
                        })
                        .collect::<exr::error::Result<Vec<_>>>()?;
                    for (index, chunk) in chunks {
                        writer.write_chunk(index, chunk)?;
                    }
                }
                Ok(())
            },
        )
        .map_err(|e| exr_error(e.to_string()))?;
        let file = out.into_inner().map_err(|e| exr_error(e.to_string()))?;
        // A device or a FIFO gets the bytes as written; a file its header in order.
        if file.metadata().is_ok_and(|m| m.is_file()) {
            std::fs::OpenOptions::new()
                .read(true)
                .write(true)
                .open(path)
                .and_then(|mut file| sort_header_attributes(&mut file))
                .map_err(|e| exr_error(e.to_string()))?;
        }
        Ok(())
    }
}

/// Most bytes of an OpenEXR header [`sort_header_attributes`] reads (ours are about
/// 1 KB).
const EXR_HEADER_MAX_BYTES: u64 = 1 << 20;

/// Puts the header attributes of the single-part OpenEXR file `file` in name order, in
/// place. The exr crate writes custom attributes in the order of a hash map, which
/// differs from one write to the next, and the same map must be the same bytes. The
/// header keeps its length, so the offset table after it still holds.
fn sort_header_attributes(file: &mut std::fs::File) -> std::io::Result<()> {
    use std::io::{Read, Seek, SeekFrom};
    let invalid = |what: &str| std::io::Error::new(std::io::ErrorKind::InvalidData, what);
    let mut head = Vec::new();
    file.seek(SeekFrom::Start(0))?;
    Read::by_ref(file)
        .take(EXR_HEADER_MAX_BYTES)
        .read_to_end(&mut head)?;
    // Magic number and version flags, then attributes (name NUL, type NUL, size as a
    // little-endian i32, value) up to an empty name.
    let flags = head
        .get(4..8)
        .ok_or_else(|| invalid("no OpenEXR version"))?;
    const MULTIPART: u8 = 0x10;
    if flags[1] & MULTIPART != 0 {
        return Err(invalid("a multi-part OpenEXR file"));
    }
    let nul = |from: usize| {
        head.get(from..)
            .and_then(|rest| rest.iter().position(|&b| b == 0))
            .map(|n| from + n)
            .ok_or_else(|| invalid("an OpenEXR header cut short"))
    };
    let mut attributes: Vec<&[u8]> = Vec::new();
    let mut at = 8;
    loop {
        let name_end = nul(at)?;
        if name_end == at {
            break;
        }
        let size_at = nul(name_end + 1)? + 1;
        let size = head
            .get(size_at..size_at + 4)
            .and_then(|b| <[u8; 4]>::try_from(b).ok())
            .map(i32::from_le_bytes)
            .and_then(|n| usize::try_from(n).ok())
            .ok_or_else(|| invalid("an OpenEXR attribute size"))?;
        let end = size_at + 4 + size;
        attributes.push(
            head.get(at..end)
                .ok_or_else(|| invalid("an OpenEXR header cut short"))?,
        );
        at = end;
    }
    // Names are unique and end in NUL: byte order of the records is name order.
    attributes.sort_unstable();
    let sorted = attributes.concat();
    file.seek(SeekFrom::Start(8))?;
    file.write_all(&sorted)?;
    file.flush()
}

/// Tiles compressed in parallel before they are written: 1024 tiles of 64×64 RGB
/// float32 pixels are 48 MB uncompressed.
const EXR_TILES_PER_BATCH: usize = 1024;

/// Reads the RGB channels of an OpenEXR radiance map (as [`HdrImage::write_exr`]
/// writes it): width, height and `rgb[3 * (y * width + x) + c]`. The size every layer
/// claims is checked against [`capture::max_pixels`] and the file's length before any
/// pixel is read; a decoder panic on malformed data becomes an error.
pub fn read_exr_rgb(path: &Path) -> Result<(usize, usize, Vec<f32>), HdrError> {
    use exr::prelude::*;
    let exr_error = |reason: String| HdrError::ExrRead {
        path: path.to_path_buf(),
        reason,
    };
    let open = || {
        gonio_files::input::open_input(path, max_exr_bytes())
            .map(std::io::BufReader::new)
            .map_err(|e| exr_error(e.to_string()))
    };
    let file = open()?;
    let file_len = file
        .get_ref()
        .metadata()
        .map_err(|e| exr_error(e.to_string()))?
        .len();
    let read = || -> std::result::Result<(usize, usize, Vec<f32>), HdrError> {
        let meta = exr::meta::MetaData::read_from_buffered(file, true)
            .map_err(|e| exr_error(e.to_string()))?;
        for header in &meta.headers {
            let (w, h) = (header.layer_size.x() as u64, header.layer_size.y() as u64);
            let pixels = w.saturating_mul(h);
            if pixels > capture::max_pixels() {
                return Err(exr_error(format!(
                    "{w}×{h} pixels is more than the {} allowed (max_frame_pixels)",
                    capture::max_pixels()
                )));
            }
            let bytes = pixels.saturating_mul(header.channels.bytes_per_pixel as u64);
            if bytes > file_len.saturating_mul(EXR_MAX_COMPRESSION_RATIO) {
                return Err(exr_error(format!(
                    "{w}×{h} pixels need {bytes} bytes, more than the {file_len}-byte file \
                     can hold even compressed"
                )));
            }
        }
        let image = read()
            .no_deep_data()
            .largest_resolution_level()
            .rgb_channels(
                |size: Vec2<usize>, _: &RgbChannels| (size.x(), vec![0f32; 3 * size.area()]),
                |(width, rgb): &mut (usize, Vec<f32>),
                 at: Vec2<usize>,
                 (r, g, b): (f32, f32, f32)| {
                    let i = 3 * (at.y() * *width + at.x());
                    if let Some(px) = rgb.get_mut(i..i + 3) {
                        px.copy_from_slice(&[r, g, b]);
                    }
                },
            )
            .first_valid_layer()
            .all_attributes()
            .from_buffered(open()?)
            .map_err(|e| exr_error(e.to_string()))?;
        let size = image.layer_data.size;
        let (_, rgb) = image.layer_data.channel_data.pixels;
        Ok((size.x(), size.y(), rgb))
    };
    crate::guard::catch(read)
        .unwrap_or_else(|panic| Err(exr_error(format!("malformed file ({panic})"))))
}

/// Largest ratio of decoded to stored bytes an OpenEXR file may claim.
const EXR_MAX_COMPRESSION_RATIO: u64 = 1032;

/// Largest OpenEXR file read at all: four float32 channels per allowed pixel (see
/// [`capture::max_pixels`]) plus 64 MiB of headers and attributes.
fn max_exr_bytes() -> u64 {
    capture::max_pixels()
        .saturating_mul(16)
        .saturating_add(64 << 20)
}

fn saturating_i32(n: usize) -> i32 {
    i32::try_from(n).unwrap_or(i32::MAX)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::hdr::HdrInfo;

    /// The same map written twice is the same bytes (the exr crate alone orders custom
    /// attributes differently each time), and reads back as written.
    #[test]
    fn the_same_map_is_written_as_the_same_bytes() {
        let dir = tempfile::tempdir().unwrap();
        let (width, height) = (70, 5);
        let image = HdrImage {
            width,
            height,
            rgb: (0..3 * width * height).map(|v| v as f32 * 0.25).collect(),
            mask: vec![0; width * height],
            info: HdrInfo {
                method: "linear",
                shutter_s: vec![0.1, 0.01],
                iso: vec![100.0, 100.0],
                theta_l: -20.0,
                camera: "test".into(),
                time: "2026-01-01T00:00:00Z".into(),
            },
        };
        let written: Vec<Vec<u8>> = (0..6)
            .map(|n| {
                let path = dir.path().join(format!("map_{n}.exr"));
                image.write_exr(&path).unwrap();
                std::fs::read(&path).unwrap()
            })
            .collect();
        assert!(written.iter().all(|w| *w == written[0]));
        let (w, h, rgb) = read_exr_rgb(&dir.path().join("map_0.exr")).unwrap();
        assert_eq!((w, h), (width, height));
        assert_eq!(rgb, image.rgb);
    }
}
