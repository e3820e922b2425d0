//! HDR radiance maps from a bracket of exposures.
//!
//! Two methods, one merge of a value's readings: the weighted mean of reading/exposure
//! over the frames that hold it, each weighted by its inverse variance H²/σ² (H the
//! frame's exposure). Which frames hold it and the variance σ² of each are decided by
//! the reading an estimate predicts for the frame (estimate × H), not by the frame's own
//! noisy reading: a reading that noise lifts over the black threshold would otherwise be
//! kept more often than one it lowers (a bias of up to 1 % at low signal in the linear
//! case, and several-fold for dark 8-bit values), and noisy readings would set their own
//! weights. The first estimate is the longest exposure's usable reading alone; the mean
//! is taken from it, then again from the merged value. A frame whose own reading is
//! clipped never counts; a black reading in a frame that should hold the value counts as
//! the signal it reads.
//! - **linear** (raw counts): the reading is the normalised signal, usable between
//!   `min_signal` and `max_signal`; σ² is shot plus read noise of the noise model.
//! - **Debevec–Malik (1997)** for non-linear frames: counts quantised to 256 levels,
//!   the log response g(z) recovered per channel by least squares from sampled pixels
//!   with hat weights, a second-difference smoothness term λ and g(128) = 0, made
//!   monotone (see `response`). The reading of level z is the exposure e^g(z) (0 at level
//!   0), usable where the prediction reads between levels 1 and 254; σ² is shot, read
//!   and quantisation noise of a model fitted to the bracket.
//!
//! Radiance is relative: for the linear method, normalised signal (0 black, 1 clipping)
//! per second of exposure at ISO 100; for Debevec–Malik the scale fixed by g(128) = 0.
//! Ratios of radiances (which is what extraction uses) are independent of that scale.
//!
//! A channel with no usable frame is flagged in [`HdrImage::mask`] and given a finite
//! value: if any frame clipped, the lower bound from the shortest clipped exposure
//! ([`SATURATED`]); otherwise (black in every frame) 0 ([`UNDEREXPOSED`]).
#![doc = include_str!("hdr.md")]

mod response;

use std::io::Write;
use std::path::{Path, PathBuf};

use rayon::prelude::*;
use thiserror::Error;

use crate::capture::{self, Frame, Response};
use response::{Observations, LEVELS};

/// Mask bit: some channel of the pixel was clipped in every frame that saw it.
pub const SATURATED: u8 = 1;
/// Mask bit: some channel of the pixel was near black in every frame.
pub const UNDEREXPOSED: u8 = 2;

/// The mask bits that flag channel `c` (0..3) with `flag` ([`SATURATED`] or
/// [`UNDEREXPOSED`]): the any-channel bit plus the channel's own, `flag << (2 + 2c)`.
pub const fn channel_mask(flag: u8, c: usize) -> u8 {
    flag | (flag << (2 + 2 * c))
}

/// Which merge to run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum MergeMethod {
    /// Linear for linear frames, Debevec–Malik for non-linear ones.
    #[default]
    Auto,
    Linear,
    DebevecMalik,
}

/// Sensor noise model for the linear merge, in units of the normalised signal.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NoiseModel {
    /// Electrons at clipping at ISO 100 (shot variance of signal s is s / full_well,
    /// scaled by ISO/100).
    pub full_well_electrons: f64,
    /// Read noise standard deviation as a fraction of the range black..white.
    pub read_noise: f64,
}

impl Default for NoiseModel {
    /// Typical of an APS-C DSLR at base ISO: 30 000 e⁻ full well, read noise 1/5000.
    fn default() -> Self {
        Self {
            full_well_electrons: 30_000.0,
            read_noise: 2e-4,
        }
    }
}

/// Options of [`merge`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MergeOptions {
    pub method: MergeMethod,
    pub noise: NoiseModel,
    /// Normalised signals below this are treated as black (linear method).
    pub min_signal: f64,
    /// Normalised signals above this are treated as clipped (linear method).
    pub max_signal: f64,
    /// Debevec–Malik smoothness weight λ, relative to the data's weight per level.
    pub smoothness: f64,
    /// Debevec–Malik: about this many pixel locations per channel are sampled evenly in
    /// rank, and as many evenly in brightness (fewer where the image has fewer usable).
    pub response_samples: usize,
}

