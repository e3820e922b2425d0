//! What a study fits and computes: its variants and options, the scores of every
//! (combination, variant) fit, and their box-plot summaries.

use super::boxplot::BoxStats;
use crate::brdf::{Model, Roughness};
use crate::color::CameraModel;
pub use crate::fit::held_out::Errors;
use crate::fit::FitResult;
pub use crate::fit::Variant;

/// What a study fits.
#[derive(Debug, Clone, PartialEq)]
pub struct StudyOptions {
    pub variants: Vec<Variant>,
    /// Also fit each combination with Nelder–Mead and compare its loss.
    pub compare_nelder_mead: bool,
    /// A Nelder–Mead fit counts as stuck in a local minimum when its loss exceeds the
    /// robust loss by more than this fraction.
    pub local_minimum_margin: f64,
    /// Fit on every `stride`-th sample of each θL (1 = all); scoring uses all points.
    pub stride: usize,
}

impl Default for StudyOptions {
    /// Every model with shared roughness, Nelder–Mead compared at 0.1 %, every sample
    /// fitted.
    fn default() -> Self {
        StudyOptions {
            variants: Model::ALL
                .into_iter()
                .map(|model| Variant {
                    model,
                    roughness: Roughness::Shared,
                })
                .collect(),
            compare_nelder_mead: true,
            local_minimum_margin: 1e-3,
            stride: 1,
        }
    }
}

/// A setup angle pair where fits are scored, with the reference there.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EvalPoint {
    pub theta_l: f64,
    pub theta_i: f64,
    pub theta_r: f64,
    /// Reference β (camera RGB) interpolated at (θi, θr).
    pub reference: [f64; 3],
    /// CIE XYZ of `reference`.
    pub reference_xyz: [f64; 3],
}

/// The scores of one successful fit.
#[derive(Debug, Clone, PartialEq)]
pub struct Scores {
    /// The robust fit on the combination's samples.
    pub fit: FitResult,
    /// ΔErr_p (eq. 11) per channel against the reference at the evaluation points.
    pub err_p: [f64; 3],
    /// Mean ΔE_u′v′ (eq. 13) over the points with a defined chromaticity; `None` if none.
    pub delta_e_uv: Option<f64>,
    /// The same errors on the points of the θL the combination did not fit; `None` when
    /// it fitted them all (or their reference has no signal in a channel).
    pub held_out: Option<Errors>,
    /// Loss of the Nelder–Mead fit on the same samples (when compared and it succeeded).
    pub nelder_mead_loss: Option<f64>,
    /// The loss evaluations × points of the fits made for it (the robust fit's own,
    /// and Nelder–Mead's when compared): its work.
    pub point_evaluations: u64,
}

/// One (θL combination, variant) of a study.
#[derive(Debug, Clone, PartialEq)]
pub struct CombinationResult {
    pub theta_l: Vec<f64>,
    pub variant: Variant,
    /// The scores, or why the fit failed.
    pub outcome: Result<Scores, String>,
}

/// Box-plot statistics of one (variant, number of θL) group.
#[derive(Debug, Clone, PartialEq)]
pub struct GroupSummary {
    pub variant: Variant,
    pub size: usize,
    /// Combinations fitted and failed.
    pub fitted: usize,
    pub failed: usize,
    pub err_p: [Option<BoxStats>; 3],
    pub delta_e_uv: Option<BoxStats>,
    /// The same on the held-out points (combinations that left some θL out).
    pub held_out_err_p: [Option<BoxStats>; 3],
    pub held_out_delta_e_uv: Option<BoxStats>,
    /// Half-widths of the fits' 95 % intervals of Ks_G and of G's m, relative to the
    /// value: the error bars of a group's parameters.
    pub ks_g_ci95_relative: Option<BoxStats>,
    pub m_ci95_relative: Option<BoxStats>,
    /// Nelder–Mead fits compared, and those ending above the robust loss.
    pub nelder_mead_compared: usize,
    pub nelder_mead_above: usize,
}

/// Box-plot statistics of one variant's held-out errors over every combination that left
/// some θL out (62 of the 63 for six θL): the paper's protocol of judging a fit on
/// angles it did not see.
#[derive(Debug, Clone, PartialEq)]
pub struct HeldOutSummary {
    pub variant: Variant,
    /// Combinations with held-out points that were fitted.
    pub combinations: usize,
    pub err_p: [Option<BoxStats>; 3],
    pub delta_e_uv: Option<BoxStats>,
}

/// Everything a study computed.
#[derive(Debug, Clone, PartialEq)]
pub struct StudyReport {
    /// Distinct θL of the samples, in order of first appearance.
    pub theta_l: Vec<f64>,
    pub points: Vec<EvalPoint>,
    pub options: StudyOptions,
    /// The camera model whose RGB → XYZ matrix scores chromaticity.
    pub camera: CameraModel,
    /// Per combination (size, then lexicographic) and variant, in that order.
    pub results: Vec<CombinationResult>,
    /// Wall time of the fits and scoring, seconds.
    pub seconds: f64,
}

