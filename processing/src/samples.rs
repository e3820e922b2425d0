//! Samples CSV: one row per surface point, header `theta_l,theta_i,theta_r,r,g,b`
//! (angles in degrees, β in the camera-RGB domain). Extra columns may follow the six
//! named ones. The four optional columns `n_dot_l,n_dot_v,n_dot_h,v_dot_h` (see
//! [`COSINE_COLUMNS`]) carry the point's true 3D cosines; when a file has all four, the
//! models are evaluated with them instead of the in-plane angles. Other extra columns are
//! ignored on reading. An empty `r`, `g` or `b` field is a value dropped at that point
//! (clipped or underexposed in every exposure, or a white too dark to divide by): it is
//! unknown, never 0 ([`Sample::dropped`]).
//!
//! Optional uncertainty columns (all or none, see [`uncertainty_columns`]):
//! `u_noise_r,u_noise_g,u_noise_b`, β's standard uncertainty from the images' noise, then
//! for each [`Source`] `u_<source>_r,…`: the signed change of β at the point's geometry
//! for a change of that source by +1 standard uncertainty ([`SampleUncertainty`]). A
//! dropped channel's fields are empty.
#![doc = include_str!("samples.md")]

use std::fs::File;
use std::io::{BufWriter, Read, Write};
use std::path::Path;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::brdf::Cosines;
use crate::decimal::{self, Brief};
use crate::setup_uncertainty::Source;

/// One measured surface point: angles in degrees, β per camera channel.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Sample {
    pub theta_l: f64,
    /// In-plane incidence angle (the angle of the light's projection on the plane of the
    /// light and the camera for points off that plane).
    pub theta_i: f64,
    /// In-plane viewing angle, as `theta_i`.
    pub theta_r: f64,
    pub rgb: [f64; 3],
    /// The point's true 3D cosines, when known; `None` means in-plane.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cosines: Option<Cosines>,
    /// Channels whose β is unknown at this point (dropped by extraction: clipped,
    /// underexposed, or a white too dark); their `rgb` entry is 0 and carries no
    /// information, and fits and metrics leave them out.
    #[serde(default, skip_serializing_if = "none_dropped")]
    pub dropped: [bool; 3],
    /// β's uncertainty at this point, when extraction estimated it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub uncertainty: Option<SampleUncertainty>,
}

/// The uncertainty of one sample's β, per channel R, G, B (docs/ARCHITECTURE.md,
/// "Uncertainty budget"), its components kept apart by how they correlate.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct SampleUncertainty {
    /// Standard uncertainty from the images' noise: independent from point to point.
    pub noise: [f64; 3],
    /// Per [`Source`] (in [`Source::ALL`]'s order), the signed change of β at this
    /// point's stated geometry when that source changes by +1 standard uncertainty:
    /// common to every point of the scan (of its θL for [`Source::ArmAngle`]).
    pub sources: [[f64; 3]; Source::COUNT],
}

impl SampleUncertainty {
    /// The uncertainty as the samples CSV states it: every value rounded to 6
    /// significant digits (`UNCERTAINTY_DIGITS`), so that samples in memory and read
    /// back from their file are the same.
    pub(crate) fn as_written(&self) -> Self {
        let round = |v: [f64; 3]| v.map(|x| decimal::rounded(x, UNCERTAINTY_DIGITS));
        Self {
            noise: round(self.noise),
            sources: self.sources.map(round),
        }
    }
}

fn none_dropped(dropped: &[bool; 3]) -> bool {
    !dropped.iter().any(|&d| d)
}

impl Sample {
    /// A sample in the plane of the light: its cosines follow from (θi, θr).
    pub fn in_plane(theta_l: f64, theta_i: f64, theta_r: f64, rgb: [f64; 3]) -> Self {
        Sample {
            theta_l,
            theta_i,
            theta_r,
            rgb,
            ..Sample::default()
        }
    }

    /// β of channel `c`, `None` where it was dropped.
    pub fn channel(&self, c: usize) -> Option<f64> {
        (!self.dropped[c]).then_some(self.rgb[c])
    }

