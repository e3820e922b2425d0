//! Choosing a bracket of shutter speeds from one metering capture.
//!
//! Each pixel of the strips has a signal rate `r = (value − black) / t_meter` in raw
//! counts per second. At shutter `t` it is *well exposed* when
//! `noise_floor ≤ r·t < clip_level − black`: unclipped and above the noise floor in the
//! same frame (which implies both conditions of the bracket). The well-exposed shutters
//! of a pixel form an interval of the sorted allowed list, and the shortest bracket is
//! the smallest set of shutters stabbing every interval, which the greedy choice of the
//! earliest-ending interval's longest shutter finds exactly.

use std::ops::Range;

use thiserror::Error;

/// A 16-bit metering capture: row-major, `channels` interleaved values per pixel.
#[derive(Debug, Clone, Copy)]
pub struct MeteringFrame<'a> {
    pub width: usize,
    pub height: usize,
    pub channels: usize,
    pub data: &'a [u16],
    /// Shutter time of the capture, seconds.
    pub shutter_s: f64,
}

/// Where the strips are and what counts as clipped or noise, in raw counts.
#[derive(Debug, Clone, PartialEq)]
pub struct BracketRegion {
    /// Rows of the sample and reference strips.
    pub rows: Vec<usize>,
    /// Columns to consider (the cylinder's extent), half-open.
    pub columns: Range<usize>,
    /// Sensor black level, counts.
    pub black_level: f64,
    /// Values at or above this many counts are clipped (e.g. 95 % of the white level).
    pub clip_level: f64,
    /// Minimum useful signal above black, counts.
    pub noise_floor: f64,
}

/// The chosen shutter speeds and the pixels no allowed shutter exposes well.
#[derive(Debug, Clone, PartialEq)]
pub struct Bracket {
    /// Shutter times, seconds, ascending.
    pub shutters_s: Vec<f64>,
    /// Pixels clipped even at the shortest allowed shutter (that shutter is included).
    pub clipped_at_shortest: usize,
    /// Pixels with signal but below the noise floor even at the longest allowed shutter
    /// (that shutter is included).
    pub dark_at_longest: usize,
    /// Pixels with no signal above black at all (ignored).
    pub no_signal: usize,
}

#[derive(Debug, Error, PartialEq)]
pub enum BracketError {
    #[error("invalid bracket input: {0}")]
    Invalid(String),
    /// The metering capture itself clipped: its rates are only lower bounds.
    #[error("{pixels} strip values clipped in the metering capture at {shutter_s} s: meter again with a shorter shutter")]
    MeteringClipped { pixels: usize, shutter_s: f64 },
}

