//! Whether the specular lobe's chromaticity changes across θL: a model-free test of the
//! measured samples, which the colour-shift verdict of `--model auto` requires
//! (`super::choice`).
//!
//! Per θL (its points with every channel known): the lobe ([`super::fold_score::lobe`],
//! taken as one interval of θh from its first point to its last, so that no point is in
//! or out by its own noise), the diffuse colour D (per channel the median of the points
//! off the lobe), and per bin of [`BIN_DEG`] degrees of signed θh the **specular colour**
//! S = Σ_bin∩lobe (β − D), whose u′v′ is the lobe's chromaticity there (bins fainter than
//! [`BRIGHT_BIN`] of the θL's brightest are left out: their chromaticity is too noisy for
//! a linear propagation of its variance; so are bins whose specular is less than
//! [`SPECULAR_OVER_DIFFUSE`] times the diffuse beneath it, where D's own error moves S's
//! chromaticity towards the body colour: a real diffuse is not flat in θh, and paper,
//! felt, fabric and paint scatter their body colour more towards some geometries). A
//! lobe's colour may change along θh (a
//! film's highlight is one colour at its centre and another on its flanks) as well as
//! with θd; the bins compare like with like: the same θh at every θL. A specular of one
//! colour over any diffuse gives every bin of every θL the same u′v′ (what the lobe's
//! tails add to D lies along S), whatever its brightness or width.
//!
//! **Significance.** Each S carries the noise of its points: var S_c = Σ σ_c² +
//! n²·(π/2)·mean_off(σ_c²)/n_off (the median's variance), σ the samples' noise
//! uncertainty from extraction, or, for samples without it, a relative noise pooled per
//! channel from second differences along θh (1.4826·median|β_j − (β_j−1 + β_j+1)/2| /
//! (√1.5·|β_j|)), which a lobe's curvature can only enlarge. Through the Jacobian of u′v′
//! each chromaticity has a 2×2 covariance Σ; in each bin, with the weighted mean ū,
//! χ² = Σ_θL (uv − ū)ᵀ Σ⁻¹ (uv − ū) has 2(n − 1) degrees of freedom when the
//! chromaticity is one, and the bins' χ² and degrees of freedom add. The change is
//! significant at p < [`LEVEL`]: noise alone reports one in at most 1 % of scans.
//!
//! **Size.** In each bin, a straight line through its θL's chromaticities against θd
//! (each coordinate weighted by its inverse variance) gives the change across the scanned
//! θd; their mean weighted by the bins' specular R + G + B must be at least
//! [`MIN_UV_CHANGE`]: a change no observer would see is not reported, however significant
//! (without noise every bias is significant).
#![doc = include_str!("colour_change.md")]

use serde::{Deserialize, Serialize};

use super::fold_score::lobe;
use super::held_out::median;
use crate::color::CameraModel;
use crate::samples::{distinct_theta_l, Sample, THETA_L_TOLERANCE};

/// The false-alarm rate of the significance test: p below it is significant.
pub const LEVEL: f64 = 0.01;

/// The smallest change of the lobe's u′v′ across θL reported as a colour shift: about a
/// just-noticeable difference (docs/ARCHITECTURE.md, "Model choice").
pub const MIN_UV_CHANGE: f64 = 0.004;

/// The test's outcome.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LobeColourChange {
    /// θL with a lobe, and bins of θh compared across two θL or more.
    pub theta_l: usize,
    pub bins: usize,
    /// χ² of the chromaticities against their weighted mean (`None`: no noise, where
    /// every difference is significant), its degrees of freedom and p-value.
    pub chi2: Option<f64>,
    pub dof: usize,
    pub p_value: f64,
    /// The change of the lobe's u′v′ across the scanned θd: per bin the slope of a
    /// straight line through its θL's chromaticities times the θd range, averaged over
    /// the bins weighted by their specular R + G + B.
    pub size_uv: f64,
    /// p < [`LEVEL`] and size ≥ [`MIN_UV_CHANGE`].
    pub changes: bool,
}

