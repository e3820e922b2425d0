//! SVG figures of a study: box plots (paper Fig. 7, 9) and x–y charts (Fig. 6, the u′v′
//! chart of Fig. 8, Pareto plots). Drawn with plotters' SVG backend; text is left to the
//! SVG viewer's fonts.

use std::path::{Path, PathBuf};

use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;

use super::boxplot::BoxStats;

/// Figure size in SVG user units (pixels).
const SIZE: (u32, u32) = (900, 600);

/// Series colours: black first (measured/reference data), then a colour-blind-safe set.
const PALETTE: [RGBColor; 7] = [
    RGBColor(0, 0, 0),
    RGBColor(0, 114, 178),
    RGBColor(213, 94, 0),
    RGBColor(0, 158, 115),
    RGBColor(204, 121, 167),
    RGBColor(230, 159, 0),
    RGBColor(86, 180, 233),
];

/// A figure could not be written.
#[derive(Debug, thiserror::Error)]
#[error("cannot draw figure {path}: {message}")]
pub struct FigureError {
    pub path: PathBuf,
    pub message: String,
}

/// One model's boxes: `(number of θL, statistics)` per group.
#[derive(Debug, Clone)]
pub struct BoxSeries {
    pub name: String,
    pub groups: Vec<(usize, BoxStats)>,
}

/// How an x–y series is drawn.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mark {
    /// Filled dots at the points.
    Points,
    /// Polylines through each segment's points, in order.
    Lines,
    /// Large hollow circles, to single out a few points.
    Highlight,
}

/// One named x–y series; each segment is drawn separately (e.g. one line per θL).
#[derive(Debug, Clone)]
pub struct XySeries {
    pub name: String,
    pub mark: Mark,
    pub segments: Vec<Vec<(f64, f64)>>,
}

/// An x–y chart. With `log_x` (`log_y`), x (y) values are plotted on a log₁₀ axis
/// (they must be > 0; others are skipped).
#[derive(Debug, Clone)]
pub struct XyPlot {
    pub title: String,
    pub x_label: String,
    pub y_label: String,
    pub log_x: bool,
    pub log_y: bool,
    pub series: Vec<XySeries>,
}

fn draw_error(path: &Path, err: impl std::fmt::Display) -> FigureError {
    FigureError {
        path: path.to_path_buf(),
        message: err.to_string(),
    }
}

/// A tick label with three significant digits (no exponent).
fn tick(v: f64) -> String {
    if v == 0.0 || !v.is_finite() {
        return format!("{v}");
    }
    let decimals = (2.0 - v.abs().log10().floor()).clamp(0.0, 8.0) as usize;
    format!("{v:.decimals$}")
}

/// Padded `(lo, hi)` range of the values; a unit range around a single value.
fn padded_range(values: impl Iterator<Item = f64>) -> (f64, f64) {
    let (lo, hi) = values
        .filter(|v| v.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
            (lo.min(v), hi.max(v))
        });
    if !lo.is_finite() {
        return (0.0, 1.0);
    }
    let span = hi - lo;
    if span <= 1e-12 * lo.abs().max(1.0) {
        let half = 0.5 * lo.abs().max(1e-3);
        return (lo - half, hi + half);
    }
    (lo - 0.05 * span, hi + 0.05 * span)
}

/// Box-and-whisker plot, groups along x by the number of θL, one coloured box per series
/// within each group; outliers as hollow circles.
pub fn box_plot_svg(
    path: &Path,
    title: &str,
    y_label: &str,
    series: &[BoxSeries],
) -> Result<(), FigureError> {
    let err = |e: &dyn std::fmt::Display| draw_error(path, e);
    let k_max = series
        .iter()
        .flat_map(|s| s.groups.iter().map(|(k, _)| *k))
        .max()
        .unwrap_or(1);
    let (y_lo, y_hi) = padded_range(series.iter().flat_map(|s| {
        s.groups.iter().flat_map(|(_, b)| {
            [b.whisker_low, b.whisker_high]
                .into_iter()
                .chain(b.outliers.iter().copied())
        })
    }));
    let root = SVGBackend::new(path, SIZE).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(&e))?;
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 22))
        .margin(12)
        .x_label_area_size(45)
        .y_label_area_size(70)
        .build_cartesian_2d(0.5..k_max as f64 + 0.5, y_lo..y_hi)
        .map_err(|e| err(&e))?;
    chart
        .configure_mesh()
        .disable_x_mesh()
        .x_labels(k_max + 1)
        .x_label_formatter(&|x| {
            if (x - x.round()).abs() < 1e-9 {
                format!("{}", x.round())
            } else {
                String::new()
            }
        })
        .x_desc("number of illumination directions θL")
        .y_desc(y_label)
        .draw()
        .map_err(|e| err(&e))?;

    let width = 0.8 / series.len().max(1) as f64;
    for (j, s) in series.iter().enumerate() {
        let color = PALETTE[1 + j % (PALETTE.len() - 1)];
        let offset = (j as f64 - (series.len() as f64 - 1.0) / 2.0) * width;
        let half = 0.4 * width;
        let boxes = s.groups.iter().map(|(k, b)| {
            let c = *k as f64 + offset;
            Rectangle::new([(c - half, b.q1), (c + half, b.q3)], color.stroke_width(2))
        });
        chart
            .draw_series(boxes)
            .map_err(|e| err(&e))?
            .label(s.name.clone())
            .legend(move |(x, y)| Rectangle::new([(x, y - 6), (x + 16, y + 6)], color.filled()));
        let lines = s.groups.iter().flat_map(|(k, b)| {
            let c = *k as f64 + offset;
            [
                vec![(c - half, b.median), (c + half, b.median)],
                vec![(c, b.q3), (c, b.whisker_high)],
                vec![(c, b.q1), (c, b.whisker_low)],
                vec![
                    (c - half / 2.0, b.whisker_high),
                    (c + half / 2.0, b.whisker_high),
                ],
                vec![
                    (c - half / 2.0, b.whisker_low),
                    (c + half / 2.0, b.whisker_low),
                ],
            ]
        });
        chart
            .draw_series(lines.map(|l| PathElement::new(l, color.stroke_width(2))))
            .map_err(|e| err(&e))?;
        let outliers = s.groups.iter().flat_map(|(k, b)| {
            let c = *k as f64 + offset;
            b.outliers.iter().map(move |&o| (c, o))
        });
        chart
            .draw_series(outliers.map(|p| Circle::new(p, 4, color.stroke_width(1))))
            .map_err(|e| err(&e))?;
    }
    legend_and_present(&mut chart, &root).map_err(|e| err(&e))
}

