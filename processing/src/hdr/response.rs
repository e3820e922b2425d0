//! Debevec–Malik response recovery (Debevec & Malik 1997, §2.1) for noisy, clipped
//! brackets quantised to 256 levels, one channel at a time, and the noise of its readings
//! that the merge weighs them by. See docs/ARCHITECTURE.md, "HDR merge".
//!
//! 1. Samples: pixel locations with a level strictly between 0 and 255 in at least two
//!    frames (only those constrain g), chosen evenly both in rank and in value of the sum
//!    of their levels over the bracket (which grows with radiance), so the dark and bright
//!    ends of every frame's range are covered as well as the bulk.
//! 2. Least squares for g(z) = ln(exposure at level z) and ln E of each sample: rows
//!    w(z)(g(z) − ln E_i) = w(z) ln H_j with Debevec–Malik's hat w (0 at levels 0 and
//!    255), smoothness rows λ·s̄·w(z)/128·g″(z) = 0 (s̄ the root-mean data weight per
//!    level, so λ does not depend on the number of samples), and g(128) = 0 exactly. The
//!    ln E_i are eliminated exactly (Schur complement), leaving a 256 × 256 Cholesky solve.
//! 3. g is made non-decreasing (pool-adjacent-violators).
//! 4. Noise: the noise is added before the response, so the variance of g(z) − ln H is
//!    σ²(z) = a·e^(−g(z)) + b·e^(−2g(z)) + g′(z)²/12 (shot noise, read noise,
//!    quantisation), and that of the exposure x = e^g read at level z is
//!    a·x + b + x²·g′(z)²/12. a, b ≥ 0 are fitted to the differences between a sample's
//!    estimates in two frames adjacent in exposure (their variance is σ²(z₁) + σ²(z₂),
//!    whatever E is). With too few such pairs, a = b = 0: quantisation alone.

use nalgebra::{DMatrix, DVector};

use super::weighting::Weighing;

/// Levels of the response table.
pub(super) const LEVELS: usize = 256;
/// The level fixed at g = 0.
const MID: usize = LEVELS / 2;
/// Top level: clipped.
const TOP: usize = LEVELS - 1;
/// Least number of sample pairs for the noise fit.
const MIN_PAIRS: usize = 32;

/// A quantised bracket as recovery reads it.
pub(super) struct Observations<'a, L: Fn(usize, usize) -> usize> {
    /// Level of frame j at value index i (3 · pixel + channel).
    pub level: &'a L,
    pub frames: usize,
    pub pixels: usize,
    /// ln of each frame's exposure (shutter × ISO/100).
    pub ln_h: &'a [f64],
}

/// A recovered response and the noise of its readings.
#[derive(Debug, Clone)]
pub(super) struct Curve {
    /// g(z): ln of the exposure that gives level z, with g(128) = 0; non-decreasing.
    pub g: [f64; LEVELS],
    /// The exposure a reading at level z stands for in the merge: e^g(z), and 0 at level
    /// 0 (black: whatever is below level 1).
    pub exposure: [f64; LEVELS],
    /// Shot noise: variance a·x of a reading of noiseless exposure x.
    shot: f64,
    /// Read noise: variance b of every reading.
    read: f64,
    /// Quantisation: g′(z)²/12, the variance of ln x that level z's width adds.
    quantisation: [f64; LEVELS],
    /// The quantisation of the level an exposure in range reads as, by [`bin`] from
    /// that of exposure[1] (`first_bin`): one lookup instead of a search through
    /// `exposure`. Its last entry, level 255's, stands for every bin above: a lookup
    /// clamped to the table has no branch, and the merge's loop stays in vector registers.
    quantisation_of_bin: Vec<f64>,
    first_bin: u64,
}

/// Mantissa bits in [`bin`]: 2⁸ bins per octave, 0.3 % of exposure each.
const BIN_BITS: u32 = 8;

/// The bin of a positive exposure: its float's exponent and top mantissa bits, which grow
/// with it (about 2^`BIN_BITS` × log₂ x).
fn bin(x: f64) -> u64 {
    x.to_bits() >> (f64::MANTISSA_DIGITS - 1 - BIN_BITS)
}

