//! Sample changes: a sweep over two samples on the emulators stops before the second
//! sample's scan (`waiting`, reason `mount sample <name>`, action `confirm`), nothing
//! moves until the operator confirms, and the scan then images the sample mounted: its
//! fits recover that sample's parameters, not the first one's.

use std::io::{BufRead, BufReader};
use std::time::Duration;

use gonio_mock_hw::scene::Scene;
use gonio_tests::{
    emulator_config, small_red_scene, sweep_scans, temp_dir, with_small_red_sample, Daemon,
    SMALL_GOLD_SCENE,
};
use serde_json::{json, Value};

/// The JSON of every event of a scan's stream, until it ends.
fn read_events(url: &str) -> Vec<Value> {
    let response = ureq::get(url)
        .timeout(Duration::from_secs(180))
        .call()
        .expect("events stream");
    BufReader::new(response.into_reader())
        .lines()
        .map_while(Result::ok)
        .filter_map(|line| {
            line.strip_prefix("data:")
                .map(|d| serde_json::from_str(d.trim()).expect("event JSON"))
        })
        .collect()
}

/// Scans `gold` and `red` each imaged their own sample: the truth each wrote is its
/// sample's, and its Cook–Torrance fit lands within 10 % of that truth and not of the
/// other sample's.
fn each_scan_imaged_its_sample(daemon: &Daemon, gold: i64, red: i64) {
    let gold_truth = Scene::from_toml_str(SMALL_GOLD_SCENE).unwrap().truth_json();
    let red_truth = Scene::from_toml_str(&small_red_scene())
        .unwrap()
        .truth_json();
    for (id, truth, other) in [
        (gold, &gold_truth, &red_truth),
        (red, &red_truth, &gold_truth),
    ] {
        let scan_dir = daemon.data.join(format!("scans/{id}"));
        let written: Value =
            serde_json::from_slice(&std::fs::read(scan_dir.join("truth.json")).unwrap()).unwrap();
        for key in ["scene", "kd", "ks", "m"] {
            assert_eq!(written[key], truth[key], "scan {id}: {key}");
        }
        let fit: Value = serde_json::from_slice(
            &std::fs::read(scan_dir.join("fit-cook-torrance.json")).unwrap(),
        )
        .unwrap();
        fit_matches(&fit, truth, 0.1).unwrap_or_else(|e| panic!("scan {id}: {e}"));
        assert!(
            fit_matches(&fit, other, 0.1).is_err(),
            "scan {id}: its fit also matches the other sample: {fit}"
        );
    }
}

/// Whether each fitted Kd, Ks and m of `fit` is within `rel` of `truth`'s.
fn fit_matches(fit: &Value, truth: &Value, rel: f64) -> Result<(), String> {
    let mut keys: Vec<(String, f64, f64)> = Vec::new();
    for key in ["kd", "ks"] {
        for c in 0..3 {
            keys.push((
                format!("{key}[{c}]"),
                fit[key][c].as_f64().unwrap(),
                truth[key][c].as_f64().unwrap(),
            ));
        }
    }
    keys.push((
        "m".into(),
        fit["m"][0].as_f64().unwrap(),
        truth["m"][0].as_f64().unwrap(),
    ));
    for (what, got, want) in keys {
        if (got - want).abs() > rel * want.abs() + 0.3 {
            return Err(format!("{what}: fitted {got}, true {want}"));
        }
    }
    Ok(())
}

fn captures_of(daemon: &Daemon, id: i64) -> usize {
    daemon
        .get("/api/hardware/log")
        .json
        .as_array()
        .unwrap()
        .iter()
        .filter(|e| e["action"] == "capture" && e["scan_id"] == id)
        .count()
}

