//! The daemon's HTTP contract on emulated hardware: authentication, validation of every
//! field, the queue (two concurrent POSTs run one after the other), operator controls,
//! and the page and API description; a busy port refused before anything is created.

use std::fs::Permissions;
use std::os::unix::fs::PermissionsExt;
use std::time::Duration;

use gonio_tests::{emulator_config, temp_dir, Daemon, TOKEN};
use serde_json::{json, Value};

fn scan_count(daemon: &Daemon) -> usize {
    daemon.get("/api/scans").json.as_array().map_or(0, Vec::len)
}

#[test]
fn mutating_routes_need_the_token_and_change_nothing_without_it() {
    let dir = temp_dir("api-auth");
    // A data directory open to all, as an earlier version left it: made private.
    let data = dir.join("data");
    std::fs::create_dir_all(&data).unwrap();
    std::fs::set_permissions(&data, Permissions::from_mode(0o755)).unwrap();
    let daemon = Daemon::start(&dir, &emulator_config(0.01));
    // Health says "degraded" (arm_disconnected) until the hardware lane has opened the
    // arm.
    let health = daemon.wait_for("/api/health", Duration::from_secs(30), |h| {
        h["status"] == "ok"
    });
    assert!(
        health["disk_free_bytes"].as_u64().is_some_and(|b| b > 0),
        "{health}"
    );
    let mode =
        |path: &std::path::Path| std::fs::metadata(path).unwrap().permissions().mode() & 0o777;
    assert_eq!(mode(&data), 0o700);
    for entry in std::fs::read_dir(&data).unwrap() {
        let path = entry.unwrap().path();
        if path
            .file_name()
            .unwrap()
            .to_string_lossy()
            .starts_with("gonio.sqlite")
        {
            assert_eq!(mode(&path), 0o600, "{}", path.display());
        }
    }
    let body = json!({"sample": "gold", "theta_l": [-20]}).to_string();
    for token in [None, Some("wrong-token"), Some("")] {
        let answer = daemon.post_raw("/api/scans", token, &body);
        assert_eq!(answer.status, 401, "token {token:?}: {:?}", answer.json);
        assert!(answer.json["error"].as_str().unwrap().contains("token"));
    }
    for path in ["/api/sweeps", "/api/scans/1/cancel", "/api/emulator/fault"] {
        assert_eq!(daemon.post_raw(path, None, "{}").status, 401, "{path}");
    }
    assert_eq!(
        scan_count(&daemon),
        0,
        "nothing may be queued without the token"
    );
    assert_eq!(
        daemon.get("/api/sweeps").json,
        json!([]),
        "nothing may be queued without the token"
    );
    // Reads are open, and so is the emergency stop: anyone at the instrument can stop
    // it; homing it again (which ends the hold) needs the token.
    assert_eq!(daemon.get("/api/hardware").status, 200);
    assert_eq!(daemon.post_raw("/api/arm/stop", None, "").status, 200);
    assert_eq!(daemon.get("/api/hardware").json["halted"], true);
    assert_eq!(daemon.post_raw("/api/arm/home", None, "").status, 401);
    std::fs::remove_dir_all(dir).ok();
}

#[test]
fn every_invalid_field_gets_422_naming_it_and_nothing_is_queued() {
    let dir = temp_dir("api-422");
    let daemon = Daemon::start(&dir, &emulator_config(0.01));
    let cases: Vec<(Value, &str)> = vec![
        (json!({"theta_l": [-20]}), "sample"),
        (json!({"sample": "../etc", "theta_l": [-20]}), "sample"),
        (json!({"sample": "a/b", "theta_l": [-20]}), "sample"),
        (json!({"sample": "", "theta_l": [-20]}), "sample"),
        (json!({"sample": "gold"}), "theta_l"),
        (json!({"sample": "gold", "theta_l": []}), "theta_l"),
        (
            json!({"sample": "gold", "theta_l": [-20, 15]}),
            "theta_l[1]",
        ),
        (json!({"sample": "gold", "theta_l": [-95]}), "theta_l[0]"),
        (json!({"sample": "gold", "theta_l": ["x"]}), "theta_l[0]"),
        (
            json!({"sample": "gold", "theta_l": [-20], "bracket": {"shutter_s": []}}),
            "bracket.shutter_s",
        ),
        (
            json!({"sample": "gold", "theta_l": [-20], "bracket": {"shutter_s": [0.01, 3600]}}),
            "bracket.shutter_s[1]",
        ),
        (
            json!({"sample": "gold", "theta_l": [-20], "bracket": {"shutter_s": [0]}}),
            "bracket.shutter_s[0]",
        ),
        (
            json!({"sample": "gold", "theta_l": [-20], "bracket": "sometimes"}),
            "bracket",
        ),
        (
            json!({"sample": "gold", "theta_l": [-20], "extra": 1}),
            "extra",
        ),
    ];
    for (body, field) in cases {
        let answer = daemon.post("/api/scans", &body);
        assert_eq!(answer.status, 422, "{body}: {:?}", answer.json);
        assert_eq!(answer.json["field"], json!(field), "{body}");
        assert!(
            answer.json["error"].as_str().unwrap().starts_with(field),
            "{body}: {}",
            answer.json["error"]
        );
    }
    let sweep = json!({"samples": ["a"], "theta_l_sets": [[-20, 30]]});
    let answer = daemon.post("/api/sweeps", &sweep);
    assert_eq!(answer.status, 422);
    assert_eq!(answer.json["field"], json!("theta_l_sets[0][1]"));
    // Not JSON at all, and a body over the size limit.
    assert_eq!(daemon.post_raw("/api/scans", Some(TOKEN), "{").status, 400);
    let huge = format!(
        "{{\"sample\":\"gold\",\"theta_l\":[-20],\"pad\":\"{}\"}}",
        "x".repeat(200_000)
    );
    assert_eq!(
        daemon.post_raw("/api/scans", Some(TOKEN), &huge).status,
        413
    );
    assert_eq!(
        scan_count(&daemon),
        0,
        "an invalid request must queue nothing"
    );
    std::fs::remove_dir_all(dir).ok();
}

