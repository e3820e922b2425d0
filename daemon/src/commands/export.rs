//! `gonio export`: a fit JSON → a Mitsuba 3 BSDF (XML) or a BRDF table on a (θi, θr)
//! grid (CSV or JSON by the output's extension); see `gonio_processing::export`.

use std::path::PathBuf;

use anyhow::{bail, Context};
use gonio_files::input::{read_input_to_string, MAX_SMALL_FILE_BYTES};
use gonio_files::output::write_atomically;
use gonio_processing::color::CameraModel;
use gonio_processing::export;
use gonio_processing::fit::FitResult;

/// What to write.
#[derive(Clone, Copy, clap::ValueEnum)]
enum Format {
    /// Mitsuba 3 scene file with the fit's BSDF (id `gonio-fit`); Cook–Torrance and Ward.
    Mitsuba,
    /// The fitted BRDF on an in-plane (θi, θr) grid: `.csv` or `.json` by the extension.
    Table,
}

/// Arguments of `gonio export`.
#[derive(clap::Args)]
pub struct Args {
    /// Fit JSON written by `gonio fit` (or a scan's fit-*.json).
    fit: PathBuf,
    /// Output format.
    #[arg(long, value_enum)]
    format: Format,
    /// Output file.
    #[arg(long)]
    out: PathBuf,
    /// Table: grid step in degrees [default: 1].
    #[arg(long)]
    step: Option<f64>,
    /// Table: the grid spans −MAX…MAX degrees in θi and θr [default: 85].
    #[arg(long)]
    max_angle: Option<f64>,
}

/// The table's grid step and extent unless given, degrees.
const TABLE_STEP_DEG: f64 = 1.0;
const TABLE_MAX_ANGLE_DEG: f64 = 85.0;

pub fn run(args: Args) -> anyhow::Result<()> {
    if matches!(args.format, Format::Mitsuba) && (args.step.is_some() || args.max_angle.is_some()) {
        anyhow::bail!(
            "--step and --max-angle shape a table: with --format mitsuba they do not apply"
        );
    }
    super::output::refuse_overwriting(&args.out, std::slice::from_ref(&args.fit), &[])?;
    let text = read_input_to_string(&args.fit, MAX_SMALL_FILE_BYTES)
        .with_context(|| format!("reading {}", args.fit.display()))?;
    let fit: FitResult = serde_json::from_str(&text)
        .with_context(|| format!("{} is not a fit JSON", args.fit.display()))?;
    let white = CameraModel::builtin().white_rgb();
    let written = match args.format {
        Format::Mitsuba => export::mitsuba_xml(&fit, white)?,
        Format::Table => {
            let rows = export::table(
                &fit,
                white,
                args.step.unwrap_or(TABLE_STEP_DEG),
                args.max_angle.unwrap_or(TABLE_MAX_ANGLE_DEG),
            )?;
            match args.out.extension().and_then(|e| e.to_str()) {
                Some("csv") => export::table_csv(&rows),
                Some("json") => {
                    serde_json::to_string_pretty(&export::table_json(&fit, white, &rows))? + "\n"
                }
                _ => bail!(
                    "--out {}: a table is written as .csv or .json",
                    args.out.display()
                ),
            }
        }
    };
    write_atomically(&args.out, written.as_bytes())
        .with_context(|| format!("writing {}", args.out.display()))?;
    // What was written: the measured table when the fit predicts with one.
    let source = if fit.table.is_some() {
        "measured (θh, θd) table".to_owned()
    } else {
        format!("{} fit ({})", fit.model, fit.roughness)
    };
    let form = match args.format {
        Format::Mitsuba => "Mitsuba 3 BSDF",
        Format::Table => "BRDF on a (θi, θr) grid",
    };
    println!("{source} as a {form} -> {}", args.out.display());
    Ok(())
}
