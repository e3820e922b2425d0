//! `gonio calibrate`: estimate a scan's setup from its own captures.

use std::path::{Path, PathBuf};

use anyhow::Context;
use gonio_files::output::write_atomically;
use gonio_processing::calibrate::{self, CalibrateOptions, Calibration, Estimate};
use gonio_processing::extract::read_setup;

/// Arguments of `gonio calibrate`.
#[derive(clap::Args)]
pub struct Args {
    /// Scan directory: captures (TIFF or camera raw with .json sidecars) and setup.json.
    pub dir: PathBuf,
    /// Output setup JSON: the setup with the estimated fields, and under `calibration`
    /// every estimate with its standard uncertainty and the fit's residuals.
    #[arg(long)]
    pub out: PathBuf,
    /// The known setup to start from (radius, focal length, pixel pitch, distances),
    /// instead of DIR/setup.json.
    #[arg(long)]
    pub setup: Option<PathBuf>,
    /// Go on when the directory lacks a θL or frame its plan.json names, or holds an
    /// image without its sidecar (or a sidecar without its image); says what is missing.
    #[arg(long)]
    pub allow_missing: bool,
}

fn show(name: &str, estimate: Option<Estimate>, prior: f64, unit: &str) -> String {
    match estimate {
        Some(e) => format!("{name} {:.4} ± {:.4}{unit}", e.value, e.stderr),
        None => format!("{name} {prior}{unit} (not estimated: the prior's)"),
    }
}

pub fn run(args: Args) -> anyhow::Result<()> {
    super::output::refuse_overwriting(&args.out, args.setup.as_slice(), &[&args.dir])?;
    super::plan_check::require_whole(&args.dir, args.allow_missing)?;
    let prior_path = args.setup.unwrap_or_else(|| args.dir.join("setup.json"));
    let prior = read_setup(&prior_path)?;
    let calibration = calibrate::calibrate_scan(&args.dir, &prior, &CalibrateOptions::default())
        .with_context(|| format!("calibrating {}", args.dir.display()))?;
    let mut text = serde_json::to_string_pretty(&calibration.setup_json())?;
    text.push('\n');
    write_atomically(&args.out, text.as_bytes())
        .with_context(|| format!("writing {}", args.out.display()))?;
    print_summary(&calibration, &prior, &args.out);
    super::plan_check::say_if_unplanned(&args.dir);
    Ok(())
}

fn print_summary(c: &Calibration, prior: &gonio_processing::geometry::Setup, out: &Path) {
    println!("calibrated from {} θL: {}", c.theta_l.len(), out.display());
    println!(
        "  {}",
        show(
            "camera offset",
            c.camera_offset_mm,
            prior.camera_offset_mm,
            " mm"
        )
    );
    println!(
        "  {}",
        show(
            "camera distance",
            c.camera_distance_mm,
            prior.camera_distance_mm,
            " mm"
        )
    );
    println!(
        "  {}",
        show(
            "cylinder tilt",
            c.cylinder_tilt_deg,
            prior.cylinder_tilt_deg,
            "°"
        )
    );
    println!(
        "  {}",
        show(
            "arm zero offset",
            c.arm_zero_offset_deg,
            prior.arm_zero_offset_deg,
            "°"
        )
    );
    for (name, estimate, value) in [
        ("camera yaw", c.camera_yaw_deg, prior.camera_yaw_deg),
        ("camera roll", c.camera_roll_deg, prior.camera_roll_deg),
    ] {
        println!("  {}", show(name, estimate, value, "°"));
    }
    println!(
        "  strip rows: sample {:.1} ± {:.1}, white {:.1} ± {:.1}",
        c.sample_row.value, c.sample_row.stderr, c.white_row.value, c.white_row.stderr
    );
    println!(
        "  axis in the image: column {:.2} on the principal row, {:.3}° from vertical",
        c.axis_in_image.column, c.axis_in_image.tilt_deg
    );
    let r = &c.residuals;
    let px = |v: Option<f64>| v.map_or("-".to_owned(), |v| format!("{v:.3}"));
    println!(
        "  residuals (rms): limbs {} px ({}), terminators {} px ({} rows), specular peaks {}° ({} rows); χ²/dof {:.2}",
        px(r.limb_px),
        r.limbs,
        px(r.terminator_px),
        r.terminator_rows,
        px(r.peak_deg),
        r.peak_rows,
        r.chi2_per_dof
    );
    if r.chi2_per_dof > 4.0 {
        println!(
            "  warning: χ²/dof {:.1}: the geometry model does not fit these captures well",
            r.chi2_per_dof
        );
    }
    for note in &c.notes {
        println!("  note: {note}");
    }
}