/// An x–y chart of points and polylines with a legend, written to `path`.
pub fn xy_svg(path: &Path, plot: &XyPlot) -> Result<(), FigureError> {
    let svg = xy_svg_text(plot).map_err(|e| FigureError {
        path: path.to_path_buf(),
        ..e
    })?;
    std::fs::write(path, svg).map_err(|e| draw_error(path, e))
}

/// [`xy_svg`]'s chart as SVG text (900 × 600 user units), for embedding in a page.
pub fn xy_svg_text(plot: &XyPlot) -> Result<String, FigureError> {
    let mut svg = String::new();
    draw_xy(
        SVGBackend::with_string(&mut svg, SIZE).into_drawing_area(),
        plot,
    )
    .map_err(|e| draw_error(Path::new(""), e))?;
    Ok(svg)
}

/// Draws `plot` on `root`; errors as text.
fn draw_xy(
    root: DrawingArea<SVGBackend<'_>, plotters::coord::Shift>,
    plot: &XyPlot,
) -> Result<(), String> {
    let err = |e: &dyn std::fmt::Display| e.to_string();
    let axis = |log: bool, v: f64| {
        if log {
            (v > 0.0).then(|| v.log10())
        } else {
            Some(v)
        }
    };
    let transformed: Vec<Vec<Vec<(f64, f64)>>> = plot
        .series
        .iter()
        .map(|s| {
            s.segments
                .iter()
                .map(|seg| {
                    seg.iter()
                        .filter_map(|&(x, y)| Some((axis(plot.log_x, x)?, axis(plot.log_y, y)?)))
                        .filter(|(x, y)| x.is_finite() && y.is_finite())
                        .collect()
                })
                .collect()
        })
        .collect();
    let all = || transformed.iter().flatten().flatten();
    let (x_lo, x_hi) = padded_range(all().map(|p| p.0));
    let (y_lo, y_hi) = padded_range(all().map(|p| p.1));

    root.fill(&WHITE).map_err(|e| err(&e))?;
    let mut chart = ChartBuilder::on(&root)
        .caption(&plot.title, ("sans-serif", 22))
        .margin(12)
        .x_label_area_size(45)
        .y_label_area_size(70)
        .build_cartesian_2d(x_lo..x_hi, y_lo..y_hi)
        .map_err(|e| err(&e))?;
    let (log_x, log_y) = (plot.log_x, plot.log_y);
    let unlog = |log: bool, v: f64| if log { 10f64.powf(v) } else { v };
    chart
        .configure_mesh()
        .x_label_formatter(&|x| tick(unlog(log_x, *x)))
        .y_label_formatter(&|y| tick(unlog(log_y, *y)))
        .x_desc(plot.x_label.as_str())
        .y_desc(plot.y_label.as_str())
        .draw()
        .map_err(|e| err(&e))?;

    for (i, (s, segments)) in plot.series.iter().zip(&transformed).enumerate() {
        let color = PALETTE[i % PALETTE.len()];
        let annotation = match s.mark {
            Mark::Points => chart
                .draw_series(
                    segments
                        .iter()
                        .flatten()
                        .map(|&p| Circle::new(p, 2, color.filled())),
                )
                .map_err(|e| err(&e))?,
            Mark::Highlight => chart
                .draw_series(
                    segments
                        .iter()
                        .flatten()
                        .map(|&p| Circle::new(p, 8, color.stroke_width(3))),
                )
                .map_err(|e| err(&e))?,
            Mark::Lines => chart
                .draw_series(
                    segments
                        .iter()
                        .map(|seg| PathElement::new(seg.clone(), color.stroke_width(2))),
                )
                .map_err(|e| err(&e))?,
        };
        annotation.label(s.name.clone()).legend(move |(x, y)| {
            PathElement::new(vec![(x, y), (x + 16, y)], color.stroke_width(3))
        });
    }
    legend_and_present(&mut chart, &root).map_err(|e| err(&e))
}

/// Draws the legend (inside the plot, on a pale box with a black border) and writes the
/// figure out.
fn legend_and_present<'a, 'b: 'a>(
    chart: &mut ChartContext<'a, SVGBackend<'b>, Cartesian2d<RangedCoordf64, RangedCoordf64>>,
    root: &DrawingArea<SVGBackend<'b>, plotters::coord::Shift>,
) -> Result<(), String> {
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()
        .map_err(|e| e.to_string())?;
    root.present().map_err(|e| e.to_string())
}
