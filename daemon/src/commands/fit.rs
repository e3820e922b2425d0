//! `gonio fit`: a samples CSV → the fit JSON of one reflection model.

use std::path::PathBuf;

use anyhow::{bail, Context};
use clap::ValueEnum;
use gonio_processing::brdf::{Model, Roughness};
use gonio_processing::color::CameraModel;
use gonio_processing::fit::{self, Criterion, FitMethod, FitOptions, Selection, AUTO_CANDIDATES};
use gonio_processing::samples::{self, Sample};

use super::output::write_output;
use crate::progress;

/// Two θL values closer than this (degrees) are the same illumination direction.
const THETA_L_MATCH_DEG: f64 = 1e-6;

/// Reflection model to fit.
#[derive(Clone, Copy, ValueEnum)]
enum ModelArg {
    CookTorrance,
    Ward,
    /// Cook–Torrance with a specular colour that varies with the facet incidence θd.
    CookTorranceFresnel,
    /// The measured table in (θh, θd), interpolated between the scan's θL; the fit JSON
    /// also holds a Cook–Torrance fit (with --roughness) for renderers.
    Table,
    /// The model (and roughness form), or the table, that best predicts each θL from the
    /// others (three θL or more), else the lowest BIC; the choice is recorded in the fit
    /// JSON.
    Auto,
}

/// One roughness for all channels or one per channel.
#[derive(Clone, Copy, ValueEnum)]
enum RoughnessArg {
    Shared,
    PerChannel,
}

/// Minimisation method.
#[derive(Clone, Copy, ValueEnum)]
enum MethodArg {
    /// Kd, Ks solved at each roughness (a convex problem) plus a global search over log m.
    Robust,
    /// Downhill simplex over all parameters (the paper's method).
    NelderMead,
}

/// Arguments of `gonio fit`.
#[derive(clap::Args)]
pub struct Args {
    /// Samples CSV (theta_l,theta_i,theta_r,r,g,b; degrees, β in camera RGB).
    samples: PathBuf,
    /// Reflection model.
    #[arg(long, value_enum)]
    model: ModelArg,
    /// Roughness m shared by R, G, B or one per channel (`--model auto` tries both).
    #[arg(long, value_enum, default_value = "shared")]
    roughness: RoughnessArg,
    /// Minimisation method of the eq. 10 loss.
    #[arg(long, value_enum, default_value = "robust")]
    method: MethodArg,
    /// Fit only the samples of these θL (degrees, comma-separated, e.g. -20,-25).
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true)]
    theta_l: Vec<f64>,
    /// Polish the robust fit with Nelder–Mead over all parameters.
    #[arg(long)]
    polish: bool,
    /// Also propagate the uncertainty budget by Monte Carlo (JCGM 101) with this many
    /// draws (at least 2; 1000 or more for a 95 % interval), beside the law of
    /// propagation.
    #[arg(long, value_name = "DRAWS")]
    monte_carlo: Option<usize>,
    /// Output fit JSON.
    #[arg(long)]
    out: PathBuf,
}

/// The samples whose θL is one of `wanted` (all when empty); an unknown θL is an error.
fn select_theta_l(all: Vec<Sample>, wanted: &[f64]) -> anyhow::Result<Vec<Sample>> {
    if wanted.is_empty() {
        return Ok(all);
    }
    let same = |a: f64, b: f64| (a - b).abs() < THETA_L_MATCH_DEG;
    let mut present: Vec<f64> = Vec::new();
    for s in &all {
        if !present.iter().any(|&p| same(p, s.theta_l)) {
            present.push(s.theta_l);
        }
    }
    for (i, &w) in wanted.iter().enumerate() {
        if !w.is_finite() {
            bail!("--theta-l {w} is not a finite angle");
        }
        if let Some(twice) = wanted[..i].iter().find(|&&v| same(v, w)) {
            bail!("--theta-l lists θL {w} twice (as {twice} before)");
        }
        if !present.iter().any(|&p| same(p, w)) {
            let list: Vec<String> = present.iter().map(|p| p.to_string()).collect();
            bail!(
                "θL {w} is not in the samples (present: {})",
                list.join(", ")
            );
        }
    }
    Ok(all
        .into_iter()
        .filter(|s| wanted.iter().any(|&w| same(w, s.theta_l)))
        .collect())
}