#[test]
fn concurrent_scans_run_one_after_the_other_and_controls_work() {
    let dir = temp_dir("api-queue");
    let daemon = Daemon::start(&dir, &emulator_config(0.01));
    let body =
        json!({"sample": "gold", "theta_l": [-20, -30], "bracket": {"shutter_s": [0.5, 0.05]}});
    let ids: Vec<i64> = std::thread::scope(|s| {
        let posts: Vec<_> = (0..2)
            .map(|_| s.spawn(|| daemon.post("/api/scans", &body)))
            .collect();
        posts
            .into_iter()
            .map(|p| {
                let answer = p.join().unwrap();
                assert_eq!(answer.status, 201, "{:?}", answer.json);
                answer.json["id"].as_i64().unwrap()
            })
            .collect()
    });
    // A third scan, paused while queued, then cancelled: it never runs.
    let third = daemon.post("/api/scans", &body).json["id"]
        .as_i64()
        .unwrap();
    let paused = daemon.post(&format!("/api/scans/{third}/pause"), &json!({}));
    assert_eq!(paused.status, 200, "{:?}", paused.json);
    assert_eq!(paused.json["state"], "paused");
    assert_eq!(paused.json["actions"], json!(["resume", "cancel"]));

    let timeout = Duration::from_secs(90);
    let first = daemon.wait_state(ids[0].min(ids[1]), &["done", "failed"], timeout);
    let second = daemon.wait_state(ids[0].max(ids[1]), &["done", "failed"], timeout);
    for scan in [&first, &second] {
        assert_eq!(scan["state"], "done", "{scan}");
        assert_eq!(scan["progress"]["done"], scan["progress"]["total"]);
    }
    // One hardware owner: every hardware action of the first scan precedes the second's.
    let log = daemon.get("/api/hardware/log").json;
    let scan_of: Vec<i64> = log
        .as_array()
        .unwrap()
        .iter()
        .filter_map(|e| e["scan_id"].as_i64())
        .collect();
    let last_first = scan_of
        .iter()
        .rposition(|s| *s == first["id"].as_i64().unwrap());
    let first_second = scan_of
        .iter()
        .position(|s| *s == second["id"].as_i64().unwrap());
    assert!(
        last_first.unwrap() < first_second.unwrap(),
        "scans interleaved: {scan_of:?}"
    );
    let captures = log
        .as_array()
        .unwrap()
        .iter()
        .filter(|e| e["action"] == "capture")
        .count();
    assert_eq!(captures, 2 * 2 * 2);

    // The latest frame is the last capture of the plan (last θL, shortest shutter), and
    // the model the `auto` fit chose is the one its fit-auto.json names.
    let view = daemon.get(&format!("/api/scans/{}", first["id"])).json;
    assert_eq!(
        view["frame"],
        json!({"theta_l": -30.0, "shutter_s": 0.05}),
        "{view}"
    );
    let choice = &view["choice"];
    let fit = daemon.get(choice["fit"].as_str().unwrap()).json;
    assert_eq!(choice["model"], fit["model"], "{choice}");
    assert!(
        !choice["reason"].as_str().unwrap().is_empty() && choice["colour_shift"].is_boolean(),
        "{choice}"
    );
    // The list shows an ended fixed-bracket scan's frame and choice as its view does.
    let list = daemon.get("/api/scans").json;
    let listed = list
        .as_array()
        .unwrap()
        .iter()
        .find(|s| s["id"] == first["id"])
        .unwrap();
    assert_eq!(listed["frame"], view["frame"], "{listed}");
    assert_eq!(listed["choice"], view["choice"], "{listed}");
    let third_view = daemon.get(&format!("/api/scans/{third}")).json;
    assert_eq!(third_view["state"], "paused");
    assert_eq!(third_view["frame"], Value::Null, "{third_view}");
    assert_eq!(third_view["choice"], Value::Null, "{third_view}");
    assert_eq!(third_view["progress"]["done"], 0);
    assert_eq!(
        daemon
            .post(&format!("/api/scans/{third}/cancel"), &json!({}))
            .json["state"],
        "cancelled"
    );
    // A cancelled scan cannot be resumed.
    assert_eq!(
        daemon
            .post(&format!("/api/scans/{third}/resume"), &json!({}))
            .status,
        409
    );
    assert_eq!(daemon.get("/api/scans/999").status, 404);
    std::fs::remove_dir_all(dir).ok();
}

