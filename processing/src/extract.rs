//! Scan directory → radiance-factor samples in the camera-RGB domain (paper §2.2).
//!
//! `DIR/setup.json` holds the [`Setup`]; captures are found recursively (TIFF or camera
//! raw with a JSON sidecar) and grouped by the sidecar's θL. Each group is merged
//! ([`hdr::merge`]) into one radiance map, of the strip rows only unless the maps are
//! wanted as files ([`ExtractOptions::hdr_dir`]); the sample and white strips are each the mean of
//! 5 rows around their centre rows; every pixel column maps to (θi, θr) through the
//! setup geometry; then per channel c
//!
//! β_c = (L_sample,c / L_white,c) · ρ_white · W_c,
//!
//! with ρ_white the white reference's reflectance (1 for a perfect reflecting
//! diffuser) and W_c = k Σ c̄ I the camera RGB of a perfect white (eq. 4), so β is in
//! the camera-RGB domain where a perfect white has β_G = 100.
//!
//! Captures may be full resolution (as `setup.image_width`) or 2×2-superpixel raw
//! (half of it): columns and rows are mapped accordingly. Columns are dropped, and
//! counted, when they miss the cylinder or are unlit (|θi| ≥ 90°), lie past the
//! grazing limit, have a clipped pixel in either strip, or see a white reference too
//! dark to divide by.

use std::collections::BTreeMap;
use std::fs;
use std::ops::Range;
use std::path::{Path, PathBuf};

use rayon::prelude::*;
use thiserror::Error;

use crate::capture::{self, CaptureError, Frame};
use crate::color::CameraModel;
use crate::geometry::{GeometryError, Setup};
use crate::hdr::{self, HdrError, HdrImage, MergeOptions, SATURATED, UNDEREXPOSED};
use crate::samples::Sample;

/// Rows averaged around each strip's centre row (paper §2.2).
pub const STRIP_ROWS: usize = 5;

/// Options of [`extract_scan`].
#[derive(Debug, Clone, PartialEq)]
pub struct ExtractOptions {
    pub merge: MergeOptions,
    /// Reflectance of the white reference (1 = perfect reflecting diffuser).
    pub white_reflectance: f64,
    /// Columns with |θi| or |θr| above this (degrees) are dropped.
    pub grazing_limit_deg: f64,
    /// Columns whose white strip (any channel) is below this fraction of the brightest
    /// white column of the same θL are dropped.
    pub min_white_fraction: f64,
    /// Camera and illuminant that define the camera-RGB domain.
    pub camera: CameraModel,
    /// When set, each θL's radiance map is written there as `theta_l_<θL>.exr`.
    pub hdr_dir: Option<PathBuf>,
}

impl Default for ExtractOptions {
    fn default() -> Self {
        Self {
            merge: MergeOptions::default(),
            white_reflectance: 1.0,
            grazing_limit_deg: 80.0,
            min_white_fraction: 0.02,
            camera: CameraModel::builtin(),
            hdr_dir: None,
        }
    }
}

/// Errors of [`extract_scan`].
#[derive(Debug, Error)]
pub enum ExtractError {
    #[error("{path}: {reason}")]
    Setup { path: PathBuf, reason: String },
    #[error("{path}: invalid setup: {error}")]
    Geometry { path: PathBuf, error: GeometryError },
    #[error("{path}: cannot list directory: {error}")]
    Walk {
        path: PathBuf,
        error: std::io::Error,
    },
    #[error("{dir}: no captures (image files with a .json sidecar) found")]
    NoCaptures { dir: PathBuf },
    #[error(transparent)]
    Capture(#[from] CaptureError),
    #[error("θL {theta_l}°: {error}")]
    Hdr { theta_l: f64, error: HdrError },
    #[error("θL {theta_l}°: captures are {width}×{height}, but the setup is {setup_width}×{setup_height} (or half of it)")]
    SizeMismatch {
        theta_l: f64,
        width: usize,
        height: usize,
        setup_width: u32,
        setup_height: u32,
    },
    #[error("{which} row {row} ± 2 lies outside the {height}-row image")]
    RowOutside {
        which: &'static str,
        row: usize,
        height: usize,
    },
    #[error("invalid extraction option: {0}")]
    Options(String),
}

/// Columns dropped, by reason (each column counts once, in the first reason that applies).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct DropCounts {
    /// The column misses the cylinder, or the point is not lit (|θi| ≥ 90°).
    pub off_cylinder: usize,
    /// |θi| or |θr| beyond the grazing limit.
    pub grazing: usize,
    /// A pixel of the sample or white strip is clipped in every exposure.
    pub saturated: usize,
    /// The white strip is too dark (or black in every exposure).
    pub dark_white: usize,
}

