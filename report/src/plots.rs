//! The report's plots, inline SVG drawn by the study's chart writer: β of the green
//! channel against θr per θL with the chosen fit, and the samples' u′v′ chromaticity.

use gonio_processing::color::CameraModel;
use gonio_processing::samples::{distinct_theta_l, Sample};
use gonio_processing::study::figures::{xy_svg_text, Mark, XyPlot, XySeries};

use crate::html::escape;
use crate::Scan;

/// Most points drawn per series (evenly thinned beyond), to keep the file small.
const MAX_POINTS: usize = 800;

/// The plots' section, empty when the scan has no samples.
pub fn section(scan: &Scan) -> String {
    if scan.samples.is_empty() {
        return String::new();
    }
    let mut body = String::new();
    for plot in [beta_plot(scan), uv_plot(&scan.samples)] {
        body += &match xy_svg_text(&plot) {
            Ok(svg) => svg,
            Err(e) => format!("<p class=\"warn\">{}</p>", escape(&e.to_string())),
        };
    }
    format!("<section><h2>Measured and fitted</h2>{body}</section>")
}

/// Every `step`-th item so that at most [`MAX_POINTS`] remain.
fn thin<T: Copy>(items: &[T]) -> Vec<T> {
    let step = items.len().div_ceil(MAX_POINTS).max(1);
    items.iter().step_by(step).copied().collect()
}

/// The samples of one θL.
fn at(samples: &[Sample], theta_l: f64) -> impl Iterator<Item = &Sample> {
    samples.iter().filter(move |s| s.theta_l == theta_l)
}

fn beta_plot(scan: &Scan) -> XyPlot {
    let samples = &scan.samples;
    let mut series = Vec::new();
    for theta_l in distinct_theta_l(samples) {
        let points: Vec<(f64, f64)> = at(samples, theta_l)
            .filter(|s| !s.dropped[1] && s.rgb[1] > 0.0)
            .map(|s| (s.theta_r, s.rgb[1]))
            .collect();
        series.push(XySeries {
            name: format!("measured, θL {theta_l}°"),
            mark: Mark::Points,
            segments: vec![thin(&points)],
        });
    }
    if let Some(chosen) = scan.chosen() {
        let segments = distinct_theta_l(samples)
            .into_iter()
            .map(|theta_l| {
                let mut line: Vec<(f64, f64)> = at(samples, theta_l)
                    .map(|s| (s.theta_r, chosen.fit.predict_sample(s)[1]))
                    .filter(|&(_, b)| b > 0.0 && b.is_finite())
                    .collect();
                line.sort_by(|a, b| a.0.total_cmp(&b.0));
                thin(&line)
            })
            .collect();
        series.push(XySeries {
            name: format!("{} ({})", chosen.fit.model, chosen.name),
            mark: Mark::Lines,
            segments,
        });
    }
    XyPlot {
        title: "β of the green channel against θr, per θL".into(),
        x_label: "θr (degrees)".into(),
        y_label: "β_G (log scale)".into(),
        log_x: false,
        log_y: true,
        series,
    }
}

fn uv_plot(samples: &[Sample]) -> XyPlot {
    let camera = CameraModel::builtin();
    let series = distinct_theta_l(samples)
        .into_iter()
        .map(|theta_l| {
            let points: Vec<(f64, f64)> = at(samples, theta_l)
                .filter(|s| !s.dropped.iter().any(|&d| d))
                .filter_map(|s| camera.uv_prime(s.rgb))
                .map(|[u, v]| (u, v))
                .collect();
            XySeries {
                name: format!("θL {theta_l}°"),
                mark: Mark::Points,
                segments: vec![thin(&points)],
            }
        })
        .collect();
    XyPlot {
        title: "CIE 1976 u′v′ chromaticity of the samples".into(),
        x_label: "u′".into(),
        y_label: "v′".into(),
        log_x: false,
        log_y: false,
        series,
    }
}
