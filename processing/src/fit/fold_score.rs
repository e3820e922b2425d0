//! Scoring a prediction at the θL a fit (or a table) did not see: every point of that θL
//! with the channels it has. A channel dropped by extraction (clipped, or too dark) is
//! missing at its point and left out of every sum, as the fits leave it out of their
//! loss; the point's other channels are scored. No point is skipped:
//! - the eq. 10 loss Σ_p √(Σ_c known (β − β̂)²) and its scale Σ_p √(Σ_c known β²) (the
//!   loss of predicting 0);
//! - ΔErr_p per channel (eq. 11) over the points where that channel is known (NaN for a
//!   channel with no signal there);
//! - the mean ΔE_u′v′ (eq. 13) over the points whose three channels are known (a
//!   chromaticity needs all three);
//! - the same over the θL's specular lobe ([`lobe`]).

use serde::{Deserialize, Serialize};

use super::FitError;
use crate::color::CameraModel;
use crate::metrics::{self, MetricsError};
use crate::samples::Sample;

/// A point of a θL is in its specular lobe when its excess over the θL's darkest point,
/// in R + G + B, is at least this fraction of the θL's largest excess.
pub const LOBE_FRACTION: f64 = 0.1;

/// Errors of predictions against measured (or reference) values on a set of points.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Errors {
    /// Number of points.
    pub points: usize,
    /// ΔErr_p (eq. 11) per channel (NaN, `null` in JSON, for a channel without signal).
    pub err_p: [f64; 3],
    /// Mean ΔE_u′v′ (eq. 13) over the points with a defined chromaticity; `None` if none.
    pub delta_e_uv: Option<f64>,
}

/// ΔErr_p per channel and mean ΔE_u′v′ of `estimated` (camera RGB) against `measured`
/// (camera RGB, and its XYZ `measured_xyz`), paired by index, every channel known.
pub fn errors(
    measured: &[[f64; 3]],
    measured_xyz: &[[f64; 3]],
    estimated: &[[f64; 3]],
    camera: &CameraModel,
) -> Result<Errors, MetricsError> {
    let err_p = metrics::err_p(measured, estimated)?;
    let estimated_xyz: Vec<[f64; 3]> = estimated.iter().map(|&rgb| camera.xyz(rgb)).collect();
    Ok(Errors {
        points: measured.len(),
        err_p,
        delta_e_uv: metrics::delta_e_uv(measured_xyz, &estimated_xyz).ok(),
    })
}

/// The measured values of a sample: `None` where a channel was dropped.
pub fn known_channels(s: &Sample) -> [Option<f64>; 3] {
    std::array::from_fn(|c| s.channel(c))
}

/// [`errors`] over measured values with missing channels (see the module).
fn masked_errors(
    measured: &[[Option<f64>; 3]],
    estimated: &[[f64; 3]],
    camera: &CameraModel,
) -> Errors {
    let err_p = std::array::from_fn(|c| {
        let (error, sum) = measured
            .iter()
            .zip(estimated)
            .filter_map(|(m, e)| Some((m[c]?, e[c])))
            .fold((0.0, 0.0), |(err, sum), (m, e)| {
                (err + (m - e).abs(), sum + m)
            });
        if sum > 0.0 && sum.is_finite() {
            error / sum
        } else {
            f64::NAN
        }
    });
    let (complete, complete_estimated): (Vec<[f64; 3]>, Vec<[f64; 3]>) = measured
        .iter()
        .zip(estimated)
        .filter_map(|(m, e)| Some(([m[0]?, m[1]?, m[2]?], *e)))
        .map(|(m, e)| (camera.xyz(m), camera.xyz(e)))
        .unzip();
    Errors {
        points: measured.len(),
        err_p,
        delta_e_uv: metrics::delta_e_uv(&complete, &complete_estimated).ok(),
    }
}

/// Which of `rgb` (one θL's measured values, every channel known) are in its specular
/// lobe ([`LOBE_FRACTION`]).
pub fn lobe(rgb: &[[f64; 3]]) -> Vec<bool> {
    let complete: Vec<[Option<f64>; 3]> = rgb.iter().map(|v| v.map(Some)).collect();
    masked_lobe(&complete)
}

/// [`lobe`] of values with missing channels: a point's R + G + B counts a missing
/// channel as the mean of its known ones (a clipped channel sits in a bright point), a
/// point with none known is not in the lobe.
pub fn masked_lobe(values: &[[Option<f64>; 3]]) -> Vec<bool> {
    let sum = |v: &[Option<f64>; 3]| -> Option<f64> {
        let known: Vec<f64> = v.iter().flatten().copied().collect();
        (!known.is_empty()).then(|| 3.0 * known.iter().sum::<f64>() / known.len() as f64)
    };
    let sums: Vec<Option<f64>> = values.iter().map(sum).collect();
    let floor = sums.iter().flatten().copied().fold(f64::INFINITY, f64::min);
    let peak = sums.iter().flatten().map(|s| s - floor).fold(0.0, f64::max);
    sums.iter()
        .map(|s| s.is_some_and(|s| peak > 0.0 && s - floor >= LOBE_FRACTION * peak))
        .collect()
}

