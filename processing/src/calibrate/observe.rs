//! What the captures of one θL show of the geometry: the two strips' rows, the
//! cylinder's limbs, the white strip's terminator ramp and the sample's specular peak.
//! Everything here is measured from the merged radiance map alone (no model); columns
//! and rows are returned in sensor pixel coordinates (centre of pixel k at k).

use crate::hdr::{HdrImage, SATURATED, UNDEREXPOSED};

/// A run of lit rows: first and last row, in capture rows.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Band {
    pub first: usize,
    pub last: usize,
}

impl Band {
    /// Centre row (capture rows).
    pub fn centre(&self) -> f64 {
        (self.first + self.last) as f64 / 2.0
    }

    fn len(&self) -> usize {
        self.last + 1 - self.first
    }

    /// Rows well inside the band (away from its edges, which a tilt makes vary across
    /// columns), at most `max` of them, evenly spread.
    pub fn core_rows(&self, max: usize) -> Vec<usize> {
        let margin = (self.len() / 8).max(3);
        if self.len() <= 2 * margin {
            return Vec::new();
        }
        let (lo, hi) = (self.first + margin, self.last - margin);
        let count = (hi + 1 - lo).min(max.max(1));
        (0..count)
            .map(|k| lo + (k * (hi - lo)) / (count - 1).max(1))
            .collect()
    }
}

/// Brightness of a pixel: the sum of its channels, `None` where a channel is clipped
/// or black in every exposure.
fn brightness(map: &HdrImage, x: usize, y: usize) -> Option<f64> {
    if map.flags(x, y) & (SATURATED | UNDEREXPOSED) != 0 {
        return None;
    }
    Some(map.pixel(x, y).iter().map(|&v| f64::from(v)).sum())
}

/// The lit bands of rows: rows whose mean brightness stands clearly above the dark
/// rows' (median plus 8 median absolute deviations, and 2 % of the brightest row),
/// in runs of at least `min_rows`.
pub fn lit_bands(map: &HdrImage, min_rows: usize) -> Vec<Band> {
    let profile: Vec<f64> = (0..map.height)
        .map(|y| {
            (0..map.width)
                .map(|x| map.pixel(x, y).iter().map(|&v| f64::from(v)).sum::<f64>())
                .sum::<f64>()
                / map.width as f64
        })
        .collect();
    let median = |values: &[f64]| {
        let mut v = values.to_vec();
        v.sort_by(f64::total_cmp);
        v.get(v.len() / 2).copied().unwrap_or(0.0)
    };
    let dark = median(&profile);
    let deviations: Vec<f64> = profile.iter().map(|p| (p - dark).abs()).collect();
    let spread = median(&deviations);
    let brightest = profile.iter().copied().fold(0.0, f64::max);
    let threshold = dark + (8.0 * spread).max(0.02 * (brightest - dark));
    let mut bands = Vec::new();
    let mut start = None;
    for (y, &p) in profile
        .iter()
        .enumerate()
        .chain([(map.height, &f64::NEG_INFINITY)])
    {
        match (start, p > threshold) {
            (None, true) => start = Some(y),
            (Some(first), false) => {
                if y - first >= min_rows {
                    bands.push(Band { first, last: y - 1 });
                }
                start = None;
            }
            _ => {}
        }
    }
    bands
}

/// Which side of the image.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Side {
    Left,
    Right,
}

/// Sensor coordinate of capture coordinate `i` (a superpixel spans `scale` pixels).
pub fn sensor(i: f64, scale: usize) -> f64 {
    scale as f64 * i + (scale as f64 - 1.0) / 2.0
}

/// The white strip's brightness along capture row `y` (`None` where flagged).
pub fn row_profile(map: &HdrImage, y: usize) -> Vec<Option<f64>> {
    (0..map.width).map(|x| brightness(map, x, y)).collect()
}

/// The cylinder's limb on `side` of a row of the white strip: where the brightness
/// first reaches half of what the next columns inward hold, interpolated between
/// pixels (capture coordinates). `None` when the row has no clear step there (the limb
/// is unlit, or the row is too dark).
pub fn limb(profile: &[Option<f64>], side: Side) -> Option<f64> {
    let width = profile.len();
    let value = |i: usize| profile[i].unwrap_or(0.0);
    let brightest = (0..width).map(value).fold(0.0, f64::max);
    if !(brightest.is_finite() && brightest > 0.0) {
        return None;
    }
    // Outermost column above a quarter of the row's brightest, from `side`.
    let order: Box<dyn Iterator<Item = usize>> = match side {
        Side::Left => Box::new(0..width),
        Side::Right => Box::new((0..width).rev()),
    };
    let inward = |i: usize, k: usize| match side {
        Side::Left => i.checked_add(k).filter(|&j| j < width),
        Side::Right => i.checked_sub(k),
    };
    let first = order.into_iter().find(|&i| value(i) > 0.25 * brightest)?;
    let outside = match side {
        Side::Left => first.checked_sub(1)?,
        Side::Right => Some(first + 1).filter(|&j| j < width)?,
    };
    // A step: the pixel outside is dark, the first inside already near the level
    // further in (a terminator ramps up over many pixels instead).
    let mut inner: Vec<f64> = (1..=6)
        .filter_map(|k| inward(first, k).map(value))
        .collect();
    if inner.len() < 6 {
        return None;
    }
    inner.sort_by(f64::total_cmp);
    let level = inner[3];
    let (v_out, v_in) = (value(outside), value(first));
    if !(v_in > 0.6 * level && v_out < 0.1 * level) {
        return None;
    }
    let t = ((0.5 * level - v_out) / (v_in - v_out)).clamp(0.0, 1.0);
    Some(match side {
        Side::Left => outside as f64 + t,
        Side::Right => outside as f64 - t,
    })
}

