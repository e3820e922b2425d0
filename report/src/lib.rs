//! gonio-report: a scan's report, one self-contained and printable HTML file a lab can
//! hand to whoever sent the sample (docs/ARCHITECTURE.md, "Scan report").
//!
//! It is made from the scan directory alone (setup.json, plan.json, the captures'
//! sidecars, samples.csv and the fit JSONs the daemon or the offline commands wrote)
//! plus what the caller knows of the scan ([`ScanFacts`]): nothing it shows is computed
//! anew but the fits' predictions at the measured points, for the plots, and the
//! multi-angle colour of the scan's model. It loads
//! nothing from the network: styles inline, plots as inline SVG.
#![doc = include_str!("report.md")]

mod colour;
mod html;
mod plots;
mod sections;

use std::path::{Path, PathBuf};

use gonio_files::input::{read_input_to_string, MAX_SMALL_FILE_BYTES};
use gonio_processing::fit::FitResult;
use gonio_processing::multi_angle::ColourReport;
use gonio_processing::samples::{self, Sample};
use serde_json::Value;
use thiserror::Error;

use html::escape;

/// What the caller knows of a scan beyond its directory (the daemon's record; the
/// offline command knows none of it). Times are RFC 3339.
#[derive(Debug, Clone, Default)]
pub struct ScanFacts {
    pub id: Option<i64>,
    pub sample: Option<String>,
    pub state: Option<String>,
    pub created: Option<String>,
    pub started: Option<String>,
    pub finished: Option<String>,
    /// The operator's notes on the scan.
    pub notes: Option<String>,
}

/// Errors making a report.
#[derive(Debug, Error)]
pub enum ReportError {
    #[error("{path}: cannot read: {error}")]
    Read {
        path: PathBuf,
        error: std::io::Error,
    },
    #[error("{path}: {reason}")]
    Invalid { path: PathBuf, reason: String },
    #[error(
        "{dir}: no samples.csv and no fit: nothing to report (extract and fit the scan first)"
    )]
    Empty { dir: PathBuf },
    #[error("{dir}: no fit: no colour to state (fit the scan first)")]
    NoFit { dir: PathBuf },
    #[error("{dir}: not a scan directory (no setup.json and no plan.json)")]
    NotAScan { dir: PathBuf },
}

/// The fit files a scan directory may hold, in the order the report prefers them as the
/// scan's model: the model choice, then the fixed models (docs/ARCHITECTURE.md,
/// "Daemon": the daemon's end-of-scan fits).
const FIT_FILES: [&str; 4] = [
    "fit-auto.json",
    "fit-cook-torrance.json",
    "fit-ward.json",
    "fit-cook-torrance-fresnel.json",
];

/// One fit file of the scan: its name, the fit and its JSON (for fields a reader of
/// this version may not know).
pub(crate) struct Fit {
    pub name: &'static str,
    pub fit: FitResult,
    pub json: Value,
}

/// What the report is made from, read from a scan directory.
pub(crate) struct Scan {
    pub dir: PathBuf,
    pub setup: Option<Value>,
    pub plan: Option<gonio_processing::scan_plan::ScanPlan>,
    pub gaps: Vec<gonio_processing::scan_plan::Gap>,
    pub samples: Vec<Sample>,
    pub fits: Vec<Fit>,
    pub truth: Option<Value>,
    /// First and last capture time of the sidecars (RFC 3339 as written).
    pub captured: Option<Captures>,
}

