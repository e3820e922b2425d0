//! `gonio hdr`: merge a bracket of exposures into an OpenEXR radiance map.

use std::path::PathBuf;

use gonio_processing::capture::{sidecar_path, Frame};
use gonio_processing::hdr::{self, MergeMethod, MergeOptions, SATURATED, UNDEREXPOSED};

use super::output::{refuse_overwriting, write_output};
use crate::progress;

/// Merge method on the command line.
#[derive(Clone, Copy, clap::ValueEnum)]
enum Method {
    /// Linear merge for linear frames, Debevec–Malik for `"response":"nonlinear"` ones.
    Auto,
    /// Noise-weighted merge of linear counts.
    Linear,
    /// Debevec–Malik response recovery and merge.
    DebevecMalik,
}

/// Arguments of `gonio hdr`.
#[derive(clap::Args)]
pub struct Args {
    /// Output OpenEXR file (float32 RGB, exposure metadata in attributes).
    #[arg(long)]
    out: PathBuf,
    /// Merge method.
    #[arg(long, value_enum, default_value = "auto")]
    method: Method,
    /// Largest capture decoded, pixels (width × height as the file stores it).
    #[arg(long, default_value_t = gonio_processing::capture::DEFAULT_MAX_PIXELS)]
    max_frame_pixels: u64,
    /// Frames of one bracket: TIFF or camera raw files, each with a .json sidecar.
    #[arg(required = true)]
    frames: Vec<PathBuf>,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    gonio_processing::capture::set_max_pixels(args.max_frame_pixels);
    // The frames and their sidecars.
    let inputs: Vec<PathBuf> = (args.frames.iter().cloned())
        .chain(args.frames.iter().map(|f| sidecar_path(f)))
        .collect();
    refuse_overwriting(&args.out, &inputs, &[])?;
    let spinner = progress::spinner(format!("decoding {} frames", args.frames.len()));
    // Decoding is the slow part of reading: the frames are decoded in parallel.
    let frames = Frame::read_all(&args.frames)?;
    spinner.set_message(format!("merging {} frames", frames.len()));
    let options = MergeOptions {
        method: match args.method {
            Method::Auto => MergeMethod::Auto,
            Method::Linear => MergeMethod::Linear,
            Method::DebevecMalik => MergeMethod::DebevecMalik,
        },
        ..MergeOptions::default()
    };
    let map = hdr::merge(&frames, &options)?;
    spinner.set_message(format!("writing {}", args.out.display()));
    write_output(&args.out, |path| map.write_exr(path))?;
    spinner.finish_and_clear();
    println!(
        "merged {} frames ({}, {}×{}) into {}: {} saturated, {} underexposed pixels flagged",
        frames.len(),
        map.info.method,
        map.width,
        map.height,
        args.out.display(),
        map.count_flagged(SATURATED),
        map.count_flagged(UNDEREXPOSED),
    );
    Ok(())
}