impl Default for MergeOptions {
    fn default() -> Self {
        Self {
            method: MergeMethod::Auto,
            noise: NoiseModel::default(),
            min_signal: 0.002,
            max_signal: 0.98,
            smoothness: 50.0,
            response_samples: 1000,
        }
    }
}

/// Errors of [`merge`] and [`HdrImage::write_exr`].
#[derive(Debug, Error)]
pub enum HdrError {
    #[error("no frames to merge")]
    NoFrames,
    #[error("{path}: {found_w}×{found_h} pixels, but the bracket is {width}×{height}")]
    SizeMismatch {
        path: PathBuf,
        width: usize,
        height: usize,
        found_w: usize,
        found_h: usize,
    },
    #[error("{path}: θL {found}° differs from the bracket's {expected}°")]
    ThetaMismatch {
        path: PathBuf,
        expected: f64,
        found: f64,
    },
    #[error("{path}: response '{found:?}' differs from the bracket's '{expected:?}'")]
    MixedResponse {
        path: PathBuf,
        expected: Response,
        found: Response,
    },
    #[error("Debevec–Malik response recovery needs at least two different exposures")]
    SingleExposure,
    #[error("response recovery failed: {0}")]
    Response(String),
    #[error("invalid merge option: {0}")]
    Options(String),
    #[error("{path}: cannot write OpenEXR: {reason}")]
    Exr { path: PathBuf, reason: String },
    #[error("{path}: cannot read OpenEXR: {reason}")]
    ExrRead { path: PathBuf, reason: String },
}

/// What the merge was made from; written to the EXR attributes.
#[derive(Debug, Clone, PartialEq)]
pub struct HdrInfo {
    /// "linear" or "debevec-malik".
    pub method: &'static str,
    pub shutter_s: Vec<f64>,
    /// ISO of each frame (100 where the sidecar has none).
    pub iso: Vec<f64>,
    pub theta_l: f64,
    pub camera: String,
    pub time: String,
}

/// A merged radiance map: f32 RGB interleaved, row-major, plus a per-pixel mask.
#[derive(Debug, Clone, PartialEq)]
pub struct HdrImage {
    pub width: usize,
    pub height: usize,
    /// `rgb[3 * (y * width + x) + c]`, relative radiance, finite and ≥ 0.
    pub rgb: Vec<f32>,
    /// Per pixel: [`SATURATED`] / [`UNDEREXPOSED`] when any channel is so flagged, and
    /// each channel's own flags ([`channel_mask`]); 0 for a good pixel.
    pub mask: Vec<u8>,
    pub info: HdrInfo,
}

impl HdrImage {
    pub fn pixel(&self, x: usize, y: usize) -> [f32; 3] {
        let i = 3 * (y * self.width + x);
        [self.rgb[i], self.rgb[i + 1], self.rgb[i + 2]]
    }

    /// [`SATURATED`] / [`UNDEREXPOSED`] if any channel of the pixel is so flagged.
    pub fn flags(&self, x: usize, y: usize) -> u8 {
        self.mask[y * self.width + x] & (SATURATED | UNDEREXPOSED)
    }

    /// [`SATURATED`] / [`UNDEREXPOSED`] of channel `c` of the pixel.
    pub fn channel_flags(&self, x: usize, y: usize, c: usize) -> u8 {
        (self.mask[y * self.width + x] >> (2 + 2 * c)) & (SATURATED | UNDEREXPOSED)
    }

