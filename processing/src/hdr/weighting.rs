//! The weighting shared by both merges: one value's readings averaged as reading /
//! exposure, each weighted by its inverse variance H²/σ², with the frames that count and
//! their variances decided by the reading an estimate predicts (see the [`hdr`](super) module).

/// The merge of one value from `frames` readings (see the module comment): the mean of
/// reading / exposure over the frames whose reading is not clipped (`reading` gives
/// `None`) and whose reading predicted from an estimate (estimate × exposure) is
/// `usable`, each weighted by exposure² / `variance(frame, predicted reading)`. Predicted
/// first from `reference`, then again from that first mean; an estimate that leaves no
/// frame is kept.
pub(super) fn predicted_mean(
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

#[cfg(test)]
mod tests {
    use super::*;

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