/// P(X > x) for X ~ χ² with an even number `dof` of degrees of freedom:
/// e^(−x/2) Σ_{i < dof/2} (x/2)^i / i!.
pub fn chi2_even_survival(x: f64, dof: usize) -> f64 {
    if x.is_nan() || x <= 0.0 {
        return 1.0;
    }
    // In logarithms: the terms overflow where e^(−x/2) underflows.
    let half = x / 2.0;
    let logs: Vec<f64> = (0..(dof / 2).max(1))
        .scan(0.0, |log_term, i| {
            if i > 0 {
                *log_term += (half / i as f64).ln();
            }
            Some(*log_term)
        })
        .collect();
    let top = logs.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let sum: f64 = logs.iter().map(|l| (l - top).exp()).sum();
    (top + sum.ln() - half).exp().clamp(0.0, 1.0)
}

/// Width (degrees of θh) of the bins the lobe's chromaticity is compared in across θL.
pub const BIN_DEG: f64 = 2.0;

/// A bin is compared only when its specular R + G + B is at least this fraction of the
/// θL's brightest bin's.
pub const BRIGHT_BIN: f64 = 0.2;

/// A bin is compared only when its specular R + G + B is at least this many times the
/// diffuse's beneath it (n·(D_R + D_G + D_B), n its points). The diffuse beneath a lobe is
/// the median off it only as far as the diffuse is flat in θh; one that differs there by
/// a fraction r moves the bin's u′v′ by about r·(D/S)·|u′v′(D) − u′v′(S)| towards the
/// body colour. With S ≥ 4·D, a diffuse 10 % off under a lobe 0.04 from its body colour
/// in u′v′ moves it by 0.001, a quarter of [`MIN_UV_CHANGE`].
pub const SPECULAR_OVER_DIFFUSE: f64 = 4.0;

/// One θL's specular colour per bin of θh, and its variance per channel, from its points
/// (signed θh, β, noise σ), sorted by θh.
fn specular_bins(points: &[(f64, [f64; 3], [f64; 3])]) -> Vec<(i64, [f64; 3], [f64; 3])> {
    let rgb: Vec<[f64; 3]> = points.iter().map(|p| p.1).collect();
    // The lobe as one interval of θh, from its first point to its last: a point is not
    // in or out by its own noise (which would bias the colour of the lobe's edges).
    let marked = lobe(&rgb);
    let first = marked.iter().position(|&l| l);
    let last = marked.iter().rposition(|&l| l);
    let in_lobe: Vec<bool> = (0..points.len())
        .map(|i| first.zip(last).is_some_and(|(a, b)| a <= i && i <= b))
        .collect();
    let off: Vec<usize> = (0..points.len()).filter(|&i| !in_lobe[i]).collect();
    if off.is_empty() {
        return Vec::new();
    }
    let mut diffuse = [0.0; 3];
    let mut diffuse_var = [0.0; 3];
    for c in 0..3 {
        diffuse[c] = median(&off.iter().map(|&i| rgb[i][c]).collect::<Vec<_>>()).unwrap_or(0.0);
        let mean_var = off.iter().map(|&i| points[i].2[c].powi(2)).sum::<f64>() / off.len() as f64;
        diffuse_var[c] = std::f64::consts::FRAC_PI_2 * mean_var / off.len() as f64;
    }
    let mut bins: Vec<(i64, [f64; 3], [f64; 3], f64)> = Vec::new();
    for (p, _) in points.iter().zip(&in_lobe).filter(|(_, &l)| l) {
        let bin = (p.0 / BIN_DEG).floor() as i64;
        if bins.last().is_none_or(|b| b.0 != bin) {
            bins.push((bin, [0.0; 3], [0.0; 3], 0.0));
        }
        if let Some(b) = bins.last_mut() {
            for (c, d) in diffuse.iter().enumerate() {
                b.1[c] += p.1[c] - d;
                b.2[c] += p.2[c].powi(2);
            }
            b.3 += 1.0;
        }
    }
    // Bins fainter than BRIGHT_BIN of the brightest carry a chromaticity too noisy for
    // the linear propagation of its variance.
    let brightest = bins
        .iter()
        .map(|b| b.1.iter().sum::<f64>())
        .fold(0.0, f64::max);
    let diffuse_sum: f64 = diffuse.iter().sum();
    bins.into_iter()
        .filter(|b| {
            let specular: f64 = b.1.iter().sum();
            specular >= BRIGHT_BIN * brightest
                && specular >= SPECULAR_OVER_DIFFUSE * b.3 * diffuse_sum
        })
        .map(|(bin, s, var, n)| {
            (
                bin,
                s,
                std::array::from_fn(|c| var[c] + n * n * diffuse_var[c]),
            )
        })
        .collect()
}

