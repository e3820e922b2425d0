//! Every k-th sample of each θL: what the candidates of `--model auto` are judged on and
//! what a table keeps, on a scan larger than [`JUDGED_PER_THETA_L`] samples in a θL
//! (neighbouring pixel columns differ little in geometry).

use crate::samples::{distinct_theta_l, Sample, THETA_L_TOLERANCE};

/// Most samples of one θL the candidates are judged on by leave-one-θL-out, and a table
/// keeps: a larger scan is judged on every k-th sample of each θL, k the smallest stride
/// that keeps each θL within it, and the chosen parametric candidate is then fitted to
/// every sample.
pub const JUDGED_PER_THETA_L: usize = 500;

/// Every `stride`-th sample of each θL of `samples` (in their order), and the stride:
/// the smallest that keeps each θL within [`JUDGED_PER_THETA_L`].
pub fn judged(samples: &[Sample]) -> (Vec<Sample>, usize) {
    let theta_l = distinct_theta_l(samples);
    let at = |s: &Sample| {
        theta_l
            .iter()
            .position(|t| (t - s.theta_l).abs() <= THETA_L_TOLERANCE)
    };
    let mut counts = vec![0usize; theta_l.len()];
    for i in samples.iter().filter_map(at) {
        counts[i] += 1;
    }
    let most = counts.iter().copied().max().unwrap_or(0);
    let stride = most.div_ceil(JUDGED_PER_THETA_L).max(1);
    let mut seen = vec![0usize; theta_l.len()];
    let kept = samples
        .iter()
        .filter(|s| {
            at(s).is_some_and(|i| {
                seen[i] += 1;
                (seen[i] - 1).is_multiple_of(stride)
            })
        })
        .copied()
        .collect();
    (kept, stride)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_large_scan_is_judged_on_every_kth_sample_of_each_theta_l() {
        let scan = |counts: &[usize]| -> Vec<Sample> {
            counts
                .iter()
                .enumerate()
                .flat_map(|(i, &n)| {
                    (0..n).map(move |k| {
                        Sample::in_plane(-20.0 - 5.0 * i as f64, k as f64 * 0.01, 0.0, [1.0; 3])
                    })
                })
                .collect()
        };
        let count = |samples: &[Sample], theta_l: f64| {
            samples.iter().filter(|s| s.theta_l == theta_l).count()
        };
        let (kept, stride) = judged(&scan(&[1200, 300, 1001]));
        assert_eq!(stride, 3);
        assert_eq!(
            [
                count(&kept, -20.0),
                count(&kept, -25.0),
                count(&kept, -30.0)
            ],
            [400, 100, 334]
        );
        assert_eq!(kept[1].theta_i, 0.03);
        let small = scan(&[500, 20, 499]);
        assert_eq!(judged(&small), (small.clone(), 1));
    }
}
