//! Validation of scan and sweep requests. Every invalid field is reported by name
//! (`theta_l[2]`, `bracket.shutter_s`, ...) and nothing is queued.

use gonio_processing::Brief;
use serde_json::{Map, Value};

use super::config::Limits;
use super::files::is_safe_name;
use super::plan::ScanPlan;
use gonio_files::scan_layout::same_theta_dir;

/// The first invalid field of a request.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{field}: {message}")]
pub struct FieldError {
    pub field: String,
    pub message: String,
}

fn invalid(field: impl Into<String>, message: impl Into<String>) -> FieldError {
    FieldError {
        field: field.into(),
        message: message.into(),
    }
}

/// What a request is checked against.
#[derive(Debug, Clone)]
pub struct Bounds {
    /// Soft limits of θL, degrees.
    pub limits: Limits,
    /// Shutter range of the camera, seconds.
    pub shutter_min_s: f64,
    pub shutter_max_s: f64,
    /// Most steps one request may queue (`max_steps_per_request`).
    pub max_steps: usize,
    /// The samples the instrument can hold, where it knows them (the emulator's
    /// scenes); `None`: any name.
    pub samples: Option<Vec<String>>,
    /// Samples whose carousel slot lies beyond the board's travel, each with why.
    pub unreachable: Vec<(String, String)>,
}

/// Most θL of one scan.
const MAX_THETA_L: usize = 181;
/// Most exposures of one bracket; an automatic bracket counts as this many captures
/// per θL against `max_steps_per_request`.
const MAX_BRACKET: usize = 32;
/// Most scans one sweep may queue.
pub const MAX_SWEEP_SCANS: usize = 1000;

fn object<'a>(value: &'a Value, allowed: &[&str]) -> Result<&'a Map<String, Value>, FieldError> {
    let map = value
        .as_object()
        .ok_or_else(|| invalid("body", "must be a JSON object"))?;
    if let Some(unknown) = map.keys().find(|k| !allowed.contains(&k.as_str())) {
        return Err(invalid(unknown.as_str(), "unknown field"));
    }
    Ok(map)
}

fn sample_name(field: &str, value: Option<&Value>) -> Result<String, FieldError> {
    let name = value
        .ok_or_else(|| invalid(field, "required"))?
        .as_str()
        .ok_or_else(|| invalid(field, "must be a string"))?;
    if !is_safe_name(name) {
        return Err(invalid(
            field,
            "must be 1-64 letters, digits, '-', '_' or '.', not starting with '.'",
        ));
    }
    Ok(name.to_owned())
}

/// Checks that the instrument can hold `sample` (field `field`).
fn holdable(field: &str, sample: &str, bounds: &Bounds) -> Result<(), FieldError> {
    match &bounds.samples {
        Some(names) if !names.iter().any(|n| n == sample) => Err(invalid(
            field,
            format!(
                "the instrument holds no sample {sample:?}; it holds {}",
                names.join(", ")
            ),
        )),
        _ => match bounds.unreachable.iter().find(|(name, _)| name == sample) {
            Some((_, why)) => Err(invalid(field, why.clone())),
            None => Ok(()),
        },
    }
}

fn theta_list(field: &str, value: Option<&Value>, limits: Limits) -> Result<Vec<f64>, FieldError> {
    let items = value
        .ok_or_else(|| invalid(field, "required"))?
        .as_array()
        .ok_or_else(|| invalid(field, "must be an array of angles in degrees"))?;
    if items.is_empty() || items.len() > MAX_THETA_L {
        return Err(invalid(
            field,
            format!("must hold 1 to {MAX_THETA_L} angles"),
        ));
    }
    let mut out: Vec<f64> = Vec::with_capacity(items.len());
    for (i, item) in items.iter().enumerate() {
        let f = format!("{field}[{i}]");
        let theta = item
            .as_f64()
            .filter(|t| t.is_finite())
            .ok_or_else(|| invalid(&f, "must be a number (degrees)"))?;
        if !(limits.min_deg..=limits.max_deg).contains(&theta) {
            return Err(invalid(
                &f,
                format!(
                    "{} is outside the soft limits [{}, {}]",
                    Brief(theta),
                    limits.min_deg,
                    limits.max_deg
                ),
            ));
        }
        // Directories are named with one decimal: angles must differ there.
        if let Some(same) = out.iter().find(|t| same_theta_dir(**t, theta)) {
            return Err(invalid(
                &f,
                format!("{theta} is listed twice (as {same} before, to 0.1°)"),
            ));
        }
        // -0.0 is stored as 0.
        out.push(theta + 0.0);
    }
    Ok(out)
}

