//! A whole 6-θL scan over HTTP on the emulators: captures, HDR maps, samples and both
//! fits land under the scan's files, progress streams as server-sent events, and the
//! Cook–Torrance fit recovers the scene's true parameters.

use std::io::{BufRead, BufReader};
use std::time::Duration;

use gonio_mock_hw::scene::Scene;
use gonio_tests::{emulator_config, files_under, temp_dir, Daemon, SMALL_GOLD_SCENE};
use serde_json::{json, Value};

/// Reads the server-sent events of a scan until the stream ends; returns the JSON of
/// every `progress` event.
fn read_events(url: &str) -> Vec<Value> {
    let response = ureq::get(url)
        .timeout(Duration::from_secs(120))
        .call()
        .expect("events stream");
    assert_eq!(response.content_type(), "text/event-stream");
    BufReader::new(response.into_reader())
        .lines()
        .map_while(Result::ok)
        .filter_map(|line| {
            line.strip_prefix("data:")
                .map(|d| serde_json::from_str(d.trim()).expect("event JSON"))
        })
        .collect()
}

fn assert_close(what: &str, got: f64, want: f64, rel: f64, abs: f64) {
    assert!(
        (got - want).abs() <= rel * want.abs() + abs,
        "{what}: fitted {got}, true {want} (tolerance {rel}·|true| + {abs})"
    );
}