#[test]
fn page_and_openapi_are_served() {
    let dir = temp_dir("api-page");
    let daemon = Daemon::start(&dir, &emulator_config(0.01));
    let page = daemon.get("/");
    assert_eq!(page.status, 200);
    assert!(page.content_type.starts_with("text/html"));
    let html = String::from_utf8(page.bytes).unwrap();
    assert!(html.contains("/api/scans"), "the page drives the API");
    let spec = daemon.get("/api/openapi.json").json;
    assert!(spec["openapi"].as_str().unwrap().starts_with("3."));
    for path in [
        "/api/scans",
        "/api/scans/{id}",
        "/api/scans/{id}/events",
        "/api/sweeps",
        "/api/arm/stop",
    ] {
        assert!(
            spec["paths"][path].is_object(),
            "{path} missing from OpenAPI"
        );
    }
    std::fs::remove_dir_all(dir).ok();
}

#[test]
fn sweep_waits_for_its_start_time_and_shows_one_progress_view() {
    let dir = temp_dir("api-sweep");
    let daemon = Daemon::start(&dir, &emulator_config(0.01));
    let created = daemon.post(
        "/api/sweeps",
        &json!({"samples": ["gold", "red"], "theta_l_sets": [[-20], [-30, -40]], "repeats": 2,
                "bracket": {"shutter_s": [0.1]}, "start_at": "2099-01-01T22:00:00Z"}),
    );
    assert_eq!(created.status, 201, "{:?}", created.json);
    assert_eq!(created.json["scans"].as_array().unwrap().len(), 8);
    let id = created.json["id"].as_i64().unwrap();
    std::thread::sleep(Duration::from_millis(1500));
    let sweep = daemon.get(&format!("/api/sweeps/{id}")).json;
    assert_eq!(sweep["state"], "scheduled", "{sweep}");
    assert_eq!(sweep["scans_by_state"]["queued"], 8);
    assert_eq!(sweep["progress"]["done"], 0);
    // 2 repeats × (2 scans of 1 θL + 2 scans of 2 θL), each θL move + capture +
    // samples + HDR, each scan home + extract + 3 fits + the fit that chooses the model.
    assert_eq!(sweep["progress"]["total"], 2 * (2 * (6 + 4) + 2 * (6 + 8)));
    assert_eq!(sweep["start_at"], "2099-01-01T22:00:00Z");
    let log = daemon.get("/api/hardware/log").json;
    assert!(
        log.as_array()
            .unwrap()
            .iter()
            .all(|e| e["action"] != "capture"),
        "nothing may run before the start time: {log}"
    );
    std::fs::remove_dir_all(dir).ok();
}

/// `gonio serve` on a port another program listens on fails at once with one line
/// naming the address, and creates nothing: no data directory, no token (it once made
/// both, and started the emulators, before trying the port).
#[test]
fn busy_port_fails_in_one_line_and_creates_nothing() {
    let dir = temp_dir("api-busy-port");
    let busy = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = busy.local_addr().unwrap().to_string();
    let data = dir.join("data");
    let output = std::process::Command::new(gonio_tests::gonio_bin())
        .args(["serve", "--bind", &addr, "--data"])
        .arg(&data)
        .env_remove("GONIO_TOKEN")
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(1), "{stderr}");
    let error = stderr
        .lines()
        .find(|l| l.starts_with("error: "))
        .unwrap_or_else(|| panic!("no error line: {stderr}"));
    assert!(error.contains(&format!("binding {addr}")), "{error}");
    assert!(error.contains("in use"), "{error}");
    assert!(!data.exists(), "{} was created", data.display());
    drop(busy);
    std::fs::remove_dir_all(dir).ok();
}