    /// The half-vector and difference angles (radians) of the point: θh = acos(n·h),
    /// signed by the side of the specular peak it lies on (the sign of θi − θr), and
    /// θd = acos(v·h).
    pub fn half_difference(&self) -> (f64, f64) {
        let c = self.cosines();
        let theta_h = c.n_dot_h.clamp(-1.0, 1.0).acos();
        let side = if self.theta_i >= self.theta_r {
            1.0
        } else {
            -1.0
        };
        (side * theta_h, c.v_dot_h.clamp(-1.0, 1.0).acos())
    }

    /// The cosines the models are evaluated with: the stored 3D ones, or the in-plane ones.
    pub fn cosines(&self) -> Cosines {
        self.cosines
            .unwrap_or_else(|| Cosines::in_plane(self.theta_i, self.theta_r))
    }

    /// The name of the first field (in CSV column order) that is NaN or infinite (dropped
    /// channels are not looked at).
    pub fn non_finite_field(&self) -> Option<&'static str> {
        [
            ("theta_l", self.theta_l),
            ("theta_i", self.theta_i),
            ("theta_r", self.theta_r),
            ("r", self.channel(0).unwrap_or(0.0)),
            ("g", self.channel(1).unwrap_or(0.0)),
            ("b", self.channel(2).unwrap_or(0.0)),
        ]
        .into_iter()
        .chain(
            self.cosines
                .map(Cosines::to_array)
                .into_iter()
                .flat_map(|c| COSINE_COLUMNS.into_iter().zip(c)),
        )
        .find(|(_, v)| !v.is_finite())
        .map(|(field, _)| field)
    }
}

/// θL values closer than this (degrees) are the same illumination direction.
pub const THETA_L_TOLERANCE: f64 = 1e-6;

/// Distinct θL of `samples` in order of first appearance.
pub fn distinct_theta_l(samples: &[Sample]) -> Vec<f64> {
    let mut out: Vec<f64> = Vec::new();
    for s in samples {
        if !out
            .iter()
            .any(|t| (t - s.theta_l).abs() <= THETA_L_TOLERANCE)
        {
            out.push(s.theta_l);
        }
    }
    out
}

/// The six leading columns of a samples CSV, in order.
pub const HEADER: [&str; 6] = ["theta_l", "theta_i", "theta_r", "r", "g", "b"];

/// The optional columns of a point's 3D cosines, in the order they are written.
pub const COSINE_COLUMNS: [&str; 4] = ["n_dot_l", "n_dot_v", "n_dot_h", "v_dot_h"];

/// The optional uncertainty columns, in the order they are written: `u_noise_r`, `…_g`,
/// `…_b`, then `u_<source>_r`, `…_g`, `…_b` for each [`Source`].
pub fn uncertainty_columns() -> Vec<String> {
    std::iter::once("noise")
        .chain(Source::ALL.iter().map(|s| s.name()))
        .flat_map(|name| ["r", "g", "b"].map(|c| format!("u_{name}_{c}")))
        .collect()
}

/// Why a samples CSV could not be read or written. Lines are 1-based and count the header.
/// Each message is complete on its own (no separate source chain).
#[derive(Debug, thiserror::Error)]
pub enum SamplesError {
    #[error("{path}: {error}")]
    Io { path: String, error: std::io::Error },
    #[error("samples CSV: header must start with `{expected}`, found `{found}`")]
    Header { expected: String, found: String },
    #[error("samples CSV line {line}: {message}")]
    Row { line: u64, message: String },
    #[error("samples CSV line {line}, column `{column}`: {message}")]
    Field {
        line: u64,
        column: &'static str,
        message: String,
    },
    #[error("samples CSV: {0}")]
    Csv(csv::Error),
    #[error("{path}: {inner}")]
    InFile {
        path: String,
        inner: Box<SamplesError>,
    },
}

impl SamplesError {
    /// A field error of an uncertainty column, with the column's own name.
    fn named(self, column: &str) -> Self {
        match self {
            SamplesError::Field { line, message, .. } => SamplesError::Row {
                line,
                message: format!("column `{column}`: {message}"),
            },
            other => other,
        }
    }

