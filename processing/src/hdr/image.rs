//! A merged radiance map: relative radiance, f32 RGB interleaved and row-major, with a
//! per-pixel mask of the channels clipped or black in every frame.

use rayon::prelude::*;

use super::weighting::Run;
use crate::capture::Frame;
#[cfg(target_arch = "x86_64")]
use crate::simd::avx2_fma;

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

/// How a merge fills one row of its map (see [`map_rows`]).
pub(super) trait Rows: Sync {
    /// Fills row `y` of the map: `rgb` RGB interleaved, `mask` a byte a pixel; `run` is
    /// the thread's own, kept from row to row.
    fn row(&self, run: &mut Run, y: usize, rgb: &mut [f32], mask: &mut [u8]);
}

/// The values and mask of a map the size of `frame`, computed a row at a time in
/// parallel by `rows`.
pub(super) fn map_rows(frame: &Frame, rows: &impl Rows) -> (Vec<f32>, Vec<u8>) {
    let width = frame.width;
    let mut rgb = vec![0f32; frame.data.len()];
    let mut mask = vec![0u8; frame.width * frame.height];
    rgb.par_chunks_mut(3 * width)
        .zip(mask.par_chunks_mut(width))
        .enumerate()
        .for_each_init(Run::default, |run, (y, (row_rgb, row_mask))| {
            fill_row(rows, run, y, row_rgb, row_mask)
        });
    (rgb, mask)
}

/// [`Rows::row`], compiled for AVX2 and FMA where the processor has them.
fn fill_row(rows: &impl Rows, run: &mut Run, y: usize, rgb: &mut [f32], mask: &mut [u8]) {
    #[cfg(target_arch = "x86_64")]
    if avx2_fma() {
        // SAFETY: the processor has AVX2 and FMA, checked just above.
        return unsafe { fill_row_avx2(rows, run, y, rgb, mask) };
    }
    rows.row(run, y, rgb, mask);
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn fill_row_avx2(
    rows: &impl Rows,
    run: &mut Run,
    y: usize,
    rgb: &mut [f32],
    mask: &mut [u8],
) {
    rows.row(run, y, rgb, mask);
}
