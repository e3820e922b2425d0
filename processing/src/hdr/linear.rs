//! The linear merge of raw counts: readings are normalised signals (0 black, 1
//! clipping), usable between `min_signal` and `max_signal`, with shot plus read noise;
//! radiance is normalised signal per second at ISO 100.

use super::image::{channel_mask, map_rows, Rows, SATURATED, UNDEREXPOSED};
use super::options::MergeOptions;
use super::weighting::{Run, Weighing, RUN};
use crate::capture::Frame;

/// Per-frame constants of the linear merge.
struct LinearFrame<'a> {
    data: &'a [u16],
    black: f64,
    inv_range: f64,
    exposure: f64,
    /// Shot variance per unit signal: (ISO/100) / full well.
    shot: f64,
}

/// A bracket's frames, longest exposure first, and the merge's constants.
struct Linear<'a> {
    sorted: Vec<LinearFrame<'a>>,
    exposures: Vec<f64>,
    /// Usable normalised signals.
    lo: f64,
    hi: f64,
    /// Read noise variance, in normalised signal².
    read_var: f64,
    width: usize,
}

pub(super) fn merge_linear(frames: &[Frame], options: &MergeOptions) -> (Vec<f32>, Vec<u8>) {
    let mut sorted: Vec<LinearFrame> = frames
        .iter()
        .map(|f| LinearFrame {
            data: &f.data,
            black: f.black_level,
            inv_range: 1.0 / (f.white_level - f.black_level),
            exposure: f.sidecar.exposure(),
            shot: f.sidecar.iso.unwrap_or(100.0) / 100.0 / options.noise.full_well_electrons,
        })
        .collect();
    // Longest exposure first: the first valid sample is the best single estimate.
    sorted.sort_by(|a, b| b.exposure.total_cmp(&a.exposure));
    let exposures: Vec<f64> = sorted.iter().map(|f| f.exposure).collect();
    let linear = Linear {
        sorted,
        exposures,
        lo: options.min_signal,
        hi: options.max_signal,
        read_var: options.noise.read_noise * options.noise.read_noise,
        width: frames[0].width,
    };
    map_rows(&frames[0], &linear)
}

impl Rows for Linear<'_> {
    #[inline(always)]
    fn row(&self, run: &mut Run, y: usize, row_rgb: &mut [f32], row_mask: &mut [u8]) {
        let (hi, exposures) = (self.hi, &self.exposures);
        for (r, rgb) in row_rgb.chunks_mut(RUN).enumerate() {
            let (start, index) = (r * RUN, 3 * self.width * y + r * RUN);
            run.start(exposures, rgb.len());
            for (j, f) in self.sorted.iter().enumerate() {
                let counts = &f.data[index..index + rgb.len()];
                run.frame(j, |k| {
                    let s = (f64::from(counts[k]) - f.black) * f.inv_range;
                    (s, s > hi, self.usable(s))
                });
            }
            run.references(|k, clipped| {
                let (radiance, flag) = match clipped {
                    Some(j) => (hi / exposures[j], SATURATED),
                    None => (0.0, UNDEREXPOSED),
                };
                rgb[k] = radiance as f32;
                row_mask[(start + k) / 3] |= channel_mask(flag, (start + k) % 3);
            });
            let means = run.means(self);
            for (k, estimate) in means {
                rgb[k] = estimate.max(0.0) as f32;
            }
        }
    }
}

/// Readings usable between `min_signal` and `max_signal`; shot plus read noise.
impl Weighing for Linear<'_> {
    #[inline(always)]
    fn usable(&self, x: f64) -> bool {
        (x >= self.lo) & (x <= self.hi)
    }

    #[inline(always)]
    fn variance(&self, j: usize, x: f64, _: f64) -> f64 {
        self.sorted[j].shot * x + self.read_var
    }
}
