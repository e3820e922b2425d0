//! `gonio study`: fit every non-empty combination of the θL in a samples CSV with both
//! models, score each fit against a reference, and write the tables and the paper's
//! figures (see `gonio_processing::study`).

use std::path::PathBuf;

use anyhow::Context;
use gonio_processing::brdf::{Model, Roughness};
use gonio_processing::color::CameraModel;
use gonio_processing::fit::LOCAL_MINIMUM_MARGIN;
use gonio_processing::reference::Reference;
use gonio_processing::samples;
use gonio_processing::study::{self, StudyOptions, Variant};

use crate::progress;

use super::output::write_output_files;

mod held_out;

/// Which roughness forms a study fits.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum RoughnessChoice {
    /// One m shared by R, G, B (paper eq. 6, 7).
    Shared,
    /// One m per channel (paper eq. 8, 9), for goniochromatic samples.
    PerChannel,
    /// Both forms: the comparison the paper makes for its goniochromatic sample.
    Both,
}

impl RoughnessChoice {
    fn forms(self) -> &'static [Roughness] {
        match self {
            RoughnessChoice::Shared => &[Roughness::Shared],
            RoughnessChoice::PerChannel => &[Roughness::PerChannel],
            RoughnessChoice::Both => &[Roughness::Shared, Roughness::PerChannel],
        }
    }
}

/// Arguments of `gonio study`.
#[derive(clap::Args)]
pub struct Args {
    /// Samples CSV (`theta_l,theta_i,theta_r,r,g,b`).
    pub samples: PathBuf,
    /// Reference CSV (`theta_i,theta_r,390,...,730` spectral radiance factor); required
    /// unless `--held-out`.
    #[arg(long, required_unless_present = "held_out")]
    pub reference: Option<PathBuf>,
    /// Instead of every combination against a reference: leave each θL out in turn, fit
    /// the others and score the left-out θL's own samples (all points and the specular
    /// lobe), then choose the model as `gonio fit --model auto` does. Writes
    /// `held_out.csv` and `held_out.json`. Takes no `--reference`.
    #[arg(long, conflicts_with = "reference")]
    pub held_out: bool,
    /// Output directory for the tables and figures (created if missing).
    #[arg(long)]
    pub out: PathBuf,
    /// Models to fit, comma-separated.
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "cook-torrance,ward,cook-torrance-fresnel"
    )]
    pub models: Vec<Model>,
    /// Roughness forms to fit: `both` for a goniochromatic sample.
    #[arg(long, value_enum, default_value_t = RoughnessChoice::Shared)]
    pub roughness: RoughnessChoice,
    /// Skip the Nelder–Mead comparison (local-minimum count).
    #[arg(long)]
    pub no_nelder_mead: bool,
    /// Relative loss excess over the robust fit at which a Nelder–Mead fit counts as a
    /// local minimum.
    #[arg(long, default_value_t = LOCAL_MINIMUM_MARGIN)]
    pub local_minimum_margin: f64,
    /// Sample name shown in the figure titles.
    #[arg(long, default_value = "")]
    pub name: String,
    /// Fit on every N-th sample of each θL (pixel-column stride); scores use all samples.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..))]
    pub stride: u32,
    /// Go on when the samples lack a θL that the plan.json beside them names (a scan
    /// directory's samples.csv).
    #[arg(long)]
    pub allow_missing: bool,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    if !(args.local_minimum_margin.is_finite() && args.local_minimum_margin >= 0.0) {
        anyhow::bail!(
            "--local-minimum-margin must be a finite number ≥ 0, got {}",
            args.local_minimum_margin
        );
    }
    // Both readers name the file in their errors.
    let samples = samples::read_csv(&args.samples)?;
    super::plan_check::require_planned_theta_l(
        &args.samples,
        &samples::distinct_theta_l(&samples),
        args.allow_missing,
    )?;
    let mut variants = Vec::new();
    for &model in &args.models {
        for &roughness in args.roughness.forms() {
            let variant = Variant { model, roughness };
            if !variants.contains(&variant) {
                variants.push(variant);
            }
        }
    }
    let Some(reference) = &args.reference.as_ref().filter(|_| !args.held_out) else {
        return held_out::run(&args, &samples, &variants);
    };
    let reference = Reference::read_csv(reference)?;
    let options = StudyOptions {
        variants,
        compare_nelder_mead: !args.no_nelder_mead,
        local_minimum_margin: args.local_minimum_margin,
        stride: args.stride as usize,
    };
    let bar = progress::bar(0, "fits");
    bar.set_message("studying");
    let report = study::run_study_with_progress(
        &samples,
        &reference,
        &CameraModel::builtin(),
        &options,
        |done, total| {
            bar.set_length(total as u64);
            bar.set_position(done as u64);
        },
    );
    bar.finish_and_clear();
    let report = report.with_context(|| format!("studying {}", args.samples.display()))?;
    let written = write_output_files(&args.out, |dir| {
        Ok(study::write_outputs(&report, dir, &args.name)?)
    })?;

    println!(
        "{} θL, {} combinations × {} variants = {} fits on {} samples, scored at {} points in {:.2} s",
        report.theta_l.len(),
        report.results.len() / options.variants.len(),
        options.variants.len(),
        report.results.len(),
        samples.len(),
        report.points.len(),
        report.seconds
    );
    println!(
        "variant  n_θL  median ΔErr_p(G)  median ΔE_u′v′  held out: median ΔErr_p(R, G, B)  median ΔE_u′v′  \
         95 % half-width (median, relative): Ks_G  m  NM above robust"
    );
    let median = |b: &Option<study::boxplot::BoxStats>| {
        b.as_ref()
            .map_or("-".to_string(), |b| format!("{:.4}", b.median))
    };
    for g in report.summary() {
        println!(
            "{:<33} {:>2}  {:>8}  {:>8}  {:>8} {:>8} {:>8}  {:>8}  {:>8} {:>8}  {}/{}{}",
            g.variant.label(),
            g.size,
            median(&g.err_p[1]),
            median(&g.delta_e_uv),
            median(&g.held_out_err_p[0]),
            median(&g.held_out_err_p[1]),
            median(&g.held_out_err_p[2]),
            median(&g.held_out_delta_e_uv),
            median(&g.ks_g_ci95_relative),
            median(&g.m_ci95_relative),
            g.nelder_mead_above,
            g.nelder_mead_compared,
            if g.failed > 0 {
                format!("  ({} fits failed)", g.failed)
            } else {
                String::new()
            }
        );
    }
    println!(
        "held out, every combination that leaves a θL out: median ΔErr_p (R, G, B), median ΔE_u′v′"
    );
    for h in report.held_out_summary() {
        println!(
            "{:<33} {:>2} fits  {:>8} {:>8} {:>8}  {:>8}",
            h.variant.label(),
            h.combinations,
            median(&h.err_p[0]),
            median(&h.err_p[1]),
            median(&h.err_p[2]),
            median(&h.delta_e_uv),
        );
    }
    for path in written {
        println!("wrote {}", path.display());
    }
    Ok(())
}