    /// Number of pixels with the given mask bit set.
    pub fn count_flagged(&self, bit: u8) -> usize {
        self.mask.iter().filter(|&&m| m & bit != 0).count()
    }

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

/// Merges a bracket of frames of one θL (any order; repeated exposures are fine).
pub fn merge(frames: &[Frame], options: &MergeOptions) -> Result<HdrImage, HdrError> {
    let first = frames.first().ok_or(HdrError::NoFrames)?;
    check_options(options)?;
    for frame in frames {
        if (frame.width, frame.height) != (first.width, first.height) {
            return Err(HdrError::SizeMismatch {
                path: frame.path.clone(),
                width: first.width,
                height: first.height,
                found_w: frame.width,
                found_h: frame.height,
            });
        }
        if (frame.sidecar.theta_l - first.sidecar.theta_l).abs() > 1e-6 {
            return Err(HdrError::ThetaMismatch {
                path: frame.path.clone(),
                expected: first.sidecar.theta_l,
                found: frame.sidecar.theta_l,
            });
        }
        if frame.sidecar.response != first.sidecar.response {
            return Err(HdrError::MixedResponse {
                path: frame.path.clone(),
                expected: first.sidecar.response,
                found: frame.sidecar.response,
            });
        }
    }
    let method = match (options.method, first.sidecar.response) {
        (MergeMethod::Auto, Response::Linear) | (MergeMethod::Linear, _) => MergeMethod::Linear,
        _ => MergeMethod::DebevecMalik,
    };
    let (rgb, mask, name) = match method {
        MergeMethod::DebevecMalik => {
            let (rgb, mask) = merge_debevec_malik(frames, options)?;
            (rgb, mask, "debevec-malik")
        }
        _ => {
            let (rgb, mask) = merge_linear(frames, options);
            (rgb, mask, "linear")
        }
    };
    Ok(HdrImage {
        width: first.width,
        height: first.height,
        rgb,
        mask,
        info: HdrInfo {
            method: name,
            shutter_s: frames.iter().map(|f| f.sidecar.shutter_s).collect(),
            iso: frames
                .iter()
                .map(|f| f.sidecar.iso.unwrap_or(100.0))
                .collect(),
            theta_l: first.sidecar.theta_l,
            camera: first.sidecar.camera.clone(),
            time: first.sidecar.time.clone(),
        },
    })
}

fn check_options(o: &MergeOptions) -> Result<(), HdrError> {
    let bad = |m: &str| Err(HdrError::Options(m.to_string()));
    let ordered =
        (0.0..1.0).contains(&o.min_signal) && o.max_signal > o.min_signal && o.max_signal <= 1.0;
    if !ordered {
        return bad("need 0 ≤ min_signal < max_signal ≤ 1");
    }
    if !(o.noise.full_well_electrons.is_finite() && o.noise.full_well_electrons > 0.0) {
        return bad("full_well_electrons must be positive");
    }
    if !(o.noise.read_noise.is_finite() && o.noise.read_noise > 0.0) {
        return bad("read_noise must be positive");
    }
    if !(o.smoothness.is_finite() && o.smoothness >= 0.0) || o.response_samples < 2 {
        return bad("smoothness must be ≥ 0 and response_samples ≥ 2");
    }
    Ok(())
}

/// Per-frame constants of the linear merge.
struct LinearFrame<'a> {
    data: &'a [u16],
    black: f64,
    inv_range: f64,
    exposure: f64,
    /// Shot variance per unit signal: (ISO/100) / full well.
    shot: f64,
    /// The smallest count whose signal reaches `min_signal` (65536 when none does).
    usable_from: u32,
}

fn merge_linear(frames: &[Frame], options: &MergeOptions) -> (Vec<f32>, Vec<u8>) {
    let (lo, hi) = (options.min_signal, options.max_signal);
    let mut sorted: Vec<LinearFrame> = frames
        .iter()
        .map(|f| {
            let inv_range = 1.0 / (f.white_level - f.black_level);
            // The signal grows with the count (white > black).
            let signal = |count: u32| (f64::from(count) - f.black_level) * inv_range;
            LinearFrame {
                data: &f.data,
                black: f.black_level,
                inv_range,
                exposure: f.sidecar.exposure(),
                shot: f.sidecar.iso.unwrap_or(100.0) / 100.0 / options.noise.full_well_electrons,
                usable_from: (0..=u32::from(u16::MAX))
                    .find(|&c| signal(c) >= lo)
                    .unwrap_or(1 << 16),
            }
        })
        .collect();
    // Longest exposure first: the first valid sample is the best single estimate.
    sorted.sort_by(|a, b| b.exposure.total_cmp(&a.exposure));
    let read_var = options.noise.read_noise * options.noise.read_noise;
    let width = frames[0].width;
    let mut rgb = vec![0f32; frames[0].data.len()];
    let mut mask = vec![0u8; frames[0].width * frames[0].height];
    rgb.par_chunks_mut(3 * width)
        .zip(mask.par_chunks_mut(width))
        .enumerate()
        .for_each_init(Vec::new, |dark, (y, (row_rgb, row_mask))| {
            let offset = 3 * width * y;
            // The samples too dark in every frame (most of a frame, usually), found
            // over the whole row at once: no frame's signal is in range or clipped.
            dark.clear();
            dark.resize(row_rgb.len(), true);
            for f in &sorted {
                let counts = &f.data[offset..offset + row_rgb.len()];
                for (d, &count) in dark.iter_mut().zip(counts) {
                    *d &= u32::from(count) < f.usable_from;
                }
            }
            // A pixel's flags are gathered before they are stored.
            for (p, (pixel, pixel_mask)) in row_rgb
                .chunks_exact_mut(3)
                .zip(row_mask.iter_mut())
                .enumerate()
            {
                for (c, value) in pixel.iter_mut().enumerate() {
                    let i = 3 * p + c;
                    let (radiance, flag) = if dark[i] {
                        (0.0, UNDEREXPOSED)
                    } else {
                        merge_sample(&sorted, offset + i, lo, hi, read_var)
                    };
                    *value = radiance as f32;
                    *pixel_mask |= channel_mask(flag, c);
                }
            }
        });
    (rgb, mask)
}

