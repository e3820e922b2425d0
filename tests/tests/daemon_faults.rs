//! Hardware faults on the emulators, injected through the daemon's test hook
//! (`emulator.fault_injection = true`): a serial unplug during a move interrupts the
//! scan with a clear state and it resumes after the reconnect; the emergency stop
//! pauses a scan mid-move; a busy or timing-out camera is retried a bounded number of
//! times, then the scan fails with a clear error (and can be retried later).

use std::time::{Duration, Instant};

use gonio_tests::{emulator_config, temp_dir, Daemon};
use serde_json::{json, Value};

/// Waits until the emulated arm is mid-way to a far target (angle below −8°).
fn wait_mid_move(daemon: &Daemon) {
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        let hw = daemon.get("/api/hardware").json;
        if hw["arm"]["angle_deg"]
            .as_f64()
            .is_some_and(|a| a < -8.0 && a > -40.0)
        {
            return;
        }
        assert!(Instant::now() < deadline, "arm never moved: {hw}");
        std::thread::sleep(Duration::from_millis(10));
    }
}

fn post_scan(daemon: &Daemon, theta_l: &[f64]) -> i64 {
    let answer = daemon.post(
        "/api/scans",
        &json!({"sample": "s", "theta_l": theta_l, "bracket": {"shutter_s": [0.1, 0.01]}}),
    );
    assert_eq!(answer.status, 201, "{:?}", answer.json);
    answer.json["id"].as_i64().unwrap()
}

fn inject(daemon: &Daemon, fault: Value) {
    let answer = daemon.post("/api/emulator/fault", &fault);
    assert_eq!(answer.status, 200, "{fault}: {:?}", answer.json);
}

#[test]
fn serial_unplug_mid_move_interrupts_then_resumes_after_reconnect() {
    let dir = temp_dir("fault-unplug");
    // Slow motion so the move is long enough to pull the cable during it.
    let daemon = Daemon::start(&dir, &emulator_config(0.4));
    let id = post_scan(&daemon, &[-50.0, -45.0]);
    wait_mid_move(&daemon);
    inject(&daemon, json!({"fault": "unplug"}));

    let scan = daemon.wait_state(
        id,
        &["interrupted", "failed", "done"],
        Duration::from_secs(60),
    );
    assert_eq!(scan["state"], "interrupted", "{scan}");
    let reason = scan["error"].as_str().unwrap();
    assert!(reason.contains("move to θL -50.0°"), "{reason}");
    let hardware = daemon.get("/api/hardware").json;
    assert_eq!(hardware["arm"]["state"], "disconnected", "{hardware}");
    // It stays interrupted (no hang, no busy failure) while the cable is out.
    std::thread::sleep(Duration::from_millis(500));
    assert_eq!(
        daemon.get(&format!("/api/scans/{id}")).json["state"],
        "interrupted"
    );

    let log_before = daemon
        .get("/api/hardware/log")
        .json
        .as_array()
        .unwrap()
        .len() as i64;
    inject(&daemon, json!({"fault": "reconnect"}));
    let scan = daemon.wait_state(id, &["done", "failed"], Duration::from_secs(90));
    assert_eq!(scan["state"], "done", "{scan}");
    assert_eq!(scan["error"], Value::Null);
    // After the reconnect the arm was homed before it moved again.
    let log = daemon
        .get(&format!("/api/hardware/log?after={}", log_before - 1))
        .json;
    let actions: Vec<&str> = log
        .as_array()
        .unwrap()
        .iter()
        .map(|e| e["action"].as_str().unwrap())
        .filter(|a| ["connect", "home", "move"].contains(a))
        .collect();
    let connect = actions
        .iter()
        .position(|a| *a == "connect")
        .expect("reconnected");
    assert_eq!(actions.get(connect + 1), Some(&"home"), "{actions:?}");
    std::fs::remove_dir_all(dir).ok();
}

