//! Coverage of the uncertainty budget's expanded intervals (docs/ARCHITECTURE.md,
//! "Uncertainty budget") over emulated scans whose setup is not the one setup.json states.
//!
//! Each scan draws, from its own seed: a material (Cook–Torrance or Ward, every
//! coefficient and the roughness drawn), the camera's noise, and the world's departures
//! from the stated setup — white reflectance, camera offset and distance, light distance,
//! cylinder tilt, arm zero, one arm-angle error per θL, and (but on the defaults) the camera's
//! yaw and roll and the white's falloff toward grazing — each from the normal
//! distribution of the standard uncertainty its setup.json states. The scan is rendered
//! (`gonio simulate`, `[effects.misalignment]`), extracted (`gonio extract`, with its
//! uncertainty columns) and fitted with its own model; the test counts, per parameter, how
//! often the expanded interval (k = 2) holds the true value, and how often the fit's
//! noise-only 95 % interval does.
//!
//! The same on gonio's default uncertainties (no `uncertainty` block), and on those with
//! the camera turned and a white that is not Lambertian ([`Case::Lab`]).
//!
//! CI runs [`FAST_SCANS`] scans; `GONIO_COVERAGE_SCANS=N` runs N, and
//! `GONIO_COVERAGE_OUT=FILE` writes the figures as JSON (`bash scripts/results.sh
//! --coverage-only` runs 200 and writes docs/results' table from them).
//! `GONIO_COVERAGE_DRAW=key,…` draws only those sources' departures (setup.json keys;
//! the others stay at the stated setup), to compare one source's line with the spread
//! it makes; `GONIO_COVERAGE_SCANS_OUT=FILE` appends each scan's truth and budget to FILE
//! as a line of JSON.

use std::collections::BTreeMap;
use std::path::Path;

use gonio_processing::brdf::Model;
use gonio_processing::fit::budget::budget;
use gonio_processing::fit::{fit, FitOptions};
use gonio_processing::samples::read_csv;
use gonio_processing::setup_uncertainty::Source;
use gonio_processing::white_angular::DEFAULT_FALLOFF;
use gonio_tests::{gonio, temp_dir};
use serde_json::{json, Value};

const GOLD: &str = include_str!("../../../mock-hw/scenes/gold.toml");

/// Scans of the CI run.
const FAST_SCANS: usize = 16;

/// The arm angles of every scan.
const THETA_L: [f64; 4] = [-20.0, -28.0, -36.0, -45.0];

/// The standard uncertainties every scan's setup.json states: a setup calibrated by
/// `gonio calibrate`, a camera turned no more than that, and a certified white (its
/// falloff toward grazing known to 0.5 %).
fn stated() -> Value {
    json!({
        "white_reflectance": 0.005,
        "camera_offset_mm": 0.05,
        "camera_distance_mm": 1.0,
        "light_distance_mm": 2.0,
        "cylinder_tilt_deg": 0.03,
        "arm_zero_offset_deg": 0.05,
        "arm_angle_deg": 0.01,
        "camera_yaw_deg": 0.005,
        "camera_roll_deg": 0.03,
        "white_falloff": 0.005,
    })
}

/// A small deterministic generator (splitmix64: each output a strong hash of a counter,
/// so nearby seeds give independent streams), uniform and normal deviates.
struct Draws(u64);