impl Curve {
    fn new(g: [f64; LEVELS], [shot, read]: [f64; 2]) -> Self {
        // g′(z) by central differences, floored so a flat stretch still quantises.
        let slope: [f64; LEVELS] = std::array::from_fn(|z| {
            let (a, b) = (z.saturating_sub(1), (z + 1).min(TOP));
            ((g[b] - g[a]) / (b - a) as f64).max(1e-6)
        });
        let exposure: [f64; LEVELS] =
            std::array::from_fn(|z| if z == 0 { 0.0 } else { g[z].exp() });
        // Each bin gets the level of its lowest exposure in range (at most 2¹⁹ bins, the
        // span of every positive float).
        let (first_bin, last_bin) = (bin(exposure[1]), bin(exposure[TOP - 1]));
        let quantisation = slope.map(|s| s * s / 12.0);
        let quantisation_of_bin = (first_bin..=last_bin)
            .map(|b| {
                let lowest = f64::from_bits(b << (f64::MANTISSA_DIGITS - 1 - BIN_BITS));
                let z = exposure.partition_point(|&v| v < lowest.max(exposure[1]));
                quantisation[z.min(TOP)]
            })
            .chain([quantisation[TOP]])
            .collect();
        Self {
            g,
            exposure,
            shot,
            read,
            quantisation,
            quantisation_of_bin,
            first_bin,
        }
    }
}

/// Readings usable between levels 1 and 254; their variance a·x + b + x²·g′(z)²/12 for
/// noiseless exposure x, z the level x reads as (to within a level), g′(z)²/12 looked up.
impl Weighing for Curve {
    #[inline(always)]
    fn usable(&self, x: f64) -> bool {
        (x > 0.0) & (x >= self.exposure[1]) & (x <= self.exposure[TOP - 1])
    }

    #[inline(always)]
    fn variance(&self, _: usize, x: f64, quantisation: f64) -> f64 {
        self.shot * x + self.read + x * x * quantisation
    }

    /// The quantisation of each exposure x = estimate × h by its [`bin`]: below
    /// exposure[1] the first bin's, above the table level 255's.
    #[inline(always)]
    fn look_up(&self, _: usize, h: f64, estimate: &[f64], quantisation: &mut [f64]) {
        let table = self.quantisation_of_bin.as_slice();
        // Never empty (it ends with level 255's): checked here, the loop needs no bounds
        // check.
        let Some(last) = table.len().checked_sub(1) else {
            return;
        };
        for (quantisation, &estimate) in quantisation.iter_mut().zip(estimate) {
            let i = bin(estimate * h).saturating_sub(self.first_bin);
            *quantisation = table[i.min(last as u64) as usize];
        }
    }
}

/// Debevec–Malik hat of level z: z for the lower half, 255 − z for the upper (0 at the ends).
fn hat(z: usize) -> f64 {
    z.min(TOP - z) as f64
}

fn usable(z: usize) -> bool {
    z > 0 && z < TOP
}

/// Recovers channel `c`'s response from about `wanted` samples with smoothness `lambda`.
/// `None` when the least-squares system is degenerate; the linear response g(z) = ln(z/128)
/// when no pixel is usable in two frames. Without enough pairs for the noise fit, only
/// quantisation is left as noise.
pub(super) fn recover<L: Fn(usize, usize) -> usize>(
    obs: &Observations<L>,
    c: usize,
    wanted: usize,
    lambda: f64,
) -> Option<Curve> {
    let samples = choose_samples(obs, c, wanted);
    if samples.is_empty() {
        let g = std::array::from_fn(|z| (z.max(1) as f64 / MID as f64).ln());
        return Some(Curve::new(g, [0.0, 0.0]));
    }
    let levels: Vec<Vec<usize>> = samples
        .iter()
        .map(|&p| (0..obs.frames).map(|j| (obs.level)(j, 3 * p + c)).collect())
        .collect();
    let g = monotone(solve(&levels, obs.ln_h, lambda)?, &levels);
    let noise = noise_coefficients(&levels, obs.ln_h, &g).unwrap_or([0.0, 0.0]);
    Some(Curve::new(g, noise))
}

