//! The JSON sidecar of a capture (`x.tiff` → `x.json`): its fields, their physical
//! ranges (seconds, ISO, f-number, counts, degrees) and the check of θL against the
//! `theta_l_<θL>` directory a capture is in.

use std::path::{Path, PathBuf};

use gonio_files::input::{read_input_to_string, MAX_SMALL_FILE_BYTES};
use serde::{Deserialize, Serialize};

use super::error::CaptureError;
use crate::decimal::Brief;

/// How pixel counts relate to exposure.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Response {
    /// Counts proportional to exposure (raw data, linear TIFF).
    #[default]
    Linear,
    /// An unknown monotonic camera response (developed images): needs response recovery.
    Nonlinear,
}

/// The JSON sidecar of a capture (docs/ARCHITECTURE.md, "File formats"). Unknown keys are ignored.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Sidecar {
    /// Exposure time in seconds.
    pub shutter_s: f64,
    /// ISO speed; `null` where the body has no ISO setting (taken as 100). Written as
    /// an integer when it is whole (`"iso":100`), as cameras report it.
    #[serde(serialize_with = "serialize_iso")]
    pub iso: Option<f64>,
    /// Light-arm angle θL in degrees.
    pub theta_l: f64,
    pub camera: String,
    /// Capture time, RFC 3339.
    pub time: String,
    /// Black level in file counts, overriding the file's own.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub black_level: Option<f64>,
    /// White (clipping) level in file counts, overriding the file's own.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub white_level: Option<f64>,
    #[serde(default)]
    pub response: Response,
    /// How many of the 16 bits of a TIFF value carry signal, at its top: an N-bit
    /// sensor count is stored times 2^(16−N) (docs/ARCHITECTURE.md, "File formats").
    /// Informative; the levels above are in stored units.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub significant_bits: Option<u32>,
    /// Lens aperture as an f-number N (f/N), informative; checked when present.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub aperture: Option<f64>,
    /// Image width in pixels as stored in the file, checked when present.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub width: Option<u32>,
    /// Image height in pixels as stored in the file, checked when present.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub height: Option<u32>,
}

fn serialize_iso<S: serde::Serializer>(iso: &Option<f64>, s: S) -> Result<S::Ok, S::Error> {
    match iso {
        Some(v) if v.fract() == 0.0 && (0.0..=u32::MAX as f64).contains(v) => {
            s.serialize_u32(*v as u32)
        }
        Some(v) => s.serialize_f64(*v),
        None => s.serialize_none(),
    }
}

impl Sidecar {
    /// Relative exposure H = shutter_s · ISO/100 (seconds at ISO 100).
    pub fn exposure(&self) -> f64 {
        self.shutter_s * self.iso.unwrap_or(100.0) / 100.0
    }

    /// Checks every value against its physical range (docs/ARCHITECTURE.md, "File
    /// formats"), and θL against the `theta_l_<θL>` directory `image` is in, if it is
    /// in one. `path` is the sidecar's.
    fn validate(&self, path: &Path, image: &Path) -> Result<(), CaptureError> {
        let bad = |field: &'static str, reason: String| CaptureError::InvalidSidecar {
            path: path.to_path_buf(),
            field,
            reason,
        };
        let (shortest, longest) = SHUTTER_RANGE_S;
        if !(self.shutter_s.is_finite() && (shortest..=longest).contains(&self.shutter_s)) {
            return Err(bad(
                "shutter_s",
                format!(
                    "{} is not an exposure time in [{shortest:e}, {longest}] s",
                    Brief(self.shutter_s)
                ),
            ));
        }
        if let Some(iso) = self.iso {
            let (lowest, highest) = ISO_RANGE;
            if !(iso.is_finite() && (lowest..=highest).contains(&iso)) {
                return Err(bad(
                    "iso",
                    format!(
                        "{} is not an ISO speed in [{lowest}, {highest}]",
                        Brief(iso)
                    ),
                ));
            }
        }
        if !(self.theta_l.is_finite() && self.theta_l.abs() <= 180.0) {
            return Err(bad(
                "theta_l",
                format!(
                    "{} is not an angle in [-180, 180] degrees",
                    Brief(self.theta_l)
                ),
            ));
        }
        if let Some((dir, theta_l)) = theta_l_directory(image) {
            if (self.theta_l - theta_l).abs() > THETA_DIR_TOLERANCE_DEG {
                return Err(bad(
                    "theta_l",
                    format!("{} but the frame is in {dir}/ (θL {theta_l})", self.theta_l),
                ));
            }
        }
        if let Some(n) = self.aperture {
            let (widest, narrowest) = APERTURE_RANGE;
            if !(n.is_finite() && (widest..=narrowest).contains(&n)) {
                return Err(bad(
                    "aperture",
                    format!("{} is not an f-number in [{widest}, {narrowest}]", Brief(n)),
                ));
            }
        }
        if let Some(bits) = self.significant_bits {
            if !(1..=16).contains(&bits) {
                return Err(bad(
                    "significant_bits",
                    format!("{bits} is not a bit count in 1..=16"),
                ));
            }
        }
        for (field, level) in [
            ("black_level", self.black_level),
            ("white_level", self.white_level),
        ] {
            if let Some(v) = level {
                if !(v.is_finite() && (0.0..=MAX_COUNT).contains(&v)) {
                    return Err(bad(
                        field,
                        format!("{} is not a count in [0, {MAX_COUNT}]", Brief(v)),
                    ));
                }
            }
        }
        Ok(())
    }
}

/// Exposure times a sidecar may state, seconds: a microsecond to an hour.
pub const SHUTTER_RANGE_S: (f64, f64) = (1e-6, 3600.0);
/// ISO speeds a sidecar may state.
pub const ISO_RANGE: (f64, f64) = (25.0, 409_600.0);
/// f-numbers a sidecar may state: from the limit of a lens in air (f/0.5) to a
/// pinhole's (f/1024).
pub const APERTURE_RANGE: (f64, f64) = (0.5, 1024.0);
/// Largest count a sidecar level may state (16-bit files).
const MAX_COUNT: f64 = u16::MAX as f64;
/// How far a sidecar's θL may be from its directory's name, written to 0.1°.
pub(crate) const THETA_DIR_TOLERANCE_DEG: f64 = 0.05 + 1e-6;

/// The name of the `theta_l_<θL>` directory `image` is in, and its θL.
pub(crate) fn theta_l_directory(image: &Path) -> Option<(String, f64)> {
    let dir = image.parent()?.file_name()?.to_str()?;
    let theta_l = dir
        .strip_prefix("theta_l_")?
        .parse::<f64>()
        .ok()
        .filter(|t| t.is_finite())?;
    Some((dir.to_owned(), theta_l))
}

/// The sidecar path of an image: same stem, `.json`.
pub fn sidecar_path(image: &Path) -> PathBuf {
    image.with_extension("json")
}

/// Reads and validates the sidecar of `image`.
pub fn read_sidecar(image: &Path) -> Result<Sidecar, CaptureError> {
    let path = sidecar_path(image);
    let text = match read_input_to_string(&path, MAX_SMALL_FILE_BYTES) {
        Ok(text) => text,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            return Err(CaptureError::MissingSidecar {
                image: image.to_path_buf(),
                sidecar: path,
            })
        }
        Err(error) => return Err(CaptureError::SidecarIo { path, error }),
    };
    let sidecar: Sidecar =
        serde_json::from_str(&text).map_err(|error| CaptureError::SidecarJson {
            path: path.clone(),
            error,
        })?;
    sidecar.validate(&path, image)?;
    Ok(sidecar)
}
