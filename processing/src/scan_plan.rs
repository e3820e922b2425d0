//! What a scan set out to capture (`plan.json` in the scan directory) and what of it a
//! scan directory lacks (docs/ARCHITECTURE.md, "File formats", plan.json).
//!
//! `gonio simulate` and the daemon write the plan when a scan starts: its θL and, for a
//! fixed bracket, its shutter times. The offline commands compare a directory with it
//! before they read it, so that a θL or frame lost to a crash, a copy or a hand is named
//! rather than silently left out of every result.
#![doc = include_str!("scan_plan.md")]

use std::collections::BTreeMap;
use std::fmt;
use std::path::{Path, PathBuf};

use gonio_files::scan_layout::format_shutter;
use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::capture;

/// File name of the plan inside a scan directory.
pub const PLAN_FILE: &str = "plan.json";

/// Shutter times within this relative distance are the same exposure (a sidecar states
/// the time the camera set, which may round the one asked for).
const SHUTTER_MATCH_REL: f64 = 0.02;

/// How far a θL directory's name may be from a planned θL, degrees (names carry 0.1°).
const THETA_MATCH_DEG: f64 = capture::THETA_DIR_TOLERANCE_DEG;

/// What a scan set out to capture.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScanPlan {
    /// Light angles θL, degrees, in acquisition order.
    pub theta_l: Vec<f64>,
    /// Shutter times of every θL's bracket, seconds; `null` for a bracket chosen per θL
    /// by metering (its frames are then checked for gaps, not against a list).
    pub bracket_s: Option<Vec<f64>>,
}

/// Errors reading a plan.
#[derive(Debug, Error)]
pub enum PlanError {
    #[error("{path}: cannot read: {error}")]
    Io {
        path: PathBuf,
        error: std::io::Error,
    },
    #[error("{path}: invalid plan: {error}")]
    Json {
        path: PathBuf,
        error: serde_json::Error,
    },
    #[error("{path}: invalid plan: {reason}")]
    Invalid { path: PathBuf, reason: String },
    #[error(transparent)]
    Capture(#[from] capture::CaptureError),
    #[error(
        "{path}: a symbolic link: θL folders and captures must be plain directories and \
         files (a link is not followed)"
    )]
    Link { path: PathBuf },
    #[error("{path}: cannot list: {error}")]
    Walk {
        path: PathBuf,
        error: std::io::Error,
    },
}

impl ScanPlan {
    /// Reads `DIR/plan.json`; `None` when the directory has none (a scan written before
    /// plans were, or captures copied by hand).
    pub fn read(dir: &Path) -> Result<Option<ScanPlan>, PlanError> {
        let path = dir.join(PLAN_FILE);
        if !path.exists() {
            return Ok(None);
        }
        let bytes = gonio_files::input::read_input(&path, gonio_files::input::MAX_SMALL_FILE_BYTES)
            .map_err(|error| PlanError::Io {
                path: path.clone(),
                error,
            })?;
        let plan: ScanPlan = serde_json::from_slice(&bytes).map_err(|error| PlanError::Json {
            path: path.clone(),
            error,
        })?;
        plan.validate()
            .map_err(|reason| PlanError::Invalid { path, reason })?;
        Ok(Some(plan))
    }

    /// The planned θL that `present` (degrees) lacks.
    pub fn missing_theta_l(&self, present: &[f64]) -> Vec<f64> {
        self.theta_l
            .iter()
            .copied()
            .filter(|&t| !present.iter().any(|&p| (p - t).abs() <= THETA_MATCH_DEG))
            .collect()
    }

    /// The plan as written to `plan.json` (pretty JSON, a final newline).
    pub fn to_json_text(&self) -> String {
        let mut text = serde_json::to_string_pretty(self).expect("a plan serializes");
        text.push('\n');
        text
    }

    fn validate(&self) -> Result<(), String> {
        if self.theta_l.is_empty() {
            return Err("`theta_l` is empty".into());
        }
        if let Some(t) = self
            .theta_l
            .iter()
            .find(|t| !(t.is_finite() && t.abs() <= 180.0))
        {
            return Err(format!("`theta_l` holds {t}, not an angle in [-180, 180]"));
        }
        if let Some(bracket) = &self.bracket_s {
            let (shortest, longest) = capture::SHUTTER_RANGE_S;
            if bracket.is_empty() {
                return Err("`bracket_s` is empty (null for a metered bracket)".into());
            }
            if let Some(s) = bracket
                .iter()
                .find(|s| !(s.is_finite() && (shortest..=longest).contains(*s)))
            {
                return Err(format!("`bracket_s` holds {s}, not an exposure time"));
            }
        }
        Ok(())
    }
}

/// One thing a scan directory lacks against its plan, or a frame half there.
#[derive(Debug, Clone, PartialEq)]
pub enum Gap {
    /// A planned θL with no capture.
    ThetaL(f64),
    /// A planned exposure (shutter time, seconds) missing at a θL.
    Exposure { theta_l: f64, shutter_s: f64 },
    /// Exposure files numbered past a missing one (a metered bracket: `exp_00`, `exp_02`).
    Numbering { theta_l: f64, missing: String },
    /// An image file with no sidecar: its exposure is unknown, so it is not read.
    SidecarMissing(PathBuf),
    /// A sidecar whose image file is gone.
    ImageMissing(PathBuf),
}

