//! The daemon with a GRBL board that is not (yet) fit for a scan, emulated: scans wait
//! with the reason (on `/api/scans/{id}`, in the event stream) instead of sitting
//! queued or failing, and the board is not reset in a storm meanwhile.
//!
//! - A stock board (`$100=250`, `$22=0`) under `homing = "off"`: each differing setting
//!   listed as the reason; `/api/hardware` shows the arm `refused` with those settings
//!   and no angle, and the board is opened (reset) again only when it is unplugged and
//!   plugged in or the operator asks (`POST /api/arm/reconnect`); with `apply_settings`
//!   the board is set up, the scan waits for the declared position, `POST
//!   /api/arm/position` declares it, and the scan is done.
//! - A board whose homing cannot pull off its switch (`$27=0`): the typed homing
//!   failure (ALARM:8, with the advice on `$27`) as the reason, homing not retried.
//! - `[arm] reply_timeout_s` is how long the driver waits for an answer: a board that
//!   goes silent is reported timed out after that long.

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

[emulator]
fault_injection = true
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

/// How often the daemon opened the board and was refused.
fn attempts(daemon: &Daemon) -> usize {
    actions(daemon)
        .iter()
        .filter(|a| *a == "connect failed")
        .count()
}

/// Waits (at most 10 s) until the board was opened `n` times, then checks that 1.5 s
/// later it still was opened exactly `n` times (no reset storm).
fn opened_exactly(daemon: &Daemon, n: usize) {
    let deadline = std::time::Instant::now() + Duration::from_secs(10);
    while attempts(daemon) < n {
        assert!(
            std::time::Instant::now() < deadline,
            "{:?}",
            actions(daemon)
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    std::thread::sleep(Duration::from_millis(1500));
    assert_eq!(attempts(daemon), n, "{:?}", actions(daemon));
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
    let hardware = daemon.get("/api/hardware").json;
    let arm = &hardware["arm"];
    assert_eq!(arm["state"], "refused", "{hardware}");
    assert_eq!(
        arm["settings"],
        json!([
            "$100 (X steps per degree) is 250, configuration expects 80",
            "$130 (X max travel, degrees) is 200, configuration expects 180",
        ]),
        "{hardware}"
    );
    assert_eq!(arm["angle_deg"], Value::Null, "{hardware}");
    // Refused, the board is not opened (reset) again by itself: once in 3.5 s, where
    // a backoff of 1 s, 2 s, … would have opened it three times.
    std::thread::sleep(Duration::from_millis(3500));
    assert_eq!(attempts(&daemon), 1, "{:?}", actions(&daemon));
    // Unplugged and plugged in: opened once more, refused again (the same board).
    let fault = |daemon: &Daemon, fault: &str| {
        let answer = daemon.post("/api/emulator/fault", &json!({ "fault": fault }));
        assert_eq!(answer.status, 200, "{fault}: {:?}", answer.json);
    };
    fault(&daemon, "unplug");
    fault(&daemon, "reconnect");
    opened_exactly(&daemon, 2);
    assert_eq!(daemon.get("/api/hardware").json["arm"]["state"], "refused");
    // The operator asks: once more. The route needs the token.
    assert_eq!(daemon.post_raw("/api/arm/reconnect", None, "").status, 401);
    let asked = daemon.post("/api/arm/reconnect", &json!({}));
    assert_eq!(asked.status, 200, "{:?}", asked.json);
    opened_exactly(&daemon, 3);
    let reconnects: Vec<String> = daemon
        .get("/api/hardware/log")
        .json
        .as_array()
        .unwrap()
        .iter()
        .filter(|e| e["action"] == "reconnect")
        .map(|e| e["detail"].as_str().unwrap_or_default().to_owned())
        .collect();
    assert_eq!(
        reconnects,
        ["the board was plugged in again", "asked by the operator"]
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
    assert_eq!(hardware["arm"]["angle_deg"], Value::Null, "{hardware}");
    assert_eq!(hardware["arm"]["settings"], json!([]), "{hardware}");
    // Connected: nothing to reconnect (it would reset the board).
    assert_eq!(daemon.post("/api/arm/reconnect", &json!({})).status, 409);
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

#[test]
fn reply_timeout_from_the_configuration_bounds_the_wait_for_an_answer() {
    let dir = temp_dir("arm-reply-timeout");
    // A board set up as expected (homing off: the position is declared), that goes
    // silent 2 s after it starts: the idle lane's status query then times out.
    let board = "steps_per_deg = 80.0\nmax_travel_deg = 180.0\n\
                 [[faults]]\nat_s = 2.0\nfault = \"silent\"\n";
    std::fs::write(
        dir.join("gonio.toml"),
        config(&dir, board, "homing = \"off\"\nreply_timeout_s = 0.3"),
    )
    .unwrap();
    let daemon = Daemon::restart(&dir);
    let hardware = daemon.wait_for("/api/hardware", Duration::from_secs(30), |hw| {
        hw["arm"]["error"]
            .as_str()
            .is_some_and(|e| e.contains("timed out"))
    });
    let error = hardware["arm"]["error"].as_str().unwrap();
    assert!(error.contains("timed out after 0.3 s"), "{error}");
}
