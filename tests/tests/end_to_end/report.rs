//! A scan's report: the daemon serves it for a finished scan and `gonio report` writes
//! it from the scan directory; one self-contained HTML file that a headless Chromium
//! opens with no network request and no error, that fits a 390 px screen (tables scroll
//! in their boxes, plots scale) and holds the budget in the GUM's layout, whole on a
//! printed A4 page.

use std::time::Duration;

use gonio_tests::browser::Browser;
use gonio_tests::{emulator_config, gonio, temp_dir, Daemon};
use serde_json::json;

/// What a report shows, read in the browser.
const REPORT_FACTS: &str = r#"(() => ({
    title: document.title,
    sections: [...document.querySelectorAll('h2')].map((h) => h.textContent),
    plots: document.querySelectorAll('svg').length,
    budgetRows: document.querySelectorAll('table.budget tbody tr').length,
    budgetHeader: [...document.querySelectorAll('table.budget th')].map((t) => t.textContent),
    budgetLabels: [...document.querySelectorAll('table.budget tbody tr')].map((r) => r.cells[0].textContent),
    colourRows: [...document.querySelectorAll('table.colour tbody tr')].map((r) =>
        [...r.cells].map((c) => c.textContent)),
    swatches: [...document.querySelectorAll('table.colour .swatch')].map((s) =>
        getComputedStyle(s).backgroundColor),
    pageWidth: document.documentElement.scrollWidth,
    resources: performance.getEntriesByType('resource').map((r) => r.name),
}))()"#;

#[test]
fn a_finished_scans_report_is_whole_self_contained_and_opens_in_a_browser() {
    let dir = temp_dir("report");
    let daemon = Daemon::start(&dir, &emulator_config(0.01));
    let id = daemon.post_gold_scan(&[-20.0, -30.0, -40.0], &[0.1, 0.01]);
    daemon.wait_state(id, &["done"], Duration::from_secs(300));

    let answer = daemon.get(&format!("/api/scans/{id}/report"));
    assert_eq!(answer.status, 200);
    assert!(
        answer.content_type.starts_with("text/html"),
        "{}",
        answer.content_type
    );
    let html = String::from_utf8(answer.bytes).unwrap();
    assert!(html.contains("BRDF measurement report: gold"));
    assert!(
        html.contains(&format!("<td>scan</td><td>{id}</td>")),
        "scan id shown"
    );
    // The exposures each θL took and the camera, as the sidecars say.
    assert!(
        html.contains("<li>θL -20°: 1/10 s, 1/100 s</li>"),
        "exposures shown"
    );
    assert!(html.contains("<td>camera</td>"), "camera shown");
    // Nothing is loaded from elsewhere: no link, script or image source, no CSS url().
    for needle in ["src=", "href=", "url(", "<script", "<link"] {
        assert!(!html.contains(needle), "the report refers out: {needle}");
    }
    assert_eq!(daemon.get("/api/scans/999/report").status, 404);

    // The same report from the scan directory, offline.
    let scan_dir = daemon.data.join(format!("scans/{id}"));
    let file = dir.join("report.html");
    let out = gonio(&[
        "report",
        scan_dir.to_str().unwrap(),
        "--sample",
        "gold",
        "--notes",
        "batch 7 <ACME>",
        "--out",
        file.to_str().unwrap(),
    ]);
    assert!(out.contains("report of"), "{out}");
    let offline = std::fs::read_to_string(&file).unwrap();
    assert!(
        offline.contains("batch 7 &lt;ACME&gt;"),
        "notes shown, escaped"
    );

    // Opened in a real browser at a phone's width.
    let browser = Browser::launch(&dir.join("profile"));
    let mut page = browser.page();
    page.call(
        "Emulation.setDeviceMetricsOverride",
        json!({"width": 390, "height": 800, "deviceScaleFactor": 1, "mobile": true}),
    );
    page.call(
        "Page.navigate",
        json!({"url": format!("file://{}", file.display())}),
    );
    page.wait_for(
        "the report",
        "document.readyState === 'complete' && document.querySelectorAll('svg').length",
        Duration::from_secs(30),
    );
    let facts = page.eval(REPORT_FACTS);
    assert_eq!(facts["title"], "gonio report: gold", "{facts}");
    let sections: Vec<&str> = facts["sections"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(|s| s.as_str())
        .collect();
    for wanted in [
        "Scan",
        "Plan and captures",
        "Setup",
        "Model",
        "Uncertainty budget",
        "Measured and fitted",
        "Held-out errors of the candidates",
        "Multi-angle colour",
    ] {
        assert!(sections.contains(&wanted), "no {wanted} in {sections:?}");
    }
    assert_eq!(facts["plots"], 2, "{facts}");
    // CIELAB at the six ASTM E2539 angles, each with its uncertainty and a painted swatch.
    let rows = facts["colourRows"].as_array().unwrap();
    let aspecular: Vec<&str> = rows.iter().filter_map(|r| r[0].as_str()).collect();
    assert_eq!(aspecular, ["-15", "15", "25", "45", "75", "110"], "{facts}");
    for row in rows {
        assert!(
            row[2].as_str().unwrap().contains(" ± "),
            "L* without U: {row}"
        );
    }
    let swatches = facts["swatches"].as_array().unwrap();
    assert_eq!(swatches.len(), 6, "{facts}");
    for colour in swatches {
        let colour = colour.as_str().unwrap();
        assert!(
            colour.starts_with("rgb("),
            "a swatch is not painted: {colour}"
        );
    }
    // Gold is yellow: at 15° (near the highlight) b* is clearly positive, and its
    // swatch has more red and green than blue.
    let b_15: f64 = rows[1][4]
        .as_str()
        .unwrap()
        .split(' ')
        .next()
        .unwrap()
        .parse()
        .unwrap();
    assert!(b_15 > 10.0, "gold's b* at 15°: {b_15}");
    // Kd, Ks per channel and m: seven quantities at least, a column each; a row per
    // source, then u_c, U and the interval.
    let header = facts["budgetHeader"].to_string();
    for column in ["Kd R", "Ks G", "m"] {
        assert!(header.contains(column), "{column} missing from {header}");
    }
    assert!(
        facts["budgetHeader"].as_array().unwrap().len() >= 8,
        "{facts}"
    );
    let labels = facts["budgetLabels"].to_string();
    for row in [
        "value",
        "u(noise)",
        "u(camera offset)",
        "U (k = 2",
        "interval",
    ] {
        assert!(labels.contains(row), "{row} missing from {labels}");
    }
    assert!(
        facts["pageWidth"].as_u64().unwrap() <= 390,
        "the report is wider than a 390 px screen: {facts}"
    );
    assert_eq!(facts["resources"], json!([]), "the report loaded resources");
    // Printed on A4 (the page's 210 mm less 2 × 15 mm margins: 680 px at 96 dpi), the
    // budget is whole on the page.
    page.call("Emulation.setEmulatedMedia", json!({"media": "print"}));
    page.call(
        "Emulation.setDeviceMetricsOverride",
        json!({"width": 680, "height": 960, "deviceScaleFactor": 1, "mobile": false}),
    );
    let printed = page.eval(
        "(() => { const t = document.querySelector('table.budget'); \
         return { table: t.getBoundingClientRect().width, page: document.documentElement.clientWidth }; })()",
    );
    assert!(
        printed["table"].as_f64().unwrap() <= printed["page"].as_f64().unwrap(),
        "the printed budget is wider than the page: {printed}"
    );
    assert_eq!(page.errors(), Vec::<String>::new());
    std::fs::remove_dir_all(dir).ok();
}