/// Half the widths of a fit's 95 % intervals of Ks_G and of G's m, relative to their
/// values; `None` without intervals or at a zero value.
fn relative_half_widths(scores: &Scores) -> [Option<f64>; 2] {
    let Some(ci) = scores.fit.ci95.as_ref() else {
        return [None, None];
    };
    let half = |[lo, hi]: [f64; 2], value: f64| (value > 0.0).then(|| (hi - lo) / (2.0 * value));
    [
        half(ci.ks[1], scores.fit.ks[1]),
        half(ci.m[1.min(ci.m.len() - 1)], scores.fit.params().m[1]),
    ]
}

impl Scores {
    /// Whether the Nelder–Mead loss exceeds the robust loss by more than `margin`
    /// (relative); `None` when Nelder–Mead was not compared or failed.
    pub fn nelder_mead_above(&self, margin: f64) -> Option<bool> {
        self.nelder_mead_loss
            .map(|nm| nm > self.fit.loss * (1.0 + margin))
    }
}

impl StudyReport {
    /// Box-plot statistics per variant and number of θL, variants in option order.
    pub fn summary(&self) -> Vec<GroupSummary> {
        let mut out = Vec::new();
        for &variant in &self.options.variants {
            for size in 1..=self.theta_l.len() {
                let group: Vec<&CombinationResult> = self
                    .results
                    .iter()
                    .filter(|r| r.variant == variant && r.theta_l.len() == size)
                    .collect();
                let scores: Vec<&Scores> = group
                    .iter()
                    .filter_map(|r| r.outcome.as_ref().ok())
                    .collect();
                let above: Vec<bool> = scores
                    .iter()
                    .filter_map(|s| s.nelder_mead_above(self.options.local_minimum_margin))
                    .collect();
                let channel = |c: usize| {
                    BoxStats::from_values(&scores.iter().map(|s| s.err_p[c]).collect::<Vec<_>>())
                };
                let held_out: Vec<&Errors> =
                    scores.iter().filter_map(|s| s.held_out.as_ref()).collect();
                let held_out_channel = |c: usize| {
                    BoxStats::from_values(&held_out.iter().map(|e| e.err_p[c]).collect::<Vec<_>>())
                };
                out.push(GroupSummary {
                    variant,
                    size,
                    fitted: scores.len(),
                    failed: group.len() - scores.len(),
                    err_p: [channel(0), channel(1), channel(2)],
                    delta_e_uv: BoxStats::from_values(
                        &scores
                            .iter()
                            .filter_map(|s| s.delta_e_uv)
                            .collect::<Vec<_>>(),
                    ),
                    held_out_err_p: [
                        held_out_channel(0),
                        held_out_channel(1),
                        held_out_channel(2),
                    ],
                    held_out_delta_e_uv: BoxStats::from_values(
                        &held_out
                            .iter()
                            .filter_map(|e| e.delta_e_uv)
                            .collect::<Vec<_>>(),
                    ),
                    ks_g_ci95_relative: BoxStats::from_values(
                        &scores
                            .iter()
                            .filter_map(|s| relative_half_widths(s)[0])
                            .collect::<Vec<_>>(),
                    ),
                    m_ci95_relative: BoxStats::from_values(
                        &scores
                            .iter()
                            .filter_map(|s| relative_half_widths(s)[1])
                            .collect::<Vec<_>>(),
                    ),
                    nelder_mead_compared: above.len(),
                    nelder_mead_above: above.iter().filter(|&&a| a).count(),
                });
            }
        }
        out
    }

    /// Held-out errors per variant over every combination that left some θL out,
    /// variants in option order.
    pub fn held_out_summary(&self) -> Vec<HeldOutSummary> {
        self.options
            .variants
            .iter()
            .map(|&variant| {
                let held_out: Vec<&Errors> = self
                    .results
                    .iter()
                    .filter(|r| r.variant == variant)
                    .filter_map(|r| r.outcome.as_ref().ok()?.held_out.as_ref())
                    .collect();
                let stats = |f: &dyn Fn(&Errors) -> Option<f64>| {
                    BoxStats::from_values(&held_out.iter().filter_map(|e| f(e)).collect::<Vec<_>>())
                };
                HeldOutSummary {
                    variant,
                    combinations: held_out.len(),
                    err_p: [
                        stats(&|e| Some(e.err_p[0])),
                        stats(&|e| Some(e.err_p[1])),
                        stats(&|e| Some(e.err_p[2])),
                    ],
                    delta_e_uv: stats(&|e| e.delta_e_uv),
                }
            })
            .collect()
    }

    /// The result of `variant` fitted on the single θL closest to `theta_l`.
    pub fn single(&self, variant: Variant, theta_l: f64) -> Option<&CombinationResult> {
        self.results
            .iter()
            .filter(|r| r.variant == variant && r.theta_l.len() == 1)
            .min_by(|a, b| {
                (a.theta_l[0] - theta_l)
                    .abs()
                    .total_cmp(&(b.theta_l[0] - theta_l).abs())
            })
    }
}
