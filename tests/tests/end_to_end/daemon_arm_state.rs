//! The arm's state on the emulated GRBL board is the arm's, and Home does what an
//! operator expects:
//!
//! - an unplug after a scan is shown `disconnected` within 2 s, and after the replug
//!   the arm is back and a new scan runs;
//! - `/api/hardware` shows `homing` during the homing cycle and `moving` during a move;
//! - a position is declared only while the arm is at rest (409 during a scan's move);
//! - Home clears an alarm (after an emergency stop during a move) with a soft reset,
//!   then homes, and says so in the hardware log; it answers 409 with the reason on a
//!   refused board and on a controller that does not home; once homed, an emergency
//!   stop's hold ends, and a stop right after Home stops the homing, the hold staying;
//! - a board that resets during a bracket is homed and placed again before its next
//!   capture;
//! - a scan waiting on the arm (a failed homing) holds the rest of its sweep;
//! - concurrent confirmations of the same scan mount its sample once.

use std::path::Path;
use std::time::{Duration, Instant};

use gonio_tests::{
    emulator_config, emulator_config_scaled, sweep_scans, temp_dir, with_small_red_sample, Daemon,
    SMALL_GOLD_SCENE,
};
use serde_json::{json, Value};

/// A daemon configuration on the emulated camera and an emulated board described by
/// `board` (the emulator's TOML), with `[arm]` keys `arm`.
fn board_config(dir: &Path, board: &str, arm: &str, time_scale: f64) -> String {
    let board_path = dir.join("board.toml");
    std::fs::write(&board_path, board).unwrap();
    std::fs::write(dir.join("scene.toml"), SMALL_GOLD_SCENE).unwrap();
    format!(
        "[arm]\nkind = \"emulator\"\ntime_scale = {time_scale}\nboard = \"{}\"\n{arm}\n\n\
         [camera]\nkind = \"emulator\"\nscene = \"{}\"\ntime_scale = 0.01\n\n\
         [retry]\nattempts = 3\nbackoff_ms = 50\n\n[emulator]\nfault_injection = true\n",
        board_path.display(),
        dir.join("scene.toml").display()
    )
}

fn fault(daemon: &Daemon, fault: &str) {
    let answer = daemon.post("/api/emulator/fault", &json!({ "fault": fault }));
    assert_eq!(answer.status, 200, "{fault}: {:?}", answer.json);
}

fn log_entries(daemon: &Daemon, action: &str) -> Vec<Value> {
    daemon
        .get("/api/hardware/log")
        .json
        .as_array()
        .unwrap()
        .iter()
        .filter(|e| e["action"] == action)
        .cloned()
        .collect()
}

fn arm_state(daemon: &Daemon) -> String {
    daemon.get("/api/hardware").json["arm"]["state"]
        .as_str()
        .unwrap_or_default()
        .to_owned()
}

#[test]
fn an_unplug_after_a_scan_is_seen_within_two_seconds_and_the_replug_works() {
    let dir = temp_dir("arm-state-unplug");
    let daemon = Daemon::start(&dir, &emulator_config(0.01));
    let first = daemon.post_gold_scan(&[-20.0, -30.0], &[0.05]);
    let done = daemon.wait_state(first, &["done", "failed"], Duration::from_secs(120));
    assert_eq!(done["state"], "done", "{done}");
    std::thread::sleep(Duration::from_millis(500));
    fault(&daemon, "unplug");
    let unplugged = Instant::now();
    daemon.wait_for("/api/hardware", Duration::from_secs(10), |h| {
        h["arm"]["state"] == "disconnected"
    });
    let seen = unplugged.elapsed();
    assert!(
        seen < Duration::from_secs(2),
        "disconnected shown after {seen:?}"
    );
    fault(&daemon, "reconnect");
    daemon.wait_for("/api/hardware", Duration::from_secs(10), |h| {
        h["arm"]["state"] != "disconnected"
    });
    let second = daemon.post_gold_scan(&[-20.0], &[0.05]);
    let done = daemon.wait_state(second, &["done", "failed"], Duration::from_secs(30));
    assert_eq!(done["state"], "done", "{done}");
}

