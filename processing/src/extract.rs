//! Scan directory → radiance-factor samples in the camera-RGB domain (paper §2.2).
//!
//! `DIR/setup.json` holds the [`Setup`] (unless [`ExtractOptions::setup`] names
//! another file); captures are found recursively (TIFF or camera
//! raw with a JSON sidecar) and grouped by the sidecar's θL. Each group is merged
//! ([`hdr::merge`]) into one radiance map, of the strip rows only unless the maps are
//! wanted as files ([`ExtractOptions::hdr_dir`]). Each pixel column gives one sample:
//! the mean of the [`STRIP_ROWS`] rows around each strip's centre row, with the mean of
//! the true 3D geometry of those sample pixels (the point on the cylinder, its normal,
//! the light and the camera: [`Setup::pixel_geometry`]). Where the sample strip lies on
//! a peak too sharp to average (β curves across the rows so that their mean is off the
//! centre row's value by more than 0.1 % and more than the rows' noise explains), the
//! sample is the centre row alone, with that pixel's geometry. Then per channel c
//!
//! β_c = (L̄_sample,c / L̄_white,c) · (Ē_white / Ē_sample) · ρ_white · W_c,
//!
//! with Ē the mean irradiance cos θi/|L − P|² of each strip's pixels (1 when the strips
//! lie symmetric about the light's plane), ρ_white the white reference's reflectance
//! (setup.json's `white_reflectance`; 1 for a perfect reflecting diffuser) and
//! W_c = k Σ c̄ I the camera RGB of a perfect white (eq. 4), so β is in the camera-RGB
//! domain where a perfect white has β_G = 100. Why one sample per column and not per
//! pixel row: docs/ARCHITECTURE.md, "Angles and geometry".
//!
//! Captures may be full resolution (as `setup.image_width`) or 2×2-superpixel raw
//! (half of it): columns and rows are mapped accordingly. Columns are dropped, and
//! counted, when a strip pixel misses the cylinder or is unlit (|θi| ≥ 90°) or the
//! sample lies past the grazing limit. Single values (one channel of one column) are
//! dropped, and counted per channel, when a strip pixel is clipped in every exposure,
//! the sample is below the noise floor in every exposure, or the white is too dark to
//! divide by; the sample keeps its other channels ([`Sample::dropped`]), and a column
//! that keeps none is dropped.
#![doc = include_str!("extract.md")]

use std::collections::BTreeMap;
use std::fs;
use std::path::{Path, PathBuf};

use gonio_files::scan_layout::theta_dir_name;
use rayon::prelude::*;

use crate::capture::{self, Frame};
use crate::geometry::Setup;
use crate::hdr;
use crate::samples::Sample;
use crate::setup_uncertainty::{Input, Source};

pub(crate) mod captures;
mod columns;
mod drops;
mod error;
mod layout;
mod options;
mod sensitivity;
mod sharp;
mod strip;

use captures::find_captures;
use columns::{extract_theta, ThetaSamples};
use layout::StripLayout;
use options::check_options;
use sensitivity::{add_sensitivities, Stated};

pub use drops::DropCounts;
pub use error::ExtractError;
pub(crate) use layout::capture_scale;
pub use layout::STRIP_ROWS;
pub use options::ExtractOptions;

/// What one θL contributed.
#[derive(Debug, Clone, PartialEq)]
pub struct ThetaSummary {
    pub theta_l: f64,
    pub frames: usize,
    pub samples: usize,
    /// Of the samples, those read from their strip's centre row alone (on a peak too
    /// sharp to average over the rows).
    pub centre_rows: usize,
    pub dropped: DropCounts,
}

/// Where the white reflectance an extraction used came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WhiteSource {
    /// [`ExtractOptions::white_reflectance`].
    Option,
    /// setup.json's `white_reflectance`.
    Setup,
    /// Neither gave one: 1, a perfect reflecting diffuser.
    Assumed,
}