impl Scan {
    fn read(dir: &Path) -> Result<Scan, ReportError> {
        let invalid = |path: &Path, reason: String| ReportError::Invalid {
            path: path.to_path_buf(),
            reason,
        };
        let json_file = |name: &str| -> Result<Option<Value>, ReportError> {
            let path = dir.join(name);
            match read_input_to_string(&path, MAX_SMALL_FILE_BYTES) {
                Ok(text) => serde_json::from_str(&text)
                    .map(Some)
                    .map_err(|e| invalid(&path, format!("invalid JSON: {e}"))),
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
                Err(error) => Err(ReportError::Read { path, error }),
            }
        };
        let mut fits = Vec::new();
        for name in FIT_FILES {
            if let Some(json) = json_file(name)? {
                let fit = serde_json::from_value(json.clone())
                    .map_err(|e| invalid(&dir.join(name), format!("not a fit JSON: {e}")))?;
                fits.push(Fit { name, fit, json });
            }
        }
        let samples_path = dir.join("samples.csv");
        let samples = if samples_path.exists() {
            samples::read_csv(&samples_path).map_err(|e| invalid(&samples_path, e.to_string()))?
        } else {
            Vec::new()
        };
        if samples.is_empty() && fits.is_empty() {
            return Err(ReportError::Empty {
                dir: dir.to_path_buf(),
            });
        }
        let plan = gonio_processing::scan_plan::ScanPlan::read(dir)
            .map_err(|e| invalid(dir, e.to_string()))?;
        let setup = json_file("setup.json")?;
        if setup.is_none() && plan.is_none() {
            return Err(ReportError::NotAScan {
                dir: dir.to_path_buf(),
            });
        }
        let gaps = gonio_processing::scan_plan::gaps(dir).unwrap_or_default();
        Ok(Scan {
            dir: dir.to_path_buf(),
            setup,
            plan,
            gaps,
            samples,
            fits,
            truth: json_file("truth.json")?,
            captured: captures(dir),
        })
    }

    /// The fit the report presents as the scan's model: the model choice's if there is
    /// one, else the first fixed model's.
    pub fn chosen(&self) -> Option<&Fit> {
        self.fits.first()
    }

    /// The sample's name: the caller's, else the emulated scene's, else the directory's.
    fn sample_name(&self, facts: &ScanFacts) -> String {
        facts
            .sample
            .clone()
            .or_else(|| {
                let truth = self.truth.as_ref()?;
                truth
                    .get("scene")
                    .and_then(Value::as_str)
                    .map(str::to_owned)
            })
            .or_else(|| {
                self.dir
                    .file_name()
                    .map(|n| n.to_string_lossy().into_owned())
            })
            .unwrap_or_else(|| "scan".into())
    }
}

/// What the captures' sidecars below a scan directory say.
#[derive(Debug, Default)]
pub struct Captures {
    /// Earliest and latest capture time (RFC 3339 as written).
    pub first: String,
    pub last: String,
    /// The cameras named, each once.
    pub cameras: Vec<String>,
    /// Each θL's exposures (shutter times, seconds, longest first), θL in order.
    pub brackets: Vec<(f64, Vec<f64>)>,
}

/// The captures below `dir`, from their sidecars; `None` without any.
fn captures(dir: &Path) -> Option<Captures> {
    let mut sidecars = Vec::new();
    for entry in std::fs::read_dir(dir).ok()?.flatten() {
        let is_theta_dir = entry.file_type().is_ok_and(|t| t.is_dir())
            && entry.file_name().to_string_lossy().starts_with("theta_l_");
        if !is_theta_dir {
            continue;
        }
        for frame in std::fs::read_dir(entry.path()).ok()?.flatten() {
            let image = frame.path();
            if gonio_processing::capture::is_capture_path(&image) {
                if let Ok(sidecar) = gonio_processing::capture::read_sidecar(&image) {
                    sidecars.push(sidecar);
                }
            }
        }
    }
    let mut captures = Captures::default();
    // RFC 3339 times in one zone sort as text.
    let mut times: Vec<&str> = sidecars.iter().map(|s| s.time.as_str()).collect();
    times.sort();
    captures.first = (*times.first()?).to_owned();
    captures.last = (*times.last()?).to_owned();
    for sidecar in &sidecars {
        if !captures.cameras.contains(&sidecar.camera) {
            captures.cameras.push(sidecar.camera.clone());
        }
        match captures
            .brackets
            .iter_mut()
            .find(|(t, _)| *t == sidecar.theta_l)
        {
            Some((_, shutters)) => shutters.push(sidecar.shutter_s),
            None => captures
                .brackets
                .push((sidecar.theta_l, vec![sidecar.shutter_s])),
        }
    }
    captures.brackets.sort_by(|a, b| b.0.total_cmp(&a.0));
    for (_, shutters) in &mut captures.brackets {
        shutters.sort_by(|a, b| b.total_cmp(a));
    }
    Some(captures)
}

