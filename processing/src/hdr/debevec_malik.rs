//! The Debevec–Malik (1997) merge of non-linear frames: counts quantised to 256 levels,
//! the log response g(z) recovered per channel ([`response`]), and the reading of level
//! z the exposure e^g(z); radiance on the scale fixed by g(128) = 0.

use rayon::prelude::*;

use super::error::HdrError;
use super::image::{channel_mask, map_rows, Rows, SATURATED, UNDEREXPOSED};
use super::options::MergeOptions;
use super::response::{self, Observations, LEVELS};
use super::weighting::{Run, RUN};
use crate::capture::Frame;

/// Per-frame table from count to the quantised level 0..=255 of its normalised signal:
/// one entry per count, so that a lookup needs no bounds check.
type LevelTable = Box<[u8; 1 << 16]>;

fn level_table(frame: &Frame) -> LevelTable {
    let range = frame.white_level - frame.black_level;
    let mut table = Box::new([0u8; 1 << 16]);
    for (count, level) in (0..=u16::MAX).zip(table.iter_mut()) {
        let s = (f64::from(count) - frame.black_level) / range;
        *level = (s.clamp(0.0, 1.0) * (LEVELS - 1) as f64).round() as u8;
    }
    table
}

pub(super) fn merge_debevec_malik(
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
    let tables: Vec<LevelTable> = frames.iter().map(level_table).collect();
    let level = |j: usize, index: usize| usize::from(tables[j][usize::from(frames[j].data[index])]);
    let observations = Observations {
        level: &level,
        frames: frames.len(),
        pixels: frames[0].width * frames[0].height,
        ln_h: &ln_h,
    };
    // The channels' curves are recovered side by side; the first channel that fails is
    // the one named.
    let recovered: Vec<Option<response::Curve>> = (0..3)
        .into_par_iter()
        .map(|c| {
            response::recover(
                &observations,
                c,
                options.response_samples,
                options.smoothness,
            )
        })
        .collect();
    let curves: Vec<response::Curve> = recovered
        .into_iter()
        .enumerate()
        .map(|(c, curve)| {
            curve.ok_or_else(|| HdrError::Response(format!("channel {c}: degenerate bracket")))
        })
        .collect::<Result<_, _>>()?;
    // Longest exposure first: the first usable reading is the reference estimate, and
    // the last clipped one the clipped-everywhere bound.
    let mut order: Vec<usize> = (0..frames.len()).collect();
    order.sort_by(|&a, &b| ln_h[b].total_cmp(&ln_h[a]));
    let exposures: Vec<f64> = order.iter().map(|&j| ln_h[j].exp()).collect();
    let merge = DebevecMalik {
        frames,
        tables: &tables,
        curves: &curves,
        ln_h: &ln_h,
        order,
        exposures,
    };
    Ok(map_rows(&frames[0], &merge))
}

/// A bracket's frames with their level tables and recovered curves.
struct DebevecMalik<'a> {
    frames: &'a [Frame],
    tables: &'a [LevelTable],
    /// One per channel.
    curves: &'a [response::Curve],
    ln_h: &'a [f64],
    /// Frames longest exposure first, and their exposures.
    order: Vec<usize>,
    exposures: Vec<f64>,
}

impl Rows for DebevecMalik<'_> {
    #[inline(always)]
    fn row(&self, run: &mut Run, y: usize, row_rgb: &mut [f32], row_mask: &mut [u8]) {
        let width = self.frames[0].width;
        // A run holds one channel's values, read through its curve.
        for (c, curve) in self.curves.iter().enumerate() {
            for x0 in (0..width).step_by(RUN) {
                let len = RUN.min(width - x0);
                let index = 3 * (width * y + x0) + c;
                run.start(&self.exposures, len);
                for (k, &j) in self.order.iter().enumerate() {
                    // The run's counts of this channel, and the frame's levels.
                    let counts = &self.frames[j].data[index..index + 3 * (len - 1) + 1];
                    let table: &[u8; 1 << 16] = &self.tables[j];
                    run.frame(k, |i| {
                        let z = usize::from(table[usize::from(counts[3 * i])]);
                        (
                            curve.exposure[z],
                            z == LEVELS - 1,
                            (z > 0) & (z < LEVELS - 1),
                        )
                    });
                }
                run.references(|i, clipped| {
                    let (radiance, flag) = match clipped {
                        Some(k) => (
                            (curve.g[LEVELS - 1] - self.ln_h[self.order[k]]).exp(),
                            SATURATED,
                        ),
                        None => (0.0, UNDEREXPOSED),
                    };
                    row_rgb[3 * (x0 + i) + c] = radiance as f32;
                    row_mask[x0 + i] |= channel_mask(flag, c);
                });
                let means = run.means(curve);
                for (i, estimate) in means {
                    row_rgb[3 * (x0 + i) + c] = estimate.max(0.0) as f32;
                }
            }
        }
    }
}