pub fn run(args: Args) -> anyhow::Result<()> {
    super::output::refuse_overwriting(&args.out, std::slice::from_ref(&args.samples), &[])?;
    let all = samples::read_csv(&args.samples)?;
    let selected = select_theta_l(all, &args.theta_l)?;
    let model = match args.model {
        ModelArg::CookTorrance => Some(Model::CookTorrance),
        ModelArg::Ward => Some(Model::Ward),
        ModelArg::CookTorranceFresnel => Some(Model::CookTorranceFresnel),
        ModelArg::Table => Some(Model::CookTorrance),
        ModelArg::Auto => None,
    };
    let mut options = FitOptions::new(model.unwrap_or(Model::CookTorrance));
    options.roughness = match args.roughness {
        RoughnessArg::Shared => Roughness::Shared,
        RoughnessArg::PerChannel => Roughness::PerChannel,
    };
    options.method = match args.method {
        MethodArg::Robust => FitMethod::Robust,
        MethodArg::NelderMead => FitMethod::NelderMead,
    };
    options.robust.polish = args.polish;
    if args.polish && options.method == FitMethod::NelderMead {
        bail!("--polish polishes the robust fit with Nelder–Mead: with --method nelder-mead it does not apply");
    }
    if model.is_none() && (options.method != FitMethod::Robust || args.polish) {
        bail!("--model auto compares robust fits: --method nelder-mead and --polish do not apply");
    }
    let spinner = progress::spinner(format!("fitting {} samples", selected.len()));
    let result = match (args.model, model) {
        (ModelArg::Table, _) => fit::fit_table(&selected, &options, &CameraModel::builtin()),
        (_, Some(_)) => fit::fit(&selected, &options),
        (_, None) => fit::fit_auto(&selected, &AUTO_CANDIDATES, &CameraModel::builtin()),
    }
    .with_context(|| format!("fitting {}", args.samples.display()));
    spinner.finish_and_clear();
    let mut result = result?;
    if let Some(selection) = &result.selection {
        print_selection(selection);
    }
    let has_uncertainty = selected.iter().all(|s| s.uncertainty.is_some());
    let spinner = progress::spinner("uncertainty budget".to_string());
    let budget = fit::budget::budget_if_possible(&selected, &result);
    spinner.finish_and_clear();
    if let Some(mut budget) = budget.context("the uncertainty budget")? {
        if let Some(draws) = args.monte_carlo {
            let spinner = progress::spinner(format!("Monte Carlo, {draws} draws"));
            let mc = fit::budget::monte_carlo(
                &selected,
                &result,
                draws,
                fit::budget::Draw::All,
                MONTE_CARLO_SEED,
            );
            spinner.finish_and_clear();
            let mut mc = mc.context("the Monte Carlo budget")?;
            mc.agreement = fit::agreement::compare(&budget, &mc);
            budget.monte_carlo = Some(mc);
        }
        result.budget = Some(budget);
    } else if args.monte_carlo.is_some() {
        bail!(
            "--monte-carlo needs samples with uncertainty columns (gonio extract writes them) \
             and a fit with standard uncertainties"
        );
    }
    let json = serde_json::to_string_pretty(&result).context("serialising the fit")?;
    write_output(&args.out, |path| std::fs::write(path, json + "\n"))?;
    if let Some(table) = &result.table {
        let columns = table.columns();
        println!(
            "predicts with the table of {} θL ({} β values, θd {:.1}°…{:.1}°) relative to the \
             shape of {}, the parametric fields below; beyond the measured θh and θd, that \
             shape scaled to the table at its edge",
            columns.len(),
            table.values(),
            columns.first().map_or(0.0, |c| c.theta_d),
            columns.last().map_or(0.0, |c| c.theta_d),
            result.model,
        );
    }
    let m = result.params().m;
    println!(
        "{} ({}, {}) on {} samples: loss {:.6}, {} evaluations in {:.3} s -> {}",
        result.model,
        result.roughness,
        result.method,
        selected.len(),
        result.loss,
        result.evaluations,
        result.seconds,
        args.out.display(),
    );
    let rgb = |v: &[f64], precision: usize| {
        v.iter()
            .map(|x| format!("{x:.precision$}"))
            .collect::<Vec<_>>()
            .join(" ")
    };
    println!(
        "  Kd {}  Ks {}  m {}",
        rgb(&result.kd, 3),
        rgb(&result.ks, 3),
        rgb(&m[..result.roughness.count()], 4)
    );
    // The robust method searches m within a range: at its end, the data lie beyond it.
    let range = fit::RobustOptions::default();
    let at_end = |m: f64| {
        [range.m_min, range.m_max]
            .into_iter()
            .any(|end| (m / end).ln().abs() < 0.005)
    };
    if result.method == FitMethod::Robust
        && m[..result.roughness.count()].iter().any(|&m| at_end(m))
    {
        println!(
            "  note: m is at an end of the range searched, [{}, {}]: the samples favour a \
             roughness beyond it; Kd, Ks and the intervals are the fit's at that end",
            range.m_min, range.m_max
        );
    }
    if let Some(ks_90) = &result.ks_90 {
        println!("  Ks at 90° between light and camera {}", rgb(ks_90, 3));
    }
    let albedo = result.model.diffuse_albedo(result.kd);
    println!(
        "  ρd {}  (diffuse albedo on one scale: Kd/100 for Cook–Torrance, Kd/(100π) for Ward)",
        rgb(&albedo, 4)
    );
    if albedo.iter().any(|&a| a > 1.0) {
        println!(
            "  note: a diffuse albedo above 1 reflects more than it receives: the samples \
             do not determine the diffuse term (too few angles, or a white reference that \
             does not match setup.json's reflectance)"
        );
    }
    if let Some(ci) = &result.ci95 {
        let interval =
            |[lo, hi]: [f64; 2], digits: usize| format!("[{lo:.digits$}, {hi:.digits$}]");
        println!(
            "  95 % intervals: m {}, Ks {}",
            ci.m.iter()
                .map(|&b| interval(b, 5))
                .collect::<Vec<_>>()
                .join(" "),
            ci.ks.map(|b| interval(b, 3)).join(" ")
        );
    }
    match &result.budget {
        Some(budget) => print_budget(budget),
        None if !has_uncertainty => println!(
            "  no uncertainty budget: the samples have no uncertainty columns (gonio extract \
             writes them); {}",
            if result.ci95.is_some() {
                "the intervals above are the noise's alone"
            } else {
                "nor intervals: the fit's standard uncertainties are not defined (too few \
                 points, or parameters the samples do not determine)"
            }
        ),
        // Samples with uncertainty, yet no budget: the fit has no standard uncertainties.
        None => println!(
            "  note: no uncertainty: the fit's standard uncertainties are not defined, so \
             the samples do not determine every parameter (a highlight dropped at every θL, \
             saturated or dark, leaves Ks and m unmeasured); the values above are not a \
             measurement of them"
        ),
    }
    if let Some(global) = result.global_minimum {
        let times = result.loss / global.loss;
        if global.reached {
            println!(
                "  at the global minimum: the robust fit's loss is {:.6} ({times:.4}×)",
                global.loss
            );
        } else {
            println!(
                "  warning: Nelder–Mead ended above the global minimum, in a local minimum or at \
                 its evaluation cap: its loss is {times:.2}× the robust fit's ({:.6}). These are \
                 not the optimal parameters and no intervals are given; fit with --method robust",
                global.loss
            );
        }
    }
    if let Some(shift) = result.colour_shift {
        // Only a choice on held-out θL tells a colour shift from a change of brightness.
        let judged = match &result.selection {
            Some(s) if s.colour_shift => ": a colour shift",
            Some(_) => ": not a colour shift (see the choice above)",
            None => ": the specular's colour or brightness changes with angle (--model auto tells which)",
        };
        match (shift.fitted, shift.p_value) {
            (true, Some(p)) if p < 1e-16 => println!("  Ks_90 ≠ Ks kept (Wald p < 1e-16){judged}"),
            (true, Some(p)) => println!("  Ks_90 ≠ Ks kept (Wald p = {p:.1e}){judged}"),
            (true, None) => println!("  Ks_90 ≠ Ks kept (noise-free data){judged}"),
            (false, Some(p)) => println!("  no significant colour shift (p = {p:.2}): Ks_90 = Ks"),
            (false, None) => println!("  one θL: colour shift not observable, Ks_90 = Ks"),
        }
    }
    Ok(())
}