/// The bracket: absent or `"auto"` (metered at each θL: no shutter times yet), or
/// `{"shutter_s": [...]}`; returns the shutter times and whether the bracket is
/// automatic.
fn bracket(value: Option<&Value>, bounds: &Bounds) -> Result<(Vec<f64>, bool), FieldError> {
    match value {
        None | Some(Value::Null) => Ok((Vec::new(), true)),
        Some(Value::String(s)) if s == "auto" => Ok((Vec::new(), true)),
        Some(v @ Value::Object(_)) => {
            let map = object(v, &["shutter_s"])
                .map_err(|e| invalid(format!("bracket.{}", e.field), e.message))?;
            let items = map
                .get("shutter_s")
                .ok_or_else(|| invalid("bracket.shutter_s", "required"))?
                .as_array()
                .ok_or_else(|| invalid("bracket.shutter_s", "must be an array of seconds"))?;
            if items.is_empty() || items.len() > MAX_BRACKET {
                return Err(invalid(
                    "bracket.shutter_s",
                    format!("must hold 1 to {MAX_BRACKET} shutter times"),
                ));
            }
            let (min, max) = (bounds.shutter_min_s, bounds.shutter_max_s);
            let mut out: Vec<f64> = Vec::with_capacity(items.len());
            for (i, item) in items.iter().enumerate() {
                let f = format!("bracket.shutter_s[{i}]");
                let s = item
                    .as_f64()
                    .filter(|s| s.is_finite() && *s > 0.0)
                    .ok_or_else(|| invalid(&f, "must be a positive number (seconds)"))?;
                if s < min * (1.0 - 1e-9) || s > max * (1.0 + 1e-9) {
                    return Err(invalid(
                        &f,
                        format!(
                            "{} s is outside the camera's range [{min}, {max}] s",
                            Brief(s)
                        ),
                    ));
                }
                if out.contains(&s) {
                    return Err(invalid(&f, format!("{s} s is listed twice")));
                }
                out.push(s);
            }
            Ok((out, false))
        }
        Some(_) => Err(invalid(
            "bracket",
            "must be \"auto\" or {\"shutter_s\": [seconds, ...]}",
        )),
    }
}

/// Checks a `POST /api/scans` body.
pub fn scan_request(body: &Value, bounds: &Bounds) -> Result<ScanPlan, FieldError> {
    let map = object(body, &["sample", "theta_l", "bracket"])?;
    let sample = sample_name("sample", map.get("sample"))?;
    let theta_l = theta_list("theta_l", map.get("theta_l"), bounds.limits)?;
    let (shutter_s, auto_bracket) = bracket(map.get("bracket"), bounds)?;
    let plan = ScanPlan {
        sample,
        theta_l,
        shutter_s,
        auto_bracket,
    };
    let steps = step_count(&plan.theta_l, &plan.shutter_s, auto_bracket);
    if steps > bounds.max_steps {
        return Err(invalid(
            if auto_bracket {
                "theta_l"
            } else {
                "bracket.shutter_s"
            },
            format!(
                "the scan would queue {steps} steps, more than max_steps_per_request = {}",
                bounds.max_steps
            ),
        ));
    }
    // Whether the instrument holds the sample comes last, as for a sweep.
    holdable("sample", &plan.sample, bounds)?;
    Ok(plan)
}

/// Steps one scan queues, counting an automatic bracket as [`MAX_BRACKET`] captures per
/// θL (they are planned when each θL is metered).
fn step_count(theta_l: &[f64], shutter_s: &[f64], auto_bracket: bool) -> usize {
    let captures = if auto_bracket {
        MAX_BRACKET
    } else {
        shutter_s.len()
    };
    // Home, then per θL: move, meter (auto), captures, HDR; then extract and the fits.
    let per_theta = 2 + usize::from(auto_bracket) + captures;
    1 + theta_l.len() * per_theta + 1 + super::plan::FINAL_FITS
}

/// A sweep's start time (`start_at`: RFC 3339, or absent or null for none), Unix
/// seconds.
fn start_at(value: Option<&Value>) -> Result<Option<i64>, FieldError> {
    let Some(v) = value.filter(|v| !v.is_null()) else {
        return Ok(None);
    };
    let text = v
        .as_str()
        .ok_or_else(|| invalid("start_at", "must be an RFC 3339 time string"))?;
    let time = time::OffsetDateTime::parse(text, &time::format_description::well_known::Rfc3339)
        .map_err(|e| invalid("start_at", format!("not an RFC 3339 time: {e}")))?;
    Ok(Some(time.unix_timestamp()))
}

