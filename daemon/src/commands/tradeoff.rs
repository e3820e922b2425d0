//! `gonio tradeoff`: what accuracy costs in time for one scene.
//!
//! One simulated scan of the scene (rendered here, or reused with `--scan`) is cut
//! into cheaper scans: the first n of the θL spread over the scanned range, b of the
//! bracket's exposures spread over its range (longest and shortest kept for b ≥ 2, the
//! middle one for b = 1), every s-th pixel column, and a fit method. For each setting:
//! - acquisition time from the hardware timing model ([`HardwareTiming`]): arm travel from home
//!   through the θL under the GRBL trapezoidal profile, and per θL each exposure plus
//!   the camera's download latency;
//! - processing time, measured: HDR merge + extraction of each θL used (with that
//!   bracket; whole image columns, so the stride does not shorten it) plus the fit on
//!   the strided samples. Rendering is simulation, not processing, and is not counted;
//! - accuracy against the scene's truth: ΔErr_p per channel (eq. 11, truth as the
//!   measurement) at the angles of the full scan, and relative Kd, Ks, m errors when the
//!   fitted model is the truth's.
//!
//! Settings are ranked by the worst channel's ΔErr_p, or with `--rank-by` by the largest
//! relative expanded uncertainty (the fit's budget, k = 2) of the parameters named. Outputs in OUT: `tradeoff.csv`
//! (one row per setting, with the 95 % intervals of m and Ks_G), `pareto.svg` (total time
//! against worst-channel ΔErr_p, the Pareto front drawn), `tradeoff.json` (the recommended
//! setting: the cheapest whose worst-channel ΔErr_p is within 10 % of the best reached, or
//! within `--tolerance` of it, with its fit and the fit's uncertainty; and the extraction
//! times).

mod scan;

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use gonio_mock_hw::scene::Scene;
use gonio_processing::brdf::{Model, Roughness};
use gonio_processing::color::CameraModel;
use gonio_processing::extract::ExtractOptions;
use gonio_processing::fit::budget::budget_if_possible;
use gonio_processing::fit::{self, FitMethod, FitOptions, FitResult, CANDIDATES};
use gonio_processing::metrics;
use gonio_processing::samples::Sample;
use gonio_processing::study::figures::{xy_svg, Mark, XyPlot, XySeries};
use gonio_processing::study::{pareto::pareto_front, subsample};

use super::output::write_output;
use crate::interrupt::RemoveOnInterrupt;
use crate::progress;
use gonio_mock_hw::scan_timing::{AcquisitionTime, HardwareTiming};
use gonio_processing::truth::{parameter_errors, Truth, TruthPoints};
use scan::{discover, extract_subset, spread, Position};

/// A setting is good enough when its worst-channel ΔErr_p is within this fraction of
/// the best (or within the absolute `--tolerance`).
const RELATIVE_SLACK: f64 = 0.10;

/// Arguments of `gonio tradeoff`.
#[derive(clap::Args)]
pub struct Args {
    #[arg(long, help = super::simulate::SCENE_HELP)]
    pub scene: String,
    /// Output directory for the table and the figure (created if missing).
    #[arg(long)]
    pub out: PathBuf,
    /// Reuse this `gonio simulate` scan of the scene instead of rendering one.
    #[arg(long)]
    pub scan: Option<PathBuf>,
    /// When rendering the scan here: bin the sensor N×N (image size divided by N).
    #[arg(long, default_value_t = 1, conflicts_with = "scan")]
    pub binning: u32,
    /// Model to fit; default: the scene's own when it is cook-torrance or ward, else
    /// (a goniochromatic or measured sample) the one `gonio fit --model auto` chooses on
    /// the full scan (with its roughness form).
    #[arg(long)]
    pub model: Option<Model>,
    /// Roughness form to fit; default: the scene's own, else shared.
    #[arg(long)]
    pub roughness: Option<Roughness>,
    /// Pixel-column strides to try, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "1,4,16")]
    pub strides: Vec<usize>,
    /// Fit methods to try, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "robust,nelder-mead")]
    pub methods: Vec<FitMethod>,
    /// Recommend the cheapest setting whose worst-channel ΔErr_p exceeds the best by at
    /// most this much (absolute) or 10 % of the best, whichever is larger.
    #[arg(long, default_value_t = 0.002)]
    pub tolerance: f64,
    /// Rank the settings by the largest relative expanded uncertainty U/|value| (k = 2,
    /// the fit's uncertainty budget) of these parameters (comma-separated, as the budget
    /// names them: kd_r … ks_b, ks_90_r …, m or m_r …) instead of by ΔErr_p against the
    /// truth; `--tolerance` is then in units of U/|value|.
    #[arg(long, value_delimiter = ',')]
    pub rank_by: Vec<String>,
}

