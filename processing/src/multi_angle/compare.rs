//! A batch judged against its standard, angle by angle (docs/ARCHITECTURE.md,
//! "Multi-angle colour", compare): ΔL*, ΔC*, ΔH*, ΔE00 and the flop index's difference,
//! each with its uncertainty, and a verdict against tolerances per angle.
//!
//! The two scans' lines are matched by name: a systematic both scans share moves both
//! colours at once, so its line of a difference is the difference's change with both
//! moved; it cancels where the two colours are alike. Which systematics both share
//! depends on the mounting ([`Mounting`]): the white reference and the camera's colour
//! transform are the instrument's and always shared; the errors of the setup's geometry
//! (camera offset and distance, light distance, cylinder tilt, arm zero) are the
//! mounting's, shared only when both scans are of one mounting, and otherwise each
//! scan's own. Independent lines (noise, misfit, the arm's repeatability) of each scan
//! are lines of their own. A difference's standard uncertainty is the root sum of
//! squares of its lines: ΔL*, ΔC*, ΔH* and ΔFI by central differences, ΔE00 (not
//! differentiable where it is 0) by the larger one-sided change.
//! Verdict with U = k·u: pass when ΔE00 + U ≤ T, fail when ΔE00 − U > T, otherwise
//! undecided (the interval straddles the tolerance); overall fail if any angle fails,
//! else undecided if any is, else pass.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};
use thiserror::Error;

use super::{AngleColour, ColourReport, Coordinate, Origin, COVERAGE_FACTOR};
use crate::color::delta_e::{ciede2000, cielab_components, flop_index};
use crate::color::observer::Conditions;

/// The ΔE00 tolerance of an angle the tolerances do not name, and without a file.
pub const DEFAULT_DELTA_E00: f64 = 1.0;

/// Why two colours cannot be compared, or tolerances not used.
#[derive(Debug, Error, PartialEq)]
pub enum CompareError {
    #[error("the standard is stated under {standard}, the batch under {batch}")]
    Conditions { standard: String, batch: String },
    #[error("no aspecular angle is in both the standard and the batch")]
    NoCommonAngle,
    #[error("tolerances: {0}")]
    Tolerances(String),
}

/// Tolerances per angle (the TOML file of `gonio compare --tolerances`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Tolerances {
    /// ΔE00 per aspecular angle (keys the angle in degrees, `"15"`, `"-15"`) and
    /// `default` for the rest.
    #[serde(default)]
    pub delta_e00: BTreeMap<String, f64>,
    /// |ΔFI| allowed, when the flop index is judged.
    #[serde(default)]
    pub flop_index: Option<f64>,
}

impl Default for Tolerances {
    fn default() -> Self {
        Tolerances {
            delta_e00: BTreeMap::from([("default".to_string(), DEFAULT_DELTA_E00)]),
            flop_index: None,
        }
    }
}

impl Tolerances {
    /// Checks every key and value: keys `default` or an angle within −90…180°, values
    /// finite and positive.
    pub fn check(&self) -> Result<(), CompareError> {
        for (key, value) in &self.delta_e00 {
            if key != "default" {
                let angle: f64 = key.trim().parse().map_err(|_| {
                    CompareError::Tolerances(format!(
                        "delta_e00 key '{key}' is neither `default` nor an aspecular angle"
                    ))
                })?;
                if !(angle.is_finite() && (-90.0..=180.0).contains(&angle)) {
                    return Err(CompareError::Tolerances(format!(
                        "delta_e00 key '{key}' is not an aspecular angle within −90…180°"
                    )));
                }
            }
            if !(value.is_finite() && *value > 0.0) {
                return Err(CompareError::Tolerances(format!(
                    "delta_e00.{key} = {value} is not a positive number"
                )));
            }
        }
        if let Some(t) = self.flop_index {
            if !(t.is_finite() && t > 0.0) {
                return Err(CompareError::Tolerances(format!(
                    "flop_index = {t} is not a positive number"
                )));
            }
        }
        Ok(())
    }

    /// The ΔE00 tolerance at `aspecular`.
    pub fn delta_e00_at(&self, aspecular: f64) -> f64 {
        self.delta_e00
            .iter()
            .find(|(k, _)| {
                k.trim()
                    .parse::<f64>()
                    .is_ok_and(|a| (a - aspecular).abs() < 1e-9)
            })
            .or_else(|| self.delta_e00.get_key_value("default"))
            .map_or(DEFAULT_DELTA_E00, |(_, v)| *v)
    }
}

/// A verdict against a tolerance.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Verdict {
    Pass,
    Fail,
    Undecided,
}

impl Verdict {
    /// |value| against tolerance `t` with expanded uncertainty `u`.
    pub fn judge(value: f64, expanded: f64, t: f64) -> Self {
        if value.abs() + expanded <= t {
            Verdict::Pass
        } else if value.abs() - expanded > t {
            Verdict::Fail
        } else {
            Verdict::Undecided
        }
    }

