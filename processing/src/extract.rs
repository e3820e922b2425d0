//! Scan directory → radiance-factor samples in the camera-RGB domain (paper §2.2).
//!
//! `DIR/setup.json` holds the [`Setup`] (unless [`ExtractOptions::setup`] names
//! another file); captures are found recursively (TIFF or camera
//! raw with a JSON sidecar) and grouped by the sidecar's θL. Each group is merged
//! ([`hdr::merge`]) into one radiance map, of the strip rows only unless the maps are
//! wanted as files ([`ExtractOptions::hdr_dir`]). Each pixel column gives one sample:
//! the mean of the [`STRIP_ROWS`] rows around each strip's centre row, with the mean of
//! the true 3D geometry of those sample pixels (the point on the cylinder, its normal,
//! the light and the camera: [`Setup::pixel_geometry`]); then per channel c
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

use std::collections::BTreeMap;
use std::fs;
use std::ops::Range;
use std::path::{Path, PathBuf};

use rayon::prelude::*;
use thiserror::Error;

use crate::brdf::Cosines;
use crate::capture::{self, CaptureError, Frame};
use crate::color::CameraModel;
use crate::geometry::{GeometryError, PixelGeometry, Setup};
use crate::hdr::{self, HdrError, HdrImage, MergeOptions, SATURATED, UNDEREXPOSED};
use crate::samples::Sample;

/// Rows averaged around each strip's centre row (paper §2.2).
pub const STRIP_ROWS: usize = 5;

/// Options of [`extract_scan`].
#[derive(Debug, Clone, PartialEq)]
pub struct ExtractOptions {
    pub merge: MergeOptions,
    /// Reflectance of the white reference (1 = perfect reflecting diffuser), overriding
    /// setup.json's `white_reflectance`; `None`: setup.json's (1 if it has none).
    pub white_reflectance: Option<f64>,
    /// Columns with |θi| or |θr| above this (degrees) are dropped.
    pub grazing_limit_deg: f64,
    /// A channel whose white strip is below this fraction of the brightest white column
    /// of the same θL and channel is dropped at that column.
    pub min_white_fraction: f64,
    /// Camera and illuminant that define the camera-RGB domain.
    pub camera: CameraModel,
    /// When set, each θL's radiance map is written there as `theta_l_<θL>.exr`.
    pub hdr_dir: Option<PathBuf>,
    /// The setup to use instead of the scan's `setup.json` (say, one `gonio calibrate`
    /// wrote).
    pub setup: Option<PathBuf>,
    /// When set, only the captures of this θL (degrees) are extracted.
    pub theta_l: Option<f64>,
}