/// Choose the fewest shutter speeds from `allowed_s` (seconds, any order) such that
/// every strip value with signal is well exposed in at least one frame.
pub fn auto_bracket(
    frame: &MeteringFrame<'_>,
    region: &BracketRegion,
    allowed_s: &[f64],
) -> Result<Bracket, BracketError> {
    let invalid = |what: String| Err(BracketError::Invalid(what));
    if frame.channels == 0 || frame.data.len() != frame.width * frame.height * frame.channels {
        return invalid(format!(
            "metering frame has {} values, expected {}×{}×{}",
            frame.data.len(),
            frame.width,
            frame.height,
            frame.channels
        ));
    }
    if !(frame.shutter_s.is_finite() && frame.shutter_s > 0.0) {
        return invalid(format!("metering shutter {} s", frame.shutter_s));
    }
    if let Some(row) = region.rows.iter().find(|&&r| r >= frame.height) {
        return invalid(format!(
            "strip row {row} outside the {}-row frame",
            frame.height
        ));
    }
    if region.rows.is_empty() || region.columns.is_empty() || region.columns.end > frame.width {
        return invalid(format!(
            "strip region rows {:?} columns {:?} in a {}-column frame",
            region.rows, region.columns, frame.width
        ));
    }
    let span = region.clip_level - region.black_level;
    if !(region.noise_floor > 0.0 && span > region.noise_floor && region.black_level >= 0.0) {
        return invalid(format!(
            "levels black {} clip {} noise floor {}: need 0 ≤ black, 0 < noise floor < clip − black",
            region.black_level, region.clip_level, region.noise_floor
        ));
    }
    let mut allowed: Vec<f64> = allowed_s.to_vec();
    if allowed.is_empty() || allowed.iter().any(|t| !(t.is_finite() && *t > 0.0)) {
        return invalid(format!("allowed shutter list {allowed_s:?}"));
    }
    allowed.sort_by(f64::total_cmp);
    allowed.dedup();

    let mut intervals = Vec::new();
    let (mut clipped_metering, mut clipped_at_shortest, mut dark_at_longest, mut no_signal) =
        (0, 0, 0, 0);
    for &row in &region.rows {
        let start = (row * frame.width + region.columns.start) * frame.channels;
        let end = (row * frame.width + region.columns.end) * frame.channels;
        for &value in &frame.data[start..end] {
            let value = f64::from(value);
            if value >= region.clip_level {
                clipped_metering += 1;
                continue;
            }
            let rate = (value - region.black_level) / frame.shutter_s;
            if rate <= 0.0 {
                no_signal += 1;
                continue;
            }
            // Well exposed: noise_floor / rate ≤ t < span / rate.
            let first = allowed.partition_point(|&t| rate * t < region.noise_floor);
            let last_unclipped = allowed.partition_point(|&t| rate * t < span);
            if last_unclipped == 0 {
                clipped_at_shortest += 1;
                intervals.push((0, 0));
            } else if first == allowed.len() {
                dark_at_longest += 1;
                intervals.push((allowed.len() - 1, allowed.len() - 1));
            } else if first >= last_unclipped {
                // The allowed steps jump over this pixel's range: take its longest
                // unclipped shutter.
                intervals.push((last_unclipped - 1, last_unclipped - 1));
            } else {
                intervals.push((first, last_unclipped - 1));
            }
        }
    }
    if clipped_metering > 0 {
        return Err(BracketError::MeteringClipped {
            pixels: clipped_metering,
            shutter_s: frame.shutter_s,
        });
    }
    intervals.sort_unstable_by_key(|&(_, last)| last);
    let mut chosen: Vec<usize> = Vec::new();
    for (first, last) in intervals {
        if chosen.last().is_some_and(|&c| c >= first) {
            continue;
        }
        chosen.push(last);
    }
    Ok(Bracket {
        shutters_s: chosen.into_iter().map(|i| allowed[i]).collect(),
        clipped_at_shortest,
        dark_at_longest,
        no_signal,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Full stops from 1/4000 s to 4 s.
    fn stops() -> Vec<f64> {
        (0..=14).map(|k| 4.0 / f64::powi(2.0, 14 - k)).collect()
    }

    fn region(rows: Vec<usize>, width: usize) -> BracketRegion {
        BracketRegion {
            rows,
            columns: 0..width,
            black_level: 100.0,
            clip_level: 60_000.0,
            noise_floor: 400.0,
        }
    }

    /// Whether value `rate·t + black` is well exposed.
    fn well_exposed(rate: f64, t: f64, r: &BracketRegion) -> bool {
        let v = rate * t;
        v >= r.noise_floor && v < r.clip_level - r.black_level
    }

    #[test]
    fn every_pixel_is_well_exposed_in_some_frame_with_the_fewest_frames() {
        // A specular strip spanning ~17 stops and a dim reference row.
        let width = 64;
        let rates: Vec<f64> = (0..width)
            .map(|c| 50.0 * 2f64.powf(c as f64 * 17.0 / (width - 1) as f64))
            .collect();
        let shutter = 1.0 / 4000.0;
        let mut data = vec![0u16; width * 2];
        for (c, &r) in rates.iter().enumerate() {
            data[c] = (100.0 + r * shutter).round().min(65535.0) as u16;
            data[width + c] = (100.0 + r * shutter / 3.0).round() as u16;
        }
        // Meter at a short shutter so nothing clips; rates come from the metering values.
        let frame = MeteringFrame {
            width,
            height: 2,
            channels: 1,
            data: &data,
            shutter_s: shutter,
        };
        let reg = region(vec![0, 1], width);
        let bracket = auto_bracket(&frame, &reg, &stops()).unwrap();
        assert!(bracket.shutters_s.windows(2).all(|w| w[0] < w[1]));
        for &v in &data {
            let rate = (f64::from(v) - 100.0) / shutter;
            if rate * 4.0 < reg.noise_floor || rate <= 0.0 {
                continue;
            }
            assert!(
                bracket
                    .shutters_s
                    .iter()
                    .any(|&t| well_exposed(rate, t, &reg)),
                "value {v} not covered by {:?}",
                bracket.shutters_s
            );
        }
        // Each frame covers log2(59900/400) ≈ 7.2 stops; the lower bound on the count is the
        // number of disjoint intervals, which removing any chosen frame would leave uncovered.
        for skip in 0..bracket.shutters_s.len() {
            let fewer: Vec<f64> = bracket
                .shutters_s
                .iter()
                .enumerate()
                .filter(|(i, _)| *i != skip)
                .map(|(_, &t)| t)
                .collect();
            let uncovered = data.iter().any(|&v| {
                let rate = (f64::from(v) - 100.0) / shutter;
                rate * 4.0 >= reg.noise_floor
                    && rate > 0.0
                    && !fewer.iter().any(|&t| well_exposed(rate, t, &reg))
            });
            assert!(
                uncovered,
                "frame {skip} of {:?} is redundant",
                bracket.shutters_s
            );
        }
        assert!(bracket.shutters_s.len() >= 2 && bracket.shutters_s.len() <= 4);
    }

    #[test]
    fn uniform_strip_needs_one_frame() {
        let data = vec![1100u16; 8 * 3 * 3];
        let frame = MeteringFrame {
            width: 8,
            height: 3,
            channels: 3,
            data: &data,
            shutter_s: 0.01,
        };
        let bracket = auto_bracket(&frame, &region(vec![1], 8), &stops()).unwrap();
        assert_eq!(bracket.shutters_s.len(), 1);
        let t = bracket.shutters_s[0];
        // 1000 counts in 0.01 s: the longest well-exposed stop keeps 1e5·t < 59900.
        assert!(well_exposed(1.0e5, t, &region(vec![1], 8)));
        assert!(!well_exposed(1.0e5, 2.0 * t, &region(vec![1], 8)));
    }

    #[test]
    fn only_strip_rows_and_columns_count() {
        let mut data = vec![100u16; 4 * 3];
        data[4..8].copy_from_slice(&[5000; 4]);
        data[8] = 60_000; // clipped, but outside the strip row
        let frame = MeteringFrame {
            width: 4,
            height: 3,
            channels: 1,
            data: &data,
            shutter_s: 0.01,
        };
        let mut reg = region(vec![1], 4);
        assert_eq!(
            auto_bracket(&frame, &reg, &stops())
                .unwrap()
                .shutters_s
                .len(),
            1
        );
        reg.rows = vec![0, 1];
        let b = auto_bracket(&frame, &reg, &stops()).unwrap();
        assert_eq!(b.no_signal, 4);
        reg.rows = vec![2];
        reg.columns = 1..4;
        assert_eq!(auto_bracket(&frame, &reg, &stops()).unwrap().no_signal, 3);
    }

    #[test]
    fn clipped_metering_and_unreachable_pixels_are_reported() {
        let data = [60_000u16, 2000];
        let frame = MeteringFrame {
            width: 2,
            height: 1,
            channels: 1,
            data: &data,
            shutter_s: 0.5,
        };
        assert_eq!(
            auto_bracket(&frame, &region(vec![0], 2), &stops()),
            Err(BracketError::MeteringClipped {
                pixels: 1,
                shutter_s: 0.5
            })
        );
        // Too bright even at 1/4000 s, and too dim even at 4 s.
        let data = [50_000u16, 101];
        let frame = MeteringFrame {
            width: 2,
            height: 1,
            channels: 1,
            data: &data,
            shutter_s: 0.25,
        };
        let b = auto_bracket(&frame, &region(vec![0], 2), &[0.5, 1.0, 2.0]).unwrap();
        assert_eq!((b.clipped_at_shortest, b.dark_at_longest), (1, 1));
        assert_eq!(b.shutters_s, vec![0.5, 2.0]);
    }

    #[test]
    fn bad_input_is_rejected() {
        let data = [1000u16; 4];
        let frame = MeteringFrame {
            width: 2,
            height: 2,
            channels: 1,
            data: &data,
            shutter_s: 0.01,
        };
        let reg = region(vec![0], 2);
        assert!(auto_bracket(&frame, &reg, &[]).is_err());
        assert!(auto_bracket(&frame, &reg, &[0.01, f64::NAN]).is_err());
        assert!(auto_bracket(&frame, &region(vec![2], 2), &stops()).is_err());
        assert!(auto_bracket(&MeteringFrame { width: 3, ..frame }, &reg, &stops()).is_err());
        assert!(auto_bracket(
            &MeteringFrame {
                shutter_s: 0.0,
                ..frame
            },
            &reg,
            &stops()
        )
        .is_err());
        let mut bad = reg.clone();
        bad.noise_floor = 70_000.0;
        assert!(auto_bracket(&frame, &bad, &stops()).is_err());
        bad = reg.clone();
        bad.columns = 1..3;
        assert!(auto_bracket(&frame, &bad, &stops()).is_err());
    }
}
