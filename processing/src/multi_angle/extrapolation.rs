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
//!
//! **Beyond the data** ([`luminance_bound`]): a microfacet lobe's radiance factor is
//! π·D(θh)·G·F(θd)/(4 cos θi cos θr) plus the diffuse. At one θh, D is the same in every
//! column, G ≤ 1 only falls toward grazing, and F rises from the measured θd to the
//! geometry's by at most [`FRESNEL_RISE`]; in plane cos θi·cos θr = cos²θh − sin²θd. So
//! the luminance the data support at (θh, θd) is at most
//! FRESNEL_RISE·max_c Y_c(θh)·(cos²θh − sin²θd_c) / (cos²θh − sin²θd), Y_c the measured
//! luminance of column c at θh (clamped to its points). A model value above it claims
//! more than any lobe of that form can make of what was measured: it is the model's
//! guess, not a reading, and is flagged so.

/// The most Fresnel's factor rises between two θd up to 52.5° (as −15°'s, the largest of
/// the standard geometries): Schlick's (F0 + (1 − F0)(1 − cos θd)⁵)/F0 ≤ 1.46 there for
/// any F0 ≥ 0.02 (dielectrics of n ≥ 1.33, metals higher still, and rising less).
pub const FRESNEL_RISE: f64 = 1.5;

/// cos θi·cos θr of an in-plane geometry by its θh and s = sin²θd, floored at 0.01
/// (80° from the normal on both sides).
fn foreshortening(theta_h: f64, s: f64) -> f64 {
    (theta_h.to_radians().cos().powi(2) - s).max(0.01)
}

/// The largest luminance Y the measured columns support at (θh, θd) for a lobe of the
/// microfacet form (see the module), `y_row` the row of camera RGB → Y; `None` when no
/// column knows all three channels there.
pub(super) fn luminance_bound(
    table: &Table,
    y_row: [f64; 3],
    theta_h: f64,
    theta_d: f64,
) -> Option<f64> {
    let target = foreshortening(theta_h, theta_d.to_radians().sin().powi(2));
    column_values(table, theta_h)
        .into_iter()
        .filter(|(_, v)| v.iter().all(|x| x.is_finite()))
        .map(|(s, v)| {
            let y: f64 = (0..3).map(|c| y_row[c] * v[c]).sum();
            y.max(0.0) * foreshortening(theta_h, s)
        })
        .reduce(f64::max)
        .map(|peak| FRESNEL_RISE * peak / target)
}

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