/// Result of [`extract_scan`]: samples ordered by θL then column.
#[derive(Debug, Clone, PartialEq)]
pub struct Extraction {
    pub samples: Vec<Sample>,
    pub dropped: DropCounts,
    pub per_theta: Vec<ThetaSummary>,
    /// Image files of capture type that were skipped for lack of a sidecar.
    pub skipped_without_sidecar: Vec<PathBuf>,
    /// The white reference's reflectance used, and where it came from.
    pub white_reflectance: f64,
    pub white_source: WhiteSource,
    /// The standard uncertainties the samples' uncertainty was computed with, when it was.
    pub inputs: Option<[Input; Source::COUNT]>,
}

/// Extracts the samples of the scan in `dir`.
pub fn extract_scan(dir: &Path, options: &ExtractOptions) -> Result<Extraction, ExtractError> {
    extract_scan_with_progress(dir, options, |_, _| {})
}

/// Capture paths grouped by θL (degrees, ascending).
pub type ThetaGroups = Vec<(f64, Vec<PathBuf>)>;

/// The captures of a scan directory grouped by θL, and the image files skipped for lack
/// of a sidecar. Errors when no capture has a sidecar.
pub fn theta_groups(dir: &Path) -> Result<(ThetaGroups, Vec<PathBuf>), ExtractError> {
    let mut images = Vec::new();
    find_captures(dir, &mut images)?;
    images.sort();
    let (with_sidecar, skipped_without_sidecar): (Vec<PathBuf>, Vec<PathBuf>) = images
        .into_iter()
        .partition(|p| capture::sidecar_path(p).is_file());
    // Group by θL (sidecars only; images are decoded per group).
    let mut groups: BTreeMap<i64, (f64, Vec<PathBuf>)> = BTreeMap::new();
    for path in with_sidecar {
        let theta_l = capture::read_sidecar(&path)?.theta_l;
        groups
            .entry(theta_key(theta_l))
            .or_insert_with(|| (theta_l, Vec::new()))
            .1
            .push(path);
    }
    if groups.is_empty() {
        return Err(ExtractError::NoCaptures {
            dir: dir.to_path_buf(),
        });
    }
    Ok((groups.into_values().collect(), skipped_without_sidecar))
}