/// Pixels usable in at least two frames, chosen evenly in rank and in the value of the
/// sum of their levels (at most about 2 × `wanted`).
fn choose_samples<L: Fn(usize, usize) -> usize>(
    obs: &Observations<L>,
    c: usize,
    wanted: usize,
) -> Vec<usize> {
    // A regular grid of about 16 × wanted candidates.
    let stride = (obs.pixels / (16 * wanted.max(1))).max(1);
    let mut candidates: Vec<(usize, usize)> = (0..obs.pixels)
        .step_by(stride)
        .filter_map(|p| {
            let mut sum = 0;
            let mut usable_frames = 0;
            for j in 0..obs.frames {
                let z = (obs.level)(j, 3 * p + c);
                sum += z;
                usable_frames += usize::from(usable(z));
            }
            (usable_frames >= 2).then_some((sum, p))
        })
        .collect();
    if candidates.len() <= 2 * wanted {
        return candidates.into_iter().map(|(_, p)| p).collect();
    }
    candidates.sort_unstable();
    let n = candidates.len();
    let (lo, hi) = (candidates[0].0 as f64, candidates[n - 1].0 as f64);
    let mut chosen: Vec<usize> = (0..wanted)
        .flat_map(|k| {
            let by_rank = k * n / wanted;
            let target = lo + (hi - lo) * (k as f64 + 0.5) / wanted as f64;
            let by_value = candidates
                .partition_point(|&(sum, _)| (sum as f64) < target)
                .min(n - 1);
            [by_rank, by_value]
        })
        .collect();
    chosen.sort_unstable();
    chosen.dedup();
    chosen.into_iter().map(|i| candidates[i].1).collect()
}

/// Weighted least squares for g with the sample radiances eliminated; `None` if singular.
fn solve(levels: &[Vec<usize>], ln_h: &[f64], lambda: f64) -> Option<[f64; LEVELS]> {
    let mut normal = DMatrix::<f64>::zeros(LEVELS, LEVELS);
    let mut rhs = DVector::<f64>::zeros(LEVELS);
    let mut entries: Vec<(usize, f64, f64)> = Vec::with_capacity(ln_h.len());
    for sample in levels {
        // Row ω(z)(g(z) − ln E) = ω(z) ln H per frame; entries (z, ω², ln H).
        entries.clear();
        entries.extend(
            sample
                .iter()
                .zip(ln_h)
                .map(|(&z, &ln)| (z, hat(z) * hat(z), ln))
                .filter(|&(_, w2, _)| w2 > 0.0),
        );
        let total: f64 = entries.iter().map(|e| e.1).sum();
        if total <= 0.0 {
            continue;
        }
        let weighted_ln: f64 = entries.iter().map(|e| e.1 * e.2).sum();
        for &(z, w2, ln) in &entries {
            normal[(z, z)] += w2;
            rhs[z] += w2 * ln - w2 * weighted_ln / total;
            for &(z2, w2b, _) in &entries {
                normal[(z, z2)] -= w2 * w2b / total;
            }
        }
    }
    // Smoothness scaled to the data: λ times the mean data weight per level.
    let data_weight = (0..LEVELS).map(|z| normal[(z, z)]).sum::<f64>() / LEVELS as f64;
    let scale = lambda * data_weight.max(f64::MIN_POSITIVE).sqrt() / MID as f64;
    for z in 1..TOP {
        let k = scale * hat(z);
        let row = [(z - 1, k), (z, -2.0 * k), (z + 1, k)];
        for &(a, ka) in &row {
            for &(b, kb) in &row {
                normal[(a, b)] += ka * kb;
            }
        }
    }
    // g(128) = 0 exactly.
    for k in 0..LEVELS {
        normal[(MID, k)] = 0.0;
        normal[(k, MID)] = 0.0;
    }
    normal[(MID, MID)] = 1.0;
    rhs[MID] = 0.0;
    // A tiny ridge keeps levels that neither data nor smoothness reach determined.
    let ridge = 1e-12 * normal.diagonal().max();
    for k in 0..LEVELS {
        normal[(k, k)] += ridge;
    }
    let x = normal.cholesky()?.solve(&rhs);
    let g: [f64; LEVELS] = std::array::from_fn(|z| x[z]);
    g.iter().all(|v| v.is_finite()).then_some(g)
}

