//! The daemon calibrates its setup from an ended scan and writes it as the setup of
//! later scans, whose fits then recover the scene; `DELETE /api/setup` forgets it.

use std::time::Duration;

use gonio_tests::{emulator_config, temp_dir, Daemon, SMALL_GOLD_SCENE};
use serde_json::{json, Value};

fn scan(daemon: &Daemon) -> (i64, Value) {
    let created = daemon.post(
        "/api/scans",
        &json!({"sample": "gold", "theta_l": [-20, -30, -45],
                "bracket": {"shutter_s": [0.5, 0.125, 1.0 / 30.0, 0.01]}}),
    );
    assert_eq!(created.status, 201, "{:?}", created.json);
    let id = created.json["id"].as_i64().unwrap();
    let state = daemon.wait_state(id, &["done", "failed"], Duration::from_secs(120));
    assert_eq!(state["state"], "done", "{state}");
    (id, state)
}

/// The largest relative error of the scan's Cook–Torrance Ks against the scene's.
fn ks_error(daemon: &Daemon, scan: &Value) -> f64 {
    let fit = daemon
        .get(scan["results"]["fits"]["cook-torrance"].as_str().unwrap())
        .json;
    [25.0, 20.0, 7.0]
        .iter()
        .enumerate()
        .map(|(c, truth)| (fit["ks"][c].as_f64().unwrap() / truth - 1.0).abs())
        .fold(0.0, f64::max)
}

#[test]
fn a_calibration_becomes_the_setup_of_later_scans() {
    let dir = temp_dir("daemon-calibrate");
    let scene = dir.join("misaligned.toml");
    std::fs::write(
        &scene,
        format!(
            "{SMALL_GOLD_SCENE}\n[effects.misalignment]\ncamera_offset_mm = 3.0\narm_zero_offset_deg = 0.3\n\
             [setup.uncertainty]\nwhite_reflectance = 0.004\ncamera_offset_mm = 0.7\n"
        ),
    )
    .unwrap();
    let config = emulator_config(0.01).replace("SCENE", scene.to_str().unwrap());
    let daemon = Daemon::start(&dir, &config);

    let (first, first_scan) = scan(&daemon);
    // Before any calibration, every field of a scan's setup comes from the scene.
    let setup_of = |id: i64| -> Value {
        serde_json::from_slice(
            &daemon
                .get(&format!("/api/scans/{id}/files/setup.json"))
                .bytes,
        )
        .unwrap()
    };
    let first_setup = setup_of(first);
    let provenance = first_setup["provenance"].as_object().unwrap();
    assert!(provenance.contains_key("camera_offset_mm"), "{first_setup}");
    // The scene's [setup.uncertainty] too, key by key.
    assert_eq!(
        first_setup["uncertainty"],
        json!({ "white_reflectance": 0.004, "camera_offset_mm": 0.7 })
    );
    assert_eq!(
        provenance["uncertainty"],
        json!({ "white_reflectance": "emulated scene", "camera_offset_mm": "emulated scene" })
    );
    assert!(
        provenance
            .iter()
            .all(|(k, v)| v == "emulated scene" || k == "uncertainty"),
        "{first_setup}"
    );
    let missing = daemon.post("/api/scans/999/calibrate", &json!({}));
    assert_eq!(missing.status, 404, "{:?}", missing.json);
    let calibrated = daemon.post(&format!("/api/scans/{first}/calibrate"), &json!({}));
    assert_eq!(calibrated.status, 200, "{:?}", calibrated.json);
    let c = &calibrated.json["calibration"];
    assert_eq!(c["scan"], first);
    let offset = c["camera_offset_mm"]["value"].as_f64().unwrap();
    let arm = c["arm_zero_offset_deg"]["value"].as_f64().unwrap();
    assert!((offset - 3.0).abs() < 0.1, "{c}");
    assert!((arm - 0.3).abs() < 0.15, "{c}");
    // Where each value came from: the estimates from this calibration, the rest as the
    // calibrated scan's setup said.
    let from = &calibrated.json["provenance"];
    let by_calibration = format!("calibrated from scan {first}");
    for field in [
        "sample_row",
        "white_row",
        "camera_offset_mm",
        "arm_zero_offset_deg",
    ] {
        assert_eq!(from[field], by_calibration.as_str(), "{field}: {from}");
    }
    for field in ["focal_length_mm", "pixel_pitch_um", "cylinder_radius_mm"] {
        assert_eq!(from[field], "emulated scene", "{field}: {from}");
    }
    // The estimates' standard uncertainties from this calibration, the white's from the
    // scene.
    let u = &calibrated.json["uncertainty"];
    assert_eq!(
        u["camera_offset_mm"], c["camera_offset_mm"]["stderr"],
        "{u}"
    );
    assert_eq!(u["white_reflectance"], 0.004, "{u}");
    assert_eq!(
        from["uncertainty"]["camera_offset_mm"],
        by_calibration.as_str()
    );
    assert_eq!(from["uncertainty"]["white_reflectance"], "emulated scene");
    let stored = dir.join("data").join("setup.json");
    assert!(stored.is_file());
    // Twelve at once all succeed (they once shared a temporary name: "writing
    // DATA/setup.json: No such file or directory" in about a third).
    let path = format!("/api/scans/{first}/calibrate");
    std::thread::scope(|scope| {
        let calls: Vec<_> = (0..12)
            .map(|_| scope.spawn(|| daemon.post(&path, &json!({}))))
            .collect();
        for call in calls {
            let answer = call.join().unwrap();
            assert_eq!(answer.status, 200, "{:?}", answer.json);
        }
    });
    let whole: Value = serde_json::from_slice(&std::fs::read(&stored).unwrap()).unwrap();
    assert_eq!(whole["calibration"]["scan"], first);

    // The next scan is set up with the calibration, and its fit recovers the scene
    // where the first one's could not.
    let (second, second_scan) = scan(&daemon);
    let setup = setup_of(second);
    assert_eq!(setup["camera_offset_mm"].as_f64().unwrap(), offset);
    // It keeps where its values came from.
    assert_eq!(setup["provenance"], whole["provenance"], "{setup}");
    assert_eq!(setup["calibration"]["scan"], first);
    assert_eq!(setup["white_reflectance"], 0.99);
    let (before, after) = (
        ks_error(&daemon, &first_scan),
        ks_error(&daemon, &second_scan),
    );
    assert!(
        before > 0.1 && after < 0.01,
        "Ks off by {before} then {after}"
    );

    let forgotten = daemon.delete("/api/setup");
    assert_eq!(forgotten.json, json!({"removed": true}));
    assert!(!stored.exists());

    // A scan that cannot be calibrated: 422 naming the file relative to the scan, no
    // path of the server.
    let scan_dir = daemon.data.join(format!("scans/{first}"));
    std::fs::remove_file(scan_dir.join("setup.json")).unwrap();
    let refused = daemon.post(&format!("/api/scans/{first}/calibrate"), &json!({}));
    assert_eq!(refused.status, 422, "{:?}", refused.json);
    let message = refused.json["error"].as_str().unwrap();
    assert!(message.contains("setup.json"), "{message}");
    let data = daemon.data.display().to_string();
    assert!(
        !message.contains(&data) && !message.contains("/scans/"),
        "{message}"
    );
    std::fs::remove_dir_all(dir).ok();
}