impl Draws {
    fn uniform(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^= z >> 31;
        ((z >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }
    fn between(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.uniform()
    }
    fn normal(&mut self) -> f64 {
        let (a, b) = (self.uniform(), self.uniform());
        (-2.0 * a.ln()).sqrt() * (2.0 * std::f64::consts::PI * b).cos()
    }
}

/// What a run of scans states and how it is taken.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Case {
    /// setup.json states [`stated`]'s uncertainties; [`THETA_L`], sensor binned 8×8.
    Stated,
    /// setup.json states none: gonio's defaults ([`Source::default_uncertainty`]) hold;
    /// gold's six θL, sensor binned 4×4 — where a lab starts.
    Defaults,
    /// As [`Case::Defaults`], and the world's camera turned (yaw and roll) and its white
    /// not Lambertian (setup.json states the default falloff toward grazing, the world's
    /// departs from it), each drawn from its default: the sources a lab has beside those
    /// it measures with a ruler.
    Lab,
}

impl Case {
    /// The standard uncertainties the world's departures are drawn from.
    fn uncertainties(self) -> Value {
        match self {
            Case::Stated => stated(),
            Case::Defaults | Case::Lab => Value::Object(
                Source::ALL
                    .iter()
                    .filter(|s| self == Case::Lab || !LAB_SOURCES.contains(s))
                    .map(|s| (s.key().to_string(), json!(s.default_uncertainty())))
                    .collect(),
            ),
        }
    }
    fn binning(self) -> &'static str {
        match self {
            Case::Stated => "8",
            Case::Defaults | Case::Lab => "4",
        }
    }
    fn theta_l(self) -> Vec<f64> {
        match self {
            Case::Stated => THETA_L.to_vec(),
            Case::Defaults | Case::Lab => GOLD_THETA_L.to_vec(),
        }
    }
}

/// The sources only [`Case::Lab`] draws the world's departures from.
const LAB_SOURCES: [Source; 3] = [Source::CameraYaw, Source::CameraRoll, Source::WhiteFalloff];

/// gold's own arm angles.
const GOLD_THETA_L: [f64; 6] = [-20.0, -25.0, -30.0, -35.0, -40.0, -45.0];

