//! `gonio colour`: CIELAB at the standard aspecular angles of 45° illumination, each
//! coordinate with its expanded uncertainty, from a fit JSON or a scan directory (its
//! samples.csv and fit-auto.json); see `gonio_processing::multi_angle` and
//! docs/ARCHITECTURE.md, "Multi-angle colour".

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{anyhow, Context};
use gonio_files::input::{read_input_to_string, MAX_SMALL_FILE_BYTES};
use gonio_files::output::write_atomically;
use gonio_processing::color::geometry::parse_geometry;
use gonio_processing::color::observer::Conditions;
use gonio_processing::color::transform::ColourTransform;
use gonio_processing::color::CameraModel;
use gonio_processing::fit::FitResult;
use gonio_processing::multi_angle::{colour, ColourReport, Measured, Origin};
use gonio_processing::samples::{self, Sample};

/// The fit a scan directory's colour is taken from, in order of preference.
const SCAN_FITS: [&str; 2] = ["fit-auto.json", "fit-cook-torrance.json"];

/// How a colour is computed: the options `colour` and `compare` share.
#[derive(clap::Args, Clone)]
pub struct Options {
    /// Geometries: `astm-e2194` (15°, 45°, 110°), `astm-e2539` (−15°, 15°, 25°, 45°, 75°,
    /// 110°) or a list of aspecular angles in degrees (`15,45,110`); 45° illumination.
    #[arg(long, default_value = "astm-e2539", allow_hyphen_values = true)]
    geometry: String,
    /// Illuminant and observer: `D65/10` or `D50/2`.
    #[arg(long, default_value = "D65/10")]
    conditions: String,
    /// With a fit JSON: the samples CSV it was fitted to, whose table gives the colour
    /// inside the measured (θh, θd) range.
    #[arg(long)]
    samples: Option<PathBuf>,
}

/// Arguments of `gonio colour`.
#[derive(clap::Args)]
pub struct Args {
    /// A fit JSON, or a scan directory holding samples.csv and fit-auto.json.
    input: PathBuf,
    #[command(flatten)]
    options: Options,
    /// Output: colour.json, or a CSV by the extension `.csv`.
    #[arg(long)]
    out: PathBuf,
    /// Also write the table as CSV here.
    #[arg(long)]
    csv: Option<PathBuf>,
}

/// The files the colour of `input` is read from: `input` itself, a scan directory's
/// samples.csv and fit JSONs, and `--samples`.
pub(super) fn inputs_of(input: &Path, options: &Options) -> Vec<PathBuf> {
    let mut inputs = super::output::scan_results(input);
    inputs.push(input.to_path_buf());
    inputs.extend(options.samples.clone());
    inputs
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let inputs = inputs_of(&args.input, &args.options);
    for out in std::iter::once(&args.out).chain(&args.csv) {
        super::output::refuse_overwriting(out, &inputs, &[])?;
    }
    let report = report(&args.input, &args.options)?;
    let is_csv = args.out.extension().is_some_and(|e| e == "csv");
    let text = if is_csv {
        csv(&report)
    } else {
        serde_json::to_string_pretty(&report)? + "\n"
    };
    write_atomically(&args.out, text.as_bytes())
        .with_context(|| format!("writing {}", args.out.display()))?;
    if let Some(path) = &args.csv {
        write_atomically(path, csv(&report).as_bytes())
            .with_context(|| format!("writing {}", path.display()))?;
    }
    print!("{}", summary(&report));
    Ok(())
}

/// The colour of `input` (a fit JSON, a scan directory, or a colour.json already made,
/// which is read as it is).
pub fn report(input: &Path, options: &Options) -> anyhow::Result<ColourReport> {
    let conditions = Conditions::parse(&options.conditions).ok_or_else(|| {
        anyhow!(
            "--conditions {}: expected D65/10 or D50/2",
            options.conditions
        )
    })?;
    let aspecular = parse_geometry(&options.geometry)
        .map_err(|e| anyhow!("--geometry {}: {e}", options.geometry))?;
    let (fit_path, samples_path) = if input.is_dir() {
        let fit = SCAN_FITS
            .iter()
            .map(|name| input.join(name))
            .find(|p| p.is_file())
            .ok_or_else(|| {
                anyhow!(
                    "{}: no {} in the scan directory",
                    input.display(),
                    SCAN_FITS.join(" or ")
                )
            })?;
        (
            fit,
            Some(
                options
                    .samples
                    .clone()
                    .unwrap_or_else(|| input.join("samples.csv")),
            ),
        )
    } else {
        (input.to_path_buf(), options.samples.clone())
    };
    let text = read_input_to_string(&fit_path, MAX_SMALL_FILE_BYTES)
        .with_context(|| format!("reading {}", fit_path.display()))?;
    let value: serde_json::Value = serde_json::from_str(&text)
        .with_context(|| format!("{} is not JSON", fit_path.display()))?;
    if value.get("angles").is_some() {
        return serde_json::from_value(value)
            .with_context(|| format!("{} is not a colour.json", fit_path.display()));
    }
    let fit: FitResult = serde_json::from_value(value)
        .with_context(|| format!("{} is not a fit JSON", fit_path.display()))?;
    let samples: Option<Vec<Sample>> = samples_path
        .map(|p| samples::read_csv(&p).with_context(|| format!("reading {}", p.display())))
        .transpose()?;
    let measured = samples
        .as_deref()
        .map(|samples| Measured::of(&fit, samples))
        .transpose()
        .context("the samples' table")?;
    let transform = ColourTransform::new(&CameraModel::builtin(), conditions)?;
    Ok(colour(&fit, measured.as_ref(), &transform, &aspecular)?)
}

/// The table as CSV: one row per angle, values and expanded uncertainties.
pub fn csv(report: &ColourReport) -> String {
    let mut out = String::from(
        "aspecular,theta_i,theta_r,origin,L,U_L,a,U_a,b,U_b,C,U_C,h,U_h,beyond_data\n",
    );
    for a in &report.angles {
        let _ = write!(
            out,
            "{},{},{},{}",
            a.aspecular,
            a.theta_i,
            a.theta_r,
            origin(a.origin)
        );
        for c in [a.l, a.a, a.b, a.c, a.h] {
            let _ = write!(out, ",{:.4},{:.4}", c.value, c.expanded);
        }
        let _ = writeln!(out, ",{}", a.beyond_data);
    }
    out
}

fn origin(o: Origin) -> &'static str {
    match o {
        Origin::Data => "data",
        Origin::Model => "model",
    }
}

/// What `gonio colour` prints.
fn summary(report: &ColourReport) -> String {
    let mut out = format!(
        "{} ({}), values ± U (k = {}); transform ΔE00 median {:.2}, p95 {:.2} over its test spectra\n",
        report.conditions.name(),
        report.model,
        report.coverage_factor,
        report.transform.delta_e00_median,
        report.transform.delta_e00_p95
    );
    out.push_str(
        "  as°  from    L*              a*              b*              C*              h°\n",
    );
    for a in &report.angles {
        let _ = write!(out, "{:>5} {:<6}", a.aspecular, origin(a.origin));
        for c in [a.l, a.a, a.b, a.c, a.h] {
            let _ = write!(out, " {:>7.2} ± {:<5.2}", c.value, c.expanded);
        }
        if a.beyond_data {
            out.push_str("  beyond the data");
        }
        out.push('\n');
    }
    if let Some(fi) = report.flop_index {
        let _ = writeln!(out, "flop index {:.2} ± {:.2}", fi.value, fi.expanded);
    }
    for note in &report.notes {
        let _ = writeln!(out, "note: {note}");
    }
    out
}