/// The report of the scan in `dir` as one HTML document; `version` is the software's,
/// `generated` the time it is made (RFC 3339).
pub fn render(
    dir: &Path,
    facts: &ScanFacts,
    version: &str,
    generated: &str,
) -> Result<String, ReportError> {
    let scan = Scan::read(dir)?;
    let sample = scan.sample_name(facts);
    let mut body = format!("<h1>BRDF measurement report: {}</h1>", escape(&sample));
    body += &sections::facts(&scan, facts, &sample, version, generated);
    body += &sections::plan(&scan);
    body += &sections::setup(&scan);
    body += &sections::model(&scan);
    body += &sections::budget(&scan);
    body += &plots::section(&scan);
    body += &colour::section(&scan);
    body += &sections::held_out(&scan);
    body += &sections::other_fits(&scan);
    body += &format!(
        "<footer>gonio {} · made {} from {}</footer>",
        escape(version),
        escape(generated),
        escape(&dir.display().to_string())
    );
    Ok(format!(
        "<!doctype html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">\
         <meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\
         <title>gonio report: {}</title><style>{STYLE}</style></head><body>{body}</body></html>\n",
        escape(&sample)
    ))
}

/// The multi-angle colour of the scan in `dir` as its report states it: CIELAB at ASTM
/// E2539's aspecular angles (D65, 10° observer) from the scan's model and its measured
/// table, each value with its expanded uncertainty.
pub fn multi_angle_colour(dir: &Path) -> Result<ColourReport, ReportError> {
    let scan = Scan::read(dir)?;
    if scan.chosen().is_none() {
        return Err(ReportError::NoFit {
            dir: dir.to_path_buf(),
        });
    }
    colour::scan_colour(&scan).map_err(|reason| ReportError::Invalid {
        path: dir.to_path_buf(),
        reason,
    })
}

/// The report's styles: readable on a screen of any width (tables scroll in their box,
/// plots scale), and on paper (A4, no scroll boxes, sections not split).
const STYLE: &str = "\
body{font:14px/1.4 system-ui,sans-serif;color:#222;margin:0 auto;max-width:1000px;padding:16px}\
h1{font-size:22px;margin:0 0 12px}h2{font-size:17px;margin:24px 0 8px;border-bottom:1px solid #ccc}\
h3{font-size:14px;margin:12px 0 4px}\
table{border-collapse:collapse;font-variant-numeric:tabular-nums}\
th,td{padding:2px 8px;border-bottom:1px solid #eee;text-align:right;font-size:13px}\
th:first-child,td:first-child{text-align:left}\
table.facts td,table.facts th{text-align:left}\
.scroll{overflow-x:auto;max-width:100%}\
.warn{color:#a40;font-weight:bold}\
.swatch{display:inline-block;width:28px;height:14px;border:1px solid #888;vertical-align:middle}.muted{color:#666;font-size:12px}\
svg{width:100%;height:auto;max-width:900px;display:block}\
footer{margin-top:32px;color:#666;font-size:12px}\
@media print{body{max-width:none;padding:0}.scroll{overflow:visible}section{break-inside:avoid}\
table.budget th,table.budget td{font-size:11px;padding:1px 4px}}\
@page{size:A4;margin:15mm}";

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_empty_directory_is_named_as_having_nothing_to_report() {
        let dir = tempfile::tempdir().unwrap();
        let err = render(dir.path(), &ScanFacts::default(), "0", "now").unwrap_err();
        assert!(matches!(err, ReportError::Empty { .. }), "{err}");
        assert!(err.to_string().contains("nothing to report"));
    }

    #[test]
    fn a_directory_that_is_not_a_scan_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(
            dir.path().join("samples.csv"),
            "theta_l,theta_i,theta_r,r,g,b\n-20,10,30,1,1,1\n",
        )
        .unwrap();
        let err = render(dir.path(), &ScanFacts::default(), "0", "now").unwrap_err();
        assert!(matches!(err, ReportError::NotAScan { .. }), "{err}");
        assert!(err.to_string().contains("not a scan directory"), "{err}");
    }

    #[test]
    fn a_bad_fit_file_is_named() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("fit-ward.json"), "{\"model\": 3}").unwrap();
        let err = render(dir.path(), &ScanFacts::default(), "0", "now").unwrap_err();
        assert!(
            err.to_string().contains("fit-ward.json: not a fit JSON"),
            "{err}"
        );
    }
}
