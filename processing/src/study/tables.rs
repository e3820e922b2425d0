//! CSV tables and the JSON summary of a study.
//!
//! - `combinations.csv`: one row per (variant, θL combination): the robust fit with its
//!   uncertainty, its scores on all points and on the held-out ones, and the Nelder–Mead
//!   loss; θL joined by `;`; empty cells where undefined.
//! - `boxplots.csv`: per variant, number of θL and metric (`err_p_r|g|b`,
//!   `delta_e_uv`, and the same on held-out points, `held_out_…`; the relative half-widths
//!   of the 95 % intervals of Ks_G and m, `ks_g_ci95_relative`, `m_ci95_relative`): count,
//!   min, quartiles, max, whiskers, outliers (`;`-joined).
//! - `local_minima.csv`: per variant and number of θL, Nelder–Mead fits compared and how
//!   many ended above the robust loss.
//! - `study.json`: totals (`point_evaluations`: the fits' loss evaluations × their
//!   points, the study's work), timing, and per variant the medians of the held-out
//!   errors over every combination that left some θL out.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use super::boxplot::BoxStats;
use super::error::StudyError;
use super::report::{GroupSummary, Scores, StudyReport};
use crate::fit::ParameterSet;

fn write_file(path: PathBuf, text: &str) -> Result<PathBuf, StudyError> {
    std::fs::write(&path, text).map_err(|error| StudyError::Io {
        path: path.clone(),
        error,
    })?;
    Ok(path)
}

fn join(values: impl IntoIterator<Item = f64>) -> String {
    values
        .into_iter()
        .map(|v| format!("{v}"))
        .collect::<Vec<_>>()
        .join(";")
}

fn opt(value: Option<f64>) -> String {
    value.map(|v| format!("{v:.6}")).unwrap_or_default()
}

/// Writes the three CSV tables and `study.json`; returns their paths.
pub fn write_tables(report: &StudyReport, dir: &Path) -> Result<Vec<PathBuf>, StudyError> {
    Ok(vec![
        write_file(dir.join("combinations.csv"), &combinations_csv(report))?,
        write_file(dir.join("boxplots.csv"), &boxplots_csv(report))?,
        write_file(dir.join("local_minima.csv"), &local_minima_csv(report))?,
        write_file(dir.join("study.json"), &summary_json(report))?,
    ])
}

/// A column of `combinations.csv` after `status`, with its value for a fit.
type Column = (String, Box<dyn Fn(&Scores) -> Option<f64>>);

fn column(name: &str, value: impl Fn(&Scores) -> Option<f64> + 'static) -> Column {
    (name.to_owned(), Box::new(value))
}

/// The columns `name_r`, `name_g`, `name_b` of a per-channel value.
fn per_channel(
    name: &str,
    value: impl Fn(&Scores, usize) -> Option<f64> + Copy + 'static,
) -> [Column; 3] {
    [("r", 0), ("g", 1), ("b", 2)]
        .map(|(suffix, c)| column(&format!("{name}_{suffix}"), move |s: &Scores| value(s, c)))
}

