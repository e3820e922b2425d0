//! The sharp-lobe test: how β curves across a strip's rows, the rows' noise pooled over
//! neighbouring columns, and whether a column lies on a peak too sharp to average (then
//! its sample is the centre row alone). All quantities are relative to the centre value.

use super::layout::STRIP_ROWS;

/// How β curves across a strip's five rows, from a least-squares parabola
/// v(t) = a + b·t + k·t² over the rows t = −2…2: the five-row mean is a + 2k, so 2k/a is
/// the relative error of the mean against the value at the centre row's geometry. The
/// parabola's residual estimates the noise of one row: σ̂² = (P3·v)²/10 + (P4·v)²/70 over
/// its two degrees of freedom, with P3, P4 the cubic and quartic discrete orthogonal
/// polynomials.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Curvature {
    /// 2k/a: the five-row mean's relative excess over the centre value.
    mean_excess: f64,
    /// σ̂/a: one row's relative noise.
    row_noise: f64,
}

impl Curvature {
    /// `None` when the centre value is not positive.
    pub(super) fn of(v: &[f64; STRIP_ROWS]) -> Option<Self> {
        let dot = |w: [f64; STRIP_ROWS]| w.iter().zip(v).map(|(w, v)| w * v).sum::<f64>();
        let two_k = dot([2.0, -1.0, -2.0, -1.0, 2.0]) / 7.0;
        let a = dot([-3.0, 12.0, 17.0, 12.0, -3.0]) / 35.0;
        let p3 = dot([-1.0, 2.0, 0.0, -2.0, 1.0]);
        let p4 = dot([1.0, -4.0, 6.0, -4.0, 1.0]);
        let sigma = ((p3 * p3 / 10.0 + p4 * p4 / 70.0) / 2.0).sqrt();
        (a > 0.0 && a.is_finite()).then(|| Curvature {
            mean_excess: two_k / a,
            row_noise: sigma / a,
        })
    }
}

/// Below this relative error of the five-row mean, a column is averaged whatever the
/// noise: far below what a fit or a colour difference can see.
const SHARP_LIMIT: f64 = 1e-3;

/// Standard errors of 2k/a that noise alone rarely reaches (Gaussian: 6·10⁻⁵).
const SHARP_SIGMAS: f64 = 4.0;

/// Standard error of 2k/a per unit of one row's relative noise: var(2k) = 4σ²/14.
const CURVATURE_SE_PER_NOISE: f64 = 0.534_522_483_824_848_8;

/// The median of σ̂ (two degrees of freedom) over σ: √(χ²₂ median / 2) = √ln 2.
const MEDIAN_SIGMA_HAT: f64 = 0.832_554_611_157_697_8;

/// Columns each side whose noise estimates are pooled with a column's own.
pub(super) const NOISE_NEIGHBOURS: usize = 8;

/// Per column and channel, one row's relative noise pooled over the column and its
/// [`NOISE_NEIGHBOURS`] each side (the median of their own estimates, scaled to σ):
/// neighbours see about the same signal, so about the same relative noise. 0 where no
/// column can tell.
pub(super) fn pooled_row_noise(curvatures: &[[Option<Curvature>; 3]]) -> Vec<[f64; 3]> {
    let mut noise = Vec::with_capacity(2 * NOISE_NEIGHBOURS + 1);
    (0..curvatures.len())
        .map(|x| {
            let near = &curvatures[x.saturating_sub(NOISE_NEIGHBOURS)
                ..(x + NOISE_NEIGHBOURS + 1).min(curvatures.len())];
            std::array::from_fn(|c| {
                noise.clear();
                noise.extend(near.iter().filter_map(|k| k[c].map(|k| k.row_noise)));
                if noise.is_empty() {
                    return 0.0;
                }
                let mid = noise.len() / 2;
                let (_, median, _) = noise.select_nth_unstable_by(mid, f64::total_cmp);
                *median / MEDIAN_SIGMA_HAT
            })
        })
        .collect()
}

/// Whether a column's sample strip lies on a peak too sharp to average: in some
/// channel the five-row mean is off the centre value by more than [`SHARP_LIMIT`] and
/// by more than [`SHARP_SIGMAS`] standard errors of what the rows' noise could make of it.
pub(super) fn is_sharp(curvature: &[Option<Curvature>; 3], noise: &[f64; 3]) -> bool {
    (0..3).any(|c| {
        curvature[c].is_some_and(|k| {
            k.mean_excess.abs() > SHARP_LIMIT.max(SHARP_SIGMAS * CURVATURE_SE_PER_NOISE * noise[c])
        })
    })
}

#[cfg(test)]
mod tests {
    use std::f64::consts::PI;

    use super::*;

    #[test]
    fn a_parabola_through_the_rows_gives_its_mean_excess_and_no_noise() {
        let (a, b, k) = (50.0, 3.0, -0.7);
        let v = [-2.0, -1.0, 0.0, 1.0, 2.0].map(|t: f64| a + b * t + k * t * t);
        let curvature = Curvature::of(&v).unwrap();
        let mean = v.iter().sum::<f64>() / 5.0;
        assert!((curvature.mean_excess - (mean - a) / a).abs() < 1e-15);
        assert!(curvature.row_noise < 1e-15);
        assert_eq!(Curvature::of(&[0.0; 5]), None);
    }

    #[test]
    fn pooled_noise_recovers_the_rows_noise() {
        // Flat rows with Gaussian noise of relative σ = 1 % (Box–Muller over a fixed
        // sequence): the pooled estimate is within 15 % of it, and noise alone marks
        // few columns as sharp.
        let mut state = 0x9e37_79b9_7f4a_7c15_u64;
        let mut uniform = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let curvatures: Vec<[Option<Curvature>; 3]> = (0..4000)
            .map(|_| {
                let v: [f64; 5] = std::array::from_fn(|_| {
                    let (u1, u2) = (uniform().max(1e-300), uniform());
                    100.0 * (1.0 + 0.01 * (-2.0 * u1.ln()).sqrt() * (2.0 * PI * u2).cos())
                });
                [Curvature::of(&v); 3]
            })
            .collect();
        let noise = pooled_row_noise(&curvatures);
        let mean = noise.iter().map(|n| n[0]).sum::<f64>() / noise.len() as f64;
        assert!((mean / 0.01 - 1.0).abs() < 0.15, "{mean}");
        let sharp = curvatures
            .iter()
            .zip(&noise)
            .filter(|(k, n)| is_sharp(k, n))
            .count();
        assert!(sharp * 100 < curvatures.len(), "{sharp}");
    }
}
