//! The paper's figures from a study report:
//! - `fig6_g_channel.svg`: reference G and both models along θr, each model fitted on the
//!   single θL nearest −25° (the paper's choice), one curve per θL line;
//! - `fig7_err_p_g.svg`: box plots of ΔErr_p (G) per number of θL and variant;
//! - `fig8_uv_chart.svg`: u′v′ of the reference and of each variant fitted on the single
//!   θL nearest −45° (the paper's choice);
//! - `fig9_delta_e_uv.svg`: box plots of ΔE_u′v′ per number of θL and variant;
//! - `fig10_uv_held_out.svg`: u′v′ of the reference at the θL a two-θL fit did not see
//!   (the pair nearest −20°, −30°) and of each variant's prediction there;
//! - `fig11_held_out_delta_e_uv.svg`, `fig12_held_out_err_p_r.svg`: box plots of ΔE_u′v′
//!   and of the R channel's ΔErr_p on the held-out points (the θL a fit did not see).

use std::path::{Path, PathBuf};

use super::boxplot::BoxStats;
use super::error::StudyError;
use super::figures::{box_plot_svg, xy_svg, BoxSeries, Mark, XyPlot, XySeries};
use super::report::{EvalPoint, GroupSummary, StudyReport};
use crate::fit::FitResult;
use crate::metrics;

/// Most points drawn per point series and per polyline (evenly thinned beyond), to keep
/// the SVGs small.
const MAX_MARKERS: usize = 1500;
const MAX_LINE_POINTS: usize = 600;

/// θL of the single-direction fit shown in Fig. 6 (paper: −25°).
const FIG6_THETA_L: f64 = -25.0;
/// θL of the single-direction fit shown in Fig. 8 (paper: −45°).
const FIG8_THETA_L: f64 = -45.0;
/// θL pair of the two-direction fit whose held-out predictions Fig. 10 shows.
const FIG10_THETA_L: [f64; 2] = [-20.0, -30.0];

/// Writes the four figures into `dir`, titles prefixed by `name` when it is not empty;
/// returns their paths.
pub fn write_figures(
    report: &StudyReport,
    dir: &Path,
    name: &str,
) -> Result<Vec<PathBuf>, StudyError> {
    let titled = |title: String| {
        if name.is_empty() {
            title
        } else {
            format!("{name}: {title}")
        }
    };
    let summary = report.summary();
    let fig6 = dir.join("fig6_g_channel.svg");
    let mut plot = g_channel_plot(report);
    plot.title = titled(plot.title);
    xy_svg(&fig6, &plot)?;
    let fig7 = dir.join("fig7_err_p_g.svg");
    box_plot_svg(
        &fig7,
        &titled("ΔErr_p of the G channel against the reference".into()),
        "ΔErr_p (G)",
        &box_series(report, &summary, |g| g.err_p[1].clone()),
    )?;
    let fig8 = dir.join("fig8_uv_chart.svg");
    let mut plot = uv_plot(report);
    plot.title = titled(plot.title);
    xy_svg(&fig8, &plot)?;
    let fig9 = dir.join("fig9_delta_e_uv.svg");
    box_plot_svg(
        &fig9,
        &titled("ΔE_u′v′ against the reference".into()),
        "mean ΔE_u′v′",
        &box_series(report, &summary, |g| g.delta_e_uv.clone()),
    )?;
    let fig10 = dir.join("fig10_uv_held_out.svg");
    let mut plot = held_out_uv_plot(report);
    plot.title = titled(plot.title);
    xy_svg(&fig10, &plot)?;
    let fig11 = dir.join("fig11_held_out_delta_e_uv.svg");
    box_plot_svg(
        &fig11,
        &titled("ΔE_u′v′ at the θL the fit did not see".into()),
        "mean ΔE_u′v′, held out",
        &box_series(report, &summary, |g| g.held_out_delta_e_uv.clone()),
    )?;
    let fig12 = dir.join("fig12_held_out_err_p_r.svg");
    box_plot_svg(
        &fig12,
        &titled("ΔErr_p of the R channel at the θL the fit did not see".into()),
        "ΔErr_p (R), held out",
        &box_series(report, &summary, |g| g.held_out_err_p[0].clone()),
    )?;
    Ok(vec![fig6, fig7, fig8, fig9, fig10, fig11, fig12])
}

fn box_series(
    report: &StudyReport,
    summary: &[GroupSummary],
    stats: impl Fn(&GroupSummary) -> Option<BoxStats>,
) -> Vec<BoxSeries> {
    report
        .options
        .variants
        .iter()
        .map(|v| BoxSeries {
            name: v.label(),
            groups: summary
                .iter()
                .filter(|g| g.variant == *v)
                .filter_map(|g| stats(g).map(|b| (g.size, b)))
                .collect(),
        })
        .collect()
}

/// Evaluation points of each θL line, sorted by θr.
fn lines(report: &StudyReport) -> Vec<Vec<EvalPoint>> {
    report
        .theta_l
        .iter()
        .map(|&t| {
            let mut line: Vec<EvalPoint> = report
                .points
                .iter()
                .filter(|p| p.theta_l == t)
                .copied()
                .collect();
            line.sort_by(|a, b| a.theta_r.total_cmp(&b.theta_r));
            line
        })
        .collect()
}

/// Each variant's successful fit on the single θL nearest `theta_l`, named by the
/// variant, and that θL (`None` when no such fit succeeded).
fn single_theta_l_fits(
    report: &StudyReport,
    theta_l: f64,
) -> (Option<f64>, Vec<(String, &FitResult)>) {
    let mut fitted_on = None;
    let mut fits = Vec::new();
    for &v in &report.options.variants {
        let Some(result) = report.single(v, theta_l) else {
            continue;
        };
        if let Ok(scores) = &result.outcome {
            fitted_on = Some(result.theta_l[0]);
            fits.push((v.label(), &scores.fit));
        }
    }
    (fitted_on, fits)
}