/// `profile` averaged over the `2·half + 1` columns around each (`None` where any is).
/// Points are chosen on it, so that whether a point is kept does not depend on its own
/// noise, which would bias a regression on the kept points.
fn smoothed(profile: &[Option<f64>], half: usize) -> Vec<Option<f64>> {
    (0..profile.len())
        .map(|i| {
            let window = profile.get(i.checked_sub(half)?..=i + half)?;
            let sum: Option<f64> = window.iter().copied().sum();
            sum.map(|s| s / window.len() as f64)
        })
        .collect()
}

/// Index and value of the largest known value of a profile.
fn largest(profile: &[Option<f64>]) -> Option<(usize, f64)> {
    profile
        .iter()
        .enumerate()
        .filter_map(|(i, v)| v.map(|v| (i, v)))
        .max_by(|a, b| a.1.total_cmp(&b.1))
}

/// The ramp of a row of the white strip toward its terminator on `side`: the
/// (capture column, brightness) of the contiguous run of columns, counted outward from
/// the row's brightest, whose brightness (smoothed over 5 columns) lies between 2 % and
/// 35 % of it. Empty when the run ends in a step (a limb) rather than fading out, or is
/// too short.
pub fn terminator_ramp(profile: &[Option<f64>], side: Side) -> Vec<(usize, f64)> {
    let width = profile.len();
    let smooth = smoothed(profile, 2);
    let Some((peak, brightest)) = largest(&smooth) else {
        return Vec::new();
    };
    let outward: Box<dyn Iterator<Item = usize>> = match side {
        Side::Left => Box::new((0..peak).rev()),
        Side::Right => Box::new(peak + 1..width),
    };
    let mut ramp = Vec::new();
    let mut faded = false;
    for i in outward {
        let (Some(v), Some(own)) = (smooth[i], profile[i]) else {
            faded = ramp.len() >= 2 && profile[i].is_some_and(|v| v < 0.02 * brightest);
            break;
        };
        if v > 0.35 * brightest {
            if !ramp.is_empty() {
                break;
            }
            continue;
        }
        if v < 0.02 * brightest {
            faded = v >= 0.0 && ramp.len() >= 2;
            break;
        }
        ramp.push((i, own, v));
    }
    // A limb cuts the ramp off with a step to black; a terminator fades to it.
    let last = ramp.last().map(|&(_, _, v)| v);
    if !faded || ramp.len() < 6 || last.is_some_and(|v| v > 0.08 * brightest) {
        return Vec::new();
    }
    ramp.into_iter().map(|(i, own, _)| (i, own)).collect()
}

/// Column profile of the white strip: the mean brightness over `rows` per column,
/// `None` where any of those pixels is flagged or the mean is not positive.
pub fn white_profile(map: &HdrImage, rows: &[usize]) -> Vec<Option<f64>> {
    (0..map.width)
        .map(|x| {
            let mut sum = 0.0;
            for &y in rows {
                sum += brightness(map, x, y)?;
            }
            Some(sum / rows.len() as f64).filter(|&m| m > 0.0)
        })
        .collect()
}

/// The specular peak along capture row `y` of the sample strip, normalised by the white
/// profile (smoothed over 9 columns): the contiguous run of columns around the brightest ratio whose ratio
/// (smoothed over 5 columns) minus the row's baseline (its 10th percentile) exceeds
/// half the peak's, as (capture column, ratio − baseline), where that is positive.
/// Empty when the row shows no clear peak (at least 5 % of the baseline above it, 7
/// points wide).
pub fn specular_peak(map: &HdrImage, y: usize, white: &[Option<f64>]) -> Vec<(usize, f64)> {
    // The white varies slowly along the row: smoothing it over 9 columns cuts the noise
    // it would otherwise share among all the sample rows divided by it.
    let white = smoothed(white, 4);
    let own: Vec<Option<f64>> = (0..map.width)
        .map(|x| Some(brightness(map, x, y)? / white[x]?))
        .collect();
    let ratio = smoothed(&own, 2);
    let mut values: Vec<f64> = ratio.iter().flatten().copied().collect();
    if values.len() < 20 {
        return Vec::new();
    }
    values.sort_by(f64::total_cmp);
    let baseline = values[values.len() / 10];
    let Some((peak, top)) = largest(&ratio) else {
        return Vec::new();
    };
    let height = top - baseline;
    if !(height > 0.05 * baseline.abs() && height > 0.0) {
        return Vec::new();
    }
    let above = |i: usize| ratio[i].filter(|v| v - baseline > 0.5 * height);
    let mut lo = peak;
    while lo > 0 && above(lo - 1).is_some() {
        lo -= 1;
    }
    let mut hi = peak;
    while hi + 1 < map.width && above(hi + 1).is_some() {
        hi += 1;
    }
    if hi - lo + 1 < 7 {
        return Vec::new();
    }
    (lo..=hi)
        .filter_map(|i| own[i].map(|v| (i, v - baseline)).filter(|&(_, e)| e > 0.0))
        .collect()
}