/// The linear merge of sample `index` of `sorted` (longest exposure first): its
/// radiance and flag.
fn merge_sample(
    sorted: &[LinearFrame],
    index: usize,
    lo: f64,
    hi: f64,
    read_var: f64,
) -> (f64, u8) {
    let signal = |f: &LinearFrame| (f64::from(f.data[index]) - f.black) * f.inv_range;
    let reference = sorted.iter().find_map(|f| {
        let s = signal(f);
        (s >= lo && s <= hi).then(|| s / f.exposure)
    });
    match reference {
        Some(l0) => {
            let estimate = predicted_mean(
                sorted.len(),
                |j| sorted[j].exposure,
                |j| Some(signal(&sorted[j])).filter(|&s| s <= hi),
                |predicted| predicted >= lo && predicted <= hi,
                |j, predicted| sorted[j].shot * predicted + read_var,
                l0,
            );
            (estimate.max(0.0), 0)
        }
        // Sorted longest first, so the last clipped frame is the shortest.
        None => match sorted.iter().rev().find(|f| signal(f) > hi) {
            Some(f) => (hi / f.exposure, SATURATED),
            None => (0.0, UNDEREXPOSED),
        },
    }
}

/// The merge of one value from `frames` readings (see the module comment): the mean of
/// reading / exposure over the frames whose reading is not clipped (`reading` gives
/// `None`) and whose reading predicted from an estimate (estimate × exposure) is
/// `usable`, each weighted by exposure² / `variance(frame, predicted reading)`. Predicted
/// first from `reference`, then again from that first mean; an estimate that leaves no
/// frame is kept.
fn predicted_mean(
    frames: usize,
    exposure: impl Fn(usize) -> f64,
    reading: impl Fn(usize) -> Option<f64>,
    usable: impl Fn(f64) -> bool,
    variance: impl Fn(usize, f64) -> f64,
    reference: f64,
) -> f64 {
    let weighted = |estimate: f64| {
        let (mut sum, mut weights) = (0.0, 0.0);
        for j in 0..frames {
            let h = exposure(j);
            let predicted = estimate * h;
            if !usable(predicted) {
                continue;
            }
            if let Some(value) = reading(j) {
                // w = H²/σ², and w·(value/H) = H·value/σ².
                let inv_var = 1.0 / variance(j, predicted);
                sum += h * value * inv_var;
                weights += h * h * inv_var;
            }
        }
        (weights > 0.0).then(|| sum / weights)
    };
    let first = weighted(reference).unwrap_or(reference);
    weighted(first).unwrap_or(first)
}

/// Per-frame table from count to the quantised level 0..=255 of its normalised signal.
fn level_table(frame: &Frame) -> Vec<u8> {
    let range = frame.white_level - frame.black_level;
    (0..=u16::MAX)
        .map(|count| {
            let s = (f64::from(count) - frame.black_level) / range;
            (s.clamp(0.0, 1.0) * (LEVELS - 1) as f64).round() as u8
        })
        .collect()
}