/// Pooled relative noise per channel of a column sorted by θh, from second differences.
fn pooled_relative_noise(rgb: &[[f64; 3]]) -> [f64; 3] {
    std::array::from_fn(|c| {
        let ratios: Vec<f64> = rgb
            .windows(3)
            .filter(|w| w[1][c].abs() > 0.0)
            .map(|w| (w[1][c] - 0.5 * (w[0][c] + w[2][c])).abs() / w[1][c].abs())
            .collect();
        median(&ratios).map_or(0.0, |m| 1.4826 * m / 1.5f64.sqrt())
    })
}

/// The u′v′ of `s` and its covariance given the channel variances `var`.
fn chromaticity(
    s: [f64; 3],
    var: [f64; 3],
    camera: &CameraModel,
) -> Option<([f64; 2], [[f64; 2]; 2])> {
    let uv = camera.uv_prime(s)?;
    let mut jacobian = [[0.0; 3]; 2];
    for c in 0..3 {
        let step = 1e-6
            * s.iter()
                .map(|v| v.abs())
                .fold(0.0, f64::max)
                .max(f64::MIN_POSITIVE);
        let (mut up, mut down) = (s, s);
        up[c] += step;
        down[c] -= step;
        let (a, b) = (camera.uv_prime(up)?, camera.uv_prime(down)?);
        for k in 0..2 {
            jacobian[k][c] = (a[k] - b[k]) / (2.0 * step);
        }
    }
    let cov = std::array::from_fn(|i| {
        std::array::from_fn(|j| {
            (0..3)
                .map(|c| jacobian[i][c] * jacobian[j][c] * var[c])
                .sum()
        })
    });
    Some((uv, cov))
}

/// The inverse of a 2×2 matrix; `None` when singular.
fn inverse(m: [[f64; 2]; 2]) -> Option<[[f64; 2]; 2]> {
    let det = m[0][0] * m[1][1] - m[0][1] * m[1][0];
    (det.is_finite() && det > 0.0).then(|| {
        [
            [m[1][1] / det, -m[0][1] / det],
            [-m[1][0] / det, m[0][0] / det],
        ]
    })
}

/// A point of a θL: signed θh, θd (degrees), β and its noise σ when extraction gave it.
type ColumnPoint = (f64, f64, [f64; 3], Option<[f64; 3]>);

/// One bin's chromaticity at one θL: θd (degrees), u′v′ and its covariance, and the
/// bin's specular R + G + B.
type Binned = (f64, [f64; 2], [[f64; 2]; 2], f64);

/// The change of u′v′ across θd in one bin: the slope of a weighted straight line (each
/// coordinate weighted by its inverse variance) times the bin's θd range.
fn change_across(colours: &[Binned]) -> f64 {
    let (lo, hi) = colours
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), c| {
            (lo.min(c.0), hi.max(c.0))
        });
    let slope = |k: usize| {
        let w: Vec<f64> = colours
            .iter()
            .map(|c| {
                if c.2[k][k] > 0.0 {
                    1.0 / c.2[k][k]
                } else {
                    1.0
                }
            })
            .collect();
        let total: f64 = w.iter().sum();
        let x = colours.iter().zip(&w).map(|(c, w)| w * c.0).sum::<f64>() / total;
        let y = colours.iter().zip(&w).map(|(c, w)| w * c.1[k]).sum::<f64>() / total;
        let sxy: f64 = colours
            .iter()
            .zip(&w)
            .map(|(c, w)| w * (c.0 - x) * (c.1[k] - y))
            .sum();
        let sxx: f64 = colours
            .iter()
            .zip(&w)
            .map(|(c, w)| w * (c.0 - x).powi(2))
            .sum();
        if sxx > 0.0 {
            sxy / sxx
        } else {
            0.0
        }
    };
    (hi - lo) * slope(0).hypot(slope(1))
}

