//! The specular lobe over a fit's points at once: each point's tan²α and angular factor
//! g held as columns, s = g·exp(−tan²α/m²)/m² for every point, and the eq. 10 loss of a
//! model with one roughness and a constant specular colour (what Nelder–Mead evaluates
//! for Cook–Torrance and Ward). The loops are written for the compiler to vectorise: an
//! exp of their own (below) instead of libm's call, no branches, the loss summed
//! in eight interleaved partial sums; on a processor with AVX2 and FMA the same code is
//! compiled for them and chosen at run time (the same values: no operation is fused
//! that the portable code does not fuse). s is [`Basis::specular`]'s to within two
//! ulps (the exp), the loss the point-by-point sum's to within rounding.

use crate::brdf::{inverse_square, Basis, EXP_UNDERFLOW};
#[cfg(target_arch = "x86_64")]
use crate::simd::avx2_fma;

/// Points per block of the loss: their norms are computed side by side, then added.
const BLOCK: usize = 64;
/// Partial sums of the loss: point p adds to sum p mod [`LANES`], so that the additions
/// run side by side too (a fixed order: the same loss on every machine).
const LANES: usize = 8;

/// tan²α and g of each point of a fit.
#[derive(Debug, Clone, Default)]
pub(crate) struct LobeColumns {
    tan2_alpha: Vec<f64>,
    gain: Vec<f64>,
}

/// A model with one roughness and a constant specular colour: per channel Kd, Ks and
/// the diffuse basis and measured values of its points.
pub(crate) struct PlainModel<'a> {
    pub kd: [f64; 3],
    pub ks: [f64; 3],
    pub m: f64,
    pub diffuse: &'a [f64],
    pub y: &'a [[f64; 3]],
    /// Per point and channel 1 (measured) or 0 (dropped), if any value was dropped.
    pub keep: Option<&'a [[f64; 3]]>,
}

impl LobeColumns {
    pub(crate) fn of(bases: &[Basis]) -> Self {
        let (tan2_alpha, gain) = bases.iter().map(Basis::lobe_terms).unzip();
        LobeColumns { tan2_alpha, gain }
    }

    /// s(m) at every point into `out` (as long as the columns).
    pub(crate) fn specular(&self, m: f64, out: &mut [f64]) {
        #[cfg(target_arch = "x86_64")]
        if avx2_fma() {
            // SAFETY: the processor has AVX2 and FMA, checked just above.
            return unsafe { specular_avx2(self, m, out) };
        }
        specular_portable(self, m, out);
    }

    /// s(m) and its derivative with respect to ln m, ∂s/∂ln m = 2·s·(tan²α/m² − 1), at
    /// every point into `s` and `slope` (as long as the columns; 0 both where s is 0):
    /// [`Basis::specular_and_slope`] over the columns.
    pub(crate) fn specular_and_slope(&self, m: f64, s: &mut [f64], slope: &mut [f64]) {
        #[cfg(target_arch = "x86_64")]
        if avx2_fma() {
            // SAFETY: the processor has AVX2 and FMA, checked just above.
            return unsafe { specular_and_slope_avx2(self, m, s, slope) };
        }
        specular_and_slope_portable(self, m, s, slope);
    }

