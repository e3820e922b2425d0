//! The sample carousel on the emulators: the emulated camera sees the sample of the slot
//! the carousel's axis physically is at (none between slots), so every capture is
//! checked against what was before the camera, not against what the daemon believes.
//!
//! - Pause → Home → resume: the homing cycle takes the carousel to its switch; the
//!   daemon turns it back to the slot before the next capture, and every frame of the
//!   scan shows its sample.
//! - An emergency stop, a board reset and an unplug + replug during a two-sample
//!   carousel sweep: every frame of each scan shows that scan's sample, and the
//!   e-stopped scan carries its reason while paused.
//! - One homing and one turn per sample change; a slot beyond the board's travel or a
//!   slot name that is not a sample name keeps the daemon from starting.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Duration;

use gonio_mock_hw::render::{render, Shot};
use gonio_mock_hw::scene::Scene;
use gonio_processing::capture::Frame;
use gonio_tests::{
    emulator_config_scaled, files_under, gonio_bin, small_red_scene, sweep_scans, temp_dir,
    with_small_red_sample, Daemon, SMALL_GOLD_SCENE,
};
use serde_json::{json, Value};

/// The carousel of these tests: gold and red on the Y axis.
const CAROUSEL: &str = "\n[carousel]\naxis = \"Y\"\nslots = { gold = -10.0, red = -60.0 }\n";

/// Rows of the small scenes' sample strip (`sample_rows`).
const SAMPLE_ROWS: std::ops::RangeInclusive<usize> = 124..=148;

fn carousel_config(dir: &Path, arm_time_scale: f64, camera_time_scale: f64) -> String {
    format!(
        "{}{CAROUSEL}",
        with_small_red_sample(
            &emulator_config_scaled(arm_time_scale, camera_time_scale),
            dir
        )
    )
}

/// Mean counts of each channel over the sample strip of `frame`.
fn strip_means(frame: &Frame) -> [f64; 3] {
    let mut sums = [0.0; 3];
    let mut n = 0.0;
    for y in SAMPLE_ROWS {
        for x in 0..frame.width {
            for (c, sum) in sums.iter_mut().enumerate() {
                *sum += f64::from(frame.data[3 * (y * frame.width + x) + c]);
            }
            n += 1.0;
        }
    }
    sums.map(|s| s / n)
}

/// What the emulated camera would show of each candidate sample (and of an empty slot)
/// with the light at `theta_l` and shutter `shutter_s`: the sample strip's means, read
/// back as the daemon's captures are (a TIFF beside a copy of `sidecar`).
fn candidates(
    dir: &Path,
    sidecar: &Path,
    theta_l: f64,
    shutter_s: f64,
    iso: u32,
) -> Vec<(&'static str, [f64; 3])> {
    let gold = Scene::from_toml_str(SMALL_GOLD_SCENE).unwrap();
    let red = Scene::from_toml_str(&small_red_scene()).unwrap();
    let empty = gold.without_sample().unwrap();
    let shot = Shot {
        theta_l_deg: theta_l,
        shutter_s,
        iso,
        frame_index: 0,
    };
    [("gold", gold), ("red", red), ("empty", empty)]
        .into_iter()
        .map(|(name, scene)| {
            let path = dir.join(format!("expected-{name}.tiff"));
            std::fs::write(&path, render(&scene, &shot).encode_tiff().unwrap()).unwrap();
            std::fs::copy(sidecar, path.with_extension("json")).unwrap();
            (name, strip_means(&Frame::read(&path).unwrap()))
        })
        .collect()
}

/// Which sample each capture of scan `id` shows (the candidate whose sample strip is
/// nearest), by capture path.
fn samples_seen(daemon: &Daemon, id: i64, work: &Path) -> BTreeMap<String, &'static str> {
    let scan_dir = daemon.data.join(format!("scans/{id}"));
    let mut seen = BTreeMap::new();
    let mut expected: BTreeMap<String, Vec<(&'static str, [f64; 3])>> = BTreeMap::new();
    for rel in files_under(&scan_dir) {
        if !(rel.starts_with("theta_l_") && rel.ends_with(".tiff")) {
            continue;
        }
        let path: PathBuf = scan_dir.join(&rel);
        let sidecar = path.with_extension("json");
        let meta: Value = serde_json::from_slice(&std::fs::read(&sidecar).unwrap()).unwrap();
        let (theta_l, shutter_s) = (
            meta["theta_l"].as_f64().unwrap(),
            meta["shutter_s"].as_f64().unwrap(),
        );
        let iso = meta["iso"].as_f64().unwrap_or(100.0) as u32;
        let key = format!("{theta_l}/{shutter_s}/{iso}");
        let options = expected
            .entry(key)
            .or_insert_with(|| candidates(work, &sidecar, theta_l, shutter_s, iso));
        let got = strip_means(&Frame::read(&path).unwrap());
        let distance =
            |m: &[f64; 3]| -> f64 { m.iter().zip(got).map(|(a, b)| (a - b).powi(2)).sum() };
        let nearest = options
            .iter()
            .min_by(|a, b| distance(&a.1).total_cmp(&distance(&b.1)))
            .unwrap()
            .0;
        seen.insert(rel, nearest);
    }
    seen
}