/// The test of `samples` (see the module); `None` with no bin of θh whose lobe has a
/// chromaticity at two θL.
pub fn lobe_colour_change(samples: &[Sample], camera: &CameraModel) -> Option<LobeColourChange> {
    let mut bins: std::collections::BTreeMap<i64, Vec<Binned>> = Default::default();
    let mut with_lobe = 0;
    for t in distinct_theta_l(samples) {
        let mut column: Vec<ColumnPoint> = samples
            .iter()
            .filter(|s| (s.theta_l - t).abs() <= THETA_L_TOLERANCE && !s.dropped.contains(&true))
            .map(|s| {
                let (h, d) = s.half_difference();
                (
                    h.to_degrees(),
                    d.to_degrees(),
                    s.rgb,
                    s.uncertainty.map(|u| u.noise),
                )
            })
            .collect();
        if column.is_empty() {
            continue;
        }
        column.sort_by(|a, b| a.0.total_cmp(&b.0));
        let theta_d = column.iter().map(|p| p.1).sum::<f64>() / column.len() as f64;
        let rgb: Vec<[f64; 3]> = column.iter().map(|p| p.2).collect();
        let relative = pooled_relative_noise(&rgb);
        let points: Vec<(f64, [f64; 3], [f64; 3])> = column
            .iter()
            .map(|&(h, _, v, u)| {
                (
                    h,
                    v,
                    u.unwrap_or(std::array::from_fn(|c| relative[c] * v[c].abs())),
                )
            })
            .collect();
        let binned = specular_bins(&points);
        with_lobe += usize::from(!binned.is_empty());
        for (bin, s, var) in binned {
            if let Some((uv, cov)) = chromaticity(s, var, camera) {
                bins.entry(bin)
                    .or_default()
                    .push((theta_d, uv, cov, s.iter().sum()));
            }
        }
    }
    let compared: Vec<&Vec<Binned>> = bins.values().filter(|b| b.len() >= 2).collect();
    if compared.is_empty() {
        return None;
    }
    let mut chi2 = Some(0.0);
    let mut dof = 0;
    let (mut change, mut weight) = (0.0, 0.0);
    for bin in &compared {
        let colours: Vec<([f64; 2], [[f64; 2]; 2])> = bin.iter().map(|b| (b.1, b.2)).collect();
        chi2 = chi2.zip(chi2_about_mean(&colours)).map(|(a, b)| a + b);
        dof += 2 * (bin.len() - 1);
        let w: f64 = bin.iter().map(|b| b.3.max(0.0)).sum();
        change += w * change_across(bin);
        weight += w;
    }
    let p_value = chi2.map_or(0.0, |x| chi2_even_survival(x, dof));
    let size_uv = if weight > 0.0 { change / weight } else { 0.0 };
    Some(LobeColourChange {
        theta_l: with_lobe,
        bins: compared.len(),
        chi2,
        dof,
        p_value,
        size_uv,
        changes: p_value < LEVEL && size_uv >= MIN_UV_CHANGE,
    })
}

/// χ² of the chromaticities `colours` (with their covariances) about their weighted
/// mean; `None` when a covariance is singular (no noise).
fn chi2_about_mean(colours: &[([f64; 2], [[f64; 2]; 2])]) -> Option<f64> {
    let weights: Vec<[[f64; 2]; 2]> = colours
        .iter()
        .map(|(_, cov)| inverse(*cov))
        .collect::<Option<_>>()?;
    let mut total = [[0.0; 2]; 2];
    let mut weighted = [0.0; 2];
    for ((uv, _), w) in colours.iter().zip(&weights) {
        for i in 0..2 {
            for j in 0..2 {
                total[i][j] += w[i][j];
                weighted[i] += w[i][j] * uv[j];
            }
        }
    }
    let inv = inverse(total)?;
    let mean: [f64; 2] = std::array::from_fn(|i| inv[i][0] * weighted[0] + inv[i][1] * weighted[1]);
    Some(
        colours
            .iter()
            .zip(&weights)
            .map(|((uv, _), w)| {
                let d = [uv[0] - mean[0], uv[1] - mean[1]];
                (0..2)
                    .map(|i| (0..2).map(|j| d[i] * w[i][j] * d[j]).sum::<f64>())
                    .sum::<f64>()
            })
            .sum(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_even_chi2_survival_is_the_poisson_sum() {
        // dof 2: e^(−x/2).
        assert!((chi2_even_survival(4.0, 2) - (-2.0f64).exp()).abs() < 1e-15);
        // dof 10 at its 1 % point, 23.209.
        assert!((chi2_even_survival(23.209, 10) - 0.01).abs() < 1e-4);
        assert_eq!(chi2_even_survival(0.0, 4), 1.0);
        // Far in the tail: 0, not NaN.
        assert_eq!(chi2_even_survival(1e12, 240), 0.0);
    }
}