/// g made non-decreasing by pool-adjacent-violators, each level weighted by how often it
/// was observed (plus one), then shifted back to g(128) = 0.
fn monotone(g: [f64; LEVELS], levels: &[Vec<usize>]) -> [f64; LEVELS] {
    let mut count = [1.0; LEVELS];
    for &z in levels.iter().flatten() {
        count[z] += 1.0;
    }
    // Blocks of (mean, weight, length).
    let mut blocks: Vec<(f64, f64, usize)> = Vec::with_capacity(LEVELS);
    for z in 0..LEVELS {
        blocks.push((g[z], count[z], 1));
        while blocks.len() > 1 && blocks[blocks.len() - 2].0 > blocks[blocks.len() - 1].0 {
            let (m2, w2, n2) = blocks.pop().expect("two blocks");
            let last = blocks.last_mut().expect("two blocks");
            let w = last.1 + w2;
            *last = ((last.0 * last.1 + m2 * w2) / w, w, last.2 + n2);
        }
    }
    let mut out = [0.0; LEVELS];
    let mut z = 0;
    for (mean, _, length) in blocks {
        out[z..z + length].fill(mean);
        z += length;
    }
    let shift = out[MID];
    out.map(|v| v - shift)
}

/// The shot and read noise coefficients a, b of σ²(z) (see the module comment), or `None`
/// without enough pairs.
fn noise_coefficients(levels: &[Vec<usize>], ln_h: &[f64], g: &[f64; LEVELS]) -> Option<[f64; 2]> {
    let quantisation = Curve::new(*g, [0.0, 0.0]).quantisation;
    let shot: [f64; LEVELS] = g.map(|v| (-v).exp());
    // Equations d² ≈ a·(u₁ + u₂) + b·(u₁² + u₂²) + q₁ + q₂ for pairs of frames adjacent in
    // exposure where both levels are usable.
    let mut order: Vec<usize> = (0..ln_h.len()).collect();
    order.sort_by(|&a, &b| ln_h[a].total_cmp(&ln_h[b]));
    let mut pairs: Vec<([f64; 2], f64, f64)> = Vec::new();
    for sample in levels {
        let mut previous: Option<usize> = None;
        for &j in &order {
            let z = sample[j];
            if !usable(z) {
                continue;
            }
            if let Some(k) = previous {
                let zk = sample[k];
                let d = (g[z] - ln_h[j]) - (g[zk] - ln_h[k]);
                let (u1, u2) = (shot[z], shot[zk]);
                pairs.push((
                    [u1 + u2, u1 * u1 + u2 * u2],
                    d * d,
                    quantisation[z] + quantisation[zk],
                ));
            }
            previous = Some(j);
        }
    }
    if pairs.len() < MIN_PAIRS {
        return None;
    }
    // Non-negative least squares in two unknowns, reweighted by the predicted variance of
    // d² (∝ its square) so that every pair counts by its relative error.
    let mut coef = [0.0, 0.0];
    let mut weights: Vec<f64> = pairs
        .iter()
        .map(|p| 1.0 / (p.1 + p.2).powi(2).max(1e-300))
        .collect();
    for _ in 0..4 {
        coef = nnls2(&pairs, &weights);
        for (w, p) in weights.iter_mut().zip(&pairs) {
            let predicted = coef[0] * p.0[0] + coef[1] * p.0[1] + p.2;
            *w = 1.0 / predicted.powi(2).max(1e-300);
        }
    }
    coef.iter().all(|v| v.is_finite()).then_some(coef)
}