#[test]
fn a_two_sample_sweep_waits_for_the_change_and_images_the_sample_confirmed() {
    let dir = temp_dir("samples-sweep");
    let daemon = Daemon::start(&dir, &with_small_red_sample(&emulator_config(0.01), &dir));
    let created = daemon.post(
        "/api/sweeps",
        &json!({"samples": ["gold", "red"], "theta_l_sets": [[-20, -30, -40]],
                "bracket": {"shutter_s": [0.5, 0.125, 1.0 / 30.0, 0.01]}}),
    );
    assert_eq!(created.status, 201, "{:?}", created.json);
    let ids = sweep_scans(&created.json);
    let (gold, red) = (ids[0], ids[1]);
    let events_url = format!("{}/api/scans/{red}/events", daemon.url);
    let events = std::thread::spawn(move || read_events(&events_url));

    // The mounted sample's scan runs at once; the next one stops for the change.
    let first = daemon.wait_state(gold, &["done", "failed"], Duration::from_secs(120));
    assert_eq!(first["state"], "done", "{first}");
    let waiting = daemon.wait_state(red, &["waiting"], Duration::from_secs(30));
    assert_eq!(waiting["reason"], "mount sample red", "{waiting}");
    assert!(
        waiting["actions"]
            .as_array()
            .unwrap()
            .contains(&json!("confirm")),
        "{waiting}"
    );
    std::thread::sleep(Duration::from_millis(1500));
    let still = daemon.get(&format!("/api/scans/{red}")).json;
    assert_eq!(
        still["state"], "waiting",
        "nothing moves until confirmed: {still}"
    );
    assert_eq!(captures_of(&daemon, red), 0);

    // Confirming needs the token, and a scan that waits for a sample.
    let confirm = format!("/api/scans/{red}/confirm");
    assert_eq!(daemon.post_raw(&confirm, None, "").status, 401);
    let refused = daemon.post(&format!("/api/scans/{gold}/confirm"), &json!({}));
    assert_eq!(refused.status, 409, "{:?}", refused.json);
    assert!(
        refused.json["error"].as_str().unwrap().contains("done"),
        "{:?}",
        refused.json
    );
    let confirmed = daemon.post(&confirm, &json!({}));
    assert_eq!(confirmed.status, 200, "{:?}", confirmed.json);
    assert_eq!(confirmed.json["id"], red);
    assert!(
        ["queued", "running", "done"].contains(&confirmed.json["state"].as_str().unwrap()),
        "{:?}",
        confirmed.json
    );
    assert!(!confirmed.json["actions"]
        .as_array()
        .unwrap()
        .contains(&json!("confirm")));
    let second = daemon.wait_state(red, &["done", "failed"], Duration::from_secs(120));
    assert_eq!(second["state"], "done", "{second}");
    // A second confirmation finds nothing waiting.
    assert_eq!(daemon.post(&confirm, &json!({})).status, 409);

    // The event stream showed the wait with its reason.
    let events = events.join().unwrap();
    assert!(
        events
            .iter()
            .any(|e| e["state"] == "waiting" && e["reason"] == "mount sample red"),
        "{events:?}"
    );
    assert_eq!(events.last().unwrap()["state"], "done");

    // Each scan imaged its own sample: truth and fits.
    each_scan_imaged_its_sample(&daemon, gold, red);
    let log = daemon.get("/api/hardware/log").json;
    assert!(
        log.as_array()
            .unwrap()
            .iter()
            .any(|e| e["action"] == "mount" && e["scan_id"] == red),
        "{log}"
    );
    drop(daemon);
    std::fs::remove_dir_all(dir).ok();
}

#[test]
fn a_sample_the_emulator_has_no_scene_for_is_refused() {
    let dir = temp_dir("samples-unknown");
    let daemon = Daemon::start(&dir, &with_small_red_sample(&emulator_config(0.01), &dir));
    let answer = daemon.post(
        "/api/scans",
        &json!({"sample": "teal", "theta_l": [-20], "bracket": {"shutter_s": [0.1]}}),
    );
    assert_eq!(answer.status, 422, "{:?}", answer.json);
    assert_eq!(answer.json["field"], "sample");
    assert!(
        answer.json["error"].as_str().unwrap().contains("red"),
        "{:?}",
        answer.json
    );
    assert_eq!(daemon.get("/api/scans").json, json!([]));
    drop(daemon);
    std::fs::remove_dir_all(dir).ok();
}

#[test]
fn a_carousel_brings_each_sample_itself_and_no_scan_waits() {
    let dir = temp_dir("samples-carousel");
    let config = format!(
        "{}\n[carousel]\naxis = \"Y\"\nslots = {{ gold = -10.0, red = -100.0 }}\n",
        with_small_red_sample(&emulator_config(0.01), &dir)
    );
    let daemon = Daemon::start(&dir, &config);
    // A sample the carousel does not hold is refused.
    let teal = daemon.post(
        "/api/scans",
        &json!({"sample": "blue-green", "theta_l": [-20], "bracket": {"shutter_s": [0.1]}}),
    );
    assert_eq!(teal.status, 422, "{:?}", teal.json);
    assert_eq!(teal.json["field"], "sample");
    let created = daemon.post(
        "/api/sweeps",
        &json!({"samples": ["red", "gold"], "theta_l_sets": [[-20, -30, -40]],
                "bracket": {"shutter_s": [0.5, 0.125, 1.0 / 30.0, 0.01]}}),
    );
    assert_eq!(created.status, 201, "{:?}", created.json);
    let sweep = created.json["id"].as_i64().unwrap();
    let ids = sweep_scans(&created.json);
    let (red, gold) = (ids[0], ids[1]);
    let deadline = std::time::Instant::now() + Duration::from_secs(180);
    loop {
        let view = daemon.get(&format!("/api/sweeps/{sweep}")).json;
        assert_eq!(view["scans_by_state"]["waiting"], 0, "{view}");
        if view["state"] == "done" || view["state"] == "finished" {
            assert_eq!(view["state"], "done", "{view}");
            break;
        }
        assert!(std::time::Instant::now() < deadline, "{view}");
        std::thread::sleep(Duration::from_millis(50));
    }

    // The carousel turned to each sample before that scan's first capture.
    let log = daemon.get("/api/hardware/log").json;
    let entries = log.as_array().unwrap();
    for (id, slot) in [(red, "Y -100.000"), (gold, "Y -10.000")] {
        let turned = entries
            .iter()
            .position(|e| e["action"] == "carousel" && e["scan_id"] == id)
            .unwrap_or_else(|| panic!("no carousel turn for scan {id}: {log}"));
        assert!(
            entries[turned]["detail"].as_str().unwrap().ends_with(slot),
            "{}",
            entries[turned]
        );
        let first_capture = entries
            .iter()
            .position(|e| e["action"] == "capture" && e["scan_id"] == id)
            .unwrap();
        assert!(turned < first_capture, "{log}");
    }
    each_scan_imaged_its_sample(&daemon, gold, red);
    drop(daemon);
    std::fs::remove_dir_all(dir).ok();
}
