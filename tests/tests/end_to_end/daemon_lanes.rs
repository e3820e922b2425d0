//! The daemon's two lanes on the emulators: the arm moves on while the processing
//! lane works on the bracket before (and the gathered `samples.csv` is exactly what
//! `gonio extract` makes of the captures); with a backlog of one bracket the arm waits
//! for each to be processed. Times come from the step journal
//! (`/api/scans/{id}/steps`).

use std::process::Command;
use std::time::Duration;

use gonio_tests::{emulator_config, gonio_bin, temp_dir, Daemon};
use serde_json::{json, Value};
use time::format_description::well_known::Rfc3339;
use time::OffsetDateTime;

const THETA_L: [f64; 3] = [-20.0, -30.0, -40.0];

fn run_scan(daemon: &Daemon) -> (i64, Vec<Value>) {
    let answer = daemon.post(
        "/api/scans",
        &json!({"sample": "gold", "theta_l": THETA_L, "bracket": {"shutter_s": [0.5, 0.05]}}),
    );
    assert_eq!(answer.status, 201, "{:?}", answer.json);
    let id = answer.json["id"].as_i64().unwrap();
    let scan = daemon.wait_state(id, &["done", "failed"], Duration::from_secs(120));
    assert_eq!(scan["state"], "done", "{scan}");
    let steps = daemon.get(&format!("/api/scans/{id}/steps")).json;
    (id, steps.as_array().unwrap().clone())
}

/// When the step of `kind` at θL (the last such one) started or finished.
fn time_of(steps: &[Value], kind: &str, theta_l: f64, field: &str) -> OffsetDateTime {
    let step = steps
        .iter()
        .rev()
        .find(|s| s["step"]["kind"] == kind && s["step"]["theta_l"] == json!(theta_l))
        .unwrap_or_else(|| panic!("no {kind} step at {theta_l}"));
    OffsetDateTime::parse(step[field].as_str().unwrap(), &Rfc3339).unwrap()
}

#[test]
fn processing_runs_beside_the_hardware_and_gathers_what_extract_gives() {
    let dir = temp_dir("lanes-overlap");
    let daemon = Daemon::start(&dir, &emulator_config(0.05));
    let (id, steps) = run_scan(&daemon);
    // The arm moved on before the previous bracket was processed (the serial daemon
    // merged each bracket before the next move).
    let overlapped = THETA_L.windows(2).any(|pair| {
        time_of(&steps, "move", pair[1], "started") < time_of(&steps, "hdr", pair[0], "finished")
    });
    assert!(overlapped, "processing never overlapped a move: {steps:?}");
    // samples.csv gathers the per-θL files, byte for byte what `gonio extract` writes.
    let scan_dir = daemon.data.join(format!("scans/{id}"));
    for theta in THETA_L {
        assert!(scan_dir
            .join(format!("samples/theta_l_{theta:.1}.csv"))
            .is_file());
    }
    let out = dir.join("extracted.csv");
    let status = Command::new(gonio_bin())
        .arg("extract")
        .arg(&scan_dir)
        .args(["--white-reflectance", "0.99", "--out"])
        .arg(&out)
        .output()
        .expect("running gonio extract");
    assert!(status.status.success(), "{status:?}");
    let daemon_csv = std::fs::read(scan_dir.join("samples.csv")).unwrap();
    assert!(daemon_csv.len() > 1000);
    assert!(daemon_csv == std::fs::read(&out).unwrap());
    std::fs::remove_dir_all(dir).ok();
}

#[test]
fn with_a_backlog_of_one_the_arm_waits_for_each_bracket_to_be_processed() {
    let dir = temp_dir("lanes-backlog");
    let config = emulator_config(0.05).replace("[processing]", "[processing]\nmax_backlog = 1");
    let daemon = Daemon::start(&dir, &config);
    let (_, steps) = run_scan(&daemon);
    for pair in THETA_L.windows(2) {
        let processed = time_of(&steps, "hdr", pair[0], "finished");
        let moved = time_of(&steps, "move", pair[1], "started");
        assert!(
            processed <= moved,
            "moved to {} at {moved} before θL {} was processed at {processed}",
            pair[1],
            pair[0]
        );
    }
    std::fs::remove_dir_all(dir).ok();
}