/// Checks a `PATCH /api/sweeps/{id}` body: `{"start_at": RFC 3339 or null}` (null:
/// start now); returns the new start time, Unix seconds.
pub fn sweep_schedule(body: &Value) -> Result<Option<i64>, FieldError> {
    let map = object(body, &["start_at"])?;
    if !map.contains_key("start_at") {
        return Err(invalid("start_at", "required (null to start now)"));
    }
    start_at(map.get("start_at"))
}

/// A checked sweep: its scans in queue order and its start time (Unix seconds).
#[derive(Debug)]
pub struct SweepPlan {
    pub scans: Vec<ScanPlan>,
    pub start_at: Option<i64>,
}

/// Checks a `POST /api/sweeps` body: `samples` × `theta_l_sets` × `repeats` scans,
/// repeat-major (each round completes before the next begins).
pub fn sweep_request(body: &Value, bounds: &Bounds) -> Result<SweepPlan, FieldError> {
    let map = object(
        body,
        &["samples", "theta_l_sets", "repeats", "bracket", "start_at"],
    )?;
    let samples_value = map
        .get("samples")
        .ok_or_else(|| invalid("samples", "required"))?
        .as_array()
        .filter(|a| !a.is_empty())
        .ok_or_else(|| invalid("samples", "must be a non-empty array of sample names"))?;
    let samples = samples_value
        .iter()
        .enumerate()
        .map(|(i, v)| sample_name(&format!("samples[{i}]"), Some(v)))
        .collect::<Result<Vec<_>, _>>()?;
    let sets_value = map
        .get("theta_l_sets")
        .ok_or_else(|| invalid("theta_l_sets", "required"))?
        .as_array()
        .filter(|a| !a.is_empty())
        .ok_or_else(|| invalid("theta_l_sets", "must be a non-empty array of θL arrays"))?;
    let sets = sets_value
        .iter()
        .enumerate()
        .map(|(i, v)| theta_list(&format!("theta_l_sets[{i}]"), Some(v), bounds.limits))
        .collect::<Result<Vec<_>, _>>()?;
    let repeats = match map.get("repeats") {
        None | Some(Value::Null) => 1,
        Some(v) => v
            .as_u64()
            .filter(|r| (1..=MAX_SWEEP_SCANS as u64).contains(r))
            .ok_or_else(|| {
                invalid(
                    "repeats",
                    format!("must be a whole number from 1 to {MAX_SWEEP_SCANS}"),
                )
            })? as usize,
    };
    let (shutter_s, auto_bracket) = bracket(map.get("bracket"), bounds)?;
    // Checked before anything is expanded: the field named is the one whose size made
    // the request too large (the θL sets alone, then × samples, then × repeats).
    let set_steps: usize = sets
        .iter()
        .map(|set| step_count(set, &shutter_s, auto_bracket))
        .sum();
    let round_scans = samples.len() * sets.len();
    let total = round_scans * repeats;
    let total_steps = set_steps * samples.len() * repeats;
    let sizes = format!(
        "{} samples × {} θL sets × {repeats} repeats",
        samples.len(),
        sets.len()
    );
    for (field, scans, steps) in [
        ("theta_l_sets", sets.len(), set_steps),
        ("samples", round_scans, set_steps * samples.len()),
        ("repeats", total, total_steps),
    ] {
        if scans > MAX_SWEEP_SCANS {
            return Err(invalid(
                field,
                format!("{sizes} would queue {total} scans, more than {MAX_SWEEP_SCANS}"),
            ));
        }
        if steps > bounds.max_steps {
            return Err(invalid(
                field,
                format!(
                    "{sizes} would queue {total_steps} steps, more than \
                     max_steps_per_request = {}",
                    bounds.max_steps
                ),
            ));
        }
    }
    for (i, sample) in samples.iter().enumerate() {
        holdable(&format!("samples[{i}]"), sample, bounds)?;
    }
    let start_at = start_at(map.get("start_at"))?;
    let mut scans = Vec::with_capacity(total);
    for _ in 0..repeats {
        for sample in &samples {
            for theta_l in &sets {
                scans.push(ScanPlan {
                    sample: sample.clone(),
                    theta_l: theta_l.clone(),
                    shutter_s: shutter_s.clone(),
                    auto_bracket,
                });
            }
        }
    }
    Ok(SweepPlan { scans, start_at })
}