impl fmt::Display for Gap {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Gap::ThetaL(t) => write!(f, "θL {t:.1}° (no capture)"),
            Gap::Exposure { theta_l, shutter_s } => {
                write!(
                    f,
                    "θL {theta_l:.1}°: the {} exposure",
                    format_shutter(*shutter_s)
                )
            }
            Gap::Numbering { theta_l, missing } => write!(f, "θL {theta_l:.1}°: {missing}"),
            Gap::SidecarMissing(p) => write!(f, "{}: no .json sidecar", p.display()),
            Gap::ImageMissing(p) => write!(f, "{}: sidecar without its image", p.display()),
        }
    }
}

/// What `dir` lacks: against `DIR/plan.json` when it has one (every planned θL, and for
/// a fixed bracket every planned exposure), and in any case every image without its
/// sidecar and every sidecar without its image. Empty when the scan is whole.
pub fn gaps(dir: &Path) -> Result<Vec<Gap>, PlanError> {
    let plan = ScanPlan::read(dir)?;
    let mut frames = Frames::default();
    frames.walk(dir)?;
    let mut gaps = Vec::new();
    if let Some(plan) = &plan {
        for &theta_l in &plan.theta_l {
            let Some(shutters) = frames.at(theta_l) else {
                gaps.push(Gap::ThetaL(theta_l));
                continue;
            };
            match &plan.bracket_s {
                Some(bracket) => gaps.extend(
                    bracket
                        .iter()
                        .filter(|&&s| !shutters.iter().any(|&have| same_shutter(have, s)))
                        .map(|&shutter_s| Gap::Exposure { theta_l, shutter_s }),
                ),
                None => gaps.extend(frames.numbering_gap(theta_l)),
            }
        }
    }
    gaps.extend(frames.without_sidecar.into_iter().map(Gap::SidecarMissing));
    gaps.extend(frames.without_image.into_iter().map(Gap::ImageMissing));
    Ok(gaps)
}

/// One line naming what is missing: the first few gaps and how many more.
pub fn describe(gaps: &[Gap]) -> String {
    const SHOWN: usize = 3;
    let mut listed: Vec<String> = gaps.iter().take(SHOWN).map(Gap::to_string).collect();
    if gaps.len() > SHOWN {
        listed.push(format!("and {} more", gaps.len() - SHOWN));
    }
    listed.join("; ")
}

fn same_shutter(a: f64, b: f64) -> bool {
    (a - b).abs() <= SHUTTER_MATCH_REL * a.abs().max(b.abs())
}

/// The captures found below a scan directory.
#[derive(Default)]
struct Frames {
    /// θL directory name → (θL, the exposure stems present, their shutter times).
    by_theta: BTreeMap<String, (f64, Vec<String>, Vec<f64>)>,
    without_sidecar: Vec<PathBuf>,
    without_image: Vec<PathBuf>,
}

impl Frames {
    fn walk(&mut self, dir: &Path) -> Result<(), PlanError> {
        let walk_error = |error| PlanError::Walk {
            path: dir.to_path_buf(),
            error,
        };
        let mut entries = Vec::new();
        for entry in std::fs::read_dir(dir).map_err(walk_error)? {
            let entry = entry.map_err(walk_error)?;
            entries.push((entry.path(), entry.file_type().map_err(walk_error)?));
        }
        entries.sort_by(|a, b| a.0.cmp(&b.0));
        let images: Vec<&PathBuf> = entries
            .iter()
            .filter(|(p, kind)| kind.is_file() && capture::is_capture_path(p))
            .map(|(p, _)| p)
            .collect();
        for (path, kind) in &entries {
            if crate::extract::captures::refused_link(path, kind) {
                return Err(PlanError::Link { path: path.clone() });
            }
            if kind.is_dir() {
                self.walk(path)?;
            } else if kind.is_file() && capture::is_capture_path(path) {
                self.image(path)?;
            } else if kind.is_file() && is_frame_sidecar(path) {
                let has_image = images
                    .iter()
                    .any(|image| &capture::sidecar_path(image) == path);
                if !has_image {
                    self.without_image.push(path.clone());
                }
            }
        }
        Ok(())
    }

    fn image(&mut self, image: &Path) -> Result<(), PlanError> {
        if !capture::sidecar_path(image).is_file() {
            self.without_sidecar.push(image.to_path_buf());
            return Ok(());
        }
        let Some((name, theta_l)) = capture::theta_l_directory(image) else {
            return Ok(());
        };
        let shutter_s = capture::read_sidecar(image)?.shutter_s;
        let entry = self
            .by_theta
            .entry(name)
            .or_insert_with(|| (theta_l, Vec::new(), Vec::new()));
        if let Some(stem) = image.file_stem().and_then(|s| s.to_str()) {
            entry.1.push(stem.to_owned());
        }
        entry.2.push(shutter_s);
        Ok(())
    }

