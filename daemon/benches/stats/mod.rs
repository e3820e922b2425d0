//! The statistics of a benchmark's runs: their median and their spread.

/// The median of `values` (the upper one of an even count); `values` is not empty.
pub fn median(values: &[f64]) -> f64 {
    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    sorted[sorted.len() / 2]
}

/// How far apart the runs were: (largest − smallest) / median, which scripts/bench.sh
/// refuses to put in its table above its limit (a busy machine, not the code).
pub fn spread(values: &[f64]) -> f64 {
    let (low, high) = values
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &v| {
            (l.min(v), h.max(v))
        });
    let middle = median(values);
    if middle > 0.0 {
        (high - low) / middle
    } else {
        0.0
    }
}
