//! Box-and-whisker statistics (the paper's Fig. 7 and 9).
//!
//! Convention (Tukey): quartiles by linear interpolation between order statistics
//! (Hyndman–Fan type 7, the default of R and NumPy); whiskers end at the most extreme
//! data within 1.5 IQR of the box; data beyond the whiskers are outliers. Non-finite
//! values are ignored.

use serde::Serialize;

/// Summary of one group of values.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct BoxStats {
    /// Number of finite values summarised.
    pub count: usize,
    pub min: f64,
    pub q1: f64,
    pub median: f64,
    pub q3: f64,
    pub max: f64,
    /// Smallest value ≥ q1 − 1.5 IQR.
    pub whisker_low: f64,
    /// Largest value ≤ q3 + 1.5 IQR.
    pub whisker_high: f64,
    /// Values outside the whiskers, ascending.
    pub outliers: Vec<f64>,
}

impl BoxStats {
    /// Statistics of the finite values in `values`; `None` if there are none.
    pub fn from_values(values: &[f64]) -> Option<BoxStats> {
        let mut v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
        if v.is_empty() {
            return None;
        }
        v.sort_by(f64::total_cmp);
        let q1 = quantile_sorted(&v, 0.25);
        let median = quantile_sorted(&v, 0.5);
        let q3 = quantile_sorted(&v, 0.75);
        let iqr = q3 - q1;
        let (fence_low, fence_high) = (q1 - 1.5 * iqr, q3 + 1.5 * iqr);
        let inside = || {
            v.iter()
                .copied()
                .filter(|&x| x >= fence_low && x <= fence_high)
        };
        // The quartiles lie inside the fences, so both folds see at least one value.
        let whisker_low = inside().fold(f64::INFINITY, f64::min);
        let whisker_high = inside().fold(f64::NEG_INFINITY, f64::max);
        let outliers = v
            .iter()
            .copied()
            .filter(|&x| x < fence_low || x > fence_high)
            .collect();
        Some(BoxStats {
            count: v.len(),
            min: v[0],
            q1,
            median,
            q3,
            max: v[v.len() - 1],
            whisker_low,
            whisker_high,
            outliers,
        })
    }
}

/// Type-7 quantile of ascending, non-empty `sorted` at probability `p` in [0, 1].
fn quantile_sorted(sorted: &[f64], p: f64) -> f64 {
    let h = (sorted.len() - 1) as f64 * p;
    let lo = h.floor() as usize;
    let hi = (lo + 1).min(sorted.len() - 1);
    sorted[lo] + (h - lo as f64) * (sorted[hi] - sorted[lo])
}
