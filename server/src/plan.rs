//! Scans as data: a validated request expands into the ordered steps of its journal,
//! stored before anything moves. Each step belongs to one lane (docs/ARCHITECTURE.md,
//! "Daemon"): the hardware lane moves and captures, the processing lane computes.

use gonio_files::scan_layout::format_shutter;
use serde::{Deserialize, Serialize};

/// What a scan measures, after validation ("auto" bracket already resolved).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ScanPlan {
    /// Sample name, safe as a path component.
    pub sample: String,
    /// Light angles θL, degrees, in acquisition order.
    pub theta_l: Vec<f64>,
    /// Shutter times of the bracket, seconds; empty for an automatic bracket.
    pub shutter_s: Vec<f64>,
    /// Whether each θL's bracket is chosen from a metering capture.
    pub auto_bracket: bool,
}

impl ScanPlan {
    /// What the scan directory's `plan.json` records: its θL and fixed bracket.
    pub fn folder_plan(&self) -> gonio_processing::scan_plan::ScanPlan {
        gonio_processing::scan_plan::ScanPlan {
            theta_l: self.theta_l.clone(),
            bracket_s: (!self.auto_bracket).then(|| self.shutter_s.clone()),
        }
    }
}

/// The reflection models fitted at the end of every scan, with their result file names.
pub const FIT_MODELS: [(&str, &str); 3] = [
    ("cook-torrance", "fit-cook-torrance.json"),
    ("ward", "fit-ward.json"),
    ("cook-torrance-fresnel", "fit-cook-torrance-fresnel.json"),
];

/// The last fit of every scan, after the [`FIT_MODELS`]: the model and roughness form
/// the scan's θL choose (`gonio fit --model auto`), with its result file name.
pub const AUTO_FIT: (&str, &str) = ("auto", "fit-auto.json");

/// Number of fit steps at the end of every scan: the [`FIT_MODELS`] and the [`AUTO_FIT`].
pub const FINAL_FITS: usize = FIT_MODELS.len() + 1;

/// Which thread runs a step.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Lane {
    /// Owns the arm and the camera: homing, moves, metering, captures.
    Hardware,
    /// Turns captures into results: HDR maps, samples, fits.
    Processing,
}

impl Lane {
    /// The lane's name, also its thread's.
    pub fn name(self) -> &'static str {
        match self {
            Lane::Hardware => "hardware",
            Lane::Processing => "processing",
        }
    }
}

/// One unit of work of a scan. Every step is idempotent on resume: a capture whose
/// frame already exists is not taken again, a processing step rewrites its outputs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(tag = "kind", rename_all = "snake_case")]
#[schema(as = StepKind)]
pub enum Step {
    /// Run the homing cycle.
    Home,
    /// Move the arm to θL (degrees).
    Move { theta_l: f64 },
    /// Take a metering capture at θL and choose its bracket; the capture steps of that
    /// bracket are added to the plan after this one.
    Meter { theta_l: f64 },
    /// Capture exposure `index` of the bracket at θL.
    Capture {
        theta_l: f64,
        index: usize,
        shutter_s: f64,
    },
    /// Extract the samples of θL's captures into `samples/theta_l_<θL>.csv` and update
    /// the live fits with every θL so far.
    Samples { theta_l: f64 },
    /// Merge the bracket of θL into `hdr/theta_l_<θL>.exr`.
    Hdr { theta_l: f64 },
    /// Gather the samples of every θL into `samples.csv`.
    Extract,
    /// Fit one model to `samples.csv`.
    Fit { model: String },
}

impl Step {
    /// One line for logs and progress views.
    pub fn describe(&self) -> String {
        match self {
            Step::Home => "home the arm".to_owned(),
            Step::Move { theta_l } => format!("move to θL {theta_l:.1}°"),
            Step::Meter { theta_l } => format!("meter θL {theta_l:.1}°"),
            Step::Capture {
                theta_l,
                index,
                shutter_s,
            } => format!(
                "capture θL {theta_l:.1}° exposure {index} ({})",
                format_shutter(*shutter_s)
            ),
            Step::Samples { theta_l } => format!("extract θL {theta_l:.1}° and fit"),
            Step::Hdr { theta_l } => format!("HDR merge θL {theta_l:.1}°"),
            Step::Extract => "extract samples".to_owned(),
            Step::Fit { model } => format!("fit {model}"),
        }
    }

