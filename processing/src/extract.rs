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
use std::ops::Range;
use std::path::{Path, PathBuf};

use rayon::prelude::*;
use thiserror::Error;

use crate::brdf::Cosines;
use crate::capture::{self, CaptureError, Frame};
use crate::color::CameraModel;
use crate::geometry::{GeometryError, PixelGeometry, Setup};
use crate::hdr::{self, HdrError, HdrImage, MergeOptions, SATURATED, UNDEREXPOSED};
use crate::samples::{Sample, SampleUncertainty};
use crate::setup_uncertainty::{Input, Source};

pub(crate) mod captures;
use captures::{find_captures, FindError};

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
    /// Whether each sample gets its uncertainty ([`Sample::uncertainty`]): its noise,
    /// and its change under each of the setup's uncertain inputs (ten more extractions
    /// of each θL's strips, one per geometric source and sign).
    pub uncertainty: bool,
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
            uncertainty: true,
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
    #[error(
        "{path}: a symbolic link: θL folders and captures must be plain directories and \
         files (a link is not followed)"
    )]
    Link { path: PathBuf },
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

impl From<FindError> for ExtractError {
    fn from(err: FindError) -> Self {
        match err {
            FindError::Walk { path, error } => ExtractError::Walk { path, error },
            FindError::Link { path } => ExtractError::Link { path },
        }
    }
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
        inputs: options.uncertainty.then(|| setup.uncertainty.inputs()),
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
        let (mut samples, columns, dropped, centre_rows) =
            extract_theta(&setup, &map, &layout, theta_l, options, white_reflectance);
        if options.uncertainty {
            let strips = Strips {
                map: &map,
                layout: &layout,
                theta_l,
            };
            add_sensitivities(
                &setup,
                &strips,
                options,
                white_reflectance,
                (&mut samples, &columns),
            );
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

/// One strip's rows at one column: each row's radiance and flags.
#[derive(Debug, Clone, Copy)]
struct StripRows {
    rgb: [[f64; 3]; STRIP_ROWS],
    flags: [[u8; 3]; STRIP_ROWS],
}

impl StripRows {
    fn read(map: &HdrImage, x: usize, centre: usize) -> Self {
        let mut rows = StripRows {
            rgb: [[0.0; 3]; STRIP_ROWS],
            flags: [[0; 3]; STRIP_ROWS],
        };
        for (i, y) in (centre - STRIP_ROWS / 2..=centre + STRIP_ROWS / 2).enumerate() {
            rows.rgb[i] = map.pixel(x, y).map(f64::from);
            for c in 0..3 {
                rows.flags[i][c] = map.channel_flags(x, y, c);
            }
        }
        rows
    }

    /// How each channel curves over the rows, per unit of their pixels' irradiance.
    fn curvatures(&self, pixels: &[PixelGeometry]) -> [Option<Curvature>; 3] {
        let irradiance = std::array::from_fn(|i| pixels[i].irradiance);
        std::array::from_fn(|c| {
            self.reflected(c, &irradiance)
                .and_then(|v| Curvature::of(&v))
        })
    }

    /// The rows' mean, each channel's flags OR-ed over the rows.
    fn mean(&self) -> StripValue {
        let mut value = StripValue::default();
        for (rgb, flags) in self.rgb.iter().zip(&self.flags) {
            for c in 0..3 {
                value.rgb[c] += rgb[c] / STRIP_ROWS as f64;
                value.flags[c] |= flags[c];
            }
        }
        value
    }

    /// The centre row alone.
    fn centre(&self) -> StripValue {
        StripValue {
            rgb: self.rgb[STRIP_ROWS / 2],
            flags: self.flags[STRIP_ROWS / 2],
        }
    }

    /// Channel `c` over the rows as radiance per unit irradiance (the rows' own
    /// `irradiance`), `None` if a row is flagged or unlit.
    fn reflected(&self, c: usize, irradiance: &[f64; STRIP_ROWS]) -> Option<[f64; STRIP_ROWS]> {
        let mut v = [0.0; STRIP_ROWS];
        for i in 0..STRIP_ROWS {
            if self.flags[i][c] != 0 || irradiance[i] <= 0.0 {
                return None;
            }
            v[i] = self.rgb[i][c] / irradiance[i];
        }
        Some(v)
    }
}

/// A strip's radiance at one column (the mean of its rows, or one row) with each
/// channel's flags.
#[derive(Debug, Clone, Copy, Default)]
struct StripValue {
    rgb: [f64; 3],
    flags: [u8; 3],
}

/// How β curves across a strip's five rows, from a least-squares parabola
/// v(t) = a + b·t + k·t² over the rows t = −2…2: the five-row mean is a + 2k, so 2k/a is
/// the relative error of the mean against the value at the centre row's geometry. The
/// parabola's residual estimates the noise of one row: σ̂² = (P3·v)²/10 + (P4·v)²/70 over
/// its two degrees of freedom, with P3, P4 the cubic and quartic discrete orthogonal
/// polynomials.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Curvature {
    /// 2k/a: the five-row mean's relative excess over the centre value.
    mean_excess: f64,
    /// σ̂/a: one row's relative noise.
    row_noise: f64,
}

impl Curvature {
    /// `None` when the centre value is not positive.
    fn of(v: &[f64; STRIP_ROWS]) -> Option<Self> {
        let dot = |w: [f64; STRIP_ROWS]| w.iter().zip(v).map(|(w, v)| w * v).sum::<f64>();
        let two_k = dot([2.0, -1.0, -2.0, -1.0, 2.0]) / 7.0;
        let a = dot([-3.0, 12.0, 17.0, 12.0, -3.0]) / 35.0;
        let p3 = dot([-1.0, 2.0, 0.0, -2.0, 1.0]);
        let p4 = dot([1.0, -4.0, 6.0, -4.0, 1.0]);
        let sigma = ((p3 * p3 / 10.0 + p4 * p4 / 70.0) / 2.0).sqrt();
        (a > 0.0 && a.is_finite()).then(|| Curvature {
            mean_excess: two_k / a,
            row_noise: sigma / a,
        })
    }
}

/// Below this relative error of the five-row mean, a column is averaged whatever the
/// noise: far below what a fit or a colour difference can see.
const SHARP_LIMIT: f64 = 1e-3;

/// Standard errors of 2k/a that noise alone rarely reaches (Gaussian: 6·10⁻⁵).
const SHARP_SIGMAS: f64 = 4.0;

/// Standard error of 2k/a per unit of one row's relative noise: var(2k) = 4σ²/14.
const CURVATURE_SE_PER_NOISE: f64 = 0.534_522_483_824_848_8;

/// The median of σ̂ (two degrees of freedom) over σ: √(χ²₂ median / 2) = √ln 2.
const MEDIAN_SIGMA_HAT: f64 = 0.832_554_611_157_697_8;

/// Columns each side whose noise estimates are pooled with a column's own.
const NOISE_NEIGHBOURS: usize = 8;

/// Per column and channel, one row's relative noise pooled over the column and its
/// [`NOISE_NEIGHBOURS`] each side (the median of their own estimates, scaled to σ):
/// neighbours see about the same signal, so about the same relative noise. 0 where no
/// column can tell.
fn pooled_row_noise(curvatures: &[[Option<Curvature>; 3]]) -> Vec<[f64; 3]> {
    let mut noise = Vec::with_capacity(2 * NOISE_NEIGHBOURS + 1);
    (0..curvatures.len())
        .map(|x| {
            let near = &curvatures[x.saturating_sub(NOISE_NEIGHBOURS)
                ..(x + NOISE_NEIGHBOURS + 1).min(curvatures.len())];
            std::array::from_fn(|c| {
                noise.clear();
                noise.extend(near.iter().filter_map(|k| k[c].map(|k| k.row_noise)));
                if noise.is_empty() {
                    return 0.0;
                }
                let mid = noise.len() / 2;
                let (_, median, _) = noise.select_nth_unstable_by(mid, f64::total_cmp);
                *median / MEDIAN_SIGMA_HAT
            })
        })
        .collect()
}

/// Whether a column's sample strip lies on a peak too sharp to average: in some
/// channel the five-row mean is off the centre value by more than [`SHARP_LIMIT`] and
/// by more than [`SHARP_SIGMAS`] standard errors of what the rows' noise could make of it.
fn is_sharp(curvature: &[Option<Curvature>; 3], noise: &[f64; 3]) -> bool {
    (0..3).any(|c| {
        curvature[c].is_some_and(|k| {
            k.mean_excess.abs() > SHARP_LIMIT.max(SHARP_SIGMAS * CURVATURE_SE_PER_NOISE * noise[c])
        })
    })
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

/// The geometry of a column's sample (the mean of its strip pixels', or the centre
/// pixel's), and the irradiance ratio Ē_white / E_sample of its two strips.
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

/// One column before the samples are made: its strips' pixel geometry (`None` off the
/// cylinder or unlit), its strips' rows, and how each strip curves per channel.
struct Column {
    geometry: Option<(Vec<PixelGeometry>, Vec<PixelGeometry>)>,
    sample: StripRows,
    white: StripRows,
    curvature: [Option<Curvature>; 3],
    white_curvature: [Option<Curvature>; 3],
}

impl Column {
    /// The sample's geometry and the two strips' values: five-row means, or on a
    /// sharp peak the sample strip's centre row with that pixel's geometry.
    fn read(&self, sharp: bool) -> Option<(ColumnGeometry, StripValue, StripValue)> {
        let (sample, white) = self.geometry.as_ref()?;
        Some(if sharp {
            let centre = std::slice::from_ref(&sample[STRIP_ROWS / 2]);
            (
                ColumnGeometry::new(centre, white),
                self.sample.centre(),
                self.white.mean(),
            )
        } else {
            (
                ColumnGeometry::new(sample, white),
                self.sample.mean(),
                self.white.mean(),
            )
        })
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
    fn of(sample: &StripValue, white: &StripValue, c: usize, threshold: f64) -> Option<Self> {
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
) -> (Vec<Sample>, Vec<usize>, DropCounts, usize) {
    let columns: Vec<Column> = (0..map.width)
        .into_par_iter()
        .map(|x| {
            let geometry = layout
                .strip_geometry(setup, x, layout.sample_row, theta_l)
                .zip(layout.strip_geometry(setup, x, layout.white_row, theta_l));
            let sample = StripRows::read(map, x, layout.sample_map_row);
            let white = StripRows::read(map, x, layout.white_map_row);
            let (curvature, white_curvature) = match &geometry {
                Some((sample_pixels, white_pixels)) => (
                    sample.curvatures(sample_pixels),
                    white.curvatures(white_pixels),
                ),
                None => ([None; 3], [None; 3]),
            };
            Column {
                geometry,
                sample,
                white,
                curvature,
                white_curvature,
            }
        })
        .collect();
    let noise = pooled_row_noise(&columns.iter().map(|c| c.curvature).collect::<Vec<_>>());
    let white_noise = pooled_row_noise(
        &columns
            .iter()
            .map(|c| c.white_curvature)
            .collect::<Vec<_>>(),
    );
    let sharp: Vec<bool> = columns
        .iter()
        .zip(&noise)
        .map(|(column, noise)| is_sharp(&column.curvature, noise))
        .collect();
    let columns: Vec<_> = columns
        .iter()
        .zip(&sharp)
        .zip(noise.iter().zip(&white_noise))
        .map(|((column, &sharp), (&noise, &white_noise))| {
            column.read(sharp).map(|read| {
                // One row's relative noise over the rows averaged, both strips.
                let rows = if sharp { 1.0 } else { STRIP_ROWS as f64 };
                let relative: [f64; 3] = std::array::from_fn(|c| {
                    (noise[c] * noise[c] / rows
                        + white_noise[c] * white_noise[c] / STRIP_ROWS as f64)
                        .sqrt()
                });
                (read, sharp, relative)
            })
        })
        .collect();
    // The brightest usable white of each channel, for the too-dark threshold.
    let mut brightest_white = [0.0f64; 3];
    for ((_, _, white), _, _) in columns.iter().flatten() {
        for (c, brightest) in brightest_white.iter_mut().enumerate() {
            if white.flags[c] == 0 {
                *brightest = brightest.max(white.rgb[c]);
            }
        }
    }
    let threshold = brightest_white.map(|w| options.min_white_fraction * w);
    let white_rgb = options.camera.white_rgb();
    let limit = options.grazing_limit_deg;

    let mut samples = Vec::new();
    let mut sample_columns = Vec::new();
    let mut dropped = DropCounts::default();
    let mut centre_rows = 0;
    for (x, column) in columns.into_iter().enumerate() {
        let Some(((g, sample, white), sharp, relative_noise)) = column else {
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
        let mut noise = [0.0; 3];
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
                    noise[c] = point.rgb[c] * relative_noise[c];
                }
            }
        }
        if point.dropped.iter().all(|&d| d) {
            dropped.no_channel += 1;
        } else {
            centre_rows += usize::from(sharp);
            if options.uncertainty {
                point.uncertainty = Some(SampleUncertainty {
                    noise,
                    ..SampleUncertainty::default()
                });
            }
            samples.push(point);
            sample_columns.push(x);
        }
    }
    (samples, sample_columns, dropped, centre_rows)
}

/// One θL's merged strips, as [`extract_theta`] reads them.
struct Strips<'a> {
    map: &'a HdrImage,
    layout: &'a StripLayout,
    theta_l: f64,
}

/// `setup` with `source` moved by `delta` (its unit); the white reflectance is not part
/// of the geometry and is returned unchanged.
fn perturbed(setup: &Setup, source: Source, delta: f64) -> Setup {
    let mut s = setup.clone();
    match source {
        Source::WhiteReflectance => {}
        Source::CameraOffset => s.camera_offset_mm += delta,
        Source::CameraDistance => s.camera_distance_mm += delta,
        Source::LightDistance => s.light_distance_mm += delta,
        Source::CylinderTilt => s.cylinder_tilt_deg += delta,
        Source::ArmZero | Source::ArmAngle => s.arm_zero_offset_deg += delta,
    }
    s
}

/// Samples each side of a point in the local line whose slope is β's derivative along
/// signed θh ([`slopes`]).
const SLOPE_NEIGHBOURS: usize = 3;

/// Per sample and channel, dβ/dθh (per radian of signed θh) along its θL: the slope of
/// the least-squares line through it and its [`SLOPE_NEIGHBOURS`] neighbours each side
/// (fewer at the ends), which averages the noise that a difference of two neighbours
/// would carry into the sensitivities. 0 where a channel is dropped or the points do not
/// spread in θh.
fn slopes(samples: &[Sample], half_angles: &[f64]) -> Vec<[f64; 3]> {
    (0..samples.len())
        .map(|i| {
            let near =
                i.saturating_sub(SLOPE_NEIGHBOURS)..(i + SLOPE_NEIGHBOURS + 1).min(samples.len());
            std::array::from_fn(|c| {
                let points: Vec<(f64, f64)> = near
                    .clone()
                    .filter_map(|k| Some((half_angles[k], samples[k].channel(c)?)))
                    .collect();
                let n = points.len() as f64;
                if samples[i].dropped[c] || n < 2.0 {
                    return 0.0;
                }
                let mean_h = points.iter().map(|p| p.0).sum::<f64>() / n;
                let mean_b = points.iter().map(|p| p.1).sum::<f64>() / n;
                let sxx: f64 = points.iter().map(|p| (p.0 - mean_h).powi(2)).sum();
                let sxy: f64 = points.iter().map(|p| (p.0 - mean_h) * (p.1 - mean_b)).sum();
                if sxx > 0.0 {
                    sxy / sxx
                } else {
                    0.0
                }
            })
        })
        .collect()
}

/// Fills each sample's [`SampleUncertainty::sources`]: how β at the sample's stated
/// geometry changes when each uncertain input moves by one standard uncertainty.
/// The white reflectance scales β. A geometric source changes where each pixel's value is
/// placed, and a little the value itself (the strips' irradiance ratio): the strips are
/// extracted again with the setup moved by ±u, and a column whose value v goes to v′ and
/// whose signed θh moves by Δ changes β at its stated θh by (v′ − v) − Δ·dβ/dθh ([`slopes`]
/// of the stated samples); half the difference of the two signs is taken (central
/// difference). The change of θd at a fixed θh (a fraction of the source's own size) is
/// left out. A column the moved extraction drops gets no change.
fn add_sensitivities(
    setup: &Setup,
    strips: &Strips,
    options: &ExtractOptions,
    white_reflectance: f64,
    (samples, columns): (&mut [Sample], &[usize]),
) {
    let inputs = setup.uncertainty.inputs();
    let half_angles: Vec<f64> = samples.iter().map(|s| s.half_difference().0).collect();
    let slope = slopes(samples, &half_angles);
    let stated: &[Sample] = samples;
    let changes: Vec<(usize, Vec<[f64; 3]>)> = inputs
        .par_iter()
        .enumerate()
        .filter(|(_, input)| input.source != Source::WhiteReflectance && input.u[0] > 0.0)
        .map(|(j, input)| {
            let [plus, minus] = [1.0, -1.0].map(|sign| {
                let moved = perturbed(setup, input.source, sign * input.u[0]);
                let (moved_samples, moved_columns, _, _) = extract_theta(
                    &moved,
                    strips.map,
                    strips.layout,
                    strips.theta_l,
                    options,
                    white_reflectance,
                );
                stated
                    .iter()
                    .zip(columns)
                    .enumerate()
                    .map(|(i, (s, x))| {
                        let Ok(k) = moved_columns.binary_search(x) else {
                            return [0.0; 3];
                        };
                        let m = &moved_samples[k];
                        let shift = m.half_difference().0 - half_angles[i];
                        std::array::from_fn(|c| match (s.channel(c), m.channel(c)) {
                            (Some(v), Some(moved)) => (moved - v) - shift * slope[i][c],
                            _ => 0.0,
                        })
                    })
                    .collect::<Vec<[f64; 3]>>()
            });
            let change = plus
                .iter()
                .zip(&minus)
                .map(|(p, m)| std::array::from_fn(|c| (p[c] - m[c]) / 2.0))
                .collect();
            (j, change)
        })
        .collect();
    // Source::ALL begins with the white reference.
    let white = inputs[0].u;
    for (i, sample) in samples.iter_mut().enumerate() {
        let rgb = sample.rgb;
        let dropped = sample.dropped;
        let u = sample
            .uncertainty
            .get_or_insert_with(SampleUncertainty::default);
        u.sources[0] = std::array::from_fn(|c| rgb[c] * white[c]);
        for (j, change) in &changes {
            u.sources[*j] = change[i];
        }
        for c in (0..3).filter(|&c| dropped[c]) {
            for source in &mut u.sources {
                source[c] = 0.0;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use std::f64::consts::PI;

    use super::*;

    #[test]
    fn a_parabola_through_the_rows_gives_its_mean_excess_and_no_noise() {
        let (a, b, k) = (50.0, 3.0, -0.7);
        let v = [-2.0, -1.0, 0.0, 1.0, 2.0].map(|t: f64| a + b * t + k * t * t);
        let curvature = Curvature::of(&v).unwrap();
        let mean = v.iter().sum::<f64>() / 5.0;
        assert!((curvature.mean_excess - (mean - a) / a).abs() < 1e-15);
        assert!(curvature.row_noise < 1e-15);
        assert_eq!(Curvature::of(&[0.0; 5]), None);
    }

    #[test]
    fn pooled_noise_recovers_the_rows_noise() {
        // Flat rows with Gaussian noise of relative σ = 1 % (Box–Muller over a fixed
        // sequence): the pooled estimate is within 15 % of it, and noise alone marks
        // few columns as sharp.
        let mut state = 0x9e37_79b9_7f4a_7c15_u64;
        let mut uniform = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let curvatures: Vec<[Option<Curvature>; 3]> = (0..4000)
            .map(|_| {
                let v: [f64; 5] = std::array::from_fn(|_| {
                    let (u1, u2) = (uniform().max(1e-300), uniform());
                    100.0 * (1.0 + 0.01 * (-2.0 * u1.ln()).sqrt() * (2.0 * PI * u2).cos())
                });
                [Curvature::of(&v); 3]
            })
            .collect();
        let noise = pooled_row_noise(&curvatures);
        let mean = noise.iter().map(|n| n[0]).sum::<f64>() / noise.len() as f64;
        assert!((mean / 0.01 - 1.0).abs() < 0.15, "{mean}");
        let sharp = curvatures
            .iter()
            .zip(&noise)
            .filter(|(k, n)| is_sharp(k, n))
            .count();
        assert!(sharp * 100 < curvatures.len(), "{sharp}");
    }
}