impl Default for ExtractOptions {
    fn default() -> Self {
        Self {
            merge: MergeOptions::default(),
            white_reflectance: None,
            grazing_limit_deg: 80.0,
            min_white_fraction: 0.02,
            camera: CameraModel::builtin(),
            hdr_dir: None,
            setup: None,
            theta_l: None,
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

/// What was dropped. Columns count once, in the first reason that applies; values (one
/// channel of one kept or dropped column) count per channel R, G, B, in the first
/// reason that applies to that channel.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct DropCounts {
    /// Columns: a strip pixel misses the cylinder, or is not lit (|θi| ≥ 90°).
    pub off_cylinder: usize,
    /// Columns: |θi| or |θr| beyond the grazing limit.
    pub grazing: usize,
    /// Columns whose three channels were all dropped (counted below too).
    pub no_channel: usize,
    /// Values: a pixel of the sample or white strip is clipped in every exposure.
    pub saturated: [usize; 3],
    /// Values: a pixel of the sample strip is below the noise floor in every exposure.
    pub underexposed: [usize; 3],
    /// Values: the white strip is too dark (or black in every exposure).
    pub dark_white: [usize; 3],
}

impl DropCounts {
    /// Columns dropped.
    pub fn total(&self) -> usize {
        self.off_cylinder + self.grazing + self.no_channel
    }

    /// Values dropped in channel `c` (R, G, B = 0, 1, 2), whatever the reason.
    pub fn values(&self, c: usize) -> usize {
        self.saturated[c] + self.underexposed[c] + self.dark_white[c]
    }

    /// The reason most columns were dropped for, with its count (`None` if none was).
    /// Columns with no usable channel are named for the reason most of their values
    /// were dropped for.
    pub fn dominant(&self) -> Option<(&'static str, usize)> {
        let sum = |v: [usize; 3]| v.iter().sum::<usize>();
        let no_channel = [
            ("no usable channel (mostly saturated)", sum(self.saturated)),
            (
                "no usable channel (mostly underexposed)",
                sum(self.underexposed),
            ),
            (
                "no usable channel (mostly a dark white reference)",
                sum(self.dark_white),
            ),
        ]
        .into_iter()
        .max_by_key(|(_, n)| *n)
        .map_or("no usable channel", |(reason, _)| reason);
        [
            ("off the cylinder or unlit", self.off_cylinder),
            ("grazing", self.grazing),
            (no_channel, self.no_channel),
        ]
        .into_iter()
        .filter(|(_, n)| *n > 0)
        .max_by_key(|(_, n)| *n)
    }

    /// Why an extraction gave no sample: the dominant reason and every count.
    pub fn explain_empty(&self) -> String {
        let rgb = |v: [usize; 3]| format!("{}/{}/{}", v[0], v[1], v[2]);
        match self.dominant() {
            Some((reason, n)) => format!(
                "no samples: all {} columns were dropped, most ({n}) as {reason} \
                 ({} off the cylinder or unlit, {} grazing, {} with no usable channel; \
                 values dropped R/G/B: {} saturated, {} underexposed, {} dark white)",
                self.total(),
                self.off_cylinder,
                self.grazing,
                self.no_channel,
                rgb(self.saturated),
                rgb(self.underexposed),
                rgb(self.dark_white),
            ),
            None => "no samples: no column of the captures was on the strips".to_owned(),
        }
    }

    fn add(&mut self, other: &DropCounts) {
        self.off_cylinder += other.off_cylinder;
        self.grazing += other.grazing;
        self.no_channel += other.no_channel;
        for c in 0..3 {
            self.saturated[c] += other.saturated[c];
            self.underexposed[c] += other.underexposed[c];
            self.dark_white[c] += other.dark_white[c];
        }
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
    };
    for (done, (theta_l, paths)) in groups.into_iter().enumerate() {
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
                let mut layout = None;
                let frame = Frame::read_rows(path, |width, height| {
                    let full = StripLayout::new(&setup, width, height, theta_l)?;
                    layout = Some(full);
                    Ok::<_, ExtractError>(full.bands())
                })?;
                let layout = layout.expect("the row selector ran").strips_only();
                Ok((frame, layout))
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
        let (samples, dropped) =
            extract_theta(&setup, &map, &layout, theta_l, options, white_reflectance);
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

/// θL in millionths of a degree: captures of one θL share it.
fn theta_key(theta_l: f64) -> i64 {
    (theta_l * 1e6).round() as i64
}

fn check_options(o: &ExtractOptions) -> Result<(), ExtractError> {
    if let Some(white) = o.white_reflectance {
        if !(white.is_finite() && white > 0.0 && white <= 2.0) {
            return Err(ExtractError::Options(format!(
                "white reflectance {white} is not in (0, 2]"
            )));
        }
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

/// The mean radiance of one strip's rows at one column, with each channel's flags
/// (OR over the rows).
#[derive(Debug, Clone, Copy)]
struct StripMean {
    rgb: [f64; 3],
    flags: [u8; 3],
}

fn strip_mean(map: &HdrImage, x: usize, centre: usize) -> StripMean {
    let mut rgb = [0.0; 3];
    let mut flags = [0; 3];
    for y in centre - STRIP_ROWS / 2..=centre + STRIP_ROWS / 2 {
        let p = map.pixel(x, y);
        for c in 0..3 {
            rgb[c] += f64::from(p[c]);
            flags[c] |= map.channel_flags(x, y, c);
        }
    }
    StripMean {
        rgb: rgb.map(|s| s / STRIP_ROWS as f64),
        flags,
    }
}

/// Sensor pixels per pixel of a `width`×`height` capture of `setup`'s sensor: 1 for
/// full resolution, 2 for 2×2-superpixel raw; other sizes are refused.
pub(crate) fn capture_scale(
    setup: &Setup,
    width: usize,
    height: usize,
    theta_l: f64,
) -> Result<usize, ExtractError> {
    let (sw, sh) = (setup.image_width as usize, setup.image_height as usize);
    if (width, height) == (sw, sh) {
        Ok(1)
    } else if (width, height) == (sw / 2, sh / 2) {
        Ok(2)
    } else {
        Err(ExtractError::SizeMismatch {
            theta_l,
            width,
            height,
            setup_width: setup.image_width,
            setup_height: setup.image_height,
        })
    }
}

/// Where the strips lie in a capture of a given size, and in the merged map.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct StripLayout {
    /// Sensor pixels per capture pixel: 1, or 2 for superpixel raw.
    scale: usize,
    /// Centre rows of the strips in the capture.
    sample_row: usize,
    white_row: usize,
    /// Centre rows of the strips in the merged map (the capture's, or those of a map
    /// holding only [`StripLayout::bands`]).
    sample_map_row: usize,
    white_map_row: usize,
}

impl StripLayout {
    fn new(setup: &Setup, width: usize, height: usize, theta_l: f64) -> Result<Self, ExtractError> {
        let scale = capture_scale(setup, width, height, theta_l)?;
        let row = |which: &'static str, sensor_row: u32| {
            let row = sensor_row as usize / scale;
            if row < STRIP_ROWS / 2 || row + STRIP_ROWS / 2 >= height {
                Err(ExtractError::RowOutside { which, row, height })
            } else {
                Ok(row)
            }
        };
        let (sample_row, white_row) = (
            row("sample", setup.sample_row)?,
            row("white", setup.white_row)?,
        );
        Ok(Self {
            scale,
            sample_row,
            white_row,
            sample_map_row: sample_row,
            white_map_row: white_row,
        })
    }

    /// The capture row ranges of the two strips (sample, then white).
    fn bands(&self) -> Vec<Range<usize>> {
        let half = STRIP_ROWS / 2;
        [self.sample_row, self.white_row]
            .map(|centre| centre - half..centre + half + 1)
            .to_vec()
    }

    /// The same strips in a frame holding only [`StripLayout::bands`].
    fn strips_only(self) -> Self {
        let half = STRIP_ROWS / 2;
        Self {
            sample_map_row: half,
            white_map_row: STRIP_ROWS + half,
            ..self
        }
    }

    /// Sensor coordinate of the centre of capture pixel `i` (a superpixel spans two).
    fn sensor(&self, i: usize) -> f64 {
        (self.scale * i) as f64 + (self.scale as f64 - 1.0) / 2.0
    }

    /// The geometry of the strip rows around capture row `centre` at column `x`:
    /// `None` if any of those pixels misses the cylinder or is unlit.
    fn strip_geometry(
        &self,
        setup: &Setup,
        x: usize,
        centre: usize,
        theta_l: f64,
    ) -> Option<Vec<PixelGeometry>> {
        let u = self.sensor(x);
        (centre - STRIP_ROWS / 2..=centre + STRIP_ROWS / 2)
            .map(|y| {
                setup
                    .pixel_geometry(u, self.sensor(y), theta_l)
                    .filter(|g| g.irradiance > 0.0 && g.theta_i.abs() < 90.0)
            })
            .collect()
    }
}

/// The mean geometry of a column's sample pixels, and the irradiance ratio
/// Ē_white / Ē_sample of its two strips.
#[derive(Debug, Clone, Copy)]
struct ColumnGeometry {
    theta_i: f64,
    theta_r: f64,
    cosines: Cosines,
    irradiance_ratio: f64,
}

impl ColumnGeometry {
    fn new(sample: &[PixelGeometry], white: &[PixelGeometry]) -> Self {
        let mean = |f: &dyn Fn(&PixelGeometry) -> f64, of: &[PixelGeometry]| {
            of.iter().map(f).sum::<f64>() / of.len() as f64
        };
        Self {
            theta_i: mean(&|g| g.theta_i, sample),
            theta_r: mean(&|g| g.theta_r, sample),
            cosines: Cosines {
                n_dot_l: mean(&|g| g.cosines.n_dot_l, sample),
                n_dot_v: mean(&|g| g.cosines.n_dot_v, sample),
                n_dot_h: mean(&|g| g.cosines.n_dot_h, sample),
                v_dot_h: mean(&|g| g.cosines.v_dot_h, sample),
            },
            irradiance_ratio: mean(&|g| g.irradiance, white) / mean(&|g| g.irradiance, sample),
        }
    }
}

/// Why one value (a channel of a column) is dropped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum DropReason {
    Saturated,
    Underexposed,
    DarkWhite,
}

impl DropReason {
    /// Why channel `c` of a column with these strips is dropped, if it is; `threshold`
    /// is the channel's too-dark white level.
    fn of(sample: &StripMean, white: &StripMean, c: usize, threshold: f64) -> Option<Self> {
        if (sample.flags[c] | white.flags[c]) & SATURATED != 0 {
            Some(Self::Saturated)
        } else if white.flags[c] & UNDEREXPOSED != 0
            || !(white.rgb[c] > threshold && white.rgb[c] > 0.0)
        {
            Some(Self::DarkWhite)
        } else if sample.flags[c] & UNDEREXPOSED != 0 {
            Some(Self::Underexposed)
        } else {
            None
        }
    }
}

impl DropCounts {
    fn count(&mut self, reason: DropReason, c: usize) {
        let counts = match reason {
            DropReason::Saturated => &mut self.saturated,
            DropReason::Underexposed => &mut self.underexposed,
            DropReason::DarkWhite => &mut self.dark_white,
        };
        counts[c] += 1;
    }
}

fn extract_theta(
    setup: &Setup,
    map: &HdrImage,
    layout: &StripLayout,
    theta_l: f64,
    options: &ExtractOptions,
    white_reflectance: f64,
) -> (Vec<Sample>, DropCounts) {
    let columns: Vec<_> = (0..map.width)
        .into_par_iter()
        .map(|x| {
            let geometry = layout
                .strip_geometry(setup, x, layout.sample_row, theta_l)
                .zip(layout.strip_geometry(setup, x, layout.white_row, theta_l))
                .map(|(sample, white)| ColumnGeometry::new(&sample, &white));
            (
                geometry,
                strip_mean(map, x, layout.sample_map_row),
                strip_mean(map, x, layout.white_map_row),
            )
        })
        .collect();
    // The brightest usable white of each channel, for the too-dark threshold.
    let mut brightest_white = [0.0f64; 3];
    for (geometry, _, white) in &columns {
        for (c, brightest) in brightest_white.iter_mut().enumerate() {
            if geometry.is_some() && white.flags[c] == 0 {
                *brightest = brightest.max(white.rgb[c]);
            }
        }
    }
    let threshold = brightest_white.map(|w| options.min_white_fraction * w);
    let white_rgb = options.camera.white_rgb();
    let limit = options.grazing_limit_deg;

    let mut samples = Vec::new();
    let mut dropped = DropCounts::default();
    for (geometry, sample, white) in columns {
        let Some(g) = geometry else {
            dropped.off_cylinder += 1;
            continue;
        };
        if g.theta_i.abs() > limit || g.theta_r.abs() > limit {
            dropped.grazing += 1;
            continue;
        }
        let mut point = Sample {
            theta_l,
            theta_i: g.theta_i,
            theta_r: g.theta_r,
            cosines: Some(g.cosines),
            ..Sample::default()
        };
        for c in 0..3 {
            match DropReason::of(&sample, &white, c, threshold[c]) {
                Some(reason) => {
                    dropped.count(reason, c);
                    point.dropped[c] = true;
                }
                None => {
                    point.rgb[c] = sample.rgb[c] / white.rgb[c]
                        * g.irradiance_ratio
                        * white_reflectance
                        * white_rgb[c];
                }
            }
        }
        if point.dropped.iter().all(|&d| d) {
            dropped.no_channel += 1;
        } else {
            samples.push(point);
        }
    }
    (samples, dropped)
}