    /// Eq. 10 loss Σ_p ‖y_p − β_p‖ of `model`, dropped values left out.
    pub(crate) fn plain_loss(&self, model: &PlainModel) -> f64 {
        #[cfg(target_arch = "x86_64")]
        if avx2_fma() {
            // SAFETY: the processor has AVX2 and FMA, checked just above.
            return unsafe { plain_loss_avx2(self, model) };
        }
        plain_loss_portable(self, model)
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn specular_avx2(columns: &LobeColumns, m: f64, out: &mut [f64]) {
    specular_portable(columns, m, out);
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn plain_loss_avx2(columns: &LobeColumns, model: &PlainModel) -> f64 {
    plain_loss_portable(columns, model)
}

#[inline(always)]
fn specular_portable(columns: &LobeColumns, m: f64, out: &mut [f64]) {
    let inv_m2 = inverse_square(m);
    let n = out.len().min(columns.gain.len());
    let (t, g, out) = (&columns.tan2_alpha[..n], &columns.gain[..n], &mut out[..n]);
    for p in 0..n {
        out[p] = lobe(t[p], g[p], inv_m2);
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn specular_and_slope_avx2(columns: &LobeColumns, m: f64, s: &mut [f64], slope: &mut [f64]) {
    specular_and_slope_portable(columns, m, s, slope);
}

#[inline(always)]
fn specular_and_slope_portable(columns: &LobeColumns, m: f64, s: &mut [f64], slope: &mut [f64]) {
    let inv_m2 = inverse_square(m);
    let n = s.len().min(slope.len()).min(columns.gain.len());
    let (t, g) = (&columns.tan2_alpha[..n], &columns.gain[..n]);
    let (s, slope) = (&mut s[..n], &mut slope[..n]);
    for p in 0..n {
        let v = lobe(t[p], g[p], inv_m2);
        s[p] = v;
        // 0 where s is 0: tan²α may be unbounded there (at grazing).
        slope[p] = if v == 0.0 {
            0.0
        } else {
            2.0 * v * (t[p] * inv_m2 - 1.0)
        };
    }
}

#[inline(always)]
fn plain_loss_portable(columns: &LobeColumns, model: &PlainModel) -> f64 {
    let inv_m2 = inverse_square(model.m);
    let n = columns
        .gain
        .len()
        .min(model.y.len())
        .min(model.diffuse.len());
    let (t, g) = (&columns.tan2_alpha[..n], &columns.gain[..n]);
    let (a, y) = (&model.diffuse[..n], &model.y[..n]);
    let (kd, ks) = (model.kd, model.ks);
    let mut norms = [0.0; BLOCK];
    let mut sums = [0.0; LANES];
    let mut start = 0;
    while start < n {
        let len = BLOCK.min(n - start);
        let range = start..start + len;
        let (t, g, a, y) = (
            &t[range.clone()],
            &g[range.clone()],
            &a[range.clone()],
            &y[range.clone()],
        );
        let norms = &mut norms[..len];
        match model.keep {
            Some(keep) => {
                let keep = &keep[range];
                for p in 0..len {
                    let s = lobe(t[p], g[p], inv_m2);
                    let d: [f64; 3] =
                        std::array::from_fn(|c| y[p][c] - (kd[c] * a[p] + ks[c] * s) * keep[p][c]);
                    norms[p] = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
                }
            }
            None => {
                for p in 0..len {
                    let s = lobe(t[p], g[p], inv_m2);
                    let d: [f64; 3] = std::array::from_fn(|c| y[p][c] - (kd[c] * a[p] + ks[c] * s));
                    norms[p] = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
                }
            }
        }
        add_interleaved(&mut sums, norms);
        start += len;
    }
    total(sums)
}

/// Adds `values` to `sums`, value i to sum i mod [`LANES`] (`values` starting at a
/// multiple of [`LANES`]).
#[inline(always)]
fn add_interleaved(sums: &mut [f64; LANES], values: &[f64]) {
    let mut chunks = values.chunks_exact(LANES);
    for chunk in &mut chunks {
        for (sum, v) in sums.iter_mut().zip(chunk) {
            *sum += v;
        }
    }
    for (sum, v) in sums.iter_mut().zip(chunks.remainder()) {
        *sum += v;
    }
}

/// The sum of the partial sums, pairwise.
#[inline(always)]
fn total(s: [f64; LANES]) -> f64 {
    ((s[0] + s[4]) + (s[2] + s[6])) + ((s[1] + s[5]) + (s[3] + s[7]))
}

/// s = g·exp(−x)/m² with x = tan²α/m², 0 where g is 0 (at or past grazing) or exp(−x)
/// would leave the normal range, as [`Basis::specular`] has it.
#[inline(always)]
fn lobe(tan2_alpha: f64, gain: f64, inv_m2: f64) -> f64 {
    let x = tan2_alpha * inv_m2;
    let on = gain != 0.0 && x <= EXP_UNDERFLOW;
    let e = exp_neg(if x <= EXP_UNDERFLOW { x } else { EXP_UNDERFLOW });
    if on {
        gain * e * inv_m2
    } else {
        0.0
    }
}

/// exp(−x) for 0 ≤ x ≤ [`EXP_UNDERFLOW`], without branches or calls: x = k·ln 2 − r
/// (k rounded to the nearest integer, ln 2 in two parts so that r is exact to the last
/// bits, |r| ≤ ln 2 / 2), exp(−x) = 2^−k·exp(r), exp(r) by its Taylor series to r¹³
/// (the rest below 10⁻¹⁷ of it) in fused multiply-adds (correctly rounded, so the same
/// on every processor; a call where it has no FMA), 2^−k built in the exponent's bits.
/// Within an ulp or two of libm's.
#[inline(always)]
fn exp_neg(x: f64) -> f64 {
    // ln 2 with its mantissa's last 21 bits zero (k·LN2_HI is exact for |k| < 2¹¹), and
    // the rest of it.
    const LN2_HI: f64 = f64::from_bits(0x3FE6_2E42_FEE0_0000);
    const LN2_LO: f64 = f64::from_bits(0x3DEA_39EF_3579_3C76);
    // 1.5·2⁵²: adding it rounds a value below 2⁵¹ in magnitude to an integer, which its
    // low bits then hold.
    const ROUND: f64 = 6_755_399_441_055_744.0;
    let shifted = -x * std::f64::consts::LOG2_E + ROUND;
    let k = shifted - ROUND;
    let r = (-x - k * LN2_HI) - k * LN2_LO;
    let mut p: f64 = 1.0 / 6_227_020_800.0;
    for factorial in [
        479_001_600.0,
        39_916_800.0,
        3_628_800.0,
        362_880.0,
        40_320.0,
        5_040.0,
        720.0,
        120.0,
        24.0,
        6.0,
        2.0,
        1.0,
        1.0,
    ] {
        p = p.mul_add(r, 1.0 / factorial);
    }
    let k_bits = shifted.to_bits().wrapping_sub(ROUND.to_bits()) as i64;
    let scale = f64::from_bits(((k_bits + 1023) as u64) << 52);
    p * scale
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::brdf::Model;

    /// Distance in ulps between two finite f64 of one sign.
    fn ulps(a: f64, b: f64) -> u64 {
        (a.to_bits() as i64 - b.to_bits() as i64).unsigned_abs()
    }

    #[test]
    fn exp_agrees_with_libm_over_its_range() {
        let mut worst = 0;
        for i in 0..=200_000 {
            let x = EXP_UNDERFLOW * f64::from(i) / 200_000.0;
            worst = worst.max(ulps(exp_neg(x), (-x).exp()));
        }
        for x in [
            0.0,
            1e-300,
            1e-12,
            0.5 * std::f64::consts::LN_2,
            707.9,
            EXP_UNDERFLOW,
        ] {
            worst = worst.max(ulps(exp_neg(x), (-x).exp()));
        }
        assert!(worst <= 2, "{worst} ulps");
    }

    #[test]
    fn columns_give_the_basis_values_and_the_loss() {
        let bases: Vec<Basis> = (0..1000)
            .map(|i| {
                let theta_r = -89.9 + 179.8 * f64::from(i) / 999.0;
                Model::CookTorrance.basis(30.0, theta_r)
            })
            .chain([Model::Ward.basis(89.99, 89.99), Model::Ward.basis(0.0, 0.0)])
            .collect();
        let columns = LobeColumns::of(&bases);
        let mut out = vec![0.0; bases.len()];
        let (mut both, mut slope) = (out.clone(), out.clone());
        for m in [1e-7, 0.01, 0.2, 1.0, 3.0, f64::NAN] {
            columns.specular(m, &mut out);
            columns.specular_and_slope(m, &mut both, &mut slope);
            for ((s, b), (s2, slope)) in out.iter().zip(&bases).zip(both.iter().zip(&slope)) {
                let expected = b.specular(m);
                assert!(
                    ulps(*s, expected) <= 2 || (*s - expected).abs() < 1e-300,
                    "m {m}: {s} vs {expected}"
                );
                assert_eq!(s, s2, "m {m}");
                let (_, expected) = b.specular_and_slope(m);
                assert!(
                    (slope - expected).abs() <= 1e-14 * expected.abs()
                        || (slope - expected).abs() < 1e-300,
                    "m {m}: slope {slope} vs {expected}"
                );
            }
        }
        let diffuse: Vec<f64> = bases.iter().map(|b| b.diffuse).collect();
        let y: Vec<[f64; 3]> = (0..bases.len())
            .map(|i| [1.0, 2.0, 0.5].map(|v| v * (1.0 + (i % 7) as f64)))
            .collect();
        let keep: Vec<[f64; 3]> = (0..bases.len())
            .map(|i| [1.0, if i % 5 == 0 { 0.0 } else { 1.0 }, 1.0])
            .collect();
        for keep in [None, Some(keep.as_slice())] {
            let model = PlainModel {
                kd: [3.0, 4.0, 5.0],
                ks: [0.5, 0.7, 0.9],
                m: 0.15,
                diffuse: &diffuse,
                y: &y,
                keep,
            };
            let expected: f64 = (0..bases.len())
                .map(|p| {
                    let s = bases[p].specular(model.m);
                    let d: [f64; 3] = std::array::from_fn(|c| {
                        let k = keep.map_or(1.0, |k| k[p][c]);
                        y[p][c] - (model.kd[c] * diffuse[p] + model.ks[c] * s) * k
                    });
                    (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt()
                })
                .sum();
            let loss = columns.plain_loss(&model);
            assert!(
                (loss - expected).abs() <= 1e-12 * expected,
                "{loss} vs {expected}"
            );
        }
    }
}