    /// Names the file a reader or writer error came from.
    fn in_file(self, path: &Path) -> Self {
        match self {
            SamplesError::Io { error, .. } => SamplesError::Io {
                path: path.display().to_string(),
                error,
            },
            other => SamplesError::InFile {
                path: path.display().to_string(),
                inner: Box::new(other),
            },
        }
    }
}

/// Largest samples CSV read (a 63-θL full-frame scan writes about 15 MB).
const MAX_CSV_BYTES: u64 = 1 << 30;

/// Reads a samples CSV file.
pub fn read_csv(path: &Path) -> Result<Vec<Sample>, SamplesError> {
    let file =
        gonio_files::input::open_input(path, MAX_CSV_BYTES).map_err(|error| SamplesError::Io {
            path: path.display().to_string(),
            error,
        })?;
    read_csv_from(file).map_err(|e| e.in_file(path))
}

/// Reads samples CSV text from any reader. Every value must be a finite number whose
/// square is finite too.
pub fn read_csv_from<R: Read>(reader: R) -> Result<Vec<Sample>, SamplesError> {
    let mut csv = csv::ReaderBuilder::new()
        .has_headers(true)
        .flexible(true)
        .from_reader(gonio_files::input::UnixLineEnds::new(reader));
    let header: Vec<String> = csv
        .headers()
        .map_err(SamplesError::Csv)?
        .iter()
        .map(|h| h.trim().to_string())
        .collect();
    let header_text = || header.join(",");
    if header.len() < HEADER.len() || header[..HEADER.len()] != HEADER {
        return Err(SamplesError::Header {
            expected: HEADER.join(","),
            found: header_text(),
        });
    }
    // Indices of the cosine columns: all four or none.
    let cosine_index: Vec<usize> = COSINE_COLUMNS
        .iter()
        .filter_map(|name| header.iter().position(|h| h == name))
        .collect();
    let cosine_index = match cosine_index.len() {
        0 => None,
        4 => Some(cosine_index),
        _ => {
            return Err(SamplesError::Header {
                expected: format!("all or none of {}", COSINE_COLUMNS.join(",")),
                found: header_text(),
            })
        }
    };
    let names = uncertainty_columns();
    let found: Vec<Option<usize>> = names
        .iter()
        .map(|name| header.iter().position(|h| h == name))
        .collect();
    // The columns of [`Source::LATER`] may be absent (no change).
    let optional: Vec<String> = Source::LATER
        .iter()
        .flat_map(|s| ["r", "g", "b"].map(|c| format!("u_{}_{c}", s.name())))
        .collect();
    let required_missing = names
        .iter()
        .zip(&found)
        .filter(|(name, i)| i.is_none() && !optional.contains(name))
        .count();
    let uncertainty_index = match (found.iter().flatten().count(), required_missing) {
        (0, _) => None,
        (_, 0) => Some(found),
        _ => {
            return Err(SamplesError::Header {
                expected: format!("all or none of {}", names.join(",")),
                found: header_text(),
            })
        }
    };
    let columns = Columns {
        cosine: cosine_index,
        uncertainty: uncertainty_index,
        names,
    };
    // Rows are read in blocks, each block's fields parsed in parallel; the first bad row
    // in file order is the one reported.
    const BLOCK: usize = 1024;
    let mut block = vec![csv::ByteRecord::new(); BLOCK];
    let mut samples = Vec::new();
    loop {
        let mut filled = 0;
        while filled < BLOCK
            && csv
                .read_byte_record(&mut block[filled])
                .map_err(|e| match e.position() {
                    Some(pos) => SamplesError::Row {
                        line: pos.line(),
                        message: e.to_string(),
                    },
                    None => SamplesError::Csv(e),
                })?
        {
            filled += 1;
        }
        let rows: Vec<Result<Sample, SamplesError>> = block[..filled]
            .par_iter()
            .map(|r| columns.sample(r))
            .collect();
        for row in rows {
            samples.push(row?);
        }
        if filled < BLOCK {
            return Ok(samples);
        }
    }
}

