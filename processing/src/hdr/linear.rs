//! The linear merge of raw counts: readings are normalised signals (0 black, 1
//! clipping), usable between `min_signal` and `max_signal`, with shot plus read noise;
//! radiance is normalised signal per second at ISO 100.

use super::image::{channel_mask, map_rows, SATURATED, UNDEREXPOSED};
use super::options::MergeOptions;
use super::weighting::predicted_mean;
use crate::capture::Frame;

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

pub(super) fn merge_linear(frames: &[Frame], options: &MergeOptions) -> (Vec<f32>, Vec<u8>) {
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
    map_rows(&frames[0], |dark, y, row_rgb, row_mask| {
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
    })
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