/// [`extract_scan`], calling `progress(done, total)` before the first θL and after each.
pub fn extract_scan_with_progress(
    dir: &Path,
    options: &ExtractOptions,
    progress: impl Fn(usize, usize),
) -> Result<Extraction, ExtractError> {
    check_options(options)?;
    let setup = match &options.setup {
        Some(path) => read_setup(path)?,
        None => read_setup(&dir.join("setup.json"))?,
    };
    let (white_reflectance, white_source) =
        match (options.white_reflectance, setup.white_reflectance) {
            (Some(given), _) => (given, WhiteSource::Option),
            (None, Some(recorded)) => (recorded, WhiteSource::Setup),
            (None, None) => (1.0, WhiteSource::Assumed),
        };
    let (mut groups, skipped_without_sidecar) = theta_groups(dir)?;
    if let Some(wanted) = options.theta_l {
        groups.retain(|(theta_l, _)| theta_key(*theta_l) == theta_key(wanted));
        if groups.is_empty() {
            return Err(ExtractError::NoCaptures {
                dir: dir.to_path_buf(),
            });
        }
    }
    if let Some(hdr_dir) = &options.hdr_dir {
        fs::create_dir_all(hdr_dir).map_err(|error| ExtractError::Walk {
            path: hdr_dir.clone(),
            error,
        })?;
    }
    let total = groups.len();
    progress(0, total);
    let mut extraction = Extraction {
        samples: Vec::new(),
        dropped: DropCounts::default(),
        per_theta: Vec::new(),
        skipped_without_sidecar,
        white_reflectance,
        white_source,
        inputs: options.uncertainty.then(|| setup.inputs()),
    };
    for (done, (theta_l, paths)) in groups.into_iter().enumerate() {
        // Without a map to write, only the strip rows are kept and merged.
        let keep_full = options.hdr_dir.is_some();
        // Each frame, its strips' layout, and its whole size (width, height).
        let frames: Vec<(Frame, StripLayout, (usize, usize))> = paths
            .par_iter()
            .map(|path| {
                if keep_full {
                    let frame = Frame::read(path)?;
                    let layout = StripLayout::new(&setup, frame.width, frame.height, theta_l)?;
                    let size = (frame.width, frame.height);
                    return Ok((frame, layout, size));
                }
                let mut layout = None;
                let frame = Frame::read_rows(path, |width, height| {
                    let full = StripLayout::new(&setup, width, height, theta_l)?;
                    layout = Some((full, (width, height)));
                    Ok::<_, ExtractError>(full.bands())
                })?;
                let (layout, size) = layout.expect("the row selector ran");
                Ok((frame, layout.strips_only(), size))
            })
            .collect::<Result<_, ExtractError>>()?;
        // Frames of two sizes (a full one and a half-size one both fit the setup) are
        // named by their whole sizes, not by the strip rows read of them.
        let (layout, size) = (frames[0].1, frames[0].2);
        if let Some((frame, _, found)) = frames.iter().find(|f| f.2 != size) {
            return Err(ExtractError::Hdr {
                theta_l,
                error: hdr::HdrError::SizeMismatch {
                    path: frame.path.clone(),
                    width: size.0,
                    height: size.1,
                    found_w: found.0,
                    found_h: found.1,
                },
            });
        }
        let frames: Vec<Frame> = frames.into_iter().map(|(frame, _, _)| frame).collect();
        let map = hdr::merge(&frames, &options.merge)
            .map_err(|error| ExtractError::Hdr { theta_l, error })?;
        if let Some(hdr_dir) = &options.hdr_dir {
            map.write_exr(&hdr_dir.join(format!("{}.exr", theta_dir_name(theta_l))))
                .map_err(|error| ExtractError::Hdr { theta_l, error })?;
        }
        let ThetaSamples {
            mut samples,
            columns,
            dropped,
            centre_rows,
            white_angular,
            geometry,
            centre_row,
        } = extract_theta(&setup, &map, &layout, theta_l, options, white_reflectance);
        if options.uncertainty {
            let stated = Stated {
                layout: &layout,
                theta_l,
                columns: &columns,
                geometry: &geometry,
                centre_row: &centre_row,
            };
            add_sensitivities(
                &setup,
                &stated,
                options.grazing_limit_deg,
                (&mut samples, &white_angular),
            );
            // Stated to the digits the samples CSV holds: fits of these samples and of
            // their file are the same.
            for u in samples.iter_mut().filter_map(|s| s.uncertainty.as_mut()) {
                *u = u.as_written();
            }
        }
        extraction.per_theta.push(ThetaSummary {
            theta_l,
            frames: frames.len(),
            samples: samples.len(),
            centre_rows,
            dropped,
        });
        extraction.dropped.add(&dropped);
        extraction.samples.extend(samples);
        progress(done + 1, total);
    }
    Ok(extraction)
}

/// θL in millionths of a degree: captures of one θL share it.
fn theta_key(theta_l: f64) -> i64 {
    (theta_l * 1e6).round() as i64
}

/// Reads and validates `setup.json`.
pub fn read_setup(path: &Path) -> Result<Setup, ExtractError> {
    let setup_error = |reason: String| ExtractError::Setup {
        path: path.to_path_buf(),
        reason,
    };
    let text =
        gonio_files::input::read_input_to_string(path, gonio_files::input::MAX_SMALL_FILE_BYTES)
            .map_err(|e| setup_error(format!("cannot read: {e}")))?;
    let setup: Setup =
        serde_json::from_str(&text).map_err(|e| setup_error(format!("invalid setup JSON: {e}")))?;
    setup.validate().map_err(|error| ExtractError::Geometry {
        path: path.to_path_buf(),
        error,
    })?;
    Ok(setup)
}