    /// The overall verdict of several.
    pub fn overall(verdicts: impl IntoIterator<Item = Verdict>) -> Self {
        let mut out = Verdict::Pass;
        for v in verdicts {
            match v {
                Verdict::Fail => return Verdict::Fail,
                Verdict::Undecided => out = Verdict::Undecided,
                Verdict::Pass => {}
            }
        }
        out
    }

    pub fn name(self) -> &'static str {
        match self {
            Verdict::Pass => "pass",
            Verdict::Fail => "fail",
            Verdict::Undecided => "undecided",
        }
    }
}

/// One angle's differences (batch − standard).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AngleDifference {
    pub aspecular: f64,
    pub origin_standard: Origin,
    pub origin_batch: Origin,
    #[serde(rename = "delta_L")]
    pub delta_l: Coordinate,
    #[serde(rename = "delta_C")]
    pub delta_c: Coordinate,
    #[serde(rename = "delta_H")]
    pub delta_h: Coordinate,
    pub delta_e00: Coordinate,
    pub tolerance: f64,
    pub verdict: Verdict,
}

/// The flop indices and their difference.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FlopDifference {
    pub standard: f64,
    pub batch: f64,
    pub delta: Coordinate,
    pub tolerance: Option<f64>,
    pub verdict: Option<Verdict>,
}

/// `gonio compare`'s result.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Comparison {
    pub conditions: Conditions,
    pub coverage_factor: f64,
    pub angles: Vec<AngleDifference>,
    pub flop_index: Option<FlopDifference>,
    pub overall: Verdict,
}

/// Whether the two scans share the sample's mounting on the cylinder.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Mounting {
    /// Each scan mounted on its own (two samples, or one sample mounted again): the
    /// errors of the setup's geometry are each scan's own; only the instrument's white
    /// and colour transform cancel.
    #[default]
    Separate,
    /// One mounting, not moved between the scans: every systematic of the setup cancels
    /// where the colours are alike.
    Same,
}

/// Sources whose error is the same for every scan whatever its mounting (a line's
/// source is `<source>:<what it moved>`): the instrument's white (its reflectance and
/// its falloff towards grazing) and colour transform, and the model's misfit carried
/// beyond the measured range, which alike samples share.
const INSTRUMENT_SOURCES: [&str; 4] = [
    "white_reflectance",
    "white_falloff",
    "transform",
    super::EXTRAPOLATION,
];

/// Whether a shared line of `source` is shared by two scans of `mounting`.
fn shared_between(source: &str, mounting: Mounting) -> bool {
    let name = source.split(':').next().unwrap_or(source);
    mounting == Mounting::Same || INSTRUMENT_SOURCES.contains(&name)
}

/// Changes of L*a*b* at each angle compared.
type Changes = Vec<[f64; 3]>;

/// One line of a difference: whether shared, the standard's and the batch's change.
type PairLine = (bool, Changes, Changes);

/// The lines of the difference between `standard` and `batch` at the angles given, each
/// the change of every angle's L*a*b* of each scan: a systematic both scans share (by
/// `mounting`) is one line moving both, matched by name; a systematic of one scan only
/// is one line moving that scan's angles; an independent line moves its one angle.
/// The flag says whether both scans share the line.
fn pair_lines(
    standard: &[&AngleColour],
    batch: &[&AngleColour],
    mounting: Mounting,
) -> Vec<PairLine> {
    let n = standard.len();
    // By source, and by the scan it belongs to when only one scan has it.
    let mut systematic: BTreeMap<(String, Option<usize>), (Changes, Changes)> = BTreeMap::new();
    let mut out: Vec<PairLine> = Vec::new();
    for (side, angles) in [standard, batch].into_iter().enumerate() {
        for (k, angle) in angles.iter().enumerate() {
            for line in &angle.lines {
                let mut d = (vec![[0.0; 3]; n], vec![[0.0; 3]; n]);
                let changes = if line.shared {
                    let owner = (!shared_between(&line.source, mounting)).then_some(side);
                    systematic
                        .entry((line.source.clone(), owner))
                        .or_insert_with(|| d.clone())
                } else {
                    &mut d
                };
                if side == 0 {
                    changes.0[k] = line.lab;
                } else {
                    changes.1[k] = line.lab;
                }
                if !line.shared {
                    out.push((false, d.0, d.1));
                }
            }
        }
    }
    out.extend(
        systematic
            .into_iter()
            .map(|((_, owner), (s, b))| (owner.is_none(), s, b)),
    );
    out
}