/// Asserts that every capture of scan `id` (at least one) shows `sample`.
fn every_frame_shows(daemon: &Daemon, id: i64, sample: &str, work: &Path) {
    let seen = samples_seen(daemon, id, work);
    assert!(!seen.is_empty(), "scan {id} has no captures");
    let wrong: Vec<_> = seen.iter().filter(|(_, s)| **s != sample).collect();
    assert!(
        wrong.is_empty(),
        "scan {id} ({sample}): {} of {} captures show another sample: {wrong:?}",
        wrong.len(),
        seen.len()
    );
}

/// The hardware log entries of scan `id` with `action`.
fn logged(daemon: &Daemon, id: Option<i64>, action: &str) -> Vec<Value> {
    daemon
        .get("/api/hardware/log")
        .json
        .as_array()
        .unwrap()
        .iter()
        .filter(|e| e["action"] == action && id.is_none_or(|id| e["scan_id"] == id))
        .cloned()
        .collect()
}

fn captures_done(daemon: &Daemon, id: i64) -> usize {
    daemon
        .get(&format!("/api/scans/{id}/steps"))
        .json
        .as_array()
        .unwrap()
        .iter()
        .filter(|s| s["step"]["kind"] == "capture" && s["state"] == "done")
        .count()
}

fn wait_captures(daemon: &Daemon, id: i64, n: usize) {
    let deadline = std::time::Instant::now() + Duration::from_secs(120);
    while captures_done(daemon, id) < n {
        assert!(
            std::time::Instant::now() < deadline,
            "scan {id}: fewer than {n} captures; {}",
            daemon.get(&format!("/api/scans/{id}")).json
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

fn scan_body(sample: &str) -> Value {
    json!({"sample": sample, "theta_l": [-20, -30, -40],
           "bracket": {"shutter_s": [0.125, 0.01]}})
}

#[test]
fn pause_home_resume_captures_every_frame_at_the_slot() {
    let dir = temp_dir("carousel-home");
    let daemon = Daemon::start(&dir, &carousel_config(&dir, 0.02, 0.2));
    let created = daemon.post("/api/scans", &scan_body("gold"));
    assert_eq!(created.status, 201, "{:?}", created.json);
    let id = created.json["id"].as_i64().unwrap();
    wait_captures(&daemon, id, 1);
    assert_eq!(
        daemon
            .post(&format!("/api/scans/{id}/pause"), &json!({}))
            .status,
        200
    );
    daemon.wait_state(id, &["paused"], Duration::from_secs(30));
    // The lane finishes its step: wait until the arm is at rest, then home it.
    daemon.wait_for("/api/hardware", Duration::from_secs(30), |h| {
        h["arm"]["state"] == "idle"
    });
    let homes = logged(&daemon, None, "home").len();
    let home = daemon.post("/api/arm/home", &json!({}));
    assert_eq!(home.status, 202, "{:?}", home.json);
    let deadline = std::time::Instant::now() + Duration::from_secs(60);
    while logged(&daemon, None, "home").len() == homes {
        assert!(
            std::time::Instant::now() < deadline,
            "the operator's homing never ran"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    assert_eq!(
        daemon
            .post(&format!("/api/scans/{id}/resume"), &json!({}))
            .status,
        200
    );
    let done = daemon.wait_state(id, &["done", "failed"], Duration::from_secs(180));
    assert_eq!(done["state"], "done", "{done}");
    every_frame_shows(&daemon, id, "gold", &dir);
    drop(daemon);
    std::fs::remove_dir_all(dir).ok();
}

#[test]
fn estop_reset_and_replug_during_a_carousel_sweep_keep_the_right_sample() {
    let dir = temp_dir("carousel-faults");
    let daemon = Daemon::start(&dir, &carousel_config(&dir, 0.02, 0.2));
    let created = daemon.post(
        "/api/sweeps",
        &json!({"samples": ["red", "gold"], "theta_l_sets": [[-20, -30, -40]],
                "bracket": {"shutter_s": [0.125, 0.01]}}),
    );
    assert_eq!(created.status, 201, "{:?}", created.json);
    let ids = sweep_scans(&created.json);
    let (red, gold) = (ids[0], ids[1]);

    // An emergency stop during red: paused, with its reason; resumed.
    wait_captures(&daemon, red, 1);
    assert_eq!(daemon.post("/api/arm/stop", &json!({})).status, 200);
    let paused = daemon.wait_state(red, &["paused"], Duration::from_secs(30));
    assert_eq!(
        paused["reason"], "emergency stop by the operator",
        "{paused}"
    );
    assert_eq!(
        daemon
            .post(&format!("/api/scans/{red}/resume"), &json!({}))
            .status,
        200
    );

    // The board resets by itself during red.
    wait_captures(&daemon, red, 3);
    let reset = daemon.post("/api/emulator/fault", &json!({"fault": "arm_reset"}));
    assert_eq!(reset.status, 200, "{:?}", reset.json);

    // Unplugged and plugged in again during gold.
    wait_captures(&daemon, gold, 1);
    assert_eq!(
        daemon
            .post("/api/emulator/fault", &json!({"fault": "unplug"}))
            .status,
        200
    );
    std::thread::sleep(Duration::from_millis(500));
    assert_eq!(
        daemon
            .post("/api/emulator/fault", &json!({"fault": "reconnect"}))
            .status,
        200
    );

    for id in [red, gold] {
        let done = daemon.wait_state(id, &["done", "failed"], Duration::from_secs(180));
        assert_eq!(done["state"], "done", "{done}");
    }
    every_frame_shows(&daemon, red, "red", &dir);
    every_frame_shows(&daemon, gold, "gold", &dir);
    drop(daemon);
    std::fs::remove_dir_all(dir).ok();
}

#[test]
fn each_sample_change_homes_once_and_turns_the_carousel_once() {
    let dir = temp_dir("carousel-traversals");
    let daemon = Daemon::start(&dir, &carousel_config(&dir, 0.01, 0.01));
    let created = daemon.post(
        "/api/sweeps",
        &json!({"samples": ["red", "gold"], "theta_l_sets": [[-20, -30]],
                "bracket": {"shutter_s": [0.125, 0.01]}}),
    );
    assert_eq!(created.status, 201, "{:?}", created.json);
    let ids = sweep_scans(&created.json);
    for (id, sample) in [(ids[0], "red"), (ids[1], "gold")] {
        let done = daemon.wait_state(id, &["done", "failed"], Duration::from_secs(180));
        assert_eq!(done["state"], "done", "{done}");
        assert_eq!(logged(&daemon, Some(id), "home").len(), 1, "scan {id}");
        let turns = logged(&daemon, Some(id), "carousel");
        assert_eq!(turns.len(), 1, "scan {id}: {turns:?}");
        every_frame_shows(&daemon, id, sample, &dir);
    }
    drop(daemon);
    std::fs::remove_dir_all(dir).ok();
}

/// `gonio serve` with `config` exits at once with an error naming `names`.
fn refused_at_start(dir: &Path, config: &str, names: &str) {
    std::fs::write(dir.join("scene.toml"), SMALL_GOLD_SCENE).unwrap();
    let path = dir.join("gonio.toml");
    std::fs::write(
        &path,
        config.replace("SCENE", &dir.join("scene.toml").display().to_string()),
    )
    .unwrap();
    let output = std::process::Command::new(gonio_bin())
        .args(["serve", "--config"])
        .arg(&path)
        .arg("--data")
        .arg(dir.join("data"))
        .args(["--bind", "127.0.0.1:0"])
        .env("GONIO_TOKEN", gonio_tests::TOKEN)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success(), "the daemon started: {stderr}");
    assert!(stderr.contains(names), "{stderr}");
}

#[test]
fn slots_beyond_the_travel_or_not_sample_names_are_refused_at_start() {
    let dir = temp_dir("carousel-slots");
    let base = with_small_red_sample(&emulator_config_scaled(0.01, 0.01), &dir);
    // The emulated board's Y axis travels 200 (stock $131).
    refused_at_start(
        &dir,
        &format!("{base}\n[carousel]\naxis = \"Y\"\nslots = {{ gold = -10.0, red = -250.0 }}\n"),
        "carousel.slots.red",
    );
    for bad in ["../red", "red one"] {
        refused_at_start(
            &dir,
            &format!("{base}\n[carousel]\naxis = \"Y\"\nslots = {{ \"{bad}\" = -10.0 }}\n"),
            bad,
        );
    }
    std::fs::remove_dir_all(dir).ok();
}
