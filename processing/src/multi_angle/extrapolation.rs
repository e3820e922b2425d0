//! How far the model's colour can be trusted beyond the data: the colour change the
//! measured columns show, carried to the geometry.
//!
//! A geometry outside the measured (θh, θd) range takes its β from the fitted model.
//! The model carries the lobe's luminance to another θd through its geometry (D, G,
//! the cosines, its Fresnel term), which the fit checks over the measured columns; its
//! colour there is another matter: a film's phase or a Bragg band's centre moves the
//! lobe's colour with θd in ways no camera-RGB model follows, and a per-channel Fresnel
//! term fitted to a few degrees of drift extrapolates that drift at will. The data
//! tell how much the colour moves: at the geometry's θh, each column's share of
//! R + G + B per channel (θh clamped to the column's points). What moves a colour with
//! θd (Snell inside a film or a flake's layers, Fresnel) goes with s = sin²θd, so each
//! share is regressed on s (a straight line, least squares) and its trend carried from
//! the nearest column to the geometry's s*: Δshare_c = slope_c·(s* − s_near). The
//! model's value gets, per channel, the line β_c·clamp(Δshare_c/share_c, −1, 1): a
//! channel's relative change of share over that distance, at most the whole channel.
//! A material whose colour holds still over the measured columns (gold, a paint) keeps
//! a small term however far the geometry lies; one whose colour drifts (a film, flakes)
//! gets one that grows with the distance, to the whole value when the data's drift
//! carried that far would move a channel's share by its size. A geometry inside the
//! measured θd range (s* between the columns', only θh beyond) gets at most the drift
//! to its nearest column.

use crate::fit::table::Table;

/// The measured β at signed θh `theta_h` in each column (θh clamped to the column's
/// points), by the column's sin²θd; NaN where the column does not know a channel.
fn column_values(table: &Table, theta_h: f64) -> Vec<(f64, [f64; 3])> {
    table
        .columns()
        .iter()
        .filter(|column| !column.points.is_empty())
        .map(|column| {
            let (lo, hi) = (
                column.points[0][0],
                column.points[column.points.len() - 1][0],
            );
            let measured = table.predict(theta_h.clamp(lo, hi), column.theta_d, None);
            (column.theta_d.to_radians().sin().powi(2), measured)
        })
        .collect()
}

/// The model's colour beyond the data at (θh, θd) as one signed change of β per
/// channel (see the module): β_c·clamp(Δshare_c/share_c, −1, 1), Δshare_c the measured
/// columns' trend of channel c's share of R + G + B (a straight line in sin²θd) carried
/// from the nearest column to the geometry. `None` when a channel is known in no column
/// or the nearest column has no signal.
pub(super) fn drift_lines(
    table: &Table,
    model_beta: [f64; 3],
    theta_h: f64,
    theta_d: f64,
) -> Option<[f64; 3]> {
    let target = theta_d.to_radians().sin().powi(2);
    let shares: Vec<(f64, [f64; 3])> = column_values(table, theta_h)
        .into_iter()
        .filter_map(|(s, v)| {
            let sum = v[0] + v[1] + v[2];
            (sum.is_finite() && sum > 0.0).then(|| (s, v.map(|x| x / sum)))
        })
        .collect();
    let (s_near, near) = *shares
        .iter()
        .min_by(|a, b| (a.0 - target).abs().total_cmp(&(b.0 - target).abs()))?;
    let mut out = [0.0; 3];
    for (c, value) in out.iter_mut().enumerate() {
        let points: Vec<(f64, f64)> = shares.iter().map(|(s, v)| (*s, v[c])).collect();
        let change = slope(&points) * (target - s_near);
        let relative = if near[c] > 0.0 {
            (change / near[c]).clamp(-1.0, 1.0)
        } else {
            0.0
        };
        *value = model_beta[c] * relative;
    }
    out.iter().all(|v| v.is_finite()).then_some(out)
}

/// The least-squares slope of y on x; 0 with fewer than two distinct x.
fn slope(points: &[(f64, f64)]) -> f64 {
    let n = points.len() as f64;
    let (mx, my) = points
        .iter()
        .fold((0.0, 0.0), |(a, b), (x, y)| (a + x / n, b + y / n));
    let (sxx, sxy) = points.iter().fold((0.0, 0.0), |(a, b), (x, y)| {
        (a + (x - mx) * (x - mx), b + (x - mx) * (y - my))
    });
    if sxx > 1e-12 {
        sxy / sxx
    } else {
        0.0
    }
}