impl DropCounts {
    pub fn total(&self) -> usize {
        self.off_cylinder + self.grazing + self.saturated + self.dark_white
    }

    /// The reason most columns were dropped for, with its count (`None` if none was).
    pub fn dominant(&self) -> Option<(&'static str, usize)> {
        [
            ("off the cylinder or unlit", self.off_cylinder),
            ("grazing", self.grazing),
            ("saturated", self.saturated),
            ("dark white reference", self.dark_white),
        ]
        .into_iter()
        .filter(|(_, n)| *n > 0)
        .max_by_key(|(_, n)| *n)
    }

    /// Why an extraction gave no sample: the dominant reason and every count.
    pub fn explain_empty(&self) -> String {
        match self.dominant() {
            Some((reason, n)) => format!(
                "no samples: all {} columns were dropped, most ({n}) as {reason} \
                 ({} off the cylinder or unlit, {} grazing, {} saturated, {} dark white)",
                self.total(),
                self.off_cylinder,
                self.grazing,
                self.saturated,
                self.dark_white
            ),
            None => "no samples: no column of the captures was on the strips".to_owned(),
        }
    }

    fn add(&mut self, other: &DropCounts) {
        self.off_cylinder += other.off_cylinder;
        self.grazing += other.grazing;
        self.saturated += other.saturated;
        self.dark_white += other.dark_white;
    }
}

/// What one θL contributed.
#[derive(Debug, Clone, PartialEq)]
pub struct ThetaSummary {
    pub theta_l: f64,
    pub frames: usize,
    pub samples: usize,
    pub dropped: DropCounts,
}

/// Result of [`extract_scan`]: samples ordered by θL then column.
#[derive(Debug, Clone, PartialEq)]
pub struct Extraction {
    pub samples: Vec<Sample>,
    pub dropped: DropCounts,
    pub per_theta: Vec<ThetaSummary>,
    /// Image files of capture type that were skipped for lack of a sidecar.
    pub skipped_without_sidecar: Vec<PathBuf>,
}

/// Extracts the samples of the scan in `dir`.
pub fn extract_scan(dir: &Path, options: &ExtractOptions) -> Result<Extraction, ExtractError> {
    extract_scan_with_progress(dir, options, |_, _| {})
}