/// Seed of `--monte-carlo`'s draws: the same samples give the same distribution.
const MONTE_CARLO_SEED: u64 = 0x676f_6e69_6f5f_6d63;

/// The budget as a GUM table: one row per parameter, one column per source.
fn print_budget(budget: &fit::budget::Budget) {
    let named = budget.named();
    let Some((_, first)) = named.first() else {
        return;
    };
    println!(
        "  uncertainty budget (standard uncertainties; U = {}·u_c; residuals {:.2}× the noise):",
        budget.coverage_factor, budget.residual_to_noise
    );
    let mut header = format!("  {:<8} {:>10}", "", "value");
    for c in &first.contributions {
        header += &format!(" {:>10}", short(&c.source));
    }
    header += &format!(
        " {:>10} {:>10}  interval (k = {})",
        "u_c", "U", budget.coverage_factor
    );
    println!("{header}");
    for (name, b) in &named {
        let mut row = format!("  {name:<8} {:>10.5}", b.value);
        for c in &b.contributions {
            row += &format!(" {:>10.2e}", c.u);
        }
        row += &format!(
            " {:>10.2e} {:>10.2e}  [{:.5}, {:.5}]",
            b.combined, b.expanded, b.interval[0], b.interval[1]
        );
        if b.interval_from == fit::budget::IntervalFrom::RefitEnds {
            row += &format!(" ({}: not linear in a source)", b.interval_from.describe());
        }
        println!("{row}");
    }
    if !budget.departure.is_empty() {
        let departure: Vec<String> = budget
            .departure
            .iter()
            .map(|d| {
                let std = d.std.map(|s| format!(" ± {s:.2}")).unwrap_or_default();
                match d.theta_l {
                    Some(t) => format!("{} (θL {t}) {:+.2}{std}", short(&d.source), d.z),
                    None => format!("{} {:+.2}{std}", short(&d.source), d.z),
                }
            })
            .collect();
        println!(
            "  the lines are taken with the setup departing as the residuals identify it (in u; \
             not applied to the values): {}",
            departure.join(", ")
        );
    } else {
        println!(
            "  the residuals identify no departure of the setup from the stated one (what they \
             show beyond the noise is the misfit line)"
        );
    }
    if let Some(mc) = &budget.monte_carlo {
        println!(
            "  Monte Carlo ({} draws): standard deviation, 95 % coverage interval",
            mc.draws
        );
        for (((name, _), d), a) in named.iter().zip(mc.parameters.flat()).zip(&mc.agreement) {
            let holds = match a.holds {
                fit::agreement::Holds::Both => "agree".to_string(),
                fit::agreement::Holds::LawOfPropagation => {
                    format!("the budget's holds: {}", a.reason)
                }
                fit::agreement::Holds::MonteCarlo => {
                    format!("the Monte Carlo's holds: {}", a.reason)
                }
            };
            println!(
                "  {name:<8} {:>10.2e}  [{:.5}, {:.5}]  ends {:.0} % of the width apart: {holds}",
                d.std,
                d.interval[0],
                d.interval[1],
                100.0 * a.end_offset
            );
        }
    }
}

