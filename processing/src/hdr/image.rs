//! A merged radiance map: relative radiance, f32 RGB interleaved and row-major, with a
//! per-pixel mask of the channels clipped or black in every frame.

use rayon::prelude::*;

use crate::capture::Frame;

/// Mask bit: some channel of the pixel was clipped in every frame that saw it.
pub const SATURATED: u8 = 1;
/// Mask bit: some channel of the pixel was near black in every frame.
pub const UNDEREXPOSED: u8 = 2;

/// The mask bits that flag channel `c` (0..3) with `flag` ([`SATURATED`] or
/// [`UNDEREXPOSED`]): the any-channel bit plus the channel's own, `flag << (2 + 2c)`.
pub const fn channel_mask(flag: u8, c: usize) -> u8 {
    flag | (flag << (2 + 2 * c))
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
}

/// The values and mask of a map the size of `frame`, computed a row at a time in
/// parallel: `row(scratch, y, rgb, mask)` fills row `y` (`rgb` RGB interleaved, `mask`
/// a byte a pixel), `scratch` buffers of the thread's own, kept from row to row.
pub(super) fn map_rows<S: Default + Send>(
    frame: &Frame,
    row: impl Fn(&mut S, usize, &mut [f32], &mut [u8]) + Send + Sync,
) -> (Vec<f32>, Vec<u8>) {
    let width = frame.width;
    let mut rgb = vec![0f32; frame.data.len()];
    let mut mask = vec![0u8; frame.width * frame.height];
    rgb.par_chunks_mut(3 * width)
        .zip(mask.par_chunks_mut(width))
        .enumerate()
        .for_each_init(S::default, |scratch, (y, (row_rgb, row_mask))| {
            row(scratch, y, row_rgb, row_mask)
        });
    (rgb, mask)
}
