//! Hardware faults on the emulators, injected through the daemon's test hook
//! (`emulator.fault_injection = true`): a serial unplug during a move interrupts the
//! scan with a clear state and it resumes after the reconnect; a camera unplugged
//! mid-scan does the same, the scan completing by itself once it is back; the
//! emergency stop pauses a scan mid-move; a busy or timing-out camera is retried a
//! bounded number of times, then the scan fails with a clear error (and can be retried
//! later). `/api/hardware` follows the arm during a move (the driver polls the
//! controller), which the mid-move faults rely on.

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

#[test]
fn hardware_view_follows_the_arm_during_a_move() {
    let dir = temp_dir("live-angle");
    let daemon = Daemon::start(&dir, &emulator_config(0.4));
    let id = daemon.post_gold_scan(&[-50.0], &[0.1, 0.01]);
    let mut seen = Vec::new();
    let deadline = Instant::now() + Duration::from_secs(60);
    while seen.last().is_none_or(|a: &f64| *a > -49.9) {
        assert!(
            Instant::now() < deadline,
            "the arm never got there: {seen:?}"
        );
        if let Some(angle) = daemon.get("/api/hardware").json["arm"]["angle_deg"].as_f64() {
            seen.push(angle);
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let mut between: Vec<f64> = seen
        .into_iter()
        .filter(|a| *a < -2.0 && *a > -48.0)
        .collect();
    between.dedup();
    assert!(between.len() >= 3, "angles seen mid-move: {between:?}");
    daemon.wait_state(id, &["done", "failed"], Duration::from_secs(60));
    std::fs::remove_dir_all(dir).ok();
}

/// Waits until scan `id` is interrupted; returns why (its `reason`, also its `error`).
fn wait_interrupted(daemon: &Daemon, id: i64) -> String {
    let scan = daemon.wait_state(
        id,
        &["interrupted", "failed", "done"],
        Duration::from_secs(60),
    );
    assert_eq!(scan["state"], "interrupted", "{scan}");
    assert!(scan["reason"].is_string(), "{scan}");
    assert_eq!(scan["reason"], scan["error"], "{scan}");
    scan["reason"].as_str().unwrap().to_owned()
}

/// Scan `id` is still interrupted after `wait` (no hang, no busy failure meanwhile).
fn stays_interrupted(daemon: &Daemon, id: i64, wait: Duration) {
    std::thread::sleep(wait);
    assert_eq!(
        daemon.get(&format!("/api/scans/{id}")).json["state"],
        "interrupted"
    );
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
    let id = daemon.post_gold_scan(&[-50.0, -45.0], &[0.1, 0.01]);
    wait_mid_move(&daemon);
    inject(&daemon, json!({"fault": "unplug"}));
    let reason = wait_interrupted(&daemon, id);
    assert!(reason.contains("move to θL -50.0°"), "{reason}");
    let hardware = daemon.get("/api/hardware").json;
    assert_eq!(hardware["arm"]["state"], "disconnected", "{hardware}");
    assert_eq!(hardware["arm"]["angle_deg"], Value::Null, "{hardware}");
    // It stays interrupted while the cable is out.
    stays_interrupted(&daemon, id, Duration::from_millis(500));

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
fn camera_unplugged_mid_scan_interrupts_and_the_scan_completes_once_it_is_back() {
    let dir = temp_dir("fault-camera-unplug");
    let daemon = Daemon::start(&dir, &emulator_config(0.05));
    let answer = daemon.post(
        "/api/scans",
        &json!({"sample": "gold", "theta_l": [-20, -25, -30],
                "bracket": {"shutter_s": [0.5, 0.1, 0.02]}}),
    );
    assert_eq!(answer.status, 201, "{:?}", answer.json);
    let id = answer.json["id"].as_i64().unwrap();
    // Pull the cable once the first frame has landed.
    let deadline = Instant::now() + Duration::from_secs(60);
    while !daemon
        .get("/api/hardware/log")
        .json
        .as_array()
        .unwrap()
        .iter()
        .any(|e| e["action"] == "capture")
    {
        assert!(Instant::now() < deadline, "no capture");
        std::thread::sleep(Duration::from_millis(10));
    }
    inject(&daemon, json!({"fault": "camera_unplug"}));
    let reason = wait_interrupted(&daemon, id);
    assert!(
        reason.contains("camera") && reason.contains("waiting for the camera to come back"),
        "{reason}"
    );
    let hardware = daemon.get("/api/hardware").json;
    assert_eq!(hardware["camera"]["state"], "disconnected", "{hardware}");
    // It waits while the camera is away (looking for it with backoff).
    stays_interrupted(&daemon, id, Duration::from_millis(700));
    // A scan queued meanwhile waits for the camera, with the reason.
    let next = daemon.post(
        "/api/scans",
        &json!({"sample": "gold", "theta_l": [-20], "bracket": {"shutter_s": [0.02]}}),
    );
    assert_eq!(next.status, 201, "{:?}", next.json);
    let next = next.json["id"].as_i64().unwrap();
    let waiting = daemon.wait_state(next, &["waiting"], Duration::from_secs(30));
    let reason = waiting["reason"].as_str().unwrap_or_default();
    assert!(reason.starts_with("camera not available"), "{waiting}");

    inject(&daemon, json!({"fault": "camera_replug"}));
    let scan = daemon.wait_state(id, &["done", "failed"], Duration::from_secs(90));
    assert_eq!(scan["state"], "done", "{scan}");
    assert_eq!(scan["error"], Value::Null);
    // The waiting scan was queued again once the camera was back, and ran.
    let queued = daemon.wait_state(next, &["done", "failed"], Duration::from_secs(90));
    assert_eq!(queued["state"], "done", "{queued}");
    assert_eq!(daemon.get("/api/hardware").json["camera"]["state"], "idle");
    // Every frame was captured once, the one lost with the cable included.
    let log = daemon.get("/api/hardware/log").json;
    let captures: Vec<&str> = log
        .as_array()
        .unwrap()
        .iter()
        .filter(|e| e["action"] == "capture" && e["scan_id"] == id)
        .map(|e| e["detail"].as_str().unwrap())
        .collect();
    assert_eq!(captures.len(), 9, "{captures:?}");
    let mut unique = captures.clone();
    unique.sort();
    unique.dedup();
    assert_eq!(unique.len(), 9, "{captures:?}");
    std::fs::remove_dir_all(dir).ok();
}

#[test]
fn emergency_stop_pauses_mid_move_holds_the_queue_and_resume_finishes() {
    let dir = temp_dir("fault-stop");
    let daemon = Daemon::start(&dir, &emulator_config(0.4));
    let id = daemon.post_gold_scan(&[-50.0], &[0.1, 0.01]);
    let next = daemon.post_gold_scan(&[-20.0], &[0.1, 0.01]);
    wait_mid_move(&daemon);
    let stopped = daemon.post("/api/arm/stop", &json!({}));
    assert_eq!(stopped.status, 200, "{:?}", stopped.json);
    assert_eq!(stopped.json["paused"], json!([id]));
    let last_id = |log: &Value| {
        log.as_array()
            .unwrap()
            .iter()
            .filter_map(|e| e["id"].as_i64())
            .max()
    };
    let stopped_at = last_id(&daemon.get("/api/hardware/log").json).unwrap_or(0);
    // The reset lost the position: the controller reports the arm at rest, and no
    // angle is shown until it is homed again.
    std::thread::sleep(Duration::from_millis(600));
    let hardware = daemon.wait_for("/api/hardware", Duration::from_secs(10), |hw| {
        hw["arm"]["state"] != "idle"
    });
    let arm = &hardware["arm"];
    assert!(
        ["needs_homing", "alarm"].contains(&arm["state"].as_str().unwrap()),
        "the arm kept moving: {hardware}"
    );
    assert_eq!(arm["angle_deg"], Value::Null, "{hardware}");
    assert_eq!(arm["homed"], false, "{hardware}");
    let scan = daemon.get(&format!("/api/scans/{id}")).json;
    assert_eq!(scan["state"], "paused", "{scan}");
    assert!(scan["error"].as_str().unwrap().contains("emergency stop"));
    // The instrument holds: the next scan does not start, nothing moves.
    std::thread::sleep(Duration::from_secs(2));
    assert!(hardware_halted(&daemon));
    let queued = daemon.get(&format!("/api/scans/{next}")).json;
    assert_eq!(queued["state"], "queued", "{queued}");
    let log = daemon
        .get(&format!("/api/hardware/log?after={stopped_at}"))
        .json;
    let moved: Vec<&Value> = log
        .as_array()
        .unwrap()
        .iter()
        .filter(|e| ["home", "move", "capture"].contains(&e["action"].as_str().unwrap_or("")))
        .collect();
    assert!(moved.is_empty(), "moved after the stop: {moved:?}");

    let resumed = daemon.post(&format!("/api/scans/{id}/resume"), &json!({}));
    assert_eq!(resumed.status, 200, "{:?}", resumed.json);
    assert!(!hardware_halted(&daemon));
    for id in [id, next] {
        let scan = daemon.wait_state(id, &["done", "failed"], Duration::from_secs(90));
        assert_eq!(scan["state"], "done", "{scan}");
    }
    std::fs::remove_dir_all(dir).ok();
}

#[test]
fn busy_or_timing_out_camera_is_retried_then_fails_clearly() {
    let dir = temp_dir("fault-camera");
    // The test config allows 3 attempts per camera operation.
    let daemon = Daemon::start(&dir, &emulator_config(0.01));

    // Busy twice: the third attempt succeeds and the scan completes.
    inject(&daemon, json!({"fault": "camera_busy", "count": 2}));
    let id = daemon.post_gold_scan(&[-20.0], &[0.1, 0.01]);
    let scan = daemon.wait_state(id, &["done", "failed"], Duration::from_secs(60));
    assert_eq!(scan["state"], "done", "{scan}");

    // Timing out on every attempt: failed, saying why.
    inject(&daemon, json!({"fault": "camera_timeout", "count": 3}));
    let id = daemon.post_gold_scan(&[-20.0], &[0.1, 0.01]);
    let scan = daemon.wait_state(id, &["done", "failed"], Duration::from_secs(60));
    assert_eq!(scan["state"], "failed", "{scan}");
    let error = scan["error"].as_str().unwrap();
    assert!(error.contains("failed after 3 attempts"), "{error}");
    assert!(error.contains("timed out"), "{error}");

    // Busy beyond the retries: failed, saying why; the queue goes on afterwards.
    inject(&daemon, json!({"fault": "camera_busy", "count": 3}));
    let id = daemon.post_gold_scan(&[-20.0], &[0.1, 0.01]);
    let next = daemon.post_gold_scan(&[-25.0], &[0.1, 0.01]);
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

/// Whether `GET /api/hardware` says an emergency stop holds the instrument.
fn hardware_halted(daemon: &Daemon) -> bool {
    let hardware = daemon.get("/api/hardware").json;
    hardware["halted"].as_bool().expect("halted")
}
