//! CSV tables and the JSON summary of a study.
//!
//! - `combinations.csv`: one row per (variant, θL combination): the robust fit, its
//!   scores and the Nelder–Mead loss; θL joined by `;`; empty cells where undefined.
//! - `boxplots.csv`: per variant, number of θL and metric (`err_p_r|g|b`,
//!   `delta_e_uv`): count, min, quartiles, max, whiskers, outliers (`;`-joined).
//! - `local_minima.csv`: per variant and number of θL, Nelder–Mead fits compared and how
//!   many ended above the robust loss.
//! - `study.json`: totals and timing.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use super::boxplot::BoxStats;
use super::{StudyError, StudyReport};

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

fn combinations_csv(report: &StudyReport) -> String {
    let mut out = String::from(
        "model,roughness,n_theta_l,theta_l,status,loss,err_p_r,err_p_g,err_p_b,delta_e_uv,\
         kd_r,kd_g,kd_b,ks_r,ks_g,ks_b,m_r,m_g,m_b,nelder_mead_loss,fit_seconds,error\n",
    );
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
                let p = s.fit.params();
                let numbers: Vec<String> = [s.fit.loss]
                    .iter()
                    .chain(&s.err_p)
                    .map(|v| format!("{v:.6}"))
                    .chain([opt(s.delta_e_uv)])
                    .chain(
                        p.kd.iter()
                            .chain(&p.ks)
                            .chain(&p.m)
                            .map(|v| format!("{v:.6}")),
                    )
                    .chain([opt(s.nelder_mead_loss), format!("{:.6}", s.fit.seconds)])
                    .collect();
                let _ = writeln!(out, "{head},ok,{},", numbers.join(","));
            }
            Err(e) => {
                let _ = writeln!(
                    out,
                    "{head},failed{},\"{}\"",
                    ",".repeat(16),
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
        let metrics: [(&str, &Option<BoxStats>); 4] = [
            ("err_p_r", &g.err_p[0]),
            ("err_p_g", &g.err_p[1]),
            ("err_p_b", &g.err_p[2]),
            ("delta_e_uv", &g.delta_e_uv),
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
            let medians = |f: &dyn Fn(&super::GroupSummary) -> Option<f64>| {
                groups.iter().map(|g| f(g)).collect::<Vec<_>>()
            };
            serde_json::json!({
                "model": v.model,
                "roughness": v.roughness,
                "median_err_p_g_by_n_theta_l": medians(&|g| g.err_p[1].as_ref().map(|b| b.median)),
                "median_delta_e_uv_by_n_theta_l": medians(&|g| g.delta_e_uv.as_ref().map(|b| b.median)),
                "fitted": groups.iter().map(|g| g.fitted).sum::<usize>(),
                "failed": groups.iter().map(|g| g.failed).sum::<usize>(),
                "nelder_mead_compared": groups.iter().map(|g| g.nelder_mead_compared).sum::<usize>(),
                "nelder_mead_above": groups.iter().map(|g| g.nelder_mead_above).sum::<usize>(),
            })
        })
        .collect();
    let value = serde_json::json!({
        "theta_l": report.theta_l,
        "evaluation_points": report.points.len(),
        "combinations": report.results.len() / report.options.variants.len().max(1),
        "fits": report.results.len(),
        "seconds": report.seconds,
        "local_minimum_margin": report.options.local_minimum_margin,
        "variants": variants,
    });
    let mut text = serde_json::to_string_pretty(&value).unwrap_or_default();
    text.push('\n');
    text
}