/// One scan setting and what it cost and reached.
struct Row {
    theta_l: Vec<f64>,
    shutters_s: Vec<f64>,
    stride: usize,
    method: FitMethod,
    points: usize,
    acquisition: AcquisitionTime,
    extract_s: f64,
    fit_s: f64,
    outcome: Result<Accuracy, String>,
}

struct Accuracy {
    fit: FitResult,
    err_p: [f64; 3],
    /// Relative errors of Kd, Ks, m, when the fitted model is the truth's.
    parameters: Option<[f64; 3]>,
    /// With `--rank-by`: the largest U/|value| of the parameters named.
    expanded: Option<f64>,
}

impl Row {
    fn processing_s(&self) -> f64 {
        self.extract_s + self.fit_s
    }

    fn total_s(&self) -> f64 {
        self.acquisition.total_s() + self.processing_s()
    }

    /// The worst channel's ΔErr_p.
    fn err_p_worst(&self) -> Option<f64> {
        self.outcome
            .as_ref()
            .ok()
            .map(|a| a.err_p.iter().copied().fold(0.0, f64::max))
    }

    /// What a setting is ranked by: the worst channel's ΔErr_p, or with `--rank-by` the
    /// largest relative expanded uncertainty of the parameters named.
    fn score(&self, by_uncertainty: bool) -> Option<f64> {
        if by_uncertainty {
            self.outcome.as_ref().ok().and_then(|a| a.expanded)
        } else {
            self.err_p_worst()
        }
    }

    fn label(&self) -> String {
        format!(
            "{} θL, {} exp, stride {}, {}",
            self.theta_l.len(),
            self.shutters_s.len(),
            self.stride,
            self.method
        )
    }
}

fn join(values: &[f64]) -> String {
    values
        .iter()
        .map(|v| format!("{v}"))
        .collect::<Vec<_>>()
        .join(";")
}