#[test]
fn six_angle_scan_completes_and_its_fit_recovers_the_scene() {
    let dir = temp_dir("scan-fit");
    let daemon = Daemon::start(&dir, &emulator_config(0.01));
    let theta_l = [-20.0, -25.0, -30.0, -35.0, -40.0, -45.0];
    let created = daemon.post(
        "/api/scans",
        &json!({"sample": "gold", "theta_l": theta_l, "bracket": "auto"}),
    );
    assert_eq!(created.status, 201, "{:?}", created.json);
    let id = created.json["id"].as_i64().unwrap();
    let events_url = format!("{}/api/scans/{id}/events", daemon.url);
    let events = std::thread::spawn(move || read_events(&events_url));

    let scan = daemon.wait_state(id, &["done", "failed"], Duration::from_secs(120));
    assert_eq!(scan["state"], "done", "{scan}");
    // A finished scan can no longer be paused, resumed or cancelled.
    assert_eq!(scan["actions"], json!([]), "{scan}");

    // Progress events: monotonic, ending with the done scan.
    let events = events.join().unwrap();
    assert!(events.len() >= 3, "{} events", events.len());
    let done: Vec<u64> = events
        .iter()
        .map(|e| e["progress"]["done"].as_u64().unwrap())
        .collect();
    assert!(done.windows(2).all(|w| w[0] <= w[1]), "{done:?}");
    let last = events.last().unwrap();
    assert_eq!(last["state"], "done");
    assert_eq!(last["progress"]["done"], last["progress"]["total"]);
    // The total stays what was planned while metering adds capture steps; the time
    // left is estimated while the scan runs.
    let first = &events[0];
    assert!(events
        .iter()
        .all(|e| e["progress"]["total"] == first["progress"]["total"]));
    assert!(
        last["progress"]["steps"]["total"].as_u64() > first["progress"]["steps"]["total"].as_u64()
    );
    let running: Vec<&Value> = events.iter().filter(|e| e["state"] == "running").collect();
    assert!(running
        .iter()
        .all(|e| e["progress"]["eta_s"].as_f64().is_some_and(|t| t >= 0.0)));
    assert!(running
        .iter()
        .any(|e| e["progress"]["eta_s"].as_f64() > Some(0.0)));
    assert_eq!(last["progress"]["eta_s"], Value::Null);
    assert_eq!(
        last["progress"]["theta_l"],
        json!({"captured": 6, "processed": 6, "total": 6})
    );
    // Live fits arrive while the scan runs, one per θL, each on every θL so far.
    assert!(running
        .iter()
        .any(|e| e["live"].as_array().is_some_and(|l| !l.is_empty())));
    let live = last["live"].as_array().unwrap();
    assert_eq!(live.len(), 6, "{live:?}");
    for (k, entry) in live.iter().enumerate() {
        assert_eq!(entry["theta_l"].as_array().unwrap().len(), k + 1);
        let ct = &entry["fits"]["cook-torrance"];
        assert!(ct["ks"][1].as_f64().is_some(), "{entry}");
        assert_eq!(ct["held_out_err_p"].is_null(), k == 0, "{entry}");
        assert_eq!(ct["change_p"].is_null(), k == 0, "{entry}");
    }

    // The automatic bracket metered every θL and planned its captures; every frame
    // exists with its sidecar.
    assert_eq!(scan["bracket"]["auto"], json!(true));
    let steps = daemon.get(&format!("/api/scans/{id}/steps")).json;
    let steps = steps.as_array().unwrap();
    let scan_dir = daemon.data.join(format!("scans/{id}"));
    let files = files_under(&scan_dir);
    for theta in theta_l {
        let metered = steps
            .iter()
            .find(|s| s["step"]["kind"] == "meter" && s["step"]["theta_l"] == json!(theta))
            .unwrap_or_else(|| panic!("no metering at {theta}"));
        let bracket = metered["result"]["shutter_s"].as_array().unwrap();
        assert!(!bracket.is_empty() && bracket.len() <= 8, "{bracket:?}");
        let captures: Vec<&Value> = steps
            .iter()
            .filter(|s| s["step"]["kind"] == "capture" && s["step"]["theta_l"] == json!(theta))
            .collect();
        assert_eq!(captures.len(), bracket.len());
        for capture in captures {
            let index = capture["step"]["index"].as_u64().unwrap();
            let stem = format!("theta_l_{theta:.1}/exp_{index:02}");
            assert!(files.contains(&format!("{stem}.tiff")), "{stem}.tiff");
            let sidecar: Value = serde_json::from_slice(
                &std::fs::read(scan_dir.join(format!("{stem}.json"))).unwrap(),
            )
            .unwrap();
            assert_eq!(sidecar["theta_l"], json!(theta));
            let planned = capture["step"]["shutter_s"].as_f64().unwrap();
            assert!((sidecar["shutter_s"].as_f64().unwrap() - planned).abs() < 1e-9);
            assert!(sidecar["time"].as_str().is_some());
            // The small scene's 12-bit counts sit in the top bits of the 16-bit TIFF.
            assert_eq!(sidecar["significant_bits"], 12);
            assert_eq!(sidecar["white_level"].as_f64(), Some(4095.0 * 16.0));
        }
        assert!(
            files.contains(&format!("hdr/theta_l_{theta:.1}.exr")),
            "{files:?}"
        );
    }
    assert!(files.iter().all(|f| !f.contains(".partial")), "{files:?}");

    // Results are served, and the fit recovers the truth.
    let samples = daemon.get(&format!("/api/scans/{id}/files/samples.csv"));
    assert_eq!(samples.status, 200);
    assert!(String::from_utf8_lossy(&samples.bytes).starts_with("theta_l,theta_i,theta_r,r,g,b"));
    let fit = daemon.get(scan["results"]["fits"]["cook-torrance"].as_str().unwrap());
    assert_eq!(fit.status, 200);
    let fit = fit.json;
    assert!(scan["results"]["fits"]["ward"].is_string());
    // Every fit carries its parameters' 95 % intervals; the goniochromatic model is fitted
    // too (on this Cook–Torrance scene without a significant colour shift).
    for c in 0..3 {
        let [lo, hi] = [0, 1].map(|k| fit["ci95"]["ks"][c][k].as_f64().unwrap());
        assert!(lo <= fit["ks"][c].as_f64().unwrap() && fit["ks"][c].as_f64().unwrap() <= hi);
    }
    let fresnel = daemon.get(
        scan["results"]["fits"]["cook-torrance-fresnel"]
            .as_str()
            .unwrap(),
    );
    assert_eq!(fresnel.json["model"], "cook-torrance-fresnel");
    let truth = Scene::from_toml_str(SMALL_GOLD_SCENE).unwrap().truth_json();
    // Tolerances: the strips are noise-free here; what remains is HDR quantisation and
    // the finite-distance geometry, a few percent at most.
    for c in 0..3 {
        let ks = truth["ks"][c].as_f64().unwrap();
        assert_close(
            &format!("ks[{c}]"),
            fit["ks"][c].as_f64().unwrap(),
            ks,
            0.08,
            0.2,
        );
        let kd = truth["kd"][c].as_f64().unwrap();
        assert_close(
            &format!("kd[{c}]"),
            fit["kd"][c].as_f64().unwrap(),
            kd,
            0.08,
            0.3,
        );
    }
    let m = truth["m"][0].as_f64().unwrap();
    assert_close("m", fit["m"][0].as_f64().unwrap(), m, 0.05, 0.0);
    // The live fit on all six θL is the final fit (same samples, another order).
    let live_ct = &live[5]["fits"]["cook-torrance"];
    for c in 0..3 {
        let final_ks = fit["ks"][c].as_f64().unwrap();
        assert_close(
            "live ks",
            live_ct["ks"][c].as_f64().unwrap(),
            final_ks,
            1e-6,
            0.0,
        );
    }

    // The fit that chooses the model runs beside the per-model fits: it starts once
    // samples.csv is gathered, before the first of them.
    let step = |kind: &str, model: Option<&str>| {
        steps
            .iter()
            .find(|s| s["step"]["kind"] == kind && model.is_none_or(|m| s["step"]["model"] == m))
            .unwrap_or_else(|| panic!("no {kind} step {model:?}"))
    };
    let at = |s: &Value, field: &str| {
        let text = s[field]
            .as_str()
            .unwrap_or_else(|| panic!("{field} of {s}"));
        time::OffsetDateTime::parse(text, &time::format_description::well_known::Rfc3339).unwrap()
    };
    let auto = step("fit", Some("auto"));
    assert!(at(auto, "started") >= at(step("extract", None), "finished"));
    for model in ["cook-torrance", "ward", "cook-torrance-fresnel"] {
        let fit = step("fit", Some(model));
        assert!(at(auto, "started") <= at(fit, "started"), "{auto} {fit}");
    }
    // It chooses shared-roughness Cook–Torrance on this scene, the same fit as
    // fit-cook-torrance.json, and carries the same budget.
    let chosen = daemon
        .get(&format!("/api/scans/{id}/files/fit-auto.json"))
        .json;
    let same = daemon.get(&format!("/api/scans/{id}/files/fit-cook-torrance.json"));
    for field in ["model", "roughness", "kd", "ks", "m", "stderr"] {
        assert_eq!(chosen[field], same.json[field], "{field}");
    }
    assert!(chosen["budget"].is_object(), "{}", chosen["budget"]);
    assert_eq!(chosen["budget"], same.json["budget"]);

    // The page's views of the scan.
    let thumbnail = daemon.get(&format!("/api/scans/{id}/thumbnail.png"));
    assert_eq!(thumbnail.status, 200);
    assert_eq!(&thumbnail.bytes[1..4], b"PNG");
    let plot = daemon.get(&format!("/api/scans/{id}/plot")).json;
    let points = plot["samples"].as_array().unwrap().len();
    assert!(points > 100, "{points} samples");
    assert_eq!(
        plot["fits"]["cook-torrance"]["predicted"]
            .as_array()
            .unwrap()
            .len(),
        points
    );
    // No escaping the scan directory through the files route.
    assert_eq!(
        daemon
            .get(&format!("/api/scans/{id}/files/..%2F..%2Fgonio.sqlite"))
            .status,
        404
    );
    std::fs::remove_dir_all(dir).ok();
}