/// [`extract_scan`], calling `progress(done, total)` before the first θL and after each.
pub fn extract_scan_with_progress(
    dir: &Path,
    options: &ExtractOptions,
    progress: impl Fn(usize, usize),
) -> Result<Extraction, ExtractError> {
    check_options(options)?;
    let setup = read_setup(&dir.join("setup.json"))?;
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
        let key = (theta_l * 1e6).round() as i64;
        groups
            .entry(key)
            .or_insert_with(|| (theta_l, Vec::new()))
            .1
            .push(path);
    }
    if groups.is_empty() {
        return Err(ExtractError::NoCaptures {
            dir: dir.to_path_buf(),
        });
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
    };
    for (done, (theta_l, paths)) in groups.into_values().enumerate() {
        // Without a map to write, only the strip rows are kept and merged.
        let keep_full = options.hdr_dir.is_some();
        let frames: Vec<(Frame, StripLayout)> = paths
            .par_iter()
            .map(|path| {
                if keep_full {
                    let frame = Frame::read(path)?;
                    let layout = StripLayout::new(&setup, frame.width, frame.height, theta_l)?;
                    return Ok((frame, layout));
                }
                let frame = Frame::read_rows(path, |width, height| {
                    StripLayout::new(&setup, width, height, theta_l).map(|l| l.bands())
                })?;
                // The selector accepted the size: full width, or half of it for raw.
                let scale = if frame.width == setup.image_width as usize {
                    1
                } else {
                    2
                };
                Ok((frame, StripLayout::strips_only(scale)))
            })
            .collect::<Result<_, ExtractError>>()?;
        let layout = frames[0].1;
        let frames: Vec<Frame> = frames.into_iter().map(|(frame, _)| frame).collect();
        let map = hdr::merge(&frames, &options.merge)
            .map_err(|error| ExtractError::Hdr { theta_l, error })?;
        if let Some(hdr_dir) = &options.hdr_dir {
            map.write_exr(&hdr_dir.join(format!("theta_l_{theta_l:.1}.exr")))
                .map_err(|error| ExtractError::Hdr { theta_l, error })?;
        }
        let (samples, dropped) = extract_theta(&setup, &map, &layout, theta_l, options);
        extraction.per_theta.push(ThetaSummary {
            theta_l,
            frames: frames.len(),
            samples: samples.len(),
            dropped,
        });
        extraction.dropped.add(&dropped);
        extraction.samples.extend(samples);
        progress(done + 1, total);
    }
    Ok(extraction)
}

fn check_options(o: &ExtractOptions) -> Result<(), ExtractError> {
    if !(o.white_reflectance.is_finite() && o.white_reflectance > 0.0 && o.white_reflectance <= 2.0)
    {
        return Err(ExtractError::Options(format!(
            "white reflectance {} is not in (0, 2]",
            o.white_reflectance
        )));
    }
    if !(o.grazing_limit_deg.is_finite()
        && o.grazing_limit_deg > 0.0
        && o.grazing_limit_deg <= 90.0)
    {
        return Err(ExtractError::Options(format!(
            "grazing limit {}° is not in (0, 90]",
            o.grazing_limit_deg
        )));
    }
    if !(o.min_white_fraction.is_finite() && (0.0..1.0).contains(&o.min_white_fraction)) {
        return Err(ExtractError::Options(format!(
            "minimum white fraction {} is not in [0, 1)",
            o.min_white_fraction
        )));
    }
    Ok(())
}

/// Reads and validates `setup.json`.
pub fn read_setup(path: &Path) -> Result<Setup, ExtractError> {
    let setup_error = |reason: String| ExtractError::Setup {
        path: path.to_path_buf(),
        reason,
    };
    let text = fs::read_to_string(path).map_err(|e| setup_error(format!("cannot read: {e}")))?;
    let setup: Setup =
        serde_json::from_str(&text).map_err(|e| setup_error(format!("invalid setup JSON: {e}")))?;
    setup.validate().map_err(|error| ExtractError::Geometry {
        path: path.to_path_buf(),
        error,
    })?;
    Ok(setup)
}

fn find_captures(dir: &Path, out: &mut Vec<PathBuf>) -> Result<(), ExtractError> {
    let walk_error = |error| ExtractError::Walk {
        path: dir.to_path_buf(),
        error,
    };
    for entry in fs::read_dir(dir).map_err(walk_error)? {
        let entry = entry.map_err(walk_error)?;
        let path = entry.path();
        let kind = entry.file_type().map_err(walk_error)?;
        if kind.is_dir() {
            find_captures(&path, out)?;
        } else if capture::is_capture_path(&path) {
            out.push(path);
        }
    }
    Ok(())
}

/// Mean radiance of the 5 rows around `row` at column `x`, and the OR of their flags.
fn strip_mean(map: &HdrImage, x: usize, row: usize) -> ([f64; 3], u8) {
    let mut sum = [0.0; 3];
    let mut flags = 0;
    for y in row - STRIP_ROWS / 2..=row + STRIP_ROWS / 2 {
        let p = map.pixel(x, y);
        for c in 0..3 {
            sum[c] += f64::from(p[c]);
        }
        flags |= map.flags(x, y);
    }
    (sum.map(|s| s / STRIP_ROWS as f64), flags)
}