fn g_channel_plot(report: &StudyReport) -> XyPlot {
    let lines = lines(report);
    let mut series = vec![XySeries {
        name: "reference".into(),
        mark: Mark::Points,
        segments: vec![thin(
            report.points.iter().map(|p| (p.theta_r, p.reference[1])),
            MAX_MARKERS,
        )],
    }];
    let (fitted_on, fits) = single_theta_l_fits(report, FIG6_THETA_L);
    for (name, fit) in fits {
        series.push(XySeries {
            name,
            mark: Mark::Lines,
            segments: lines
                .iter()
                .map(|line| {
                    thin(
                        line.iter()
                            .map(|p| (p.theta_r, fit.predict(p.theta_i, p.theta_r)[1])),
                        MAX_LINE_POINTS,
                    )
                })
                .collect(),
        });
    }
    XyPlot {
        title: match fitted_on {
            Some(t) => format!("G channel: reference and models fitted on θL = {t}°"),
            None => "G channel: reference (no single-θL fit succeeded)".into(),
        },
        x_label: "θr (degrees)".into(),
        y_label: "β_G".into(),
        log_x: false,
        log_y: false,
        series,
    }
}

fn uv_plot(report: &StudyReport) -> XyPlot {
    let uv = |xyz: [f64; 3]| metrics::uv_prime(xyz).map(|[u, v]| (u, v));
    let mut series = vec![XySeries {
        name: "reference".into(),
        mark: Mark::Points,
        segments: vec![thin(
            report.points.iter().filter_map(|p| uv(p.reference_xyz)),
            MAX_MARKERS,
        )],
    }];
    let (fitted_on, fits) = single_theta_l_fits(report, FIG8_THETA_L);
    for (name, fit) in fits {
        series.push(XySeries {
            name,
            mark: Mark::Points,
            segments: vec![thin(
                report
                    .points
                    .iter()
                    .filter_map(|p| uv(report.camera.xyz(fit.predict(p.theta_i, p.theta_r)))),
                MAX_MARKERS,
            )],
        });
    }
    XyPlot {
        title: match fitted_on {
            Some(t) => format!("CIE 1976 u′v′: reference and models fitted on θL = {t}°"),
            None => "CIE 1976 u′v′: reference (no single-θL fit succeeded)".into(),
        },
        x_label: "u′".into(),
        y_label: "v′".into(),
        log_x: false,
        log_y: false,
        series,
    }
}

/// The θL of the report nearest each of `wanted`, if they are distinct.
fn nearest_theta_l(report: &StudyReport, wanted: &[f64]) -> Option<Vec<f64>> {
    let mut chosen: Vec<f64> = wanted
        .iter()
        .filter_map(|&w| {
            report
                .theta_l
                .iter()
                .copied()
                .min_by(|a, b| (a - w).abs().total_cmp(&(b - w).abs()))
        })
        .collect();
    chosen.dedup();
    (chosen.len() == wanted.len()).then_some(chosen)
}

fn held_out_uv_plot(report: &StudyReport) -> XyPlot {
    let uv = |xyz: [f64; 3]| metrics::uv_prime(xyz).map(|[u, v]| (u, v));
    let pair = nearest_theta_l(report, &FIG10_THETA_L);
    let held_out: Vec<&EvalPoint> = report
        .points
        .iter()
        .filter(|p| pair.as_ref().is_some_and(|t| !t.contains(&p.theta_l)))
        .collect();
    let mut series = vec![XySeries {
        name: "reference".into(),
        mark: Mark::Points,
        segments: vec![thin(
            held_out.iter().filter_map(|p| uv(p.reference_xyz)),
            MAX_MARKERS,
        )],
    }];
    for &v in &report.options.variants {
        let fitted = report.results.iter().find(|r| {
            r.variant == v
                && pair.as_ref().is_some_and(|t| {
                    r.theta_l.len() == 2 && r.theta_l.iter().all(|x| t.contains(x))
                })
        });
        let Some(Ok(scores)) = fitted.map(|r| &r.outcome) else {
            continue;
        };
        series.push(XySeries {
            name: v.label(),
            mark: Mark::Points,
            segments: vec![thin(
                held_out.iter().filter_map(|p| {
                    uv(report.camera.xyz(scores.fit.predict(p.theta_i, p.theta_r)))
                }),
                MAX_MARKERS,
            )],
        });
    }
    XyPlot {
        title: match &pair {
            Some(t) => format!(
                "CIE 1976 u′v′ at the θL not fitted: models fitted on θL = {}°, {}°",
                t[0], t[1]
            ),
            None => "CIE 1976 u′v′: fewer than two θL, no held-out prediction".into(),
        },
        x_label: "u′".into(),
        y_label: "v′".into(),
        log_x: false,
        log_y: false,
        series,
    }
}

/// Every k-th item, k chosen so that at most `max` remain (first and last kept).
fn thin(items: impl Iterator<Item = (f64, f64)>, max: usize) -> Vec<(f64, f64)> {
    let all: Vec<(f64, f64)> = items.collect();
    if all.len() <= max {
        return all;
    }
    let step = all.len().div_ceil(max.max(2) - 1);
    let mut out: Vec<(f64, f64)> = all.iter().step_by(step).copied().collect();
    if let (Some(last), Some(kept)) = (all.last(), out.last()) {
        if last != kept {
            out.push(*last);
        }
    }
    out
}