#[test]
fn an_unplug_during_a_move_is_seen_within_two_seconds() {
    let dir = temp_dir("arm-state-unplug-move");
    let daemon = Daemon::start(&dir, &emulator_config_scaled(1.0, 0.01));
    let id = daemon.post_gold_scan(&[-80.0], &[0.05]);
    daemon.wait_for("/api/hardware", Duration::from_secs(60), |h| {
        h["arm"]["state"] == "moving"
    });
    fault(&daemon, "unplug");
    let unplugged = Instant::now();
    daemon.wait_for("/api/hardware", Duration::from_secs(30), |h| {
        h["arm"]["state"] == "disconnected"
    });
    let seen = unplugged.elapsed();
    assert!(
        seen < Duration::from_secs(2),
        "disconnected shown after {seen:?}"
    );
    fault(&daemon, "reconnect");
    let done = daemon.wait_state(id, &["done", "failed"], Duration::from_secs(120));
    assert_eq!(done["state"], "done", "{done}");
}

#[test]
fn hardware_shows_homing_and_moving_while_they_happen() {
    let dir = temp_dir("arm-state-moving");
    let daemon = Daemon::start(&dir, &emulator_config_scaled(0.5, 0.01));
    let id = daemon.post_gold_scan(&[-80.0], &[0.05]);
    let mut seen = Vec::new();
    let deadline = Instant::now() + Duration::from_secs(120);
    loop {
        let state = arm_state(&daemon);
        if seen.last() != Some(&state) {
            seen.push(state);
        }
        let scan = daemon.get(&format!("/api/scans/{id}")).json;
        if scan["state"] == "done" || scan["state"] == "failed" {
            break;
        }
        assert!(Instant::now() < deadline, "{seen:?}");
        std::thread::sleep(Duration::from_millis(20));
    }
    assert!(seen.contains(&"homing".to_owned()), "{seen:?}");
    assert!(seen.contains(&"moving".to_owned()), "{seen:?}");
    assert_eq!(arm_state(&daemon), "idle");
}

#[test]
fn a_position_is_declared_only_at_rest() {
    let dir = temp_dir("arm-state-declare");
    let board = "steps_per_deg = 80.0\nmax_travel_deg = 180.0\n";
    let daemon = Daemon::start(&dir, &board_config(&dir, board, "homing = \"off\"", 0.5));
    let id = daemon.post_gold_scan(&[-80.0], &[0.05]);
    daemon.wait_state(id, &["waiting"], Duration::from_secs(30));
    let declared = daemon.post("/api/arm/position", &json!({"angle": 0.0}));
    assert_eq!(declared.status, 200, "{:?}", declared.json);
    daemon.wait_for("/api/hardware", Duration::from_secs(60), |h| {
        h["arm"]["state"] == "moving"
    });
    let asked = Instant::now();
    let during = daemon.post("/api/arm/position", &json!({"angle": -10.0}));
    assert_eq!(during.status, 409, "{:?}", during.json);
    assert!(
        asked.elapsed() < Duration::from_secs(2),
        "{:?}",
        asked.elapsed()
    );
    let done = daemon.wait_state(id, &["done", "failed"], Duration::from_secs(120));
    assert_eq!(done["state"], "done", "{done}");
    // The refused declaration was never applied: the arm is where the scan left it.
    let angle = daemon.get("/api/hardware").json["arm"]["angle_deg"].as_f64();
    assert!(angle.is_some_and(|a| (a + 80.0).abs() < 0.1), "{angle:?}");
    assert_eq!(log_entries(&daemon, "declare").len(), 1);
}

/// A daemon whose scan (its id) was paused by STOP ARM during a long move: the stop
/// reset the board, which reports an alarm.
fn stopped_mid_move(dir: &Path) -> (Daemon, i64) {
    let daemon = Daemon::start(dir, &emulator_config_scaled(0.5, 0.01));
    let id = daemon.post_gold_scan(&[-80.0], &[0.05]);
    daemon.wait_for("/api/hardware", Duration::from_secs(60), |h| {
        h["arm"]["state"] == "moving"
    });
    assert_eq!(daemon.post("/api/arm/stop", &json!({})).status, 200);
    let paused = daemon.wait_state(id, &["paused"], Duration::from_secs(30));
    assert_eq!(
        paused["reason"], "emergency stop by the operator",
        "{paused}"
    );
    daemon.wait_for("/api/hardware", Duration::from_secs(10), |h| {
        h["arm"]["state"] == "alarm"
    });
    (daemon, id)
}