pub fn run(args: Args) -> anyhow::Result<()> {
    if args.strides.is_empty() || args.strides.contains(&0) {
        anyhow::bail!("--strides must list integers ≥ 1");
    }
    if args.methods.is_empty() {
        anyhow::bail!("--methods must list at least one fit method");
    }
    if !(args.tolerance.is_finite() && args.tolerance >= 0.0) {
        anyhow::bail!(
            "--tolerance must be a finite number ≥ 0, got {}",
            args.tolerance
        );
    }
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    // Holds a scan rendered here until the end of the run.
    let rendered;
    let scan_dir: PathBuf = match &args.scan {
        Some(dir) => dir.clone(),
        None => {
            let (dir, guard) =
                RemoveOnInterrupt::tempdir_in(tempfile::Builder::new().prefix(".scan-"), &args.out)
                    .context("creating a scan directory")?;
            let (count, _) = super::simulate::render_scan(super::simulate::Args {
                scene: args.scene.clone(),
                out: dir.path().to_path_buf(),
                theta_l: None,
                seed: None,
                binning: args.binning,
            })?;
            // The scan is deleted at the end: its path is not worth printing.
            progress::say(format_args!(
                "rendered {count} captures of scene `{}`",
                args.scene
            ));
            rendered = (dir, guard);
            rendered.0.path().to_path_buf()
        }
    };
    let truth = Truth::read(&scan_dir.join("truth.json"))?;
    if Scene::builtin(&args.scene).is_some() && truth.scene != args.scene {
        anyhow::bail!(
            "{} is a scan of scene `{}`, not `{}`",
            scan_dir.display(),
            truth.scene,
            args.scene
        );
    }
    let positions = discover(&scan_dir)?;
    let bracket_len = positions
        .iter()
        .map(|p| p.exposures.len())
        .min()
        .unwrap_or(1);
    let by_uncertainty = !args.rank_by.is_empty();
    let extracted = extract_all(
        &scan_dir,
        &args.out,
        &positions,
        bracket_len,
        by_uncertainty,
    )?;
    let full: Vec<Sample> = extracted[bracket_len - 1]
        .iter()
        .flat_map(|e| e.samples.iter().copied())
        .collect();
    let points = TruthPoints::new(&truth, &full, &scan_dir.join("reference.csv"))?;
    // A scene without a model of ours (goniochromatic or measured): the model and
    // roughness `gonio fit --model auto` chooses on the full scan.
    let chosen = match (args.model, truth.model) {
        (None, None) => {
            let spinner = progress::spinner("choosing the model by the θL it did not see");
            // Its parametric candidates: the tradeoff is of a model's fit.
            let forms = CANDIDATES.map(fit::Form::Parametric);
            let fit = fit::fit_auto(&full, &forms, &CameraModel::builtin());
            spinner.finish_and_clear();
            let fit = fit.context("choosing the model")?;
            if let Some(selection) = &fit.selection {
                progress::say(format_args!("model: {}", selection.reason));
            }
            Some((fit.model, fit.roughness))
        }
        _ => None,
    };
    let model = args
        .model
        .or(truth.model.map(|(m, _, _)| m))
        .or(chosen.map(|(m, _)| m))
        .unwrap_or(Model::CookTorrance);
    let roughness = args
        .roughness
        .or(truth.model.map(|(_, r, _)| r))
        .or(chosen.map(|(_, r)| r))
        .unwrap_or(Roughness::Shared);

    // Nelder–Mead is the baseline of the paper's two models only.
    let methods: Vec<FitMethod> = args
        .methods
        .iter()
        .copied()
        .filter(|&m| !(model.has_fresnel_colour() && m == FitMethod::NelderMead))
        .collect();
    if methods.len() < args.methods.len() {
        progress::say(format_args!(
            "nelder-mead skipped: {model} is fitted by the robust method only"
        ));
    }
    if methods.is_empty() {
        anyhow::bail!("--methods: {model} is fitted by the robust method only");
    }

    let timing = HardwareTiming::default();
    let settings = positions.len() * bracket_len * args.strides.len() * args.methods.len();
    let bar = progress::bar(settings as u64, "settings");
    bar.set_message("fitting");
    let mut rows = Vec::new();
    for n in 1..=positions.len() {
        let used: Vec<usize> = spread(positions.len(), n);
        let theta_l: Vec<f64> = used.iter().map(|&i| positions[i].theta_l).collect();
        for b in 1..=bracket_len {
            let chosen = spread(bracket_len, b);
            let shutters_s: Vec<f64> = chosen
                .iter()
                .map(|&i| positions[used[0]].exposures[i].shutter_s)
                .collect();
            let acquisition = timing.scan(&theta_l, &shutters_s);
            let extract_s: f64 = used.iter().map(|&i| extracted[b - 1][i].seconds).sum();
            for &stride in &args.strides {
                let samples: Vec<Sample> = used
                    .iter()
                    .flat_map(|&i| subsample(&extracted[b - 1][i].samples, stride))
                    .collect();
                for &method in &methods {
                    let mut options = FitOptions::new(model);
                    options.roughness = roughness;
                    options.method = method;
                    let start = Instant::now();
                    let fitted = fit::fit(&samples, &options);
                    // A Nelder–Mead fit's check against the robust fit is not its cost.
                    let mut fit_s = fitted
                        .as_ref()
                        .map_or_else(|_| start.elapsed().as_secs_f64(), |f| f.seconds);
                    let outcome = fitted.map_err(|e| e.to_string()).and_then(|mut fit| {
                        let err_p = metrics::err_p(&points.beta, &points.predict(&fit))
                            .map_err(|e| e.to_string())?;
                        let mut expanded = None;
                        if by_uncertainty {
                            // The budget is part of what the setting costs.
                            let start = Instant::now();
                            fit.budget = budget_if_possible(&samples, &fit)
                                .map_err(|e| format!("uncertainty budget: {e}"))?;
                            fit_s += start.elapsed().as_secs_f64();
                            expanded = Some(largest_relative_expanded(&fit, &args.rank_by)?);
                        }
                        Ok(Accuracy {
                            parameters: parameter_errors(&truth, &fit),
                            fit,
                            err_p,
                            expanded,
                        })
                    });
                    rows.push(Row {
                        theta_l: theta_l.clone(),
                        shutters_s: shutters_s.clone(),
                        stride,
                        method,
                        points: samples.len(),
                        acquisition,
                        extract_s,
                        fit_s,
                        outcome,
                    });
                    bar.inc(1);
                }
            }
        }
    }
    bar.finish_and_clear();
    if let (true, Some(Err(e))) = (by_uncertainty, rows.first().map(|r| &r.outcome)) {
        if rows.iter().all(|r| r.outcome.is_err()) {
            anyhow::bail!("--rank-by: {e}");
        }
    }
    let fitted = Fitted {
        truth: &truth,
        model,
        roughness,
        tolerance: args.tolerance,
        rank_by: &args.rank_by,
    };
    write_outputs(&args.out, &fitted, &rows, &extracted, &positions)
}