    /// The lane that runs this step.
    pub fn lane(&self) -> Lane {
        match self {
            Step::Home | Step::Move { .. } | Step::Meter { .. } | Step::Capture { .. } => {
                Lane::Hardware
            }
            Step::Samples { .. } | Step::Hdr { .. } | Step::Extract | Step::Fit { .. } => {
                Lane::Processing
            }
        }
    }

    /// Whether the processing lane runs this step beside its others, as soon as the
    /// steps before it that it [`needs`](Step::needs) are done: a θL's HDR map (an
    /// input of no other step) and the [`AUTO_FIT`] (it reads `samples.csv` alone, not
    /// the fits of the [`FIT_MODELS`] before it, whose budgets it may share).
    pub fn runs_beside(&self) -> bool {
        match self {
            Step::Hdr { .. } => true,
            Step::Fit { model } => model == AUTO_FIT.0,
            _ => false,
        }
    }

    /// Whether this step waits for `before`, a step before it in the journal: an HDR
    /// map needs only its captures (and the hardware steps before them), the
    /// [`AUTO_FIT`] every step but the other fits and the maps (it reads `samples.csv`);
    /// every other step waits for all.
    pub fn needs(&self, before: &Step) -> bool {
        match self {
            Step::Hdr { .. } => before.lane() == Lane::Hardware,
            Step::Fit { model } if model == AUTO_FIT.0 => {
                !matches!(before, Step::Fit { .. } | Step::Hdr { .. })
            }
            _ => true,
        }
    }

    /// The θL whose bracket this step captures or processes, if it is one θL's.
    pub fn theta_l(&self) -> Option<f64> {
        match self {
            Step::Move { theta_l }
            | Step::Meter { theta_l }
            | Step::Capture { theta_l, .. }
            | Step::Samples { theta_l }
            | Step::Hdr { theta_l } => Some(*theta_l),
            Step::Home | Step::Extract | Step::Fit { .. } => None,
        }
    }
}

/// Why a scan waits for the operator to mount its sample (`POST
/// /api/scans/{id}/confirm` once it is on the cylinder).
pub fn mount_reason(sample: &str) -> String {
    format!("mount sample {sample}")
}

pub use gonio_files::scan_layout::theta_dir_name;

/// Samples file of one θL inside a scan directory (the rows of `samples.csv` at θL).
pub fn theta_samples_path(theta_l: f64) -> String {
    format!("samples/{}.csv", theta_dir_name(theta_l))
}

/// The live fits saved by one θL's samples step: the [`FIT_MODELS`] fitted to every θL
/// up to it, a JSON object of fit results by model.
pub fn theta_fits_path(theta_l: f64) -> String {
    format!("samples/{}.fits.json", theta_dir_name(theta_l))
}

/// HDR map of one θL inside a scan directory.
pub fn theta_map_path(theta_l: f64) -> String {
    format!("hdr/{}.exr", theta_dir_name(theta_l))
}

/// What one θL's HDR map was made from and its checksum, beside the map: a map whose
/// record matches its frames and its bytes is kept when its step runs again.
pub fn theta_map_record_path(theta_l: f64) -> String {
    format!("{}.json", theta_map_path(theta_l))
}

/// File stem of bracket exposure `index`.
pub fn exposure_stem(index: usize) -> String {
    format!("exp_{index:02}")
}

impl ScanPlan {
    /// The steps of the plan in journal order (an automatic bracket adds its captures
    /// when its metering step is done). A processing step needs the steps before it.
    pub fn steps(&self) -> Vec<Step> {
        let mut steps = vec![Step::Home];
        for &theta_l in &self.theta_l {
            steps.push(Step::Move { theta_l });
            if self.auto_bracket {
                steps.push(Step::Meter { theta_l });
            }
            steps.extend(Self::captures(theta_l, &self.shutter_s));
            steps.push(Step::Samples { theta_l });
            steps.push(Step::Hdr { theta_l });
        }
        steps.push(Step::Extract);
        steps.extend(
            FIT_MODELS
                .iter()
                .chain([&AUTO_FIT])
                .map(|(model, _)| Step::Fit {
                    model: (*model).to_owned(),
                }),
        );
        steps
    }

