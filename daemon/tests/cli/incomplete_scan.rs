//! A scan directory that lacks a θL or a frame its plan.json names, or holds half a
//! frame, is refused by `extract`, `calibrate` and `study` in one line naming what is
//! missing; `--allow-missing` goes on and says so; without a plan, `extract` says it
//! could not check. And the small outputs an operator
//! reads: the setup's source, `hdr` of a file that is not a capture, `export`'s summary.

use crate::common;

use std::path::Path;

use common::{gonio, gonio_ok, small_scan, text};

fn path(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// Runs `gonio args`, expects failure; returns stderr.
fn refused(args: &[&str]) -> String {
    let out = gonio(args);
    assert!(!out.status.success(), "gonio {args:?} succeeded");
    text(&out.stderr)
}

#[test]
fn simulate_writes_its_plan_and_a_whole_scan_extracts() {
    let dir = tempfile::tempdir().unwrap();
    let scan = small_scan(dir.path());
    let plan: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(scan.join("plan.json")).unwrap()).unwrap();
    assert_eq!(plan["theta_l"], serde_json::json!([-20.0, -30.0, -40.0]));
    assert!(plan["bracket_s"].as_array().is_some_and(|b| !b.is_empty()));
    let samples = dir.path().join("s.csv");
    let out = gonio_ok(&["extract", path(&scan), "--out", path(&samples)]);
    assert!(out.contains("from 3 θL"), "{out}");
}

#[test]
fn a_missing_theta_l_or_frame_is_named_and_allow_missing_goes_on() {
    let dir = tempfile::tempdir().unwrap();
    let scan = small_scan(dir.path());
    let samples = dir.path().join("s.csv");

    // A frame deleted, its sidecar left behind.
    std::fs::remove_file(scan.join("theta_l_-30.0/exp_01.tiff")).unwrap();
    let err = refused(&["extract", path(&scan), "--out", path(&samples)]);
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(err.contains("incomplete scan"), "{err}");
    assert!(err.contains("θL -30.0°: the "), "{err}");
    assert!(
        err.contains("exp_01.json: sidecar without its image"),
        "{err}"
    );
    assert!(err.contains("--allow-missing"), "{err}");
    assert!(!samples.exists());

    // A whole θL gone: extract and calibrate both refuse, naming it.
    std::fs::remove_dir_all(scan.join("theta_l_-40.0")).unwrap();
    let err = refused(&["extract", path(&scan), "--out", path(&samples)]);
    assert!(err.contains("θL -40.0° (no capture)"), "{err}");
    let err = refused(&[
        "calibrate",
        path(&scan),
        "--out",
        path(&dir.path().join("c.json")),
    ]);
    assert!(err.contains("θL -40.0° (no capture)"), "{err}");

    // --allow-missing goes on and says what it goes on without.
    let out = gonio(&[
        "extract",
        path(&scan),
        "--out",
        path(&samples),
        "--allow-missing",
    ]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let warning = text(&out.stderr);
    assert!(warning.contains("going on without θL -30.0°"), "{warning}");
    assert!(warning.contains("θL -40.0° (no capture)"), "{warning}");
    assert!(text(&out.stdout).contains("from 2 θL"));

    // With its stderr's reader gone, the warning is lost, not the work.
    std::fs::remove_file(&samples).unwrap();
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_gonio"))
        .args([
            "extract",
            path(&scan),
            "--out",
            path(&samples),
            "--allow-missing",
        ])
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    drop(child.stderr.take());
    let status = child.wait().unwrap();
    assert!(status.success(), "{status}");
    assert!(samples.is_file());

    // Without its plan the scan cannot be checked, and the command says so once done.
    std::fs::remove_file(scan.join("theta_l_-30.0/exp_01.json")).unwrap();
    std::fs::remove_file(scan.join("plan.json")).unwrap();
    let out = gonio(&["extract", path(&scan), "--out", path(&samples)]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let warning = text(&out.stderr);
    assert!(
        warning.contains("no plan.json: whether every θL and frame was here is not checked"),
        "{warning}"
    );
}

#[test]
fn study_of_a_scan_folders_samples_refuses_a_planned_theta_l_they_lack() {
    let dir = tempfile::tempdir().unwrap();
    let scan = small_scan(dir.path());
    std::fs::remove_dir_all(scan.join("theta_l_-40.0")).unwrap();
    let samples = scan.join("samples.csv");
    gonio_ok(&[
        "extract",
        path(&scan),
        "--out",
        path(&samples),
        "--allow-missing",
        "--no-uncertainty",
    ]);
    let out_dir = dir.path().join("study");
    let err = refused(&[
        "study",
        path(&samples),
        "--held-out",
        "--out",
        path(&out_dir),
    ]);
    assert!(err.contains("samples lack θL -40.0°"), "{err}");
    // The same samples elsewhere have no plan to be judged by.
    let copy = dir.path().join("copy.csv");
    std::fs::copy(&samples, &copy).unwrap();
    let out = gonio(&["study", path(&copy), "--held-out", "--out", path(&out_dir)]);
    assert!(out.status.success(), "{}", text(&out.stderr));
}

#[test]
fn extract_names_the_setup_it_read_and_states_uncertainties_to_three_digits() {
    let dir = tempfile::tempdir().unwrap();
    let scan = small_scan(dir.path());
    let mut setup: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(scan.join("setup.json")).unwrap()).unwrap();
    setup["uncertainty"] = serde_json::json!({"camera_offset_mm": 0.031234567890123});
    let other = dir.path().join("calibrated.json");
    std::fs::write(&other, setup.to_string()).unwrap();
    let out = gonio_ok(&[
        "extract",
        path(&scan),
        "--setup",
        path(&other),
        "--out",
        path(&dir.path().join("s.csv")),
    ]);
    assert!(
        out.contains(&format!("({}'s `uncertainty`)", other.display())),
        "{out}"
    );
    assert!(out.contains("camera offset 0.0312 mm"), "{out}");
    assert!(!out.contains("(setup.json"), "{out}");
}

#[test]
fn hdr_of_a_file_that_is_no_capture_says_so() {
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("samples.csv");
    std::fs::write(&csv, "theta_l,theta_i,theta_r,r,g,b\n").unwrap();
    let err = refused(&["hdr", "--out", path(&dir.path().join("m.exr")), path(&csv)]);
    assert!(err.contains("unsupported file type"), "{err}");
    assert!(!err.contains("sidecar"), "{err}");
}

#[test]
fn help_names_every_scene_and_the_fits_budget() {
    for command in ["simulate", "tradeoff"] {
        let help = gonio_ok(&[command, "--help"]);
        for scene in ["gold", "red", "blue-green", "opal"] {
            assert!(help.contains(scene), "{command} --help lacks {scene}");
        }
    }
    let help = gonio_ok(&["fit", "--help"]);
    assert!(help.contains("uncertainty budget"), "{help}");
}
