//! `gonio extract`: the captures of a scan → samples CSV.

use std::path::PathBuf;

use anyhow::bail;
use gonio_processing::extract::{self, ExtractOptions, WhiteSource};
use gonio_processing::samples;

use crate::progress;

use super::output::{refuse_overwriting, write_output};

/// Arguments of `gonio extract`.
#[derive(clap::Args)]
pub struct Args {
    /// Scan directory: setup.json plus captures (TIFF or camera raw with .json sidecars).
    dir: PathBuf,
    /// Output samples CSV (theta_l,theta_i,theta_r,r,g,b, then the 3D cosines
    /// n_dot_l,n_dot_v,n_dot_h,v_dot_h and the uncertainty columns u_*; β in camera RGB,
    /// empty where dropped).
    #[arg(long)]
    out: PathBuf,
    /// Reflectance of the white reference (1 = perfect reflecting diffuser), instead of
    /// setup.json's `white_reflectance`.
    #[arg(long)]
    white_reflectance: Option<f64>,
    /// Drop points with |θi| or |θr| above this many degrees.
    #[arg(long, default_value_t = 80.0)]
    grazing_limit: f64,
    /// Largest capture decoded, pixels (width × height as the file stores it).
    #[arg(long, default_value_t = gonio_processing::capture::DEFAULT_MAX_PIXELS)]
    max_frame_pixels: u64,
    /// Also write each θL's radiance map there as theta_l_<θL>.exr.
    #[arg(long)]
    hdr_dir: Option<PathBuf>,
    /// Setup JSON to use instead of DIR/setup.json (e.g. what `gonio calibrate` wrote).
    #[arg(long)]
    setup: Option<PathBuf>,
    /// Leave out the samples' uncertainty columns (and the extractions they take).
    #[arg(long)]
    no_uncertainty: bool,
    /// Go on when the directory lacks a θL or frame its plan.json names, or holds an
    /// image without its sidecar (or a sidecar without its image); says what is missing.
    #[arg(long)]
    allow_missing: bool,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    gonio_processing::capture::set_max_pixels(args.max_frame_pixels);
    refuse_overwriting(&args.out, args.setup.as_slice(), &[&args.dir])?;
    super::plan_check::require_whole(&args.dir, args.allow_missing)?;
    let setup_name = args.setup.as_ref().map_or_else(
        || "setup.json".to_owned(),
        |path| path.display().to_string(),
    );
    let options = ExtractOptions {
        white_reflectance: args.white_reflectance,
        grazing_limit_deg: args.grazing_limit,
        hdr_dir: args.hdr_dir,
        setup: args.setup.clone(),
        uncertainty: !args.no_uncertainty,
        ..ExtractOptions::default()
    };
    let bar = progress::bar(0, "θL");
    bar.set_message("extracting");
    let extraction = extract::extract_scan_with_progress(&args.dir, &options, |done, total| {
        bar.set_length(total as u64);
        bar.set_position(done as u64);
    });
    bar.finish_and_clear();
    let extraction = extraction?;
    if extraction.samples.is_empty() {
        bail!(
            "{}: {}",
            args.dir.display(),
            extraction.dropped.explain_empty()
        );
    }
    write_output(&args.out, |path| {
        samples::write_csv(path, &extraction.samples)
    })?;
    let d = extraction.dropped;
    let rgb = |v: [usize; 3]| format!("{}/{}/{}", v[0], v[1], v[2]);
    println!(
        "wrote {} samples from {} θL to {} (columns dropped: {} off the cylinder or unlit, {} grazing, {} with no usable channel; values dropped R/G/B: {} saturated, {} underexposed, {} dark white)",
        extraction.samples.len(),
        extraction.per_theta.len(),
        args.out.display(),
        d.off_cylinder,
        d.grazing,
        d.no_channel,
        rgb(d.saturated),
        rgb(d.underexposed),
        rgb(d.dark_white),
    );
    let centre_rows: usize = extraction.per_theta.iter().map(|t| t.centre_rows).sum();
    if centre_rows > 0 {
        println!(
            "{centre_rows} samples on a peak too sharp to average over the strip's rows read from its centre row"
        );
    }
    let source = match extraction.white_source {
        WhiteSource::Option => "--white-reflectance".to_owned(),
        WhiteSource::Setup => setup_name.clone(),
        WhiteSource::Assumed => format!("assumed: {setup_name} gives none"),
    };
    println!(
        "white reference reflectance {} ({source})",
        extraction.white_reflectance
    );
    if let Some(inputs) = &extraction.inputs {
        let listed: Vec<String> = inputs.iter().map(|i| i.describe()).collect();
        println!(
            "standard uncertainties of the setup ({setup_name}'s `uncertainty`): {}",
            listed.join(", ")
        );
    }
    super::plan_check::say_if_unplanned(&args.dir);
    Ok(())
}