/// Where a samples CSV holds its optional columns.
struct Columns {
    /// The four cosine columns, if present.
    cosine: Option<Vec<usize>>,
    /// Per uncertainty column ([`uncertainty_columns`] order), where it is, if present.
    uncertainty: Option<Vec<Option<usize>>>,
    names: Vec<String>,
}

impl Columns {
    /// The sample of one row.
    fn sample(&self, record: &csv::ByteRecord) -> Result<Sample, SamplesError> {
        let line = record.position().map_or(0, csv::Position::line);
        let text = std::str::from_utf8(record.as_slice()).map_err(|_| SamplesError::Row {
            line,
            message: String::from("not UTF-8 text"),
        })?;
        // Field `i`, trimmed; empty when absent.
        let field = |i: usize| {
            record
                .range(i)
                .and_then(|r| text.get(r))
                .unwrap_or("")
                .trim_ascii()
        };
        if record.len() < HEADER.len() {
            return Err(SamplesError::Row {
                line,
                message: format!(
                    "{} fields, expected at least {} ({})",
                    record.len(),
                    HEADER.len(),
                    HEADER.join(",")
                ),
            });
        }
        let mut values = [0.0; 6];
        let mut dropped = [false; 3];
        for (i, (value, column)) in values.iter_mut().zip(HEADER).enumerate() {
            let text = field(i);
            // An empty β field is a dropped value; the angles are always required.
            if i >= 3 && text.is_empty() {
                dropped[i - 3] = true;
            } else {
                *value = parse_field(text, line, column)?;
            }
        }
        // θL as a sidecar may state it; θi and θr in front of the surface.
        for (i, limit) in [(0, 180.0), (1, 90.0), (2, 90.0)] {
            if values[i].abs() > limit {
                return Err(SamplesError::Field {
                    line,
                    column: HEADER[i],
                    message: format!("{}° is outside [−{limit}°, {limit}°]", Brief(values[i])),
                });
            }
        }
        let cosines = match &self.cosine {
            None => None,
            Some(index) => {
                let mut c = [0.0; 4];
                for ((value, column), &i) in c.iter_mut().zip(COSINE_COLUMNS).zip(index) {
                    if i >= record.len() {
                        return Err(SamplesError::Field {
                            line,
                            column,
                            message: String::from("missing"),
                        });
                    }
                    *value = parse_field(field(i), line, column)?;
                    if value.abs() > 1.0 {
                        return Err(SamplesError::Field {
                            line,
                            column,
                            message: format!("{} is not a cosine (outside [−1, 1])", Brief(*value)),
                        });
                    }
                }
                Some(Cosines {
                    n_dot_l: c[0],
                    n_dot_v: c[1],
                    n_dot_h: c[2],
                    v_dot_h: c[3],
                })
            }
        };
        let uncertainty = match &self.uncertainty {
            None => None,
            Some(index) => {
                let mut u = [[0.0; 3]; 1 + Source::COUNT];
                for (k, i) in index.iter().enumerate() {
                    let Some(&i) = i.as_ref() else {
                        continue;
                    };
                    let text = field(i);
                    // A dropped channel has no uncertainty; a kept one needs its value.
                    if dropped[k % 3] && text.is_empty() {
                        continue;
                    }
                    u[k / 3][k % 3] = parse_field(text, line, "uncertainty")
                        .map_err(|e| e.named(&self.names[k]))?;
                }
                if u[0].iter().any(|&v| v < 0.0) {
                    return Err(SamplesError::Row {
                        line,
                        message: String::from("a noise uncertainty (u_noise_*) is negative"),
                    });
                }
                Some(SampleUncertainty {
                    noise: u[0],
                    sources: std::array::from_fn(|j| u[j + 1]),
                })
            }
        };
        Ok(Sample {
            theta_l: values[0],
            theta_i: values[1],
            theta_r: values[2],
            rgb: [values[3], values[4], values[5]],
            cosines,
            dropped,
            uncertainty,
        })
    }
}

