//! Whether the specular lobe's chromaticity changes across θL: a model-free test of the
//! measured samples, which the colour-shift verdict of `--model auto` requires
//! ([`super::choice`]).
//!
//! Per θL (its points with every channel known): the lobe ([`super::fold_score::lobe`]),
//! the diffuse colour D (per channel the median of the points off the lobe) and the
//! **specular colour** S = Σ_lobe (β − D), whose u′v′ is the lobe's chromaticity. A
//! specular of one colour over any diffuse gives every θL the same u′v′ (what the lobe's
//! tails add to D lies along S), whatever its brightness or width.
//!
//! **Significance.** Each S carries the noise of its points: var S_c = Σ_lobe σ_c² +
//! n_lobe²·(π/2)·mean_off(σ_c²)/n_off (the median's variance), σ the samples' noise
//! uncertainty from extraction, or, for samples without it, a relative noise pooled per
//! channel from second differences along θh (1.4826·median|β_j − (β_j−1 + β_j+1)/2| /
//! (√1.5·|β_j|)), which a lobe's curvature can only enlarge. Through the Jacobian of u′v′
//! each θL's chromaticity has a 2×2 covariance Σ_t; with the weighted mean ū,
//! χ² = Σ_t (uv_t − ū)ᵀ Σ_t⁻¹ (uv_t − ū) has 2(n − 1) degrees of freedom when the
//! chromaticity is one. The change is significant at p < [`LEVEL`]: noise alone reports
//! one in at most 1 % of scans.
//!
//! **Size.** The largest u′v′ distance between two θL's specular chromaticities must be
//! at least [`MIN_UV_CHANGE`]: a change no observer would see is not reported, however
//! significant (without noise every bias is significant).

use serde::{Deserialize, Serialize};

use super::fold_score::lobe;
use super::held_out::median;
use crate::color::CameraModel;
use crate::samples::{distinct_theta_l, Sample, THETA_L_TOLERANCE};

/// The false-alarm rate of the significance test: p below it is significant.
pub const LEVEL: f64 = 0.01;

/// The smallest change of the lobe's u′v′ across θL reported as a colour shift: about a
/// just-noticeable difference (docs/ARCHITECTURE.md, "Model choice").
pub const MIN_UV_CHANGE: f64 = 0.005;

/// The test's outcome.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LobeColourChange {
    /// θL whose lobe has a chromaticity.
    pub theta_l: usize,
    /// χ² of the chromaticities against their weighted mean (`None`: no noise, where
    /// every difference is significant), its degrees of freedom and p-value.
    pub chi2: Option<f64>,
    pub dof: usize,
    pub p_value: f64,
    /// The largest u′v′ distance between two θL's specular chromaticities.
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
    let half = x / 2.0;
    let (mut term, mut sum) = (1.0, 1.0);
    for i in 1..dof / 2 {
        term *= half / i as f64;
        sum += term;
    }
    (sum * (-half).exp()).clamp(0.0, 1.0)
}

/// One θL's specular colour and its variance per channel, from its points' β and noise σ.
fn specular(points: &[([f64; 3], [f64; 3])]) -> Option<([f64; 3], [f64; 3])> {
    let rgb: Vec<[f64; 3]> = points.iter().map(|p| p.0).collect();
    let in_lobe = lobe(&rgb);
    let n_lobe = in_lobe.iter().filter(|&&l| l).count();
    let off: Vec<usize> = (0..points.len()).filter(|&i| !in_lobe[i]).collect();
    if n_lobe == 0 || off.is_empty() {
        return None;
    }
    let mut s = [0.0; 3];
    let mut var = [0.0; 3];
    for c in 0..3 {
        let d = median(&off.iter().map(|&i| rgb[i][c]).collect::<Vec<_>>())?;
        let off_var = off.iter().map(|&i| points[i].1[c].powi(2)).sum::<f64>() / off.len() as f64;
        for (p, _) in points.iter().zip(&in_lobe).filter(|(_, &l)| l) {
            s[c] += p.0[c] - d;
            var[c] += p.1[c].powi(2);
        }
        var[c] += (n_lobe as f64).powi(2) * std::f64::consts::FRAC_PI_2 * off_var / off.len() as f64;
    }
    Some((s, var))
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
fn chromaticity(s: [f64; 3], var: [f64; 3], camera: &CameraModel) -> Option<([f64; 2], [[f64; 2]; 2])> {
    let uv = camera.uv_prime(s)?;
    let mut jacobian = [[0.0; 3]; 2];
    for c in 0..3 {
        let step = 1e-6 * s.iter().map(|v| v.abs()).fold(0.0, f64::max).max(f64::MIN_POSITIVE);
        let (mut up, mut down) = (s, s);
        up[c] += step;
        down[c] -= step;
        let (a, b) = (camera.uv_prime(up)?, camera.uv_prime(down)?);
        for k in 0..2 {
            jacobian[k][c] = (a[k] - b[k]) / (2.0 * step);
        }
    }
    let cov = std::array::from_fn(|i| {
        std::array::from_fn(|j| (0..3).map(|c| jacobian[i][c] * jacobian[j][c] * var[c]).sum())
    });
    Some((uv, cov))
}

/// The inverse of a 2×2 matrix; `None` when singular.
fn inverse(m: [[f64; 2]; 2]) -> Option<[[f64; 2]; 2]> {
    let det = m[0][0] * m[1][1] - m[0][1] * m[1][0];
    (det.is_finite() && det > 0.0).then(|| [[m[1][1] / det, -m[0][1] / det], [-m[1][0] / det, m[0][0] / det]])
}

/// The test of `samples` (see the module); `None` with fewer than two θL whose lobe has a
/// chromaticity and a noise.
pub fn lobe_colour_change(samples: &[Sample], camera: &CameraModel) -> Option<LobeColourChange> {
    let mut colours: Vec<([f64; 2], [[f64; 2]; 2])> = Vec::new();
    for t in distinct_theta_l(samples) {
        let mut column: Vec<(f64, [f64; 3], Option<[f64; 3]>)> = samples
            .iter()
            .filter(|s| (s.theta_l - t).abs() <= THETA_L_TOLERANCE && !s.dropped.contains(&true))
            .map(|s| (s.half_difference().0, s.rgb, s.uncertainty.map(|u| u.noise)))
            .collect();
        column.sort_by(|a, b| a.0.total_cmp(&b.0));
        let rgb: Vec<[f64; 3]> = column.iter().map(|p| p.1).collect();
        let relative = pooled_relative_noise(&rgb);
        let points: Vec<([f64; 3], [f64; 3])> = column
            .iter()
            .map(|&(_, v, u)| (v, u.unwrap_or(std::array::from_fn(|c| relative[c] * v[c].abs()))))
            .collect();
        let Some((s, var)) = specular(&points) else { continue };
        if let Some(colour) = chromaticity(s, var, camera) {
            colours.push(colour);
        }
    }
    if colours.len() < 2 {
        return None;
    }
    let dof = 2 * (colours.len() - 1);
    let chi2 = chi2_about_mean(&colours);
    let p_value = chi2.map_or(0.0, |x| chi2_even_survival(x, dof));
    let size_uv = colours
        .iter()
        .flat_map(|(a, _)| colours.iter().map(move |(b, _)| ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt()))
        .fold(0.0, f64::max);
    Some(LobeColourChange {
        theta_l: colours.len(),
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
    }
}
