//! `gonio calibrate` against the emulator's misalignments (the built-in `gold` scene,
//! binned 4×, θL −20°, −30°, −45°): with the camera 3 mm off axis, the cylinder tilted
//! 0.5° and the arm's zero off by 0.3°, alone or together, it recovers each within
//! 0.03 mm, 0.03° and 0.08° (and within 4 of its stated standard uncertainties), and the
//! fits after calibration are as close to the truth as with the true setup (within
//! 0.2 % of those fits), while the nominal setup's are off by the amount each test
//! states; the misalignments a scan does not have come out as none. (At full size,
//! with six θL, the uncertainties are several times smaller.) The calibrated
//! setup.json's `uncertainty` block states the estimates' standard uncertainties and
//! keeps the prior's (the scene's `[setup.uncertainty]`) for the rest.

use std::path::Path;

use gonio_processing::brdf::Model;
use gonio_processing::fit::{fit, FitOptions, FitResult};
use gonio_processing::geometry::Setup;
use gonio_processing::samples::read_csv;
use gonio_tests::{gonio, temp_dir};
use serde_json::Value;

const GOLD: &str = include_str!("../../../mock-hw/scenes/gold.toml");
const THETA_L: &str = "--theta-l=-20,-30,-45";

/// The misalignments of a test, as the scene states them.
#[derive(Clone, Copy)]
struct Misalignment {
    camera_offset_mm: f64,
    cylinder_tilt_deg: f64,
    arm_zero_offset_deg: f64,
    camera_roll_deg: f64,
}

/// What one misaligned scan gave: the calibration block and the CT fits with the
/// nominal, true and calibrated setups, and the truth.
struct Outcome {
    calibration: Value,
    nominal: FitResult,
    true_setup: FitResult,
    calibrated: FitResult,
    truth: Value,
}

/// `gonio extract SCAN --setup SETUP`, then a Cook–Torrance fit of its samples.
fn fit_with(scan: &Path, setup: &Path) -> FitResult {
    let samples = scan.with_extension("csv");
    let s = |p: &Path| p.to_str().unwrap().to_owned();
    gonio(&[
        "extract",
        &s(scan),
        "--setup",
        &s(setup),
        "--out",
        &s(&samples),
    ]);
    fit(
        &read_csv(&samples).unwrap(),
        &FitOptions::new(Model::CookTorrance),
    )
    .unwrap()
}

fn run(name: &str, m: Misalignment) -> Outcome {
    let dir = temp_dir(&format!("calibration-{name}"));
    let scene = dir.join("scene.toml");
    std::fs::write(
        &scene,
        format!(
            "{GOLD}\n[effects.misalignment]\ncamera_offset_mm = {}\ncylinder_tilt_deg = {}\narm_zero_offset_deg = {}\ncamera_roll_deg = {}\n{PRIOR_UNCERTAINTY}",
            m.camera_offset_mm, m.cylinder_tilt_deg, m.arm_zero_offset_deg, m.camera_roll_deg
        ),
    )
    .unwrap();
    let scan = dir.join("scan");
    let out = dir.join("calibrated.json");
    let s = |p: &Path| p.to_str().unwrap().to_owned();
    gonio(&[
        "simulate",
        "--scene",
        &s(&scene),
        "--binning",
        "4",
        THETA_L,
        "--out",
        &s(&scan),
    ]);
    let summary = gonio(&["calibrate", &s(&scan), "--out", &s(&out)]);
    assert!(summary.contains("camera offset"), "{summary}");
    let written: Value = serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
    let nominal: Setup =
        serde_json::from_str(&std::fs::read_to_string(scan.join("setup.json")).unwrap()).unwrap();
    let true_setup = Setup {
        camera_offset_mm: m.camera_offset_mm,
        cylinder_tilt_deg: m.cylinder_tilt_deg,
        arm_zero_offset_deg: m.arm_zero_offset_deg,
        camera_roll_deg: m.camera_roll_deg,
        ..nominal.clone()
    };
    let true_path = dir.join("true-setup.json");
    std::fs::write(&true_path, serde_json::to_string(&true_setup).unwrap()).unwrap();
    let truth: Value =
        serde_json::from_str(&std::fs::read_to_string(scan.join("truth.json")).unwrap()).unwrap();
    assert_uncertainty_block(&written);
    let outcome = Outcome {
        calibration: written["calibration"].clone(),
        nominal: fit_with(&scan, &scan.join("setup.json")),
        true_setup: fit_with(&scan, &true_path),
        // The file calibrate wrote, `calibration` block and all, is a setup.
        calibrated: fit_with(&scan, &out),
        truth,
    };
    std::fs::remove_dir_all(dir).ok();
    outcome
}