/// One CSV field as a finite number.
fn parse_field(text: &str, line: u64, column: &'static str) -> Result<f64, SamplesError> {
    let parsed: f64 = text.parse().map_err(|_| SamplesError::Field {
        line,
        column,
        message: format!("`{text}` is not a number"),
    })?;
    if !parsed.is_finite() {
        return Err(SamplesError::Field {
            line,
            column,
            message: format!("`{text}` is not finite"),
        });
    }
    // Fits and metrics square values: one whose square overflows cannot be fitted.
    if !(parsed * parsed).is_finite() {
        return Err(SamplesError::Field {
            line,
            column,
            message: format!("`{text}` is too large (its square overflows)"),
        });
    }
    Ok(parsed)
}

/// Writes samples as CSV to a file (created or truncated).
pub fn write_csv(path: &Path, samples: &[Sample]) -> Result<(), SamplesError> {
    let file = File::create(path).map_err(|error| SamplesError::Io {
        path: path.display().to_string(),
        error,
    })?;
    let mut out = BufWriter::new(file);
    write_csv_to(&mut out, samples).map_err(|e| e.in_file(path))?;
    out.flush().map_err(|error| SamplesError::Io {
        path: path.display().to_string(),
        error,
    })
}

/// Writes samples as CSV text to any writer; numbers in Rust's shortest round-trip form
/// (the `decimal` module), the uncertainty columns rounded to 6 significant digits.
/// When any sample carries 3D cosines, every row gets the four cosine columns (in-plane
/// cosines for samples without). When every sample carries its uncertainty, the
/// uncertainty columns follow. A dropped channel is written as an empty field. No field
/// needs quoting (numbers and the header's names), so rows are formatted directly, in
/// parallel blocks written in order.
pub fn write_csv_to<W: Write>(mut writer: W, samples: &[Sample]) -> Result<(), SamplesError> {
    let with_cosines = samples.iter().any(|s| s.cosines.is_some());
    let with_uncertainty = !samples.is_empty() && samples.iter().all(|s| s.uncertainty.is_some());
    let mut header: Vec<String> = HEADER.iter().map(|h| h.to_string()).collect();
    if with_cosines {
        header.extend(COSINE_COLUMNS.iter().map(|h| h.to_string()));
    }
    if with_uncertainty {
        header.extend(uncertainty_columns());
    }
    let io = |error| SamplesError::Io {
        path: String::from("samples CSV output"),
        error,
    };
    writeln!(writer, "{}", header.join(",")).map_err(io)?;
    // Rows per block formatted at once: a few hundred kB of text.
    const BLOCK: usize = 1024;
    let blocks: Vec<Vec<u8>> = samples
        .par_chunks(BLOCK)
        .map(|block| {
            let mut text = Vec::new();
            for s in block {
                write_row(&mut text, s, with_cosines, with_uncertainty);
            }
            text
        })
        .collect();
    for block in blocks {
        writer.write_all(&block).map_err(io)?;
    }
    writer.flush().map_err(io)
}

/// Significant digits of the uncertainty columns: rounding them so changes a budget by
/// under 10⁻⁵ of itself, far below what any uncertainty is known to.
const UNCERTAINTY_DIGITS: i32 = 6;

/// One sample's CSV line, with its newline, appended to `text`.
fn write_row(text: &mut Vec<u8>, s: &Sample, with_cosines: bool, with_uncertainty: bool) {
    let number = |text: &mut Vec<u8>, v: f64| {
        text.push(b',');
        decimal::push(text, v);
    };
    decimal::push(text, s.theta_l);
    number(text, s.theta_i);
    number(text, s.theta_r);
    let channel = |text: &mut Vec<u8>, c: usize, v: f64| {
        if s.dropped[c] {
            text.push(b',');
        } else {
            number(text, v);
        }
    };
    for (c, &value) in s.rgb.iter().enumerate() {
        channel(text, c, value);
    }
    if with_cosines {
        for v in s.cosines().to_array() {
            number(text, v);
        }
    }
    if let (Some(u), true) = (&s.uncertainty, with_uncertainty) {
        for v in std::iter::once(&u.noise).chain(&u.sources) {
            for (c, &value) in v.iter().enumerate() {
                text.push(b',');
                if !s.dropped[c] {
                    decimal::push_rounded(text, value, UNCERTAINTY_DIGITS);
                }
            }
        }
    }
    text.push(b'\n');
}
