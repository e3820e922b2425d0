//! A scan's multi-angle colour on the operator's page and through the API: the table of
//! CIELAB at ASTM E2539's six aspecular angles with a swatch each, and a second scan
//! judged against it as its standard, in headless Chromium at 1280 and 390 px.

use std::time::Duration;

use gonio_tests::browser::Browser;
use gonio_tests::page::{fits_the_screen, open_page, select_and_wait};
use gonio_tests::{emulator_config, temp_dir, Daemon};
use serde_json::{json, Value};

/// What the colour box shows: the rows of its two tables and the verdict.
const COLOUR: &str = r#"(() => {
    const rows = (id) => [...document.querySelectorAll(`#${id} tbody tr`)]
        .map((tr) => [...tr.children].map((td) => td.textContent));
    const swatches = [...document.querySelectorAll('#colourtable .swatch')]
        .map((s) => getComputedStyle(s).backgroundColor);
    const overall = document.getElementById('overall');
    return { colour: rows('colourtable'), swatches, compare: rows('comparetable'),
             overall: overall ? overall.textContent : null };
})()"#;

fn finite(v: &Value) -> bool {
    v.as_f64().is_some_and(f64::is_finite)
}

#[test]
fn a_scans_colour_and_a_batch_judged_against_it_on_the_page_and_through_the_api() {
    let dir = temp_dir("page-colour");
    let daemon = Daemon::start(&dir, &emulator_config(0.01));
    let theta_l = [-20.0, -30.0, -45.0];
    let standard = daemon.post_gold_scan(&theta_l, &[0.5, 1.0 / 30.0]);
    let batch = daemon.post_gold_scan(&theta_l, &[0.5, 1.0 / 30.0]);
    // A third, paused while it waits behind them: it has no fit.
    let unfitted = daemon.post_gold_scan(&[-20.0], &[0.5]);
    let paused = daemon.post(&format!("/api/scans/{unfitted}/pause"), &json!({}));
    assert_eq!(paused.json["state"], "paused", "{:?}", paused.json);
    for id in [standard, batch] {
        daemon.wait_state(id, &["done"], Duration::from_secs(240));
    }

    // The API: six angles, each value with its expanded uncertainty and a swatch.
    let colour = daemon.get(&format!("/api/scans/{standard}/colour"));
    assert_eq!(colour.status, 200, "{:?}", colour.json);
    let angles = colour.json["angles"].as_array().unwrap();
    let aspecular: Vec<f64> = angles
        .iter()
        .map(|a| a["aspecular"].as_f64().unwrap())
        .collect();
    assert_eq!(aspecular, [-15.0, 15.0, 25.0, 45.0, 75.0, 110.0]);
    for a in angles {
        for k in ["L", "a", "b", "C", "h"] {
            assert!(finite(&a[k]["value"]) && finite(&a[k]["expanded"]), "{a}");
        }
        let hex = a["swatch"]["hex"].as_str().unwrap();
        assert!(hex.len() == 7 && hex.starts_with('#'), "{a}");
        assert!(
            a["swatch"]["in_gamut"].is_boolean() && a.get("lines").is_none(),
            "{a}"
        );
    }
    let comparison = daemon.get(&format!("/api/scans/{standard}/compare/{batch}"));
    assert_eq!(comparison.status, 200, "{:?}", comparison.json);
    let k = &comparison.json;
    assert_eq!(
        (k["standard"].as_i64(), k["batch"].as_i64()),
        (Some(standard), Some(batch))
    );
    assert_eq!(k["angles"].as_array().unwrap().len(), 6, "{k}");
    let verdicts = ["pass", "fail", "undecided"];
    assert!(verdicts.contains(&k["overall"].as_str().unwrap()), "{k}");
    for a in k["angles"].as_array().unwrap() {
        assert!(
            finite(&a["delta_e00"]["value"]) && finite(&a["delta_e00"]["expanded"]),
            "{a}"
        );
        assert!(verdicts.contains(&a["verdict"].as_str().unwrap()), "{a}");
    }
    // No such scan; a scan with no fit yet.
    assert_eq!(daemon.get("/api/scans/999/colour").status, 404);
    assert_eq!(
        daemon
            .get(&format!("/api/scans/{standard}/compare/999"))
            .status,
        404
    );
    let answer = daemon.get(&format!("/api/scans/{unfitted}/colour"));
    assert_eq!(answer.status, 409, "{:?}", answer.json);
    assert!(
        answer.json["error"].as_str().unwrap().contains("no fit"),
        "{:?}",
        answer.json
    );
    let answer = daemon.get(&format!("/api/scans/{standard}/compare/{unfitted}"));
    assert_eq!(answer.status, 409, "{:?}", answer.json);

    // The page: the table and its swatches, then the batch judged.
    let browser = Browser::launch(&dir.join("profile"));
    let mut page = browser.page();
    open_page(&mut page, &daemon.url);
    select_and_wait(
        &mut page,
        standard,
        "done",
        |_| true,
        Duration::from_secs(30),
    );
    page.wait_for(
        "the colour table",
        "document.querySelectorAll('#colourtable tbody tr').length === 6",
        Duration::from_secs(60),
    );
    page.wait_for(
        "the batch in the list",
        &format!(
            "[...document.getElementById('batch').options].some((o) => o.value === '{batch}')"
        ),
        Duration::from_secs(30),
    );
    page.eval(&format!(
        "(() => {{ const s = document.getElementById('batch'); s.value = '{batch}'; \
         s.dispatchEvent(new Event('change')); }})()"
    ));
    page.wait_for(
        "the comparison",
        "document.querySelectorAll('#comparetable tbody tr').length === 6",
        Duration::from_secs(60),
    );
    let shown = page.eval(COLOUR);
    let rows = shown["colour"].as_array().unwrap();
    for (row, a) in rows.iter().zip(angles) {
        let cells: Vec<&str> = row
            .as_array()
            .unwrap()
            .iter()
            .map(|c| c.as_str().unwrap())
            .collect();
        assert_eq!(
            cells[0],
            format!("{}°", a["aspecular"].as_f64().unwrap()),
            "{row}"
        );
        let l = &a["L"];
        let text = format!(
            "{:.1} ± {:.1}",
            l["value"].as_f64().unwrap(),
            l["expanded"].as_f64().unwrap()
        );
        assert_eq!(cells[2], text, "{row}");
    }
    // Every swatch painted (a colour, not the transparent default).
    let swatches = shown["swatches"].as_array().unwrap();
    assert_eq!(swatches.len(), 6, "{shown}");
    assert!(
        swatches
            .iter()
            .all(|s| s.as_str().unwrap().starts_with("rgb(")),
        "{shown}"
    );
    let overall = shown["overall"].as_str().unwrap();
    assert!(overall.contains(k["overall"].as_str().unwrap()), "{shown}");
    fits_the_screen(&mut page, "multi-angle colour and comparison");
    assert_eq!(page.errors(), Vec::<String>::new(), "console errors");
}