/// The largest U/|value| of the parameters `names` in `fit`'s budget; an error naming the
/// parameters there are when a name is not one of them.
fn largest_relative_expanded(fit: &FitResult, names: &[String]) -> Result<f64, String> {
    let budget = fit
        .budget
        .as_ref()
        .ok_or("the fit has no uncertainty budget (no standard uncertainties)")?;
    let named = budget.named();
    names
        .iter()
        .map(|name| {
            let (_, b) = named.iter().find(|(n, _)| n == name).ok_or_else(|| {
                let known: Vec<&str> = named.iter().map(|(n, _)| n.as_str()).collect();
                format!("no parameter `{name}` (the fit has {})", known.join(", "))
            })?;
            Ok(if b.value != 0.0 {
                b.expanded / b.value.abs()
            } else {
                f64::INFINITY
            })
        })
        .try_fold(0.0, |worst: f64, v: Result<f64, String>| Ok(worst.max(v?)))
}

/// m (G channel's) and Ks_G with their 95 % intervals, formatted; empty intervals when
/// the fit has none.
fn intervals(fit: &FitResult) -> [String; 6] {
    let m = fit.params().m[1];
    let ci = fit.ci95.as_ref();
    let m_ci = ci.map(|c| c.m[1.min(c.m.len() - 1)]);
    let ks_ci = ci.map(|c| c.ks[1]);
    let bound = |b: Option<f64>| b.map_or(String::new(), |v| format!("{v:.5}"));
    [
        format!("{m:.5}"),
        bound(m_ci.map(|c| c[0])),
        bound(m_ci.map(|c| c[1])),
        format!("{:.4}", fit.ks[1]),
        bound(ks_ci.map(|c| c[0])),
        bound(ks_ci.map(|c| c[1])),
    ]
}

/// What was fitted, against what, and the recommendation tolerance.
struct Fitted<'a> {
    truth: &'a Truth,
    model: Model,
    roughness: Roughness,
    tolerance: f64,
    /// The parameters whose expanded uncertainty ranks the settings (`--rank-by`); empty:
    /// ranked by ΔErr_p.
    rank_by: &'a [String],
}

/// Extractions of every θL with every bracket length: `[b − 1][position]`; the samples'
/// uncertainty only when `uncertainty` (settings ranked by their budget).
fn extract_all(
    scan_dir: &Path,
    out: &Path,
    positions: &[Position],
    bracket_len: usize,
    uncertainty: bool,
) -> anyhow::Result<Vec<Vec<scan::Extracted>>> {
    let (work, _guard) =
        RemoveOnInterrupt::tempdir_in(tempfile::Builder::new().prefix(".extract-"), out)
            .context("creating a work directory")?;
    // The scan's setup.json carries the white reflectance and its uncertainties.
    let options = ExtractOptions {
        uncertainty,
        ..ExtractOptions::default()
    };
    let bar = progress::bar((bracket_len * positions.len()) as u64, "extractions");
    let mut all = Vec::new();
    for b in 1..=bracket_len {
        let chosen = spread(bracket_len, b);
        bar.set_message(format!("{b} of {bracket_len} exposures"));
        let mut row = Vec::new();
        for (i, position) in positions.iter().enumerate() {
            let dir = work.path().join(format!("b{b}_p{i}"));
            row.push(extract_subset(scan_dir, &dir, position, &chosen, &options)?);
            bar.inc(1);
        }
        bar.suspend(|| {
            progress::say(format_args!(
                "extracted {} θL with {b} of {bracket_len} exposures in {:.2} s",
                positions.len(),
                row.iter().map(|e| e.seconds).sum::<f64>()
            ))
        });
        all.push(row);
    }
    bar.finish_and_clear();
    Ok(all)
}