/// A difference `f(standard L*a*b*s, batch L*a*b*s)` with its uncertainty over `lines`.
fn difference(
    lines: &[PairLine],
    standard: &[[f64; 3]],
    batch: &[[f64; 3]],
    one_sided: bool,
    f: impl Fn(&[[f64; 3]], &[[f64; 3]]) -> Option<f64>,
) -> Option<Coordinate> {
    let value = f(standard, batch)?;
    let shift = |x: &[[f64; 3]], d: &[[f64; 3]], sign: f64| -> Vec<[f64; 3]> {
        x.iter()
            .zip(d)
            .map(|(a, b)| std::array::from_fn(|c| a[c] + sign * b[c]))
            .collect()
    };
    let (mut independent, mut shared) = (0.0, 0.0);
    for (is_shared, ds, db) in lines {
        let up = f(&shift(standard, ds, 1.0), &shift(batch, db, 1.0))?;
        let down = f(&shift(standard, ds, -1.0), &shift(batch, db, -1.0))?;
        let change = if one_sided {
            (up - value).abs().max((down - value).abs())
        } else {
            (up - down) / 2.0
        };
        if *is_shared {
            shared += change * change;
        } else {
            independent += change * change;
        }
    }
    Some(Coordinate {
        value,
        u_independent: independent.sqrt(),
        u_shared: shared.sqrt(),
        expanded: COVERAGE_FACTOR * (independent + shared).sqrt(),
    })
}

/// `batch` against `standard` at every aspecular angle both hold.
pub fn compare(
    standard: &ColourReport,
    batch: &ColourReport,
    tolerances: &Tolerances,
    mounting: Mounting,
) -> Result<Comparison, CompareError> {
    tolerances.check()?;
    if standard.conditions != batch.conditions {
        return Err(CompareError::Conditions {
            standard: standard.conditions.name().into(),
            batch: batch.conditions.name().into(),
        });
    }
    let mut angles = Vec::new();
    for s in &standard.angles {
        let Some(b) = batch
            .angles
            .iter()
            .find(|b| (b.aspecular - s.aspecular).abs() < 1e-9)
        else {
            continue;
        };
        let lines = pair_lines(&[s], &[b], mounting);
        let (ls, lb) = ([s.lab()], [b.lab()]);
        let component = |i: usize| {
            difference(&lines, &ls, &lb, false, |x, y| {
                Some(cielab_components(x[0], y[0])[i])
            })
            .expect("CIELAB differences are defined everywhere")
        };
        let delta_e00 = difference(&lines, &ls, &lb, true, |x, y| Some(ciede2000(x[0], y[0])))
            .expect("CIEDE2000 is defined everywhere");
        let tolerance = tolerances.delta_e00_at(s.aspecular);
        angles.push(AngleDifference {
            aspecular: s.aspecular,
            origin_standard: s.origin,
            origin_batch: b.origin,
            delta_l: component(0),
            delta_c: component(1),
            delta_h: component(2),
            verdict: Verdict::judge(delta_e00.value, delta_e00.expanded, tolerance),
            delta_e00,
            tolerance,
        });
    }
    if angles.is_empty() {
        return Err(CompareError::NoCommonAngle);
    }
    let flop = flop_difference(standard, batch, tolerances, mounting);
    let overall = Verdict::overall(
        angles
            .iter()
            .map(|a| a.verdict)
            .chain(flop.as_ref().and_then(|f| f.verdict)),
    );
    Ok(Comparison {
        conditions: standard.conditions,
        coverage_factor: COVERAGE_FACTOR,
        angles,
        flop_index: flop,
        overall,
    })
}

/// ΔFI = FI(batch) − FI(standard) with its uncertainty, when both hold 15°, 45°, 110°.
fn flop_difference(
    standard: &ColourReport,
    batch: &ColourReport,
    tolerances: &Tolerances,
    mounting: Mounting,
) -> Option<FlopDifference> {
    let pick = |r: &'_ ColourReport| -> Option<Vec<AngleColour>> {
        [15.0, 45.0, 110.0]
            .iter()
            .map(|a| {
                r.angles
                    .iter()
                    .find(|c| (c.aspecular - a).abs() < 1e-9)
                    .cloned()
            })
            .collect()
    };
    let (s, b) = (pick(standard)?, pick(batch)?);
    let (sr, br): (Vec<&AngleColour>, Vec<&AngleColour>) = (s.iter().collect(), b.iter().collect());
    let lines = pair_lines(&sr, &br, mounting);
    let fi = |x: &[[f64; 3]]| flop_index(x[0][0], x[1][0], x[2][0]);
    let (ls, lb): (Vec<[f64; 3]>, Vec<[f64; 3]>) = (
        s.iter().map(|c| c.lab()).collect(),
        b.iter().map(|c| c.lab()).collect(),
    );
    let delta = difference(&lines, &ls, &lb, false, |x, y| Some(fi(y)? - fi(x)?))?;
    let verdict = tolerances
        .flop_index
        .map(|t| Verdict::judge(delta.value, delta.expanded, t));
    Some(FlopDifference {
        standard: fi(&ls)?,
        batch: fi(&lb)?,
        delta,
        tolerance: tolerances.flop_index,
        verdict,
    })
}