    /// The shutter times found at `theta_l`, if its directory holds any capture.
    fn at(&self, theta_l: f64) -> Option<&[f64]> {
        self.by_theta
            .values()
            .find(|(t, stems, _)| (t - theta_l).abs() <= THETA_MATCH_DEG && !stems.is_empty())
            .map(|(_, _, shutters)| shutters.as_slice())
    }

    /// For `exp_NN` frames: the first number missing below the highest present.
    fn numbering_gap(&self, theta_l: f64) -> Option<Gap> {
        let (_, stems, _) = self
            .by_theta
            .values()
            .find(|(t, _, _)| (t - theta_l).abs() <= THETA_MATCH_DEG)?;
        let mut numbers: Vec<usize> = stems
            .iter()
            .filter_map(|s| s.strip_prefix("exp_")?.parse().ok())
            .collect();
        numbers.sort_unstable();
        numbers.dedup();
        let missing = (0..numbers.len()).find(|&i| numbers[i] != i)?;
        Some(Gap::Numbering {
            theta_l,
            missing: format!("exp_{missing:02} (frames after it are present)"),
        })
    }
}

/// Whether `path` is a frame's sidecar: a `.json` file inside a `theta_l_<θL>` directory.
fn is_frame_sidecar(path: &Path) -> bool {
    path.extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("json"))
        && capture::theta_l_directory(path).is_some()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(dir: &Path, theta: f64, index: usize, shutter_s: f64) {
        let d = dir.join(format!("theta_l_{theta:.1}"));
        std::fs::create_dir_all(&d).unwrap();
        std::fs::write(d.join(format!("exp_{index:02}.tiff")), b"x").unwrap();
        let sidecar = serde_json::json!({"shutter_s": shutter_s, "theta_l": theta,
            "iso": 100, "camera": "test", "time": "2026-01-01T00:00:00Z"});
        std::fs::write(d.join(format!("exp_{index:02}.json")), sidecar.to_string()).unwrap();
    }

    fn plan(dir: &Path, theta_l: &[f64], bracket_s: Option<&[f64]>) {
        let plan = ScanPlan {
            theta_l: theta_l.to_vec(),
            bracket_s: bracket_s.map(<[f64]>::to_vec),
        };
        std::fs::write(dir.join(PLAN_FILE), plan.to_json_text()).unwrap();
    }

    #[test]
    fn a_whole_scan_has_no_gaps_and_each_kind_of_loss_is_named() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        plan(d, &[-20.0, -30.0], Some(&[0.01, 0.1]));
        for theta in [-20.0, -30.0] {
            frame(d, theta, 0, 0.01);
            frame(d, theta, 1, 0.1);
        }
        assert_eq!(gaps(d).unwrap(), vec![]);

        std::fs::remove_file(d.join("theta_l_-30.0/exp_01.tiff")).unwrap();
        let found = gaps(d).unwrap();
        assert_eq!(
            found,
            vec![
                Gap::Exposure {
                    theta_l: -30.0,
                    shutter_s: 0.1
                },
                Gap::ImageMissing(d.join("theta_l_-30.0/exp_01.json")),
            ]
        );
        assert!(describe(&found).contains("θL -30.0°: the 1/10 s exposure"));

        std::fs::remove_dir_all(d.join("theta_l_-20.0")).unwrap();
        assert_eq!(gaps(d).unwrap()[0], Gap::ThetaL(-20.0));
    }

    #[test]
    fn a_metered_bracket_is_checked_for_numbering_gaps_and_stray_images_are_named() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        plan(d, &[-20.0], None);
        frame(d, -20.0, 0, 0.01);
        frame(d, -20.0, 2, 0.5);
        std::fs::write(d.join("theta_l_-20.0/extra.tiff"), b"x").unwrap();
        let found = gaps(d).unwrap();
        assert_eq!(found.len(), 2, "{found:?}");
        assert!(
            matches!(&found[0], Gap::Numbering { missing, .. } if missing.starts_with("exp_01"))
        );
        assert_eq!(
            found[1],
            Gap::SidecarMissing(d.join("theta_l_-20.0/extra.tiff"))
        );
    }

    #[test]
    fn a_directory_without_a_plan_is_checked_for_half_frames_only() {
        let dir = tempfile::tempdir().unwrap();
        frame(dir.path(), -20.0, 0, 0.01);
        assert_eq!(gaps(dir.path()).unwrap(), vec![]);
    }

    #[test]
    fn a_bad_plan_is_refused_naming_the_field() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(
            dir.path().join(PLAN_FILE),
            r#"{"theta_l": [], "bracket_s": null}"#,
        )
        .unwrap();
        let err = ScanPlan::read(dir.path()).unwrap_err().to_string();
        assert!(err.contains("`theta_l` is empty"), "{err}");
        std::fs::write(dir.path().join(PLAN_FILE), r#"{"theta_l": [1e999]}"#).unwrap();
        assert!(ScanPlan::read(dir.path()).is_err());
    }
}