/// The scene's `[setup.uncertainty]`, the prior's `uncertainty` block in setup.json.
const PRIOR_UNCERTAINTY: &str = "[setup.uncertainty]\nwhite_reflectance = [0.004, 0.003, 0.005]\n\
     camera_offset_mm = 0.7\ncamera_distance_mm = 0.9\nlight_distance_mm = 1.5\narm_angle_deg = 0.003\n";

/// The calibrated setup.json states each estimate's standard uncertainty in its
/// `uncertainty` block, and the prior's for the rest (here the camera distance, which
/// one lit limb cannot give).
fn assert_uncertainty_block(written: &Value) {
    let calibration = &written["calibration"];
    let stderr = |key: &str| calibration[key]["stderr"].clone();
    assert!(calibration["camera_distance_mm"].is_null());
    assert_eq!(
        written["uncertainty"],
        serde_json::json!({
            "white_reflectance": [0.004, 0.003, 0.005],
            "camera_offset_mm": stderr("camera_offset_mm"),
            "camera_distance_mm": 0.9,
            "light_distance_mm": 1.5,
            "cylinder_tilt_deg": stderr("cylinder_tilt_deg"),
            "arm_zero_offset_deg": stderr("arm_zero_offset_deg"),
            "arm_angle_deg": 0.003,
            "camera_yaw_deg": stderr("camera_yaw_deg"),
            "camera_roll_deg": stderr("camera_roll_deg"),
        })
    );
    // The estimates' own, not the prior's.
    assert_ne!(written["uncertainty"]["camera_offset_mm"], 0.7);
}

/// Checks one estimate against the truth: within `tolerance` and within 4 of its
/// stated standard uncertainties.
fn assert_recovered(calibration: &Value, key: &str, truth: f64, tolerance: f64) {
    let value = calibration[key]["value"].as_f64().unwrap();
    let stderr = calibration[key]["stderr"].as_f64().unwrap();
    let error = (value - truth).abs();
    assert!(
        error <= tolerance && error <= 4.0 * stderr && stderr > 0.0,
        "{key}: {value} ± {stderr}, truth {truth} (tolerance {tolerance})"
    );
}

/// The largest relative difference of Kd, Ks and m between two fits.
fn largest_difference(a: &FitResult, b: &FitResult) -> f64 {
    let (pa, pb) = (a.params(), b.params());
    (0..3)
        .flat_map(|c| {
            [
                pa.kd[c] / pb.kd[c] - 1.0,
                pa.ks[c] / pb.ks[c] - 1.0,
                pa.m[c] / pb.m[c] - 1.0,
            ]
        })
        .fold(0.0, |worst, d: f64| worst.max(d.abs()))
}

/// The largest relative error of Kd, Ks and m of a fit against truth.json.
fn largest_error(fit: &FitResult, truth: &Value) -> f64 {
    let p = fit.params();
    let t = |key: &str, c: usize| {
        truth[key][c.min(truth[key].as_array().unwrap().len() - 1)]
            .as_f64()
            .unwrap()
    };
    (0..3)
        .flat_map(|c| {
            [
                p.kd[c] / t("kd", c) - 1.0,
                p.ks[c] / t("ks", c) - 1.0,
                p.m[c] / t("m", c) - 1.0,
            ]
        })
        .fold(0.0, |worst, e: f64| worst.max(e.abs()))
}

fn assert_calibrated_fits_as_well_as_the_truth(o: &Outcome) {
    let (calibrated, exact) = (
        largest_error(&o.calibrated, &o.truth),
        largest_error(&o.true_setup, &o.truth),
    );
    assert!(
        largest_difference(&o.calibrated, &o.true_setup) < 2e-3,
        "calibrated {:?} vs true setup {:?}",
        o.calibrated,
        o.true_setup
    );
    assert!(calibrated < 3e-3 && exact < 3e-3, "{calibrated} {exact}");
}

/// Scans gold with misalignment `m`, checks that calibration recovers each of its
/// parts (and finds none of the others) and that the calibrated fits are as good as
/// the true setup's; returns the outcome for the test's own checks.
fn recovered(name: &str, m: Misalignment) -> Outcome {
    let o = run(name, m);
    assert_recovered(&o.calibration, "camera_offset_mm", m.camera_offset_mm, 0.03);
    assert_recovered(
        &o.calibration,
        "cylinder_tilt_deg",
        m.cylinder_tilt_deg,
        0.03,
    );
    assert_recovered(
        &o.calibration,
        "arm_zero_offset_deg",
        m.arm_zero_offset_deg,
        0.08,
    );
    assert_calibrated_fits_as_well_as_the_truth(&o);
    o
}