#[test]
fn home_clears_the_alarm_of_an_emergency_stop_and_says_so() {
    let dir = temp_dir("arm-state-home-alarm");
    let (daemon, id) = stopped_mid_move(&dir);
    assert_eq!(daemon.get("/api/hardware").json["halted"], true);
    let home = daemon.post("/api/arm/home", &json!({}));
    assert_eq!(home.status, 202, "{:?}", home.json);
    assert_eq!(home.json["clears_alarm"], true, "{:?}", home.json);
    let deadline = Instant::now() + Duration::from_secs(120);
    let homed = loop {
        if let Some(entry) = log_entries(&daemon, "home").into_iter().find(|e| {
            e["detail"]
                .as_str()
                .unwrap_or("")
                .contains("asked by the operator")
        }) {
            break entry;
        }
        let failed = log_entries(&daemon, "home failed");
        assert!(failed.is_empty(), "{failed:?}");
        assert!(Instant::now() < deadline, "the operator's homing never ran");
        std::thread::sleep(Duration::from_millis(50));
    };
    assert_eq!(
        homed["detail"], "asked by the operator: alarm cleared (soft reset), then $H",
        "{homed}"
    );
    let hardware = daemon.get("/api/hardware").json;
    assert_eq!(hardware["arm"]["state"], "idle", "{hardware}");
    assert_eq!(hardware["arm"]["homed"], true, "{hardware}");
    // Homed, the hold is over.
    assert_eq!(hardware["halted"], false, "{hardware}");
    assert_eq!(
        daemon
            .post(&format!("/api/scans/{id}/resume"), &json!({}))
            .status,
        200
    );
    let done = daemon.wait_state(id, &["done", "failed"], Duration::from_secs(120));
    assert_eq!(done["state"], "done", "{done}");
}

#[test]
fn a_stop_right_after_home_stops_the_homing_and_the_hold_stays() {
    let dir = temp_dir("arm-state-stop-homing");
    let (daemon, _) = stopped_mid_move(&dir);
    let next = daemon.post_gold_scan(&[-20.0], &[0.05]);
    // Home, and STOP ARM at once, as an operator changing their mind: the homing is
    // dropped or abandoned, the hold stays, nothing moves.
    assert_eq!(daemon.post("/api/arm/home", &json!({})).status, 202);
    std::thread::sleep(Duration::from_millis(50));
    assert_eq!(daemon.post("/api/arm/stop", &json!({})).status, 200);
    let stopped_at = Instant::now();
    while stopped_at.elapsed() < Duration::from_secs(3) {
        let hardware = daemon.get("/api/hardware").json;
        assert_eq!(hardware["halted"], true, "{hardware}");
        assert_ne!(hardware["arm"]["homed"], true, "{hardware}");
        std::thread::sleep(Duration::from_millis(100));
    }
    let homed: Vec<Value> = log_entries(&daemon, "home")
        .into_iter()
        .filter(|e| {
            e["detail"]
                .as_str()
                .unwrap_or("")
                .contains("asked by the operator")
        })
        .collect();
    assert!(homed.is_empty(), "homed after the stop: {homed:?}");
    let queued = daemon.get(&format!("/api/scans/{next}")).json;
    assert_eq!(queued["state"], "queued", "{queued}");
    // Home again, left to finish: the hold ends and the queue goes on.
    assert_eq!(daemon.post("/api/arm/home", &json!({})).status, 202);
    daemon.wait_for("/api/hardware", Duration::from_secs(60), |h| {
        h["halted"] == false && h["arm"]["homed"] == true
    });
    let done = daemon.wait_state(next, &["done", "failed"], Duration::from_secs(120));
    assert_eq!(done["state"], "done", "{done}");
}

