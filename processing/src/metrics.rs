//! Error metrics of the paper: fit loss (eq. 10), relative error ΔErr_p (eq. 11),
//! u′v′ chromaticity (eq. 12) and the chromaticity difference ΔE_u′v′ (eq. 13).
//! Measured and estimated values are paired by index; β in the camera-RGB domain.

/// Why a metric could not be computed.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum MetricsError {
    #[error("{measured} measured values but {estimated} estimated ones")]
    LengthMismatch { measured: usize, estimated: usize },
    #[error("channel {channel} has no signal (sum of measured β ≤ 0): ΔErr_p is undefined")]
    NoSignal { channel: char },
    #[error("no point has a defined chromaticity: ΔE_u′v′ is undefined")]
    NoChromaticity,
}

fn check_lengths<T>(measured: &[T], estimated: &[T]) -> Result<(), MetricsError> {
    if measured.len() == estimated.len() {
        Ok(())
    } else {
        Err(MetricsError::LengthMismatch {
            measured: measured.len(),
            estimated: estimated.len(),
        })
    }
}

/// Euclidean distance between two RGB triples: one point's term of eq. 10.
#[inline]
pub fn point_loss(measured: &[f64; 3], estimated: &[f64; 3]) -> f64 {
    let d = [
        measured[0] - estimated[0],
        measured[1] - estimated[1],
        measured[2] - estimated[2],
    ];
    (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt()
}

/// Eq. 10: Σ_p sqrt(Σ_c (β_c,mea − β_c,est)²), the sum (not the mean) of per-point distances.
pub fn loss(measured: &[[f64; 3]], estimated: &[[f64; 3]]) -> Result<f64, MetricsError> {
    check_lengths(measured, estimated)?;
    Ok(measured
        .iter()
        .zip(estimated)
        .map(|(m, e)| point_loss(m, e))
        .sum())
}

/// Eq. 11 per channel (R, G, B): Σ_p |β_mea − β_est| / Σ_p β_mea.
pub fn err_p(measured: &[[f64; 3]], estimated: &[[f64; 3]]) -> Result<[f64; 3], MetricsError> {
    check_lengths(measured, estimated)?;
    let mut result = [0.0; 3];
    for (c, (out, name)) in result.iter_mut().zip(['R', 'G', 'B']).enumerate() {
        let (abs_err, sum) = measured
            .iter()
            .zip(estimated)
            .fold((0.0, 0.0), |(e, s), (m, est)| {
                (e + (m[c] - est[c]).abs(), s + m[c])
            });
        if sum.is_nan() || sum <= 0.0 {
            return Err(MetricsError::NoSignal { channel: name });
        }
        *out = abs_err / sum;
    }
    Ok(result)
}

/// Eq. 12: CIE 1976 (u′, v′) of tristimulus values XYZ; `None` where X + 15Y + 3Z ≤ 0
/// (black or non-physical), where the chromaticity is undefined.
pub fn uv_prime(xyz: [f64; 3]) -> Option<[f64; 2]> {
    let [x, y, z] = xyz;
    let denominator = x + 15.0 * y + 3.0 * z;
    (denominator > 0.0 && denominator.is_finite())
        .then(|| [4.0 * x / denominator, 9.0 * y / denominator])
}

/// Eq. 13 for one point: |u′mea − u′est|/u′mea + |v′mea − v′est|/v′mea; `None` where a
/// chromaticity is undefined or u′mea or v′mea is not positive.
pub fn delta_e_uv_point(measured_xyz: [f64; 3], estimated_xyz: [f64; 3]) -> Option<f64> {
    let [um, vm] = uv_prime(measured_xyz)?;
    let [ue, ve] = uv_prime(estimated_xyz)?;
    (um > 0.0 && vm > 0.0).then(|| (um - ue).abs() / um + (vm - ve).abs() / vm)
}

/// Eq. 13 reported as the mean over points of [`delta_e_uv_point`], from XYZ values.
/// Points whose chromaticity is undefined are left out of the mean.
pub fn delta_e_uv(
    measured_xyz: &[[f64; 3]],
    estimated_xyz: &[[f64; 3]],
) -> Result<f64, MetricsError> {
    check_lengths(measured_xyz, estimated_xyz)?;
    let (sum, count) = measured_xyz
        .iter()
        .zip(estimated_xyz)
        .filter_map(|(m, e)| delta_e_uv_point(*m, *e))
        .fold((0.0, 0usize), |(s, n), d| (s + d, n + 1));
    if count == 0 {
        return Err(MetricsError::NoChromaticity);
    }
    Ok(sum / count as f64)
}
