//! The daemon with a GRBL board that is not (yet) fit for a scan, emulated: scans wait
//! with the reason (on `/api/scans/{id}`, in the event stream) instead of sitting
//! queued or failing, and the board is not reset in a storm meanwhile.
//!
//! - A stock board (`$100=250`, `$22=0`) under `homing = "off"`: each differing setting
//!   listed as the reason; with `apply_settings` the board is set up, the scan waits for
//!   the declared position, `POST /api/arm/position` declares it, and the scan is done.
//! - A board whose homing cannot pull off its switch (`$27=0`): the typed homing
//!   failure (ALARM:8, with the advice on `$27`) as the reason, homing not retried.

use std::io::{BufRead, BufReader};
use std::path::Path;
use std::time::Duration;

use gonio_tests::{temp_dir, Daemon, SMALL_GOLD_SCENE, TOKEN};
use serde_json::{json, Value};

/// A daemon on the emulated camera and an emulated GRBL board described by
/// `board` (the emulator's TOML), with `[arm]` keys `arm`.
fn config(dir: &Path, board: &str, arm: &str) -> String {
    let board_path = dir.join("board.toml");
    std::fs::write(&board_path, board).unwrap();
    let scene = dir.join("scene.toml");
    std::fs::write(&scene, SMALL_GOLD_SCENE).unwrap();
    format!(
        r#"
[arm]
kind = "emulator"
time_scale = 0.01
board = "{}"
{arm}

[camera]
kind = "emulator"
scene = "{}"
time_scale = 0.01

[retry]
attempts = 3
backoff_ms = 50
"#,
        board_path.display(),
        scene.display()
    )
}

/// The hardware log's actions, in order.
fn actions(daemon: &Daemon) -> Vec<String> {
    daemon
        .get("/api/hardware/log")
        .json
        .as_array()
        .unwrap()
        .iter()
        .map(|e| e["action"].as_str().unwrap_or_default().to_owned())
        .collect()
}

/// The first server-sent event of scan `id` that `wanted` accepts.
fn first_event(daemon: &Daemon, id: i64, wanted: impl Fn(&Value) -> bool) -> Value {
    let response = ureq::get(&format!("{}/api/scans/{id}/events", daemon.url))
        .timeout(Duration::from_secs(60))
        .call()
        .expect("events stream");
    BufReader::new(response.into_reader())
        .lines()
        .map_while(Result::ok)
        .filter_map(|line| {
            line.strip_prefix("data:")
                .map(|d| serde_json::from_str::<Value>(d.trim()).expect("event JSON"))
        })
        .find(|event| wanted(event))
        .expect("no such event")
}