    /// The capture steps of a bracket at θL.
    pub fn captures(theta_l: f64, shutter_s: &[f64]) -> Vec<Step> {
        shutter_s
            .iter()
            .enumerate()
            .map(|(index, &shutter_s)| Step::Capture {
                theta_l,
                index,
                shutter_s,
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plan_expands_home_moves_brackets_hdr_and_processing() {
        let plan = ScanPlan {
            sample: "gold".into(),
            theta_l: vec![-20.0, -25.0],
            shutter_s: vec![0.1, 0.01, 0.001],
            auto_bracket: false,
        };
        let steps = plan.steps();
        assert_eq!(steps.len(), 1 + 2 * (1 + 3 + 2) + 1 + 4);
        assert_eq!(steps[0], Step::Home);
        assert_eq!(steps[1], Step::Move { theta_l: -20.0 });
        assert_eq!(
            steps[4],
            Step::Capture {
                theta_l: -20.0,
                index: 2,
                shutter_s: 0.001
            }
        );
        assert_eq!(steps[5], Step::Samples { theta_l: -20.0 });
        assert_eq!(steps[6], Step::Hdr { theta_l: -20.0 });
        assert_eq!(steps[13], Step::Extract);
        assert!(matches!(&steps[15], Step::Fit { model } if model == "ward"));
        assert!(matches!(&steps[16], Step::Fit { model } if model == "cook-torrance-fresnel"));
        assert!(matches!(&steps[17], Step::Fit { model } if model == "auto"));
        // Hardware steps move and capture; everything after a bracket is processing.
        let lanes: Vec<Lane> = steps.iter().map(Step::lane).collect();
        assert_eq!(lanes[..5], [Lane::Hardware; 5]);
        assert_eq!(lanes[5..7], [Lane::Processing; 2]);
        assert_eq!(lanes[13..], [Lane::Processing; 5]);
        assert_eq!(steps[6].theta_l(), Some(-20.0));
        assert_eq!(steps[13].theta_l(), None);
    }

    #[test]
    fn auto_plan_meters_each_angle_instead_of_fixed_captures() {
        let plan = ScanPlan {
            sample: "gold".into(),
            theta_l: vec![-20.0, -25.0],
            shutter_s: vec![],
            auto_bracket: true,
        };
        let steps = plan.steps();
        assert_eq!(
            &steps[..5],
            &[
                Step::Home,
                Step::Move { theta_l: -20.0 },
                Step::Meter { theta_l: -20.0 },
                Step::Samples { theta_l: -20.0 },
                Step::Hdr { theta_l: -20.0 }
            ]
        );
        assert_eq!(steps.len(), 1 + 2 * 4 + 5);
    }

    #[test]
    fn maps_and_the_auto_fit_run_beside_and_wait_only_for_their_inputs() {
        let auto = Step::Fit {
            model: AUTO_FIT.0.into(),
        };
        let ward = Step::Fit {
            model: "ward".into(),
        };
        let (samples, hdr) = (
            Step::Samples { theta_l: -45.0 },
            Step::Hdr { theta_l: -45.0 },
        );
        let capture = Step::Capture {
            theta_l: -45.0,
            index: 0,
            shutter_s: 0.1,
        };
        assert!(auto.runs_beside() && hdr.runs_beside());
        assert!(![&ward, &samples, &Step::Extract, &capture]
            .iter()
            .any(|s| s.runs_beside()));
        assert!(!auto.needs(&ward) && !auto.needs(&hdr));
        assert!(auto.needs(&Step::Extract) && auto.needs(&samples) && auto.needs(&capture));
        assert!(hdr.needs(&capture) && !hdr.needs(&samples) && !hdr.needs(&Step::Extract));
        assert!(ward.needs(&Step::Fit {
            model: "cook-torrance".into()
        }));
    }

    #[test]
    fn layout_names_follow_the_scan_directory_contract() {
        assert_eq!(theta_dir_name(-20.0), "theta_l_-20.0");
        assert_eq!(theta_dir_name(-32.5), "theta_l_-32.5");
        assert_eq!(exposure_stem(3), "exp_03");
        assert_eq!(theta_samples_path(-20.0), "samples/theta_l_-20.0.csv");
        assert_eq!(theta_map_path(-20.0), "hdr/theta_l_-20.0.exr");
        assert_eq!(theta_map_record_path(-20.0), "hdr/theta_l_-20.0.exr.json");
    }
}
