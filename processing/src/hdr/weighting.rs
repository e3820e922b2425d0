//! The weighting shared by both merges: one value's readings averaged as reading /
//! exposure, each weighted by its inverse variance H²/σ², with the frames that count and
//! their variances decided by the reading an estimate predicts (see the [`hdr`](super) module).
//!
//! Values are merged a run at a time ([`Run`]), frame after frame: each step is the same
//! few operations for every value of the run, without branches, so that the compiler
//! keeps them in vector registers; a value's result is the same to the bit as merging
//! it alone (the same operations in the same order; a frame that does not count adds
//! exact zeros).

/// Most values in a run: their readings in every frame (a few tens of kilobytes) stay in
/// the first level cache.
pub(super) const RUN: usize = 256;

/// Marks a value that no frame reads in range, or that none clips.
const NONE: u32 = u32::MAX;

/// How a merge weighs a frame's reading predicted from an estimate (estimate × the
/// frame's exposure).
pub(super) trait Weighing {
    /// Whether a predicted reading `x` is usable.
    fn usable(&self, x: f64) -> bool;
    /// The variance of predicted reading `x` in frame `j`, given what
    /// [`look_up`](Self::look_up) found for it.
    fn variance(&self, j: usize, x: f64, looked_up: f64) -> f64;
    /// Whatever the variance of frame `j`'s readings predicted from `estimate` (exposure
    /// `h`) takes from a table, into `looked_up`: a pass of its own, so that the
    /// weighing itself stays in vector registers. Nothing by default.
    #[inline(always)]
    fn look_up(&self, _j: usize, _h: f64, _estimate: &[f64], _looked_up: &mut [f64]) {}
}

/// A run of values being merged, and its buffers (kept from run to run).
#[derive(Default)]
pub(super) struct Run {
    /// Frames of the bracket, their exposures longest first.
    exposure: Vec<f64>,
    /// Values in the run.
    len: usize,
    /// The reading of value k in frame j at `j * RUN + k`, and whether it is clipped.
    reading: Vec<f64>,
    clipped: Vec<bool>,
    /// Per value: the first frame reading it in range and the last (shortest) clipping it.
    first: Vec<u32>,
    last_clipped: Vec<u32>,
    /// Per value: the estimate (0 for one no frame reads in range), the weighted sums.
    estimate: Vec<f64>,
    /// Per value, for the frame being weighed: what [`Weighing::look_up`] found.
    looked_up: Vec<f64>,
    next: Vec<f64>,
    sum: Vec<f64>,
    weights: Vec<f64>,
}

impl Run {
    /// Starts a run of `len` (≤ [`RUN`]) values of a bracket whose frames, longest
    /// exposure first, have exposures `exposure`.
    #[inline(always)]
    pub fn start(&mut self, exposure: &[f64], len: usize) {
        debug_assert!(len <= RUN);
        self.exposure.clear();
        self.exposure.extend_from_slice(exposure);
        self.len = len;
        let frames = exposure.len();
        self.reading.resize(frames * RUN, 0.0);
        self.clipped.resize(frames * RUN, false);
        self.first.clear();
        self.first.resize(len, NONE);
        self.last_clipped.clear();
        self.last_clipped.resize(len, NONE);
    }

    /// Sets frame `j`'s readings: `read(k)` gives value k's reading, whether it is clipped
    /// (then it never counts) and whether it is in range (usable as the first estimate).
    #[inline(always)]
    pub fn frame(&mut self, j: usize, mut read: impl FnMut(usize) -> (f64, bool, bool)) {
        let n = self.len;
        let readings = self.reading[j * RUN..j * RUN + n].iter_mut();
        let clipped = self.clipped[j * RUN..j * RUN + n].iter_mut();
        let firsts = self.first.iter_mut().zip(&mut self.last_clipped);
        let frame = j as u32;
        for (k, ((reading, clipped), (first, last))) in
            readings.zip(clipped).zip(firsts).enumerate()
        {
            let (value, is_clipped, in_range) = read(k);
            *reading = value;
            *clipped = is_clipped;
            *first = if (*first == NONE) & in_range {
                frame
            } else {
                *first
            };
            *last = if is_clipped { frame } else { *last };
        }
    }

    /// Gives `unread(k, shortest clipped frame)` each value no frame reads in range, and
    /// takes the others' first estimates: reading / exposure of the first (longest) frame
    /// reading them in range.
    #[inline(always)]
    pub fn references(&mut self, mut unread: impl FnMut(usize, Option<usize>)) {
        self.estimate.clear();
        for k in 0..self.len {
            let j = self.first[k];
            let estimate = if j == NONE {
                let last = self.last_clipped[k];
                unread(k, (last != NONE).then_some(last as usize));
                0.0
            } else {
                let j = j as usize;
                self.reading[j * RUN + k] / self.exposure[j]
            };
            self.estimate.push(estimate);
        }
    }