/// Scores' columns: errors on all points and on the held-out ones, parameters (m per
/// channel; `ks_90` empty for models without it), their standard uncertainties, the
/// 95 % interval of m and the Ks–m correlation.
fn score_columns() -> Vec<Column> {
    let mut columns = vec![column("loss", |s| Some(s.fit.loss))];
    columns.extend(per_channel("err_p", |s, c| Some(s.err_p[c])));
    columns.push(column("delta_e_uv", |s| s.delta_e_uv));
    columns.extend(per_channel("held_out_err_p", |s, c| {
        s.held_out.as_ref().map(|h| h.err_p[c])
    }));
    columns.push(column("held_out_delta_e_uv", |s| {
        s.held_out.as_ref().and_then(|h| h.delta_e_uv)
    }));
    columns.extend(per_channel("kd", |s, c| Some(s.fit.kd[c])));
    columns.extend(per_channel("ks", |s, c| Some(s.fit.ks[c])));
    columns.extend(per_channel("ks_90", |s, c| s.fit.ks_90.map(|k| k[c])));
    columns.extend(per_channel("m", |s, c| Some(s.fit.params().m[c])));
    columns.extend(per_channel("kd_stderr", |s, c| {
        stderr_of(s).map(|e| e.kd[c])
    }));
    columns.extend(per_channel("ks_stderr", |s, c| {
        stderr_of(s).map(|e| e.ks[c])
    }));
    columns.extend(per_channel("ks_90_stderr", |s, c| {
        stderr_of(s).and_then(|e| e.ks_90).map(|k| k[c])
    }));
    columns.extend(per_channel("m_stderr", |s, c| {
        stderr_of(s).map(|e| channel_m(&e.m, c))
    }));
    columns.extend(per_channel("m_ci95_lo", |s, c| {
        s.fit.ci95.as_ref().map(|e| channel_m(&e.m, c)[0])
    }));
    columns.extend(per_channel("m_ci95_hi", |s, c| {
        s.fit.ci95.as_ref().map(|e| channel_m(&e.m, c)[1])
    }));
    columns.extend(per_channel("ks_m_correlation", |s, c| {
        s.fit.correlation.map(|k| k.ks_m[c])
    }));
    columns.push(column("nelder_mead_loss", |s| s.nelder_mead_loss));
    columns.push(column("fit_seconds", |s| Some(s.fit.seconds)));
    columns
}

fn stderr_of(s: &Scores) -> Option<&ParameterSet<f64>> {
    s.fit.stderr.as_ref()
}

/// Channel c's entry of a per-roughness list: the one shared value or the channel's.
fn channel_m<T: Copy>(m: &[T], c: usize) -> T {
    m[c.min(m.len() - 1)]
}

fn combinations_csv(report: &StudyReport) -> String {
    let columns = score_columns();
    let mut out = String::from("model,roughness,n_theta_l,theta_l,status,");
    for (name, _) in &columns {
        out.push_str(name);
        out.push(',');
    }
    out.push_str("error\n");
    for r in &report.results {
        let head = format!(
            "{},{},{},{}",
            r.variant.model,
            r.variant.roughness,
            r.theta_l.len(),
            join(r.theta_l.iter().copied())
        );
        match &r.outcome {
            Ok(s) => {
                let numbers: Vec<String> = columns.iter().map(|(_, f)| opt(f(s))).collect();
                let _ = writeln!(out, "{head},ok,{},", numbers.join(","));
            }
            Err(e) => {
                let _ = writeln!(
                    out,
                    "{head},failed{},\"{}\"",
                    ",".repeat(columns.len()),
                    e.replace('"', "'")
                );
            }
        }
    }
    out
}

fn boxplots_csv(report: &StudyReport) -> String {
    let mut out = String::from(
        "model,roughness,n_theta_l,metric,count,min,q1,median,q3,max,whisker_low,whisker_high,outliers\n",
    );
    for g in report.summary() {
        let metrics: [(&str, &Option<BoxStats>); 10] = [
            ("err_p_r", &g.err_p[0]),
            ("err_p_g", &g.err_p[1]),
            ("err_p_b", &g.err_p[2]),
            ("delta_e_uv", &g.delta_e_uv),
            ("held_out_err_p_r", &g.held_out_err_p[0]),
            ("held_out_err_p_g", &g.held_out_err_p[1]),
            ("held_out_err_p_b", &g.held_out_err_p[2]),
            ("held_out_delta_e_uv", &g.held_out_delta_e_uv),
            ("ks_g_ci95_relative", &g.ks_g_ci95_relative),
            ("m_ci95_relative", &g.m_ci95_relative),
        ];
        for (name, stats) in metrics {
            let Some(b) = stats else { continue };
            let _ = writeln!(
                out,
                "{},{},{},{name},{},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{}",
                g.variant.model,
                g.variant.roughness,
                g.size,
                b.count,
                b.min,
                b.q1,
                b.median,
                b.q3,
                b.max,
                b.whisker_low,
                b.whisker_high,
                b.outliers
                    .iter()
                    .map(|v| format!("{v:.6}"))
                    .collect::<Vec<_>>()
                    .join(";")
            );
        }
    }
    out
}