/// argmin over a, b ≥ 0 of Σ w (a·x₀ + b·x₁ + q − y)².
fn nnls2(pairs: &[([f64; 2], f64, f64)], weights: &[f64]) -> [f64; 2] {
    let mut m = [[0.0; 2]; 2];
    let mut v = [0.0; 2];
    for ((x, y, q), &w) in pairs.iter().zip(weights) {
        let r = y - q;
        for a in 0..2 {
            v[a] += w * x[a] * r;
            for b in 0..2 {
                m[a][b] += w * x[a] * x[b];
            }
        }
    }
    let single = |a: usize| {
        if m[a][a] > 0.0 {
            (v[a] / m[a][a]).max(0.0)
        } else {
            0.0
        }
    };
    let det = m[0][0] * m[1][1] - m[0][1] * m[1][0];
    if det > 0.0 {
        let a = (v[0] * m[1][1] - v[1] * m[0][1]) / det;
        let b = (m[0][0] * v[1] - m[1][0] * v[0]) / det;
        if a >= 0.0 && b >= 0.0 {
            return [a, b];
        }
    }
    // The minimum lies on a bound: the better of the two one-unknown fits.
    let candidates = [[single(0), 0.0], [0.0, single(1)]];
    let cost = |c: &[f64; 2]| -> f64 {
        pairs
            .iter()
            .zip(weights)
            .map(|((x, y, q), w)| w * (c[0] * x[0] + c[1] * x[1] + q - y).powi(2))
            .sum()
    };
    if cost(&candidates[0]) <= cost(&candidates[1]) {
        candidates[0]
    } else {
        candidates[1]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn monotone_pools_violations_and_keeps_g128_at_zero() {
        let mut g: [f64; LEVELS] = std::array::from_fn(|z| (z as f64 - 128.0) / 50.0);
        g[10] = g[14] + 0.5;
        g[200] = g[195] - 0.3;
        let out = monotone(g, &[]);
        assert!(out.windows(2).all(|w| w[0] <= w[1]));
        assert_eq!(out[MID], 0.0);
        // Levels away from the violations are untouched.
        for z in (20..190).chain(210..LEVELS) {
            assert!((out[z] - g[z]).abs() < 1e-12, "level {z}");
        }
    }

    /// Without a noise fit (a = b = 0) and with flat stretches in g, every exposure in
    /// range still has a finite, positive variance, and 0 is never in range.
    #[test]
    fn variance_is_positive_wherever_a_reading_is_usable() {
        let mut g: [f64; LEVELS] = std::array::from_fn(|z| (z.max(1) as f64 / 128.0).ln());
        let flat = g[50];
        g[40..60].fill(flat);
        let curve = Curve::new(g, [0.0, 0.0]);
        assert!(!curve.usable(0.0));
        for z in 1..TOP {
            for x in [curve.exposure[z], curve.exposure[z] * 1.001] {
                if curve.usable(x) {
                    let mut quantisation = 0.0;
                    curve.look_up(0, 1.0, &[x], std::slice::from_mut(&mut quantisation));
                    let v = curve.variance(0, x, quantisation);
                    assert!(v.is_finite() && v > 0.0, "level {z}: {v}");
                }
            }
        }
    }

    /// A linear 8-bit camera (level = 128·x) with shot and read noise: the variance of
    /// ln x at level z is s·e^(−g) + r²·e^(−2g) plus quantisation, with g = ln(z/128).
    #[test]
    fn noise_model_recovers_shot_and_read_noise() {
        let (shot, read) = (2e-3, 4e-3);
        let g: [f64; LEVELS] = std::array::from_fn(|z| (z.max(1) as f64 / 128.0).ln());
        let ln_h: Vec<f64> = (0..5).map(|k| (2f64.powi(k - 4)).ln()).collect();
        let mut state = 0x9e37_79b9_7f4a_7c15_u64;
        let mut uniform = move || {
            state ^= state >> 12;
            state ^= state << 25;
            state ^= state >> 27;
            ((state.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 11) as f64 + 0.5) / (1u64 << 53) as f64
        };
        let levels: Vec<Vec<usize>> = (0..2000)
            .map(|_| {
                let e = 0.02 * 100f64.powf(uniform());
                ln_h.iter()
                    .map(|ln| {
                        let x = e * ln.exp();
                        let sigma = (shot * x + read * read).sqrt();
                        let normal = (-2.0 * uniform().ln()).sqrt()
                            * (std::f64::consts::TAU * uniform()).cos();
                        ((x + sigma * normal) * 128.0).round().clamp(0.0, 255.0) as usize
                    })
                    .collect()
            })
            .collect();
        let [a, b] = noise_coefficients(&levels, &ln_h, &g).expect("enough pairs");
        let quantisation = Curve::new(g, [0.0, 0.0]).quantisation;
        for z in [20, 60, 128, 220] {
            let u = (-g[z]).exp();
            let sigma2 = a * u + b * u * u + quantisation[z];
            let x = (z as f64 / 128.0).max(1e-9);
            let slope = 1.0 / z as f64;
            let truth = shot / x + read * read / (x * x) + slope * slope / 12.0;
            let ratio = sigma2 / truth;
            assert!(
                (0.8..1.25).contains(&ratio),
                "level {z}: {sigma2} vs {truth}"
            );
        }
    }
}