/// A budget line's column heading.
fn short(source: &str) -> &str {
    match source {
        "white_reflectance" => "white",
        "camera_offset" => "cam offset",
        "camera_distance" => "cam dist",
        "light_distance" => "light dist",
        "cylinder_tilt" => "tilt",
        "arm_zero" => "arm zero",
        "arm_angle" => "arm angle",
        other => other,
    }
}

/// The candidates' scores and the reason for the choice.
fn print_selection(selection: &Selection) {
    let score = match selection.criterion {
        Criterion::LeaveOneThetaLOut => "held-out loss",
        Criterion::Bic => "BIC",
    };
    let value = |v: Option<f64>| v.map_or("-".to_string(), |v| format!("{v:.4}"));
    println!(
        "candidate                            params  {score:>13}  held out: ΔE_u′v′ (all, lobe)  \
         ΔErr_p R G B (all)"
    );
    for (i, c) in selection.candidates.iter().enumerate() {
        let err_p = c
            .held_out_err_p
            .map_or("-".to_string(), |e| e.map(|x| format!("{x:.4}")).join(" "));
        println!(
            "{} {:<35} {:>6}  {:>13}  {:>8} {:>8}  {err_p}{}",
            if i == selection.chosen { "*" } else { " " },
            c.form.label(),
            c.parameters,
            c.score.map_or("failed".to_string(), |s| format!("{s:.6}")),
            value(c.held_out_delta_e_uv),
            value(c.held_out_delta_e_uv_lobe),
            c.error
                .as_ref()
                .map_or(String::new(), |e| format!("  ({e})")),
        );
    }
    println!("chosen: {}", selection.reason);
}