fn local_minima_csv(report: &StudyReport) -> String {
    let mut out =
        String::from("model,roughness,n_theta_l,fitted,failed,nelder_mead_compared,nelder_mead_above,fraction_above\n");
    for g in report.summary() {
        let fraction = (g.nelder_mead_compared > 0)
            .then(|| g.nelder_mead_above as f64 / g.nelder_mead_compared as f64);
        let _ = writeln!(
            out,
            "{},{},{},{},{},{},{},{}",
            g.variant.model,
            g.variant.roughness,
            g.size,
            g.fitted,
            g.failed,
            g.nelder_mead_compared,
            g.nelder_mead_above,
            opt(fraction)
        );
    }
    out
}

fn summary_json(report: &StudyReport) -> String {
    let summary = report.summary();
    let variants: Vec<serde_json::Value> = report
        .options
        .variants
        .iter()
        .map(|v| {
            let groups: Vec<_> = summary.iter().filter(|g| g.variant == *v).collect();
            let medians = |f: &dyn Fn(&GroupSummary) -> Option<f64>| {
                groups.iter().map(|g| f(g)).collect::<Vec<_>>()
            };
            serde_json::json!({
                "model": v.model,
                "roughness": v.roughness,
                "median_err_p_g_by_n_theta_l": medians(&|g| g.err_p[1].as_ref().map(|b| b.median)),
                "median_delta_e_uv_by_n_theta_l": medians(&|g| g.delta_e_uv.as_ref().map(|b| b.median)),
                "median_ks_g_ci95_relative_by_n_theta_l": medians(&|g| g.ks_g_ci95_relative.as_ref().map(|b| b.median)),
                "median_m_ci95_relative_by_n_theta_l": medians(&|g| g.m_ci95_relative.as_ref().map(|b| b.median)),
                "fitted": groups.iter().map(|g| g.fitted).sum::<usize>(),
                "failed": groups.iter().map(|g| g.failed).sum::<usize>(),
                "nelder_mead_compared": groups.iter().map(|g| g.nelder_mead_compared).sum::<usize>(),
                "nelder_mead_above": groups.iter().map(|g| g.nelder_mead_above).sum::<usize>(),
            })
        })
        .collect();
    let median = |b: &Option<BoxStats>| b.as_ref().map(|b| b.median);
    let held_out: Vec<serde_json::Value> = report
        .held_out_summary()
        .iter()
        .map(|h| {
            serde_json::json!({
                "model": h.variant.model,
                "roughness": h.variant.roughness,
                "combinations": h.combinations,
                "median_err_p": h.err_p.each_ref().map(median),
                "median_delta_e_uv": median(&h.delta_e_uv),
            })
        })
        .collect();
    let value = serde_json::json!({
        "theta_l": report.theta_l,
        "evaluation_points": report.points.len(),
        "combinations": report.results.len() / report.options.variants.len().max(1),
        "fits": report.results.len(),
        "point_evaluations": report
            .results
            .iter()
            .filter_map(|r| r.outcome.as_ref().ok())
            .map(|s| s.point_evaluations)
            .sum::<u64>(),
        "seconds": report.seconds,
        "local_minimum_margin": report.options.local_minimum_margin,
        "variants": variants,
        "held_out": held_out,
    });
    let mut text = serde_json::to_string_pretty(&value).unwrap_or_default();
    text.push('\n');
    text
}