/// The scores of one fit at the θL it left out.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Fold {
    /// The θL left out.
    pub theta_l: f64,
    /// Eq. 10 loss of the prediction at its points (their known channels).
    pub loss: f64,
    /// Σ_p ‖β_p‖ at its points (their known channels): the loss of predicting 0.
    pub scale: f64,
    /// Errors over all of its points and over its specular lobe.
    pub all: Errors,
    pub lobe: Option<Errors>,
    /// Whether the fit kept a colour shift (Cook–Torrance–Fresnel only).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub colour_shift: Option<bool>,
}

/// The fold of θL `theta_l`: `estimated` scored against the samples `held` (every sample
/// of that θL with a channel known), see the module.
pub fn score(
    theta_l: f64,
    held: &[Sample],
    estimated: &[[f64; 3]],
    camera: &CameraModel,
) -> Result<Fold, String> {
    let measured: Vec<[Option<f64>; 3]> = held.iter().map(known_channels).collect();
    let distance = |m: &[Option<f64>; 3], e: &[f64; 3]| -> f64 {
        (0..3)
            .filter_map(|c| Some((m[c]? - e[c]).powi(2)))
            .sum::<f64>()
            .sqrt()
    };
    let loss: f64 = measured
        .iter()
        .zip(estimated)
        .map(|(m, e)| distance(m, e))
        .sum();
    let scale: f64 = measured.iter().map(|m| distance(m, &[0.0; 3])).sum();
    if !loss.is_finite() {
        return Err(FitError::Overflow("held-out loss").to_string());
    }
    if scale <= 0.0 {
        return Err(format!("θL {theta_l} has no signal in its known channels"));
    }
    let all = masked_errors(&measured, estimated, camera);
    let in_lobe = masked_lobe(&measured);
    let (lobe_measured, lobe_estimated): (Vec<[Option<f64>; 3]>, Vec<[f64; 3]>) = measured
        .iter()
        .zip(estimated)
        .zip(&in_lobe)
        .filter(|(_, &l)| l)
        .map(|((m, e), _)| (*m, *e))
        .unzip();
    let lobe_errors = (!lobe_measured.is_empty())
        .then(|| masked_errors(&lobe_measured, &lobe_estimated, camera))
        .filter(|e| e.err_p.iter().any(|v| v.is_finite()));
    Ok(Fold {
        theta_l,
        loss,
        scale,
        all,
        lobe: lobe_errors,
        colour_shift: None,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_lobe_is_what_rises_a_tenth_of_the_peak_above_the_floor() {
        let rgb = [
            [1.0; 3],
            [1.2, 1.2, 1.2],
            [1.4, 1.4, 1.4],
            [11.0, 11.0, 11.0],
        ];
        // Excesses 0, 0.6, 1.2, 30 (R + G + B): the threshold is 3.
        assert_eq!(lobe(&rgb), [false, false, false, true]);
        // A flat θL has no lobe.
        assert_eq!(lobe(&[[2.0; 3]; 3]), [false; 3]);
        // A clipped blue at the peak: the point stays in the lobe.
        let clipped = [[Some(1.0); 3], [Some(11.0), Some(11.0), None], [None; 3]];
        assert_eq!(masked_lobe(&clipped), [false, true, false]);
    }

    #[test]
    fn a_missing_channel_is_left_out_and_its_point_scored() {
        let camera = CameraModel::builtin();
        let mut held = vec![
            Sample::in_plane(-20.0, 0.0, -20.0, [10.0, 10.0, 10.0]),
            Sample::in_plane(-20.0, 5.0, -25.0, [50.0, 60.0, 0.0]),
        ];
        held[1].dropped = [false, false, true];
        let estimated = [[10.0, 10.0, 10.0], [25.0, 60.0, 1e6]];
        let fold = score(-20.0, &held, &estimated, &camera).unwrap();
        // The second point's red counts; its missing blue does not.
        assert_eq!(fold.loss, 25.0);
        assert!((fold.scale - (300.0f64.sqrt() + 6100.0f64.sqrt())).abs() < 1e-9);
        assert_eq!(fold.all.err_p, [25.0 / 60.0, 0.0, 0.0]);
        // Its chromaticity is unknown: ΔE_u′v′ is the complete point's alone.
        assert_eq!(fold.all.delta_e_uv, Some(0.0));
        // The bright point is the lobe, scored on the channels it has.
        let lobe = fold.lobe.unwrap();
        assert_eq!(lobe.points, 1);
        assert!(lobe.err_p[2].is_nan() && lobe.delta_e_uv.is_none());
    }
}