/// The gold scene with another material, noise seed and the world's departures.
fn scene(index: usize, case: Case) -> (String, Model) {
    let mut draws =
        Draws(0x9e37_79b9_7f4a_7c15 ^ (index as u64 + 1).wrapping_mul(0xbf58_476d_1ce4_e5b9));
    let u = case.uncertainties();
    // `GONIO_COVERAGE_DRAW=key,key…` draws only those sources' departures (the others
    // at the stated setup; every draw is still taken, so the rest of the scan is alike).
    let drawn = std::env::var("GONIO_COVERAGE_DRAW").ok();
    let u = |key: &str| {
        let key_drawn = drawn
            .as_deref()
            .is_none_or(|d| d.split(',').any(|k| k.trim() == key));
        if key_drawn {
            u[key].as_f64().unwrap()
        } else {
            0.0
        }
    };
    let model = if index.is_multiple_of(2) {
        Model::CookTorrance
    } else {
        Model::Ward
    };
    let kd: Vec<f64> = (0..3).map(|_| draws.between(2.0, 12.0)).collect();
    let ks: Vec<f64> = (0..3).map(|_| draws.between(4.0, 30.0)).collect();
    let m = (draws.between(0.06f64.ln(), 0.3f64.ln())).exp();
    let sample = format!(
        "[sample]\nmodel = \"{model}\"\nkd = [{}, {}, {}]\nks = [{}, {}, {}]\nm = [{m}]\n",
        kd[0], kd[1], kd[2], ks[0], ks[1], ks[2]
    );
    let angles: Vec<String> = case
        .theta_l()
        .iter()
        .map(|_| (draws.normal() * u("arm_angle_deg")).to_string())
        .collect();
    let mut misalignment = format!(
        "[effects.misalignment]\nwhite_reflectance_error = {}\ncamera_offset_mm = {}\n\
         camera_distance_error_mm = {}\nlight_distance_error_mm = {}\ncylinder_tilt_deg = {}\n\
         arm_zero_offset_deg = {}\narm_angle_errors_deg = [{}]\n",
        draws.normal() * u("white_reflectance"),
        draws.normal() * u("camera_offset_mm"),
        draws.normal() * u("camera_distance_mm"),
        draws.normal() * u("light_distance_mm"),
        draws.normal() * u("cylinder_tilt_deg"),
        draws.normal() * u("arm_zero_offset_deg"),
        angles.join(", "),
    );
    if case != Case::Defaults {
        misalignment += &format!(
            "camera_yaw_deg = {}\ncamera_roll_deg = {}\nwhite_falloff = {}\n",
            draws.normal() * u("camera_yaw_deg"),
            draws.normal() * u("camera_roll_deg"),
            draws.normal() * u("white_falloff"),
        );
    }
    let start = GOLD.find("[sample]").unwrap();
    let end = start + GOLD[start..].find("\n\n").unwrap();
    let text = format!("{}{sample}{}", &GOLD[..start], &GOLD[end..])
        .replace(
            "theta_l_deg = [-20.0, -25.0, -30.0, -35.0, -40.0, -45.0]",
            &format!(
                "theta_l_deg = [{}]",
                case.theta_l()
                    .iter()
                    .map(|t| format!("{t:.1}"))
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        )
        .replace(
            "[effects]\nseed = 1",
            &format!("[effects]\nseed = {}", 1000 + index),
        );
    // The lab's white: setup.json states the default falloff (what extraction assumes
    // when it states none), the world's departs from it as drawn above.
    let text = match case {
        Case::Lab => text.replace(
            "reflectance = 0.99",
            &format!("reflectance = 0.99\nfalloff = {DEFAULT_FALLOFF}"),
        ),
        _ => text,
    };
    // setup.json states the nominal setup and the uncertainties the errors are drawn from
    // (none: the defaults).
    let block = match case {
        Case::Stated => {
            let stated: Vec<String> = stated()
                .as_object()
                .unwrap()
                .iter()
                .map(|(k, v)| format!("{k} = {v}"))
                .collect();
            format!("[setup.uncertainty]\n{}\n", stated.join("\n"))
        }
        Case::Defaults | Case::Lab => String::new(),
    };
    (format!("{text}\n{misalignment}\n{block}"), model)
}

/// Hits of one kind of interval, per parameter.
#[derive(Default)]
struct Tally(BTreeMap<String, (usize, usize)>);

impl Tally {
    fn add(&mut self, name: &str, hit: bool) {
        let entry = self.0.entry(name.to_string()).or_default();
        entry.0 += usize::from(hit);
        entry.1 += 1;
    }
    fn merge(&mut self, other: Tally) {
        for (name, (hit, n)) in other.0 {
            let entry = self.0.entry(name).or_default();
            entry.0 += hit;
            entry.1 += n;
        }
    }
}

/// One scan: rendered, extracted, fitted; each parameter's two intervals against its truth.
fn run(index: usize, case: Case, dir: &Path, expanded: &mut Tally, noise_only: &mut Tally) {
    let (text, model) = scene(index, case);
    let scene_path = dir.join(format!("scene-{index}.toml"));
    std::fs::write(&scene_path, text).unwrap();
    let scan = dir.join(format!("scan-{index}"));
    let s = |p: &Path| p.to_str().unwrap().to_owned();
    gonio(&[
        "simulate",
        "--scene",
        &s(&scene_path),
        "--binning",
        case.binning(),
        "--out",
        &s(&scan),
    ]);
    let csv = dir.join(format!("samples-{index}.csv"));
    gonio(&["extract", &s(&scan), "--out", &s(&csv)]);
    let truth: Value =
        serde_json::from_str(&std::fs::read_to_string(scan.join("truth.json")).unwrap()).unwrap();
    let samples = read_csv(&csv).unwrap();
    let result = fit(&samples, &FitOptions::new(model)).unwrap();
    let b = budget(&samples, &result).unwrap();
    let ci = result.ci95.as_ref().unwrap();
    let label = match model {
        Model::Ward => "ward",
        _ => "cook-torrance",
    };
    let truth_of = |key: &str, c: usize| truth[key][c].as_f64().unwrap();
    let noise_intervals = ci.kd.iter().chain(&ci.ks).chain(&ci.m);
    let truths = (0..3)
        .map(|c| truth_of("kd", c))
        .chain((0..3).map(|c| truth_of("ks", c)))
        .chain([truth_of("m", 0)]);
    for (((name, budgeted), noise), truth) in b.named().into_iter().zip(noise_intervals).zip(truths)
    {
        let name = format!("{label} {name}");
        let hit = budgeted.interval[0] <= truth && truth <= budgeted.interval[1];
        expanded.add(&name, hit);
        noise_only.add(&name, noise[0] <= truth && truth <= noise[1]);
    }
    if let Ok(out) = std::env::var("GONIO_COVERAGE_SCANS_OUT") {
        append_scan(
            &out,
            &json!({"scan": index, "case": format!("{case:?}"),
                                  "model": label, "truth": truth, "budget": b}),
        );
    }
    std::fs::remove_dir_all(&scan).ok();
}

/// Appends one scan's record (its truth, the world's departures among them, and its
/// budget) as a line of JSON to `out`: `GONIO_COVERAGE_SCANS_OUT=FILE` keeps every scan's,
/// to see which line of the budget holds and which does not.
fn append_scan(out: &str, record: &Value) {
    use std::io::Write;
    static LOCK: std::sync::Mutex<()> = std::sync::Mutex::new(());
    let _guard = LOCK.lock().unwrap_or_else(|e| e.into_inner());
    let mut file = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(out)
        .unwrap_or_else(|e| panic!("{out}: {e}"));
    writeln!(file, "{record}").unwrap_or_else(|e| panic!("{out}: {e}"));
}

/// Runs `scans` scans of `case` and prints, per parameter, how often each interval held
/// the truth; writes them as JSON to `out` when given. Returns the expanded intervals'
/// hits per parameter and the pooled coverage.
fn coverage(case: Case, scans: usize, out: Option<String>) -> (Tally, f64) {
    let dir = temp_dir(&format!("budget-coverage-{case:?}"));
    // Scans run on GONIO_COVERAGE_JOBS threads (default 1), each its own seed: the
    // figures do not depend on how many.
    let jobs = scans_of("GONIO_COVERAGE_JOBS", 1).max(1);
    let tallies: Vec<(Tally, Tally)> = std::thread::scope(|scope| {
        let workers: Vec<_> = (0..jobs)
            .map(|job| {
                let dir = &dir;
                scope.spawn(move || {
                    let (mut expanded, mut noise_only) = (Tally::default(), Tally::default());
                    for index in (job..scans).step_by(jobs) {
                        run(index, case, dir, &mut expanded, &mut noise_only);
                    }
                    (expanded, noise_only)
                })
            })
            .collect();
        workers.into_iter().map(|w| w.join().unwrap()).collect()
    });
    let (mut expanded, mut noise_only) = (Tally::default(), Tally::default());
    for (e, n) in tallies {
        expanded.merge(e);
        noise_only.merge(n);
    }
    std::fs::remove_dir_all(&dir).ok();
    println!("parameter            expanded (k = 2)   noise-only 95 %   ({scans} scans, {case:?})");
    let mut total = (0, 0);
    for ((name, (hit, n)), (_, (noise_hit, _))) in expanded.0.iter().zip(&noise_only.0) {
        println!(
            "{name:<20} {:>8.1} % ({hit}/{n}) {:>8.1} % ({noise_hit}/{n})",
            100.0 * *hit as f64 / *n as f64,
            100.0 * *noise_hit as f64 / *n as f64
        );
        total.0 += hit;
        total.1 += n;
    }
    let pooled = total.0 as f64 / total.1 as f64;
    println!("all parameters       {:>8.1} %", 100.0 * pooled);
    if let Some(out) = out {
        let parameters: Vec<Value> = expanded
            .0
            .iter()
            .zip(&noise_only.0)
            .map(|((name, (hit, n)), (_, (noise_hit, _)))| {
                json!({"parameter": name, "scans": n, "expanded_hits": hit,
                       "noise_only_hits": noise_hit})
            })
            .collect();
        let stated = match case {
            Case::Stated => stated(),
            Case::Defaults | Case::Lab => json!({}),
        };
        let report = json!({
            "scans": scans,
            "stated": stated,
            "drawn_from": case.uncertainties(),
            "binning": case.binning().parse::<u32>().unwrap(),
            "theta_l_deg": case.theta_l(),
            "parameters": parameters,
        });
        std::fs::write(&out, serde_json::to_string_pretty(&report).unwrap() + "\n")
            .unwrap_or_else(|e| panic!("{out}: {e}"));
    }
    (expanded, pooled)
}

/// The number `var` asks for, else `fast`.
fn scans_of(var: &str, fast: usize) -> usize {
    std::env::var(var)
        .ok()
        .map(|v| v.parse().unwrap_or_else(|_| panic!("{var} is a number")))
        .unwrap_or(fast)
}

#[test]
fn expanded_intervals_hold_the_truth_of_scans_whose_setup_is_off() {
    let scans = scans_of("GONIO_COVERAGE_SCANS", FAST_SCANS);
    let (expanded, pooled) = coverage(
        Case::Stated,
        scans,
        std::env::var("GONIO_COVERAGE_OUT").ok(),
    );
    // The seeds are fixed: the same scans every run. Few scans estimate a coverage
    // coarsely (16 scans, 8 per model: one miss is 12.5 %), so the fast run checks the
    // pooled figure and that no parameter falls far below; a full run (200 scans or more)
    // holds each in 92–99 %: the target is 92–98 %, and with 100 scans per model one
    // scan is 1 % (a coverage of 97 % comes out at 99 % or more one time in five).
    if scans >= 200 {
        for (name, (hit, n)) in &expanded.0 {
            let coverage = *hit as f64 / *n as f64;
            assert!((0.92..=0.99).contains(&coverage), "{name}: {coverage}");
        }
    } else {
        assert!((0.90..=0.995).contains(&pooled), "pooled coverage {pooled}");
        for (name, (hit, n)) in &expanded.0 {
            assert!(*hit as f64 >= 0.75 * *n as f64, "{name}: {hit}/{n}");
        }
    }
}

/// A full run (400 scans, 200 per model) holds each parameter in 92–98 %, the target;
/// a fast one (a few scans per model) holds the truth of most.
fn holds_the_target(scans: usize, expanded: &Tally, pooled: f64) {
    if scans >= 400 {
        for (name, (hit, n)) in &expanded.0 {
            let coverage = *hit as f64 / *n as f64;
            assert!((0.92..=0.98).contains(&coverage), "{name}: {coverage}");
        }
    } else {
        assert!(pooled >= 0.85, "pooled coverage {pooled}");
    }
}

/// Scans of the CI run on the defaults (each a 6-θL scan binned 4×4: several seconds).
const FAST_DEFAULT_SCANS: usize = 4;

#[test]
fn expanded_intervals_hold_the_truth_on_the_default_uncertainties() {
    let scans = scans_of("GONIO_COVERAGE_DEFAULTS_SCANS", FAST_DEFAULT_SCANS);
    let (expanded, pooled) = coverage(
        Case::Defaults,
        scans,
        std::env::var("GONIO_COVERAGE_DEFAULTS_OUT").ok(),
    );
    holds_the_target(scans, &expanded, pooled);
}

/// Scans of the CI run with the lab's further sources.
const FAST_LAB_SCANS: usize = 4;

#[test]
fn expanded_intervals_hold_the_truth_with_a_turned_camera_and_a_real_white() {
    let scans = scans_of("GONIO_COVERAGE_LAB_SCANS", FAST_LAB_SCANS);
    let (expanded, pooled) = coverage(
        Case::Lab,
        scans,
        std::env::var("GONIO_COVERAGE_LAB_OUT").ok(),
    );
    holds_the_target(scans, &expanded, pooled);
}