#[test]
fn a_board_reset_during_a_bracket_is_seen_before_the_next_capture() {
    let dir = temp_dir("arm-state-reset-bracket");
    let daemon = Daemon::start(&dir, &emulator_config_scaled(0.05, 0.5));
    let id = daemon.post_gold_scan(&[-20.0], &[2.0, 1.0, 0.5, 0.25]);
    let first = daemon.wait_for("/api/hardware/log", Duration::from_secs(60), |log| {
        log.as_array()
            .unwrap()
            .iter()
            .any(|e| e["action"] == "capture")
    });
    let before = first.as_array().unwrap().len();
    fault(&daemon, "arm_reset");
    let done = daemon.wait_state(id, &["done", "failed"], Duration::from_secs(120));
    assert_eq!(done["state"], "done", "{done}");
    // After the reset: the arm homed and placed again before the next frame.
    let log = daemon.get("/api/hardware/log").json;
    let after: Vec<String> = log.as_array().unwrap()[before..]
        .iter()
        .map(|e| format!("{} {}", e["action"].as_str().unwrap(), e["detail"]))
        .collect();
    // The capture under way when the board reset ends; the next one is taken only
    // once the arm is homed and back at its θL.
    let homed = after.iter().position(|e| e.starts_with("home "));
    let captures_before = after[..homed.unwrap_or(after.len())]
        .iter()
        .filter(|e| e.starts_with("capture "))
        .count();
    assert!(
        homed.is_some() && captures_before <= 1,
        "no homing before the next capture: {after:?}"
    );
    let placed = after[homed.unwrap()..]
        .iter()
        .position(|e| e.starts_with("move "));
    let next = after[homed.unwrap()..]
        .iter()
        .position(|e| e.starts_with("capture "));
    assert!(
        placed < next,
        "not placed again before capturing: {after:?}"
    );
}

#[test]
fn home_answers_409_with_the_reason_where_it_cannot_run() {
    // A refused board (a stock board, $100=250, against the configured 80).
    let dir = temp_dir("arm-state-home-refused");
    let stock = "# a stock GRBL 1.1h board\n";
    let daemon = Daemon::start(
        &dir,
        &board_config(&dir, stock, "homing = \"required\"", 0.01),
    );
    daemon.wait_for("/api/hardware", Duration::from_secs(30), |h| {
        h["arm"]["state"] == "refused"
    });
    let refused = daemon.post("/api/arm/home", &json!({}));
    assert_eq!(refused.status, 409, "{:?}", refused.json);
    assert!(
        refused.json["error"].as_str().unwrap().contains("refused"),
        "{:?}",
        refused.json
    );
    drop(daemon);

    // A controller that does not home, whose position was declared.
    let dir = temp_dir("arm-state-home-off");
    let board = "steps_per_deg = 80.0\nmax_travel_deg = 180.0\n";
    let daemon = Daemon::start(&dir, &board_config(&dir, board, "homing = \"off\"", 0.01));
    daemon.wait_for("/api/hardware", Duration::from_secs(30), |h| {
        h["arm"]["state"] == "needs_position"
    });
    let declared = daemon.post("/api/arm/position", &json!({"angle": 0.0}));
    assert_eq!(declared.status, 200, "{:?}", declared.json);
    assert_eq!(arm_state(&daemon), "idle");
    let off = daemon.post("/api/arm/home", &json!({}));
    assert_eq!(off.status, 409, "{:?}", off.json);
    assert!(
        off.json["error"]
            .as_str()
            .unwrap()
            .contains("does not home"),
        "{:?}",
        off.json
    );
}

#[test]
fn a_scan_waiting_on_a_failed_homing_holds_its_sweep() {
    let dir = temp_dir("arm-state-sweep-hold");
    // Homing cannot pull off its switch ($27=0): ALARM:8, the scan waits.
    let board = "steps_per_deg = 80.0\nmax_travel_deg = 180.0\nmax_rate_deg_per_min = 1200.0\n\
                 accel_deg_per_s2 = 40.0\nhoming_enabled = true\nsoft_limits = true\n\
                 homing_seek_deg_per_min = 600.0\nhoming_cycles = [\"X\"]\n\
                 homing_pulloff_deg = 0.0\n";
    let daemon = Daemon::start(&dir, &board_config(&dir, board, "", 0.01));
    let created = daemon.post(
        "/api/sweeps",
        &json!({"samples": ["gold"], "repeats": 2, "theta_l_sets": [[-20]],
                "bracket": {"shutter_s": [0.05]}}),
    );
    assert_eq!(created.status, 201, "{:?}", created.json);
    let ids = sweep_scans(&created.json);
    let first = daemon.wait_state(ids[0], &["waiting", "failed"], Duration::from_secs(30));
    assert_eq!(first["state"], "waiting", "{first}");
    std::thread::sleep(Duration::from_secs(2));
    let second = daemon.get(&format!("/api/scans/{}", ids[1])).json;
    assert_eq!(second["state"], "queued", "{second}");
    let touched: Vec<Value> = daemon
        .get("/api/hardware/log")
        .json
        .as_array()
        .unwrap()
        .iter()
        .filter(|e| e["scan_id"] == ids[1])
        .cloned()
        .collect();
    assert!(touched.is_empty(), "{touched:?}");
}