fn write_outputs(
    out: &Path,
    fitted: &Fitted,
    rows: &[Row],
    extracted: &[Vec<scan::Extracted>],
    positions: &[Position],
) -> anyhow::Result<()> {
    let Fitted {
        truth,
        model,
        roughness,
        tolerance,
        rank_by,
    } = *fitted;
    let by_uncertainty = !rank_by.is_empty();
    let score_key = |what: &str| {
        if by_uncertainty {
            format!("{what}_rel_expanded")
        } else {
            format!("{what}_err_p_worst")
        }
    };
    let costs: Vec<(f64, f64)> = rows
        .iter()
        .map(|r| (r.total_s(), r.score(by_uncertainty).unwrap_or(f64::NAN)))
        .collect();
    let front = pareto_front(&costs);
    let best = rows
        .iter()
        .filter_map(|r| r.score(by_uncertainty))
        .fold(f64::INFINITY, f64::min);
    let ranked_by = if by_uncertainty {
        "largest U/|value| of the parameters ranked by (k = 2)"
    } else {
        "worst-channel ΔErr_p against the truth"
    };
    let good_enough = best + (RELATIVE_SLACK * best).max(tolerance);
    let recommended = front.iter().copied().find(|&i| costs[i].1 <= good_enough);

    let mut csv = String::from(
        "n_theta_l,theta_l,bracket,shutters_s,stride,method,points,acquisition_s,travel_s,capture_s,\
         processing_s,extract_s,fit_s,total_s,err_p_r,err_p_g,err_p_b,kd_rel_err,ks_rel_err,m_rel_err,\
         m,m_ci95_lo,m_ci95_hi,ks_g,ks_g_ci95_lo,ks_g_ci95_hi,rel_expanded,pareto,recommended,status\n",
    );
    for (i, r) in rows.iter().enumerate() {
        let head = format!(
            "{},{},{},{},{},{},{},{:.3},{:.3},{:.3},{:.4},{:.4},{:.4},{:.3}",
            r.theta_l.len(),
            join(&r.theta_l),
            r.shutters_s.len(),
            join(&r.shutters_s),
            r.stride,
            r.method,
            r.points,
            r.acquisition.total_s(),
            r.acquisition.travel_s,
            r.acquisition.capture_s,
            r.processing_s(),
            r.extract_s,
            r.fit_s,
            r.total_s()
        );
        let scores = match &r.outcome {
            Ok(a) => {
                let p = a.parameters.map_or(",,".to_string(), |p| {
                    format!("{:.5},{:.5},{:.5}", p[0], p[1], p[2])
                });
                format!(
                    "{:.5},{:.5},{:.5},{p},{},{},{},{},ok",
                    a.err_p[0],
                    a.err_p[1],
                    a.err_p[2],
                    intervals(&a.fit).join(","),
                    a.expanded.map_or(String::new(), |v| format!("{v:.6}")),
                    front.contains(&i),
                    recommended == Some(i)
                )
            }
            Err(e) => format!(
                ",,,,,,,,,,,,,false,false,\"failed: {}\"",
                e.replace('"', "'")
            ),
        };
        let _ = writeln!(csv, "{head},{scores}");
    }
    let csv_path = out.join("tradeoff.csv");
    write_output(&csv_path, |temp| std::fs::write(temp, csv))?;

    let series_of = |method: FitMethod| XySeries {
        name: format!("{method} fits"),
        mark: Mark::Points,
        segments: vec![rows
            .iter()
            .zip(&costs)
            .filter(|(r, _)| r.method == method)
            .map(|(_, &c)| c)
            .collect()],
    };
    let mut series = vec![
        XySeries {
            name: "Pareto front".into(),
            mark: Mark::Lines,
            segments: vec![front.iter().map(|&i| costs[i]).collect()],
        },
        series_of(FitMethod::Robust),
        series_of(FitMethod::NelderMead),
    ];
    if let Some(i) = recommended {
        series.push(XySeries {
            name: format!("recommended: {}", rows[i].label()),
            mark: Mark::Highlight,
            segments: vec![vec![costs[i]]],
        });
    }
    let plot = XyPlot {
        title: format!(
            "{}: accuracy against scan + processing time ({} {})",
            truth.scene, model, roughness
        ),
        x_label: "acquisition + processing time (s, log scale)".into(),
        y_label: format!("{ranked_by} (log scale)"),
        log_x: true,
        log_y: true,
        series,
    };
    let svg_path = out.join("pareto.svg");
    write_output(&svg_path, |temp| xy_svg(temp, &plot))?;

    let row_json = |r: &Row| {
        serde_json::json!({
            "theta_l": r.theta_l,
            "shutters_s": r.shutters_s,
            "stride": r.stride,
            "method": r.method,
            "acquisition_s": r.acquisition.total_s(),
            "processing_s": r.processing_s(),
            "total_s": r.total_s(),
            "err_p": r.outcome.as_ref().ok().map(|a| a.err_p),
            "rel_expanded": r.outcome.as_ref().ok().and_then(|a| a.expanded),
            "parameter_rel_err": r.outcome.as_ref().ok().and_then(|a| a.parameters),
            "fit": r.outcome.as_ref().ok().map(|a| &a.fit),
        })
    };
    let summary = serde_json::json!({
        "scene": truth.scene,
        "material": truth.material,
        "model": model,
        "roughness": roughness,
        "settings": rows.len(),
        "failed": rows.iter().filter(|r| r.outcome.is_err()).count(),
        "ranked_by": if by_uncertainty { serde_json::json!({"rel_expanded": rank_by}) } else { serde_json::json!("err_p_worst") },
        score_key("best"): best.is_finite().then_some(best),
        score_key("good_enough"): good_enough.is_finite().then_some(good_enough),
        "recommended": recommended.map(|i| row_json(&rows[i])),
        "pareto_front": front.iter().map(|&i| row_json(&rows[i])).collect::<Vec<_>>(),
        "extract_seconds_by_bracket_and_theta_l": extracted
            .iter()
            .map(|row| row.iter().zip(positions).map(|(e, p)| serde_json::json!({
                "theta_l": p.theta_l,
                "seconds": e.seconds,
                "samples": e.samples.len(),
            })).collect::<Vec<_>>())
            .collect::<Vec<_>>(),
    });
    let json_path = out.join("tradeoff.json");
    let json = serde_json::to_string_pretty(&summary)? + "\n";
    write_output(&json_path, |temp| std::fs::write(temp, json))?;

    println!(
        "{}: {} settings ({} failed); Pareto front:",
        truth.scene,
        rows.len(),
        rows.iter().filter(|r| r.outcome.is_err()).count()
    );
    println!(
        "  total s  acquisition s  processing s  ΔErr_p(worst)  m [95 %]  Ks_G [95 %]  setting"
    );
    for &i in &front {
        let r = &rows[i];
        let spread = r.outcome.as_ref().ok().map_or(String::new(), |a| {
            let v = intervals(&a.fit);
            format!(
                "{} [{}, {}]  {} [{}, {}]",
                v[0], v[1], v[2], v[3], v[4], v[5]
            )
        });
        println!(
            "  {:>7.2}  {:>13.2}  {:>12.3}  {:>13.4}  {spread}  {}{}",
            r.total_s(),
            r.acquisition.total_s(),
            r.processing_s(),
            costs[i].1,
            r.label(),
            if recommended == Some(i) {
                "  <- recommended"
            } else {
                ""
            }
        );
    }
    for path in [csv_path, svg_path, json_path] {
        println!("wrote {}", path.display());
    }
    Ok(())
}