#[test]
fn emergency_stop_pauses_mid_move_and_resume_finishes() {
    let dir = temp_dir("fault-stop");
    let daemon = Daemon::start(&dir, &emulator_config(0.4));
    let id = post_scan(&daemon, &[-50.0]);
    wait_mid_move(&daemon);
    let stopped = daemon.post("/api/arm/stop", &json!({}));
    assert_eq!(stopped.status, 200, "{:?}", stopped.json);
    assert_eq!(stopped.json["paused"], json!([id]));
    let angle_at_stop = daemon.get("/api/hardware").json["arm"]["angle_deg"]
        .as_f64()
        .unwrap();
    std::thread::sleep(Duration::from_millis(600));
    let angle_later = daemon.get("/api/hardware").json["arm"]["angle_deg"]
        .as_f64()
        .unwrap();
    assert!(
        (angle_later - angle_at_stop).abs() < 3.0,
        "the arm kept moving: {angle_at_stop} -> {angle_later}"
    );
    let scan = daemon.get(&format!("/api/scans/{id}")).json;
    assert_eq!(scan["state"], "paused", "{scan}");
    assert!(scan["error"].as_str().unwrap().contains("emergency stop"));

    let resumed = daemon.post(&format!("/api/scans/{id}/resume"), &json!({}));
    assert_eq!(resumed.status, 200, "{:?}", resumed.json);
    let scan = daemon.wait_state(id, &["done", "failed"], Duration::from_secs(90));
    assert_eq!(scan["state"], "done", "{scan}");
    std::fs::remove_dir_all(dir).ok();
}

#[test]
fn busy_or_timing_out_camera_is_retried_then_fails_clearly() {
    let dir = temp_dir("fault-camera");
    // The test config allows 3 attempts per camera operation.
    let daemon = Daemon::start(&dir, &emulator_config(0.01));

    // Busy twice: the third attempt succeeds and the scan completes.
    inject(&daemon, json!({"fault": "camera_busy", "count": 2}));
    let id = post_scan(&daemon, &[-20.0]);
    let scan = daemon.wait_state(id, &["done", "failed"], Duration::from_secs(60));
    assert_eq!(scan["state"], "done", "{scan}");

    // Timing out on every attempt: failed, saying why.
    inject(&daemon, json!({"fault": "camera_timeout", "count": 3}));
    let id = post_scan(&daemon, &[-20.0]);
    let scan = daemon.wait_state(id, &["done", "failed"], Duration::from_secs(60));
    assert_eq!(scan["state"], "failed", "{scan}");
    let error = scan["error"].as_str().unwrap();
    assert!(error.contains("failed after 3 attempts"), "{error}");
    assert!(error.contains("timed out"), "{error}");

    // Busy beyond the retries: failed, saying why; the queue goes on afterwards.
    inject(&daemon, json!({"fault": "camera_busy", "count": 3}));
    let id = post_scan(&daemon, &[-20.0]);
    let next = post_scan(&daemon, &[-25.0]);
    let scan = daemon.wait_state(id, &["done", "failed"], Duration::from_secs(60));
    assert_eq!(scan["state"], "failed", "{scan}");
    let error = scan["error"].as_str().unwrap();
    assert!(
        error.contains("camera busy") && error.contains("3 attempts"),
        "{error}"
    );
    let scan = daemon.wait_state(next, &["done", "failed"], Duration::from_secs(60));
    assert_eq!(scan["state"], "done", "{scan}");

    // The operator retries the failed scan once the camera is fine: it completes from
    // its first step not done.
    let resumed = daemon.post(&format!("/api/scans/{id}/resume"), &json!({}));
    assert_eq!(resumed.status, 200, "{:?}", resumed.json);
    let scan = daemon.wait_state(id, &["done", "failed"], Duration::from_secs(60));
    assert_eq!(scan["state"], "done", "{scan}");
    assert_eq!(scan["error"], Value::Null);
    std::fs::remove_dir_all(dir).ok();
}