#[test]
fn concurrent_confirms_mount_the_sample_once() {
    let dir = temp_dir("arm-state-confirms");
    let daemon = Daemon::start(&dir, &with_small_red_sample(&emulator_config(0.01), &dir));
    let created = daemon.post(
        "/api/scans",
        &json!({"sample": "red", "theta_l": [-20], "bracket": {"shutter_s": [0.05]}}),
    );
    let id = created.json["id"].as_i64().unwrap();
    daemon.wait_state(id, &["waiting"], Duration::from_secs(30));
    let url = format!("{}/api/scans/{id}/confirm", daemon.url);
    let answers: Vec<u16> = std::thread::scope(|scope| {
        let handles: Vec<_> = (0..8)
            .map(|_| {
                let url = url.clone();
                scope.spawn(move || {
                    match ureq::post(&url)
                        .set("Authorization", &format!("Bearer {}", gonio_tests::TOKEN))
                        .call()
                    {
                        Ok(r) => r.status(),
                        Err(ureq::Error::Status(code, _)) => code,
                        Err(e) => panic!("{e}"),
                    }
                })
            })
            .collect();
        handles.into_iter().map(|h| h.join().unwrap()).collect()
    });
    assert_eq!(
        answers.iter().filter(|s| **s == 200).count(),
        1,
        "{answers:?}"
    );
    assert!(
        answers.iter().all(|s| [200, 409].contains(s)),
        "{answers:?}"
    );
    let mounts: Vec<Value> = log_entries(&daemon, "mount")
        .into_iter()
        .filter(|e| e["scan_id"] == id)
        .collect();
    assert_eq!(mounts.len(), 1, "{mounts:?}");
    let done = daemon.wait_state(id, &["done", "failed"], Duration::from_secs(60));
    assert_eq!(done["state"], "done", "{done}");
}

#[test]
fn home_after_a_failed_homing_resets_the_alarm_and_tries_again() {
    let dir = temp_dir("arm-state-home-after-failure");
    // Homing cannot pull off its switch ($27=0): every cycle ends in ALARM:8.
    let board = "steps_per_deg = 80.0\nmax_travel_deg = 180.0\nmax_rate_deg_per_min = 1200.0\n\
                 accel_deg_per_s2 = 40.0\nhoming_enabled = true\nsoft_limits = true\n\
                 homing_seek_deg_per_min = 600.0\nhoming_cycles = [\"X\"]\n\
                 homing_pulloff_deg = 0.0\n";
    let daemon = Daemon::start(&dir, &board_config(&dir, board, "", 0.01));
    let id = daemon.post_gold_scan(&[-20.0], &[0.05]);
    let waiting = daemon.wait_state(id, &["waiting", "failed"], Duration::from_secs(30));
    assert_eq!(waiting["state"], "waiting", "{waiting}");
    daemon.wait_for("/api/hardware", Duration::from_secs(10), |h| {
        h["arm"]["state"] == "alarm"
    });
    let home = daemon.post("/api/arm/home", &json!({}));
    assert_eq!(home.status, 202, "{:?}", home.json);
    assert_eq!(home.json["clears_alarm"], true, "{:?}", home.json);
    let failed = daemon.wait_for("/api/hardware/log", Duration::from_secs(60), |log| {
        log.as_array()
            .unwrap()
            .iter()
            .any(|e| e["action"] == "home failed")
    });
    let entry = failed
        .as_array()
        .unwrap()
        .iter()
        .find(|e| e["action"] == "home failed")
        .unwrap()
        .clone();
    // The alarm was reset and the cycle run again (it fails again on this board).
    let detail = entry["detail"].as_str().unwrap();
    assert!(
        detail.starts_with("asked by the operator: alarm cleared (soft reset), then $H: "),
        "{detail}"
    );
    assert!(detail.contains("alarm 8"), "{detail}");
}