/// Where the strips lie in a capture of a given size.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct StripLayout {
    /// Sensor pixels per capture pixel: 1, or 2 for superpixel raw.
    scale: usize,
    sample_row: usize,
    white_row: usize,
}

impl StripLayout {
    fn new(setup: &Setup, width: usize, height: usize, theta_l: f64) -> Result<Self, ExtractError> {
        let (sw, sh) = (setup.image_width as usize, setup.image_height as usize);
        let scale = if (width, height) == (sw, sh) {
            1
        } else if (width, height) == (sw / 2, sh / 2) {
            2
        } else {
            return Err(ExtractError::SizeMismatch {
                theta_l,
                width,
                height,
                setup_width: setup.image_width,
                setup_height: setup.image_height,
            });
        };
        let row = |which: &'static str, sensor_row: u32| {
            let row = sensor_row as usize / scale;
            if row < STRIP_ROWS / 2 || row + STRIP_ROWS / 2 >= height {
                Err(ExtractError::RowOutside { which, row, height })
            } else {
                Ok(row)
            }
        };
        Ok(Self {
            scale,
            sample_row: row("sample", setup.sample_row)?,
            white_row: row("white", setup.white_row)?,
        })
    }

    /// The row ranges of the two strips (sample, then white).
    fn bands(&self) -> Vec<Range<usize>> {
        let half = STRIP_ROWS / 2;
        [self.sample_row, self.white_row]
            .map(|centre| centre - half..centre + half + 1)
            .to_vec()
    }

    /// The layout of a frame holding only [`StripLayout::bands`].
    fn strips_only(scale: usize) -> Self {
        let half = STRIP_ROWS / 2;
        Self {
            scale,
            sample_row: half,
            white_row: STRIP_ROWS + half,
        }
    }
}

fn extract_theta(
    setup: &Setup,
    map: &HdrImage,
    layout: &StripLayout,
    theta_l: f64,
    options: &ExtractOptions,
) -> (Vec<Sample>, DropCounts) {
    let (width, scale) = (map.width, layout.scale);
    let (sample_row, white_row) = (layout.sample_row, layout.white_row);
    let columns: Vec<_> = (0..width)
        .map(|x| {
            // Centre of the column in sensor pixels (a superpixel spans two columns).
            let u = (scale * x) as f64 + (scale as f64 - 1.0) / 2.0;
            let angles = setup.angles_at_column(u, theta_l);
            (
                angles,
                strip_mean(map, x, sample_row),
                strip_mean(map, x, white_row),
            )
        })
        .collect();
    let brightest_white = columns
        .iter()
        .filter(|(angles, _, (_, flags))| {
            angles.is_some() && flags & (SATURATED | UNDEREXPOSED) == 0
        })
        .map(|(_, _, (white, _))| white[0].min(white[1]).min(white[2]))
        .fold(0.0, f64::max);
    let threshold = options.min_white_fraction * brightest_white;
    let white_rgb = options.camera.white_rgb();
    let limit = options.grazing_limit_deg;

    let mut samples = Vec::new();
    let mut dropped = DropCounts::default();
    for (angles, (sample, sample_flags), (white, white_flags)) in columns {
        let Some(a) = angles.filter(|a| a.theta_i.abs() < 90.0) else {
            dropped.off_cylinder += 1;
            continue;
        };
        if a.theta_i.abs() > limit || a.theta_r.abs() > limit {
            dropped.grazing += 1;
        } else if (sample_flags | white_flags) & SATURATED != 0 {
            dropped.saturated += 1;
        } else if white_flags & UNDEREXPOSED != 0
            || white.iter().any(|&w| !(w > threshold && w > 0.0))
        {
            dropped.dark_white += 1;
        } else {
            let rgb =
                [0, 1, 2].map(|c| sample[c] / white[c] * options.white_reflectance * white_rgb[c]);
            samples.push(Sample {
                theta_l,
                theta_i: a.theta_i,
                theta_r: a.theta_r,
                rgb,
                cosines: None,
            });
        }
    }
    (samples, dropped)
}