#[test]
fn every_misalignment_together_is_recovered() {
    let o = recovered(
        "all",
        Misalignment {
            camera_offset_mm: 3.0,
            cylinder_tilt_deg: 0.5,
            arm_zero_offset_deg: 0.3,
            camera_roll_deg: 0.0,
        },
    );
    // One limb lit (θL < 0 everywhere): the distance stays the prior's, and says so.
    assert!(o.calibration["camera_distance_mm"].is_null());
    assert!(o.calibration["residuals"]["chi2_per_dof"].as_f64().unwrap() < 4.0);
    // The uncalibrated setup misplaces every column by degrees: the fit is far off.
    assert!(largest_error(&o.nominal, &o.truth) > 0.1, "{:?}", o.nominal);
}

/// [`recovered`] for one misalignment alone; returns how far off the nominal setup's fit
/// is (the largest relative error of Kd, Ks and m).
fn nominal_error_alone(
    name: &str,
    camera_offset_mm: f64,
    cylinder_tilt_deg: f64,
    arm_zero_offset_deg: f64,
) -> f64 {
    let m = Misalignment {
        camera_offset_mm,
        cylinder_tilt_deg,
        arm_zero_offset_deg,
        camera_roll_deg: 0.0,
    };
    let o = recovered(name, m);
    largest_error(&o.nominal, &o.truth)
}

#[test]
fn a_camera_off_axis_alone_is_recovered() {
    let error = nominal_error_alone("camera", 3.0, 0.0, 0.0);
    assert!(error > 0.1, "nominal setup off by {error}");
}

#[test]
fn a_tilted_cylinder_alone_is_recovered() {
    // A tilt of 0.5° lifts the fitted Ks and m by about 0.7 %.
    let error = nominal_error_alone("tilt", 0.0, 0.5, 0.0);
    assert!(error > 4e-3, "nominal setup off by {error}");
}

#[test]
fn an_arm_zero_offset_alone_is_recovered() {
    // An arm 0.3° off lifts the fitted Ks by about 3 %.
    let error = nominal_error_alone("arm", 0.0, 0.0, 0.3);
    assert!(error > 0.015, "nominal setup off by {error}");
}

#[test]
fn a_rolled_camera_is_estimated_as_far_as_the_target_tells_it_from_a_tilt() {
    // A roll slants the picture as a tilt of the cylinder does; only the light's and the
    // camera's finite distances tell them apart, which this target barely sees. With the
    // default prior (0 ± 0.1°), a roll of 0.1° and the tilt each come out within 4 of
    // their standard uncertainties, the roll's no larger than its prior's; the camera's
    // yaw, 0 ± 0.01°, stays within its own.
    let o = run(
        "roll",
        Misalignment {
            camera_offset_mm: 0.0,
            cylinder_tilt_deg: 0.0,
            arm_zero_offset_deg: 0.0,
            camera_roll_deg: 0.1,
        },
    );
    let c = &o.calibration;
    let estimate = |key: &str| {
        (
            c[key]["value"].as_f64().unwrap(),
            c[key]["stderr"].as_f64().unwrap(),
        )
    };
    let (roll, roll_u) = estimate("camera_roll_deg");
    let (tilt, tilt_u) = estimate("cylinder_tilt_deg");
    let (yaw, yaw_u) = estimate("camera_yaw_deg");
    println!("roll {roll} ± {roll_u}, tilt {tilt} ± {tilt_u}, yaw {yaw} ± {yaw_u}");
    assert!(roll_u > 0.0 && roll_u <= 0.1 + 1e-9, "roll ± {roll_u}");
    assert!((roll - 0.1).abs() <= 4.0 * roll_u, "roll {roll} ± {roll_u}");
    assert!(tilt.abs() <= 4.0 * tilt_u, "tilt {tilt} ± {tilt_u}");
    assert!(
        yaw.abs() <= 4.0 * yaw_u && yaw_u <= 0.01 + 1e-9,
        "yaw {yaw} ± {yaw_u}"
    );
}

/// A white strip clipped in every frame has no edge to measure: calibrate refuses the
/// scan, naming the θL and the share clipped, rather than stating an offset the clipping
/// made (the gold scene 1,000× brighter, its bracket unchanged).
#[test]
fn an_overexposed_white_is_refused_not_measured() {
    let dir = temp_dir("calibration-overexposed");
    let scene = dir.join("scene.toml");
    std::fs::write(
        &scene,
        GOLD.replace("intensity = 6000.0", "intensity = 6000000.0"),
    )
    .unwrap();
    let s = |p: &Path| p.to_str().unwrap().to_owned();
    let scan = dir.join("scan");
    gonio(&[
        "simulate",
        "--scene",
        &s(&scene),
        "--binning",
        "8",
        "--theta-l=-20,-30",
        "--out",
        &s(&scan),
    ]);
    let output = std::process::Command::new(gonio_tests::gonio_bin())
        .args(["calibrate", &s(&scan), "--out", &s(&dir.join("c.json"))])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success(), "{stderr}");
    assert!(
        stderr.contains("of the white strip's lit pixels are saturated in every frame"),
        "{stderr}"
    );
    assert!(!dir.join("c.json").exists());
}