    /// The merge of each value some frame reads in range: the mean of reading / exposure
    /// over the frames whose reading is not clipped and whose reading predicted from an
    /// estimate (estimate × exposure) is usable, each weighted by exposure² over the
    /// variance of the predicted reading (both as `weighing` says). Predicted first from
    /// the reference, then again from that first mean; an estimate that leaves no frame
    /// is kept. Yields each value's place in the run and its merge. Every value of the
    /// run is merged side by side; those no frame reads in range are left out of what is
    /// yielded.
    #[inline(always)]
    pub fn means(&mut self, weighing: &impl Weighing) -> impl Iterator<Item = (usize, f64)> + '_ {
        let m = self.len;
        self.next.resize(m, 0.0);
        self.looked_up.resize(m, 0.0);
        for _ in 0..2 {
            self.sum.clear();
            self.sum.resize(m, 0.0);
            self.weights.clear();
            self.weights.resize(m, 0.0);
            for (j, &h) in self.exposure.iter().enumerate() {
                weighing.look_up(j, h, &self.estimate, &mut self.looked_up);
                let readings = self.reading[j * RUN..j * RUN + m]
                    .iter()
                    .zip(&self.clipped[j * RUN..j * RUN + m]);
                let sums = self.sum.iter_mut().zip(&mut self.weights);
                let estimates = self.estimate.iter().zip(&self.looked_up);
                for ((sum, weights), ((&estimate, &looked_up), (&value, &clipped))) in
                    sums.zip(estimates.zip(readings))
                {
                    let predicted = estimate * h;
                    let inv_var = 1.0 / weighing.variance(j, predicted, looked_up);
                    let inv_var = if weighing.usable(predicted) & !clipped {
                        inv_var
                    } else {
                        0.0
                    };
                    // w = H²/σ², and w·(value/H) = H·value/σ².
                    *sum += h * value * inv_var;
                    *weights += h * h * inv_var;
                }
            }
            let sums = self.sum.iter().zip(&self.weights);
            for ((next, &estimate), (&sum, &weights)) in
                self.next.iter_mut().zip(&self.estimate).zip(sums)
            {
                *next = if weights > 0.0 {
                    sum / weights
                } else {
                    estimate
                };
            }
            std::mem::swap(&mut self.estimate, &mut self.next);
        }
        let read = self.first.iter().map(|&first| first != NONE);
        self.estimate
            .iter()
            .copied()
            .zip(read)
            .enumerate()
            .filter_map(|(k, (estimate, read))| read.then_some((k, estimate)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Constant variance, readings usable from 0.01 to 0.9.
    struct Constant;

    impl Weighing for Constant {
        fn usable(&self, x: f64) -> bool {
            (0.01..=0.9).contains(&x)
        }
        fn variance(&self, _: usize, _: f64, _: f64) -> f64 {
            1e-4
        }
    }

    /// Constant variance, readings usable from 0.01 to 0.9 (`None`: clipped).
    fn mean(exposures: &[f64], readings: &[Option<f64>]) -> f64 {
        let mut run = Run::default();
        run.start(exposures, 1);
        for (j, reading) in readings.iter().enumerate() {
            run.frame(j, |_| match *reading {
                Some(v) => (v, false, (0.01..=0.9).contains(&v)),
                None => (1.0, true, false),
            });
        }
        run.references(|_, _| panic!("no frame in range"));
        let means: Vec<(usize, f64)> = run.means(&Constant).collect();
        assert_eq!(means.len(), 1);
        means[0].1
    }

    #[test]
    fn a_clipped_reading_never_counts() {
        // The short frame alone: the long one predicts 0.8 (usable) but reads clipped.
        let estimate = mean(&[2.0, 1.0], &[None, Some(0.4)]);
        assert!((estimate - 0.4).abs() < 1e-12, "{estimate}");
    }

    #[test]
    fn a_frame_predicted_below_the_range_does_not_count_whatever_it_reads() {
        // Noise lifts the short frame's reading to 0.3; the estimate predicts 0.005.
        let estimate = mean(&[1.0, 0.01], &[Some(0.5), Some(0.3)]);
        assert!((estimate - 0.5).abs() < 1e-12, "{estimate}");
    }

    #[test]
    fn a_black_reading_where_the_value_should_show_counts() {
        // The long frame (H = 2) reads 0 where the short one reads 0.2: with equal
        // variances the mean is (2·0 + 1·0.2) / (2² + 1²) = 0.04, and it predicts 0.08
        // for the long frame, still usable.
        let estimate = mean(&[2.0, 1.0], &[Some(0.0), Some(0.2)]);
        assert!((estimate - 0.04).abs() < 1e-12, "{estimate}");
    }

    #[test]
    fn values_no_frame_reads_in_range_are_told_with_their_shortest_clipped_frame() {
        let mut run = Run::default();
        run.start(&[4.0, 2.0, 1.0], 3);
        // Value 0: clipped in the two longest frames, black in the shortest; value 1:
        // black everywhere; value 2: in range in the shortest frame only.
        let readings = [[1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 0.5]];
        for (j, frame) in readings.iter().enumerate() {
            run.frame(j, |k| {
                let v = frame[k];
                (v, v > 0.9, (0.01..=0.9).contains(&v))
            });
        }
        let mut unread = Vec::new();
        run.references(|k, clipped| unread.push((k, clipped)));
        assert_eq!(unread, [(0, Some(1)), (1, None)]);
        let means: Vec<(usize, f64)> = run.means(&Constant).collect();
        assert_eq!(means, [(2, 0.5)]);
    }
}
