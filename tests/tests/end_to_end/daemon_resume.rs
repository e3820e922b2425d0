//! Crash safety: `kill -9` of the daemon in the middle of a sweep, then a restart. The
//! sweep resumes by itself, the arm is homed before anything else moves, and every
//! frame exists exactly once with no partial file left.

use std::collections::HashMap;
use std::time::{Duration, Instant};

use gonio_tests::{emulator_config, files_under, sweep_scans, temp_dir, Daemon};
use serde_json::{json, Value};

fn captures(log: &Value) -> usize {
    log.as_array()
        .unwrap()
        .iter()
        .filter(|e| e["action"] == "capture")
        .count()
}

#[test]
fn kill_9_mid_sweep_then_restart_resumes_with_every_frame_once() {
    let dir = temp_dir("resume");
    let daemon = Daemon::start(&dir, &emulator_config(0.05));
    let theta_sets = [[-20.0, -30.0, -40.0]];
    let bracket = [0.5, 0.1, 0.02];
    let created = daemon.post(
        "/api/sweeps",
        &json!({"samples": ["gold"], "theta_l_sets": theta_sets, "repeats": 2,
                "bracket": {"shutter_s": bracket}}),
    );
    assert_eq!(created.status, 201, "{:?}", created.json);
    let sweep = created.json["id"].as_i64().unwrap();
    let scans = sweep_scans(&created.json);
    assert_eq!(scans.len(), 2);

    // Kill it once a few frames of the first scan have landed.
    let deadline = Instant::now() + Duration::from_secs(60);
    while captures(&daemon.get("/api/hardware/log").json) < 4 {
        assert!(Instant::now() < deadline, "no captures");
        std::thread::sleep(Duration::from_millis(20));
    }
    daemon.kill9();

    let daemon = Daemon::restart(&dir);
    let view = daemon.wait_for(
        &format!("/api/sweeps/{sweep}"),
        Duration::from_secs(120),
        |s| s["state"] == "done" || s["state"] == "finished",
    );
    assert_eq!(view["state"], "done", "{view}");
    assert_eq!(view["progress"]["done"], view["progress"]["total"]);
    assert_eq!(view["scans_by_state"]["done"], 2);

    let log = daemon.get("/api/hardware/log").json;
    let entries = log.as_array().unwrap();
    // After the restart, the first motion is homing.
    let first_motion = entries
        .iter()
        .filter(|e| e["boot"] == 2)
        .find(|e| ["home", "move", "capture"].contains(&e["action"].as_str().unwrap()))
        .expect("hardware actions after the restart");
    assert_eq!(first_motion["action"], "home", "{first_motion}");
    // No frame was captured twice, across both runs.
    let mut captured: HashMap<(i64, String), usize> = HashMap::new();
    for e in entries.iter().filter(|e| e["action"] == "capture") {
        *captured
            .entry((
                e["scan_id"].as_i64().unwrap(),
                e["detail"].as_str().unwrap().to_owned(),
            ))
            .or_default() += 1;
    }
    assert!(captured.values().all(|n| *n == 1), "{captured:?}");

    // Every frame exists exactly once, with its sidecar, and nothing else.
    for id in scans {
        let scan_dir = daemon.data.join(format!("scans/{id}"));
        let files = files_under(&scan_dir);
        let frames: Vec<&String> = files.iter().filter(|f| f.starts_with("theta_l_")).collect();
        let mut expected = Vec::new();
        for theta in theta_sets[0] {
            for index in 0..bracket.len() {
                for ext in ["json", "tiff"] {
                    expected.push(format!("theta_l_{theta:.1}/exp_{index:02}.{ext}"));
                }
            }
        }
        expected.sort();
        assert_eq!(frames, expected.iter().collect::<Vec<_>>(), "scan {id}");
        assert!(files.iter().all(|f| !f.contains(".partial")), "{files:?}");
        assert!(files.contains(&"samples.csv".to_owned()), "{files:?}");
        let steps = daemon.get(&format!("/api/scans/{id}/steps")).json;
        assert!(steps
            .as_array()
            .unwrap()
            .iter()
            .all(|s| s["state"] == "done"));
    }
    std::fs::remove_dir_all(dir).ok();
}