/// `{"angle": degrees}` of `POST /api/arm/position`: where the arm is now, on its
/// travel [−`max_travel_deg`, 0] (the home switch at 0).
pub fn arm_position(value: &Value, max_travel_deg: f64) -> Result<f64, FieldError> {
    let map = object(value, &["angle"])?;
    let angle = map
        .get("angle")
        .ok_or_else(|| invalid("angle", "required"))?
        .as_f64()
        .ok_or_else(|| invalid("angle", "must be a number of degrees"))?;
    if !(angle.is_finite() && (-max_travel_deg..=0.0).contains(&angle)) {
        return Err(invalid(
            "angle",
            format!(
                "{angle} is not on the arm's travel, [-{max_travel_deg}, 0] degrees \
                 (arm.max_travel_deg)"
            ),
        ));
    }
    Ok(angle)
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    fn bounds() -> Bounds {
        Bounds {
            limits: Limits {
                min_deg: -90.0,
                max_deg: 0.0,
            },
            shutter_min_s: 1.0 / 4000.0,
            shutter_max_s: 30.0,
            max_steps: 10_000,
            samples: None,
            unreachable: Vec::new(),
        }
    }

    fn field_of(body: Value) -> String {
        scan_request(&body, &bounds()).unwrap_err().field
    }

    #[test]
    fn valid_scan_defaults_to_the_auto_bracket() {
        let plan = scan_request(
            &json!({"sample": "gold", "theta_l": [-20, -25.5]}),
            &bounds(),
        )
        .unwrap();
        assert_eq!(plan.theta_l, vec![-20.0, -25.5]);
        assert!(plan.shutter_s.is_empty());
        assert!(plan.auto_bracket);
        let plan = scan_request(
            &json!({"sample": "g", "theta_l": [-20], "bracket": {"shutter_s": [0.5]}}),
            &bounds(),
        )
        .unwrap();
        assert_eq!((plan.shutter_s, plan.auto_bracket), (vec![0.5], false));
    }

    #[test]
    fn each_invalid_field_is_named() {
        assert_eq!(field_of(json!({"theta_l": [-20]})), "sample");
        assert_eq!(
            field_of(json!({"sample": "../x", "theta_l": [-20]})),
            "sample"
        );
        assert_eq!(field_of(json!({"sample": "g"})), "theta_l");
        assert_eq!(field_of(json!({"sample": "g", "theta_l": []})), "theta_l");
        assert_eq!(
            field_of(json!({"sample": "g", "theta_l": [-20, 10]})),
            "theta_l[1]"
        );
        assert_eq!(
            field_of(json!({"sample": "g", "theta_l": [-20, "x"]})),
            "theta_l[1]"
        );
        assert_eq!(
            field_of(json!({"sample": "g", "theta_l": [-20, -20]})),
            "theta_l[1]"
        );
        // Compared as numbers: 0 and -0.0 are one angle, as are -0.04 and 0.04.
        assert_eq!(
            field_of(json!({"sample": "g", "theta_l": [0, -0.0]})),
            "theta_l[1]"
        );
        assert_eq!(
            field_of(json!({"sample": "g", "theta_l": [-0.04, 0.04]})),
            "theta_l[1]"
        );
        // And as the directories are named: -1.25 and -1.2 are both theta_l_-1.2.
        assert_eq!(
            field_of(json!({"sample": "g", "theta_l": [-1.25, -1.2]})),
            "theta_l[1]"
        );
        let bracket = |b: Value| field_of(json!({"sample": "g", "theta_l": [-20], "bracket": b}));
        assert_eq!(bracket(json!({"shutter_s": []})), "bracket.shutter_s");
        assert_eq!(
            bracket(json!({"shutter_s": [0.1, 60]})),
            "bracket.shutter_s[1]"
        );
        assert_eq!(bracket(json!({"shutter_s": [-1]})), "bracket.shutter_s[0]");
        assert_eq!(bracket(json!({"shots": [1]})), "bracket.shots");
        assert_eq!(bracket(json!("manual")), "bracket");
        assert_eq!(
            field_of(json!({"sample": "g", "theta_l": [-20], "x": 1})),
            "x"
        );
        assert_eq!(field_of(json!([1])), "body");
    }

    #[test]
    fn too_large_requests_name_the_field_that_makes_them_too_large() {
        let sweep = |body: Value| sweep_request(&body, &bounds()).unwrap_err();
        let sets: Vec<Vec<f64>> = (0..40).map(|k| vec![-(k as f64)]).collect();
        let names: Vec<String> = (0..20).map(|k| format!("s{k}")).collect();
        // 40 one-angle sets of a 32-capture bracket: 40 × 38 = 1520 steps fit; × 20
        // samples do not, whatever the repeats.
        let bracket =
            json!({"shutter_s": (1..=32).map(|k| f64::from(k) / 100.0).collect::<Vec<_>>()});
        let err = sweep(
            json!({"samples": names, "theta_l_sets": sets, "bracket": bracket, "repeats": 1}),
        );
        assert_eq!(err.field, "samples", "{err}");
        assert!(err.message.contains("max_steps_per_request"), "{err}");
        let err = sweep(
            json!({"samples": ["a"], "theta_l_sets": sets, "bracket": bracket, "repeats": 7}),
        );
        assert_eq!(err.field, "repeats", "{err}");
        let err = sweep(json!({"samples": names, "theta_l_sets": [[-20]], "repeats": 60}));
        assert_eq!(err.field, "repeats", "{err}");
        assert!(err.message.contains("scans"), "{err}");
        let bounds = Bounds {
            max_steps: 100,
            ..bounds()
        };
        let many: Vec<f64> = (0..40).map(|k| -(k as f64)).collect();
        let err = scan_request(&json!({"sample": "g", "theta_l": many}), &bounds).unwrap_err();
        assert_eq!(err.field, "theta_l", "{err}");
    }

    #[test]
    fn a_sample_the_instrument_cannot_hold_is_named() {
        let bounds = Bounds {
            samples: Some(vec!["gold".into(), "red".into()]),
            ..bounds()
        };
        let err = scan_request(&json!({"sample": "blue", "theta_l": [-20]}), &bounds).unwrap_err();
        assert_eq!(err.field, "sample", "{err}");
        assert!(err.message.contains("gold, red"), "{err}");
        assert!(scan_request(&json!({"sample": "red", "theta_l": [-20]}), &bounds).is_ok());
        let err = sweep_request(
            &json!({"samples": ["gold", "blue"], "theta_l_sets": [[-20]]}),
            &bounds,
        )
        .unwrap_err();
        assert_eq!(err.field, "samples[1]", "{err}");
    }

    #[test]
    fn a_sample_whose_carousel_slot_is_beyond_the_travel_is_named() {
        let why = "carousel.slots.red = -250 is beyond the board's travel";
        let bounds = Bounds {
            samples: Some(vec!["gold".into(), "red".into()]),
            unreachable: vec![("red".into(), why.into())],
            ..bounds()
        };
        assert!(scan_request(&json!({"sample": "gold", "theta_l": [-20]}), &bounds).is_ok());
        let err = scan_request(&json!({"sample": "red", "theta_l": [-20]}), &bounds).unwrap_err();
        assert_eq!((err.field.as_str(), err.message.as_str()), ("sample", why));
        let err = sweep_request(
            &json!({"samples": ["gold", "red"], "theta_l_sets": [[-20]]}),
            &bounds,
        )
        .unwrap_err();
        assert_eq!(err.field, "samples[1]", "{err}");
    }

    #[test]
    fn sweep_expands_repeat_major_with_start_time() {
        let sweep = sweep_request(
            &json!({"samples": ["a", "b"], "theta_l_sets": [[-20], [-30, -40]],
                    "repeats": 2, "start_at": "2030-01-01T22:00:00Z"}),
            &bounds(),
        )
        .unwrap();
        assert_eq!(sweep.scans.len(), 8);
        assert_eq!(sweep.scans[0].sample, "a");
        assert_eq!(sweep.scans[1].theta_l, vec![-30.0, -40.0]);
        assert_eq!(sweep.scans[2].sample, "b");
        assert_eq!(sweep.scans[4].sample, "a");
        assert_eq!(sweep.start_at, Some(1_893_535_200));
        let err = sweep_request(
            &json!({"samples": ["a"], "theta_l_sets": [[-20, 5]]}),
            &bounds(),
        )
        .unwrap_err();
        assert_eq!(err.field, "theta_l_sets[0][1]");
        let err = sweep_request(
            &json!({"samples": ["a"], "theta_l_sets": [[-20]], "start_at": "tonight"}),
            &bounds(),
        )
        .unwrap_err();
        assert_eq!(err.field, "start_at");
    }

    #[test]
    fn a_declared_arm_position_lies_on_the_travel() {
        for angle in [0.0, -0.5, -180.0] {
            assert_eq!(arm_position(&json!({ "angle": angle }), 180.0), Ok(angle));
        }
        for angle in [10.0, 0.5, -180.5, 359.0, 1e300] {
            let err = arm_position(&json!({ "angle": angle }), 180.0).unwrap_err();
            assert_eq!(err.field, "angle");
            assert!(err.to_string().contains("[-180, 0]"), "{err}");
        }
        assert!(arm_position(&json!({ "angle": -190.0 }), 200.0).is_ok());
    }
}