#[test]
fn stock_board_waits_with_each_setting_then_for_the_declared_position() {
    let dir = temp_dir("arm-stock");
    let stock = "# a stock GRBL 1.1h board: $100=250, $22=0, $130=200\n";
    std::fs::write(
        dir.join("gonio.toml"),
        config(&dir, stock, "homing = \"off\""),
    )
    .unwrap();
    let daemon = Daemon::restart(&dir);
    let body = json!({"sample": "gold", "theta_l": [-20, -30], "bracket": {"shutter_s": [0.05]}});
    let created = daemon.post("/api/scans", &body);
    assert_eq!(created.status, 201, "{:?}", created.json);
    let id = created.json["id"].as_i64().unwrap();
    let scan = daemon.wait_state(id, &["waiting"], Duration::from_secs(30));
    let reason = scan["reason"].as_str().unwrap();
    for line in [
        "$100 (X steps per degree) is 250, configuration expects 80",
        "$130 (X max travel, degrees) is 200, configuration expects 180",
    ] {
        assert!(reason.contains(line), "{reason}");
    }
    assert_eq!(scan["error"], scan["reason"]);
    // Refused, the board is reopened with a backoff (1 s, 2 s, …), not in a storm.
    std::thread::sleep(Duration::from_millis(2500));
    let attempts = actions(&daemon)
        .iter()
        .filter(|a| *a == "connect failed")
        .count();
    assert!(
        (1..=3).contains(&attempts),
        "{attempts} connection attempts"
    );
    drop(daemon);

    // Let the driver write the settings: the scan then waits for the position.
    std::fs::write(
        dir.join("gonio.toml"),
        config(&dir, stock, "homing = \"off\"\napply_settings = true"),
    )
    .unwrap();
    let daemon = Daemon::restart(&dir);
    // The stream opens on the scan as it was left (waiting for the settings), then
    // shows it queued, running, and waiting again, for the position this time.
    let waiting = first_event(&daemon, id, |event| {
        event["state"] == "waiting"
            && event["reason"]
                .as_str()
                .is_some_and(|r| r.contains("declare where the arm is"))
    });
    assert!(
        waiting["reason"].as_str().unwrap().starts_with("home: "),
        "{waiting}"
    );
    let hardware = daemon.get("/api/hardware").json;
    assert_eq!(hardware["arm"]["state"], "needs_position", "{hardware}");
    // Declaring needs the token, and a proper angle; the emulated arm rests at 0°.
    let path = "/api/arm/position";
    assert_eq!(daemon.post_raw(path, None, r#"{"angle": 0}"#).status, 401);
    let bad = daemon.post_raw(path, Some(TOKEN), r#"{"angle": "zero"}"#);
    assert_eq!((bad.status, &bad.json["field"]), (422, &json!("angle")));
    // Off the travel [−180, 0] (a scan after +10 declared at 0 once ended `done` with
    // Ks 13× too small).
    for angle in [10.0, 0.5, -180.5, 359.0] {
        let off = daemon.post(path, &json!({ "angle": angle }));
        assert_eq!(
            (off.status, &off.json["field"]),
            (422, &json!("angle")),
            "{angle}: {:?}",
            off.json
        );
    }
    let declared = daemon.post(path, &json!({"angle": 0.0}));
    assert_eq!(declared.status, 200, "{:?}", declared.json);
    let done = daemon.wait_state(id, &["done", "failed"], Duration::from_secs(120));
    assert_eq!(done["state"], "done", "{done}");
    let log = daemon.get("/api/hardware/log").json;
    let declare = log
        .as_array()
        .unwrap()
        .iter()
        .find(|e| e["action"] == "declare")
        .expect("declaration not logged");
    assert!(
        declare["detail"].as_str().unwrap().contains("0.000°"),
        "{declare}"
    );
}

#[test]
fn homing_failure_waits_with_its_alarm_and_advice_without_retrying() {
    let dir = temp_dir("arm-homing");
    let board = "steps_per_deg = 80.0\nmax_travel_deg = 180.0\nmax_rate_deg_per_min = 1200.0\n\
                 accel_deg_per_s2 = 40.0\nhoming_enabled = true\nsoft_limits = true\n\
                 homing_seek_deg_per_min = 600.0\nhoming_cycles = [\"X\"]\n\
                 homing_pulloff_deg = 0.0\n";
    std::fs::write(dir.join("gonio.toml"), config(&dir, board, "")).unwrap();
    let daemon = Daemon::restart(&dir);
    let body = json!({"sample": "gold", "theta_l": [-20], "bracket": {"shutter_s": [0.05]}});
    let id = daemon.post("/api/scans", &body).json["id"]
        .as_i64()
        .unwrap();
    let scan = daemon.wait_state(id, &["waiting", "failed"], Duration::from_secs(30));
    assert_eq!(scan["state"], "waiting", "{scan}");
    let reason = scan["reason"].as_str().unwrap();
    assert!(reason.contains("homing failed, alarm 8"), "{reason}");
    assert!(reason.contains("$27"), "{reason}");
    // No retries, no resets: the log stays as it was.
    let before = actions(&daemon);
    std::thread::sleep(Duration::from_secs(2));
    assert_eq!(actions(&daemon), before);
    assert_eq!(
        before.iter().filter(|a| *a == "connect").count(),
        1,
        "{before:?}"
    );
    assert_eq!(
        before.iter().filter(|a| *a == "wait").count(),
        1,
        "{before:?}"
    );
    assert_eq!(
        daemon.get(&format!("/api/scans/{id}")).json["state"],
        "waiting"
    );
    // Declaring is refused where homing is required.
    let refused = daemon.post("/api/arm/position", &json!({"angle": -5}));
    assert_eq!(refused.status, 409, "{:?}", refused.json);
}
