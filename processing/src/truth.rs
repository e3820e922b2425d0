//! A rendered scene's truth (`truth.json` of a simulated scan) and a fit's accuracy
//! against it.

use std::path::{Path, PathBuf};

use gonio_files::input::{read_input_to_string, MAX_SMALL_FILE_BYTES};
use serde::Deserialize;

use crate::brdf::{Model, Params, Roughness};
use crate::fit::FitResult;
use crate::reference::{Reference, ReferenceError};
use crate::samples::Sample;

/// Why a scene's truth could not be had.
#[derive(Debug, thiserror::Error)]
pub enum TruthError {
    #[error("reading {}: {source}", path.display())]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("parsing {}: {source}", path.display())]
    Parse {
        path: PathBuf,
        source: serde_json::Error,
    },
    #[error("{}: m must hold 1 or 3 values", path.display())]
    Roughness { path: PathBuf },
    #[error("reading {}: {source}", path.display())]
    Reference {
        path: PathBuf,
        source: ReferenceError,
    },
    #[error("no angle of the scan has a true β to compare with")]
    NoOverlap,
}

/// The fields of `truth.json` the tradeoff uses (camera-RGB β domain).
#[derive(Debug, Clone, Deserialize)]
struct TruthFile {
    scene: String,
    model: String,
    #[serde(default)]
    kd: Option<[f64; 3]>,
    #[serde(default)]
    ks: Option<[f64; 3]>,
    #[serde(default)]
    m: Option<Vec<f64>>,
}

/// A scene's truth: its parameters when its material is one of the fitted models.
#[derive(Debug, Clone, PartialEq)]
pub struct Truth {
    pub scene: String,
    /// The material's model name (`cook-torrance`, `ward`, `thin-film`, ...).
    pub material: String,
    /// Model, roughness form and parameters when the material is Cook–Torrance or Ward.
    pub model: Option<(Model, Roughness, Params)>,
}

impl Truth {
    /// Reads `truth.json` at `path`.
    pub fn read(path: &Path) -> Result<Truth, TruthError> {
        let text = read_input_to_string(path, MAX_SMALL_FILE_BYTES).map_err(|source| {
            TruthError::Read {
                path: path.to_path_buf(),
                source,
            }
        })?;
        let file: TruthFile = serde_json::from_str(&text).map_err(|source| TruthError::Parse {
            path: path.to_path_buf(),
            source,
        })?;
        let model = match (file.model.parse::<Model>(), file.kd, file.ks, &file.m) {
            (Ok(model), Some(kd), Some(ks), Some(m)) => {
                let (roughness, m) = match m.as_slice() {
                    [m] => (Roughness::Shared, [*m; 3]),
                    [r, g, b] => (Roughness::PerChannel, [*r, *g, *b]),
                    _ => {
                        return Err(TruthError::Roughness {
                            path: path.to_path_buf(),
                        })
                    }
                };
                Some((model, roughness, Params { kd, ks, m }))
            }
            _ => None,
        };
        Ok(Truth {
            scene: file.scene,
            material: file.model,
            model,
        })
    }
}

/// Where accuracy is measured: angles with the true β there.
#[derive(Debug, Clone)]
pub struct TruthPoints {
    pub angles: Vec<(f64, f64)>,
    pub beta: Vec<[f64; 3]>,
}

impl TruthPoints {
    /// The true β at the (θi, θr) of `samples`: the truth model itself when the material
    /// is Cook–Torrance or Ward, otherwise the scene's noise-free reference interpolated
    /// there (angles it does not cover are left out).
    pub fn new(truth: &Truth, samples: &[Sample], reference: &Path) -> Result<Self, TruthError> {
        let angles: Vec<(f64, f64)> = samples.iter().map(|s| (s.theta_i, s.theta_r)).collect();
        let (angles, beta) = match &truth.model {
            Some((model, _, params)) => {
                let beta = angles
                    .iter()
                    .map(|&(ti, tr)| model.evaluate(params, ti, tr))
                    .collect();
                (angles, beta)
            }
            None => {
                let reference =
                    Reference::read_csv(reference).map_err(|source| TruthError::Reference {
                        path: reference.to_path_buf(),
                        source,
                    })?;
                angles
                    .into_iter()
                    .filter_map(|(ti, tr)| reference.interpolate(ti, tr).map(|b| ((ti, tr), b)))
                    .unzip()
            }
        };
        if angles.is_empty() {
            return Err(TruthError::NoOverlap);
        }
        Ok(TruthPoints { angles, beta })
    }

    /// The fit's predictions at the truth angles.
    pub fn predict(&self, fit: &FitResult) -> Vec<[f64; 3]> {
        self.angles
            .iter()
            .map(|&(ti, tr)| fit.predict(ti, tr))
            .collect()
    }
}

/// ‖a − b‖ / ‖b‖ over the three channels.
fn relative(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    let norm = |v: [f64; 3]| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    let diff = norm(std::array::from_fn(|c| a[c] - b[c]));
    let scale = norm(*b);
    if scale > 0.0 {
        diff / scale
    } else {
        diff
    }
}

/// Relative parameter errors (Kd, Ks, m) of `fit` against the truth, when it is the
/// same model as the truth's.
pub fn parameter_errors(truth: &Truth, fit: &FitResult) -> Option<[f64; 3]> {
    let (model, _, p) = truth.model.as_ref()?;
    if *model != fit.model {
        return None;
    }
    let f = fit.params();
    Some([
        relative(&f.kd, &p.kd),
        relative(&f.ks, &p.ks),
        relative(&f.m, &p.m),
    ])
}