fn merge_debevec_malik(
    frames: &[Frame],
    options: &MergeOptions,
) -> Result<(Vec<f32>, Vec<u8>), HdrError> {
    let ln_h: Vec<f64> = frames.iter().map(|f| f.sidecar.exposure().ln()).collect();
    let mut distinct = ln_h.clone();
    distinct.sort_by(f64::total_cmp);
    distinct.dedup_by(|a, b| (*a - *b).abs() < 1e-9);
    if distinct.len() < 2 {
        return Err(HdrError::SingleExposure);
    }
    let tables: Vec<Vec<u8>> = frames.iter().map(level_table).collect();
    let level = |j: usize, index: usize| usize::from(tables[j][usize::from(frames[j].data[index])]);
    let observations = Observations {
        level: &level,
        frames: frames.len(),
        pixels: frames[0].width * frames[0].height,
        ln_h: &ln_h,
    };
    let curves: Vec<response::Curve> = (0..3)
        .map(|c| {
            response::recover(
                &observations,
                c,
                options.response_samples,
                options.smoothness,
            )
            .ok_or_else(|| HdrError::Response(format!("channel {c}: degenerate bracket")))
        })
        .collect::<Result<_, _>>()?;
    // Longest exposure first: the first usable reading is the reference estimate, and
    // the last clipped one the clipped-everywhere bound.
    let mut order: Vec<usize> = (0..frames.len()).collect();
    order.sort_by(|&a, &b| ln_h[b].total_cmp(&ln_h[a]));
    let exposures: Vec<f64> = order.iter().map(|&j| ln_h[j].exp()).collect();
    let width = frames[0].width;
    let mut rgb = vec![0f32; frames[0].data.len()];
    let mut mask = vec![0u8; frames[0].width * frames[0].height];
    rgb.par_chunks_mut(3 * width)
        .zip(mask.par_chunks_mut(width))
        .enumerate()
        .for_each_init(Vec::new, |levels, (y, (row_rgb, row_mask))| {
            for (i, value) in row_rgb.iter_mut().enumerate() {
                let index = 3 * width * y + i;
                let curve = &curves[i % 3];
                levels.clear();
                levels.extend(order.iter().map(|&j| level(j, index)));
                let reference = levels
                    .iter()
                    .zip(&exposures)
                    .find(|(&z, _)| z > 0 && z < LEVELS - 1)
                    .map(|(&z, h)| curve.exposure[z] / h);
                let (radiance, flag) = match reference {
                    Some(l0) => {
                        let estimate = predicted_mean(
                            levels.len(),
                            |k| exposures[k],
                            |k| (levels[k] < LEVELS - 1).then(|| curve.exposure[levels[k]]),
                            |predicted| curve.in_range(predicted),
                            |_, predicted| curve.variance(predicted),
                            l0,
                        );
                        (estimate.max(0.0), 0)
                    }
                    None => match levels.iter().rposition(|&z| z == LEVELS - 1) {
                        Some(k) => ((curve.g[LEVELS - 1] - ln_h[order[k]]).exp(), SATURATED),
                        None => (0.0, UNDEREXPOSED),
                    },
                };
                *value = radiance as f32;
                row_mask[i / 3] |= channel_mask(flag, i % 3);
            }
        });
    Ok((rgb, mask))
}

#[cfg(test)]
mod tests {
    use super::*;

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

    /// Constant variance, readings usable from 0.01 to 0.9.
    fn mean(exposures: &[f64], readings: &[Option<f64>], reference: f64) -> f64 {
        predicted_mean(
            exposures.len(),
            |j| exposures[j],
            |j| readings[j],
            |p| (0.01..=0.9).contains(&p),
            |_, _| 1e-4,
            reference,
        )
    }

    #[test]
    fn a_clipped_reading_never_counts() {
        // The short frame alone: the long one predicts 0.8 (usable) but reads clipped.
        let estimate = mean(&[2.0, 1.0], &[None, Some(0.4)], 0.4);
        assert!((estimate - 0.4).abs() < 1e-12, "{estimate}");
    }

    #[test]
    fn a_frame_predicted_below_the_range_does_not_count_whatever_it_reads() {
        // Noise lifts the short frame's reading to 0.3; the estimate predicts 0.005.
        let estimate = mean(&[1.0, 0.01], &[Some(0.5), Some(0.3)], 0.5);
        assert!((estimate - 0.5).abs() < 1e-12, "{estimate}");
    }

    #[test]
    fn a_black_reading_where_the_value_should_show_counts() {
        // The long frame (H = 2) reads 0 where the short one reads 0.2: with equal
        // variances the mean is (2·0 + 1·0.2) / (2² + 1²) = 0.04, and it predicts 0.08
        // for the long frame, still usable.
        let estimate = mean(&[2.0, 1.0], &[Some(0.0), Some(0.2)], 0.2);
        assert!((estimate - 0.04).abs() < 1e-12, "{estimate}");
    }
}
