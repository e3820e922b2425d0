//! The web page's own files in a real browser (headless Chromium): the page loads its
//! stylesheet and ES modules from the daemon alone, each served with its content type,
//! and the fit plot gives the values of the point under the pointer.

use std::time::Duration;

use gonio_tests::browser::Browser;
use gonio_tests::{emulator_config, temp_dir, Daemon};
use serde_json::{json, Value};

/// Where the first measured marker of the plot that no other lies within 4 units of is
/// on screen (the pointer on it can mean only it; markers of neighbouring θr overlap),
/// the plot scrolled into view.
const LONE_MARKER: &str = r#"(() => {
    document.querySelector('#plot svg').scrollIntoView({ block: 'center' });
    const markers = [...document.querySelectorAll('#plot circle.marker')];
    const at = m => [parseFloat(m.getAttribute('cx')), parseFloat(m.getAttribute('cy'))];
    const m = markers.find(a => {
        const [x, y] = at(a);
        return markers.every(b => b === a || Math.hypot(at(b)[0] - x, at(b)[1] - y) > 4);
    });
    const r = m.getBoundingClientRect();
    return { x: r.left + r.width / 2, y: r.top + r.height / 2, cx: m.getAttribute('cx'), cy: m.getAttribute('cy') };
})()"#;

/// What the plot's hover shows: the ring and the readout below the figure.
const HOVER: &str = r#"(() => {
    const ring = document.querySelector('#plot svg circle.hover');
    return {
        visible: ring.getAttribute('visibility') === 'visible',
        cx: ring.getAttribute('cx'),
        cy: ring.getAttribute('cy'),
        text: document.getElementById('plotreadout').textContent,
    };
})()"#;

#[test]
fn page_loads_its_modules_from_the_daemon_and_the_plot_gives_values_under_the_pointer() {
    let dir = temp_dir("page-modules");
    let daemon = Daemon::start(&dir, &emulator_config(0.01));
    let id = daemon.post_gold_scan(&[-20.0, -35.0], &[0.5, 1.0 / 30.0]);
    daemon.wait_state(id, &["done"], Duration::from_secs(180));

    let browser = Browser::launch(&dir.join("profile"));
    let mut page = browser.page();
    page.call("Page.navigate", json!({"url": format!("{}/", daemon.url)}));
    page.wait_for(
        "the fit plot",
        "document.querySelector('#plot svg path') !== null",
        Duration::from_secs(60),
    );
    assert_eq!(page.errors(), Vec::<String>::new(), "console errors");

    // Everything the page loaded came from the daemon; its own files with their types.
    let resources = page.eval("performance.getEntriesByType('resource').map((r) => r.name)");
    let resources: Vec<String> = serde_json::from_value(resources).unwrap();
    let prefix = format!("{}/page/", daemon.url);
    let files: Vec<&str> = resources
        .iter()
        .filter_map(|r| r.strip_prefix(&prefix))
        .collect();
    assert!(
        resources.iter().all(|r| r.starts_with(&daemon.url)),
        "{resources:?}"
    );
    assert!(
        files.contains(&"page.css") && files.contains(&"main.js") && files.len() >= 4,
        "{resources:?}"
    );
    for file in &files {
        let answer = daemon.get(&format!("/page/{file}"));
        assert_eq!(answer.status, 200, "{file}");
        let wanted = if file.ends_with(".js") {
            "text/javascript"
        } else {
            "text/css"
        };
        assert!(
            answer.content_type.starts_with(wanted),
            "{file}: {}",
            answer.content_type
        );
    }
    let missing = daemon.get("/page/nothing.js");
    assert_eq!(missing.status, 404);
    assert!(
        missing.json["error"]
            .as_str()
            .unwrap()
            .contains("nothing.js"),
        "{:?}",
        missing.json
    );

    // The pointer on a marker: that point ringed, its values written below the plot.
    let hint = page.eval(HOVER)["text"].clone();
    let marker = page.eval(LONE_MARKER);
    page.call(
        "Input.dispatchMouseEvent",
        json!({"type": "mouseMoved", "x": marker["x"], "y": marker["y"]}),
    );
    let shown = page.wait_for(
        "the values under the pointer",
        &format!("(() => {{ const h = {HOVER}; return h.visible && h; }})()"),
        Duration::from_secs(10),
    );
    assert_eq!(
        (&shown["cx"], &shown["cy"]),
        (&marker["cx"], &marker["cy"]),
        "{shown} vs {marker}"
    );
    let text = shown["text"].as_str().unwrap();
    assert!(
        (text.starts_with("θL -20°") || text.starts_with("θL -35°"))
            && text.contains("β green measured")
            && ["Cook–Torrance", "Ward", "Cook–Torrance–Fresnel"]
                .iter()
                .all(|m| text.contains(m)),
        "{text}"
    );
    // Off the plot area (below the θr axis) the readout goes back to its hint.
    let below = page.eval(
        "(() => { const r = document.querySelector('#plot svg').getBoundingClientRect(); return { x: r.left + r.width / 2, y: r.bottom - 2 }; })()",
    );
    page.call(
        "Input.dispatchMouseEvent",
        json!({"type": "mouseMoved", "x": below["x"], "y": below["y"]}),
    );
    let cleared: Value = page.wait_for(
        "the hover cleared",
        &format!("(() => {{ const h = {HOVER}; return !h.visible && h; }})()"),
        Duration::from_secs(10),
    );
    assert_eq!(cleared["text"], hint, "{cleared}");
    assert_eq!(page.errors(), Vec::<String>::new(), "console errors");
    drop(browser);
    drop(daemon);
    let _ = std::fs::remove_dir_all(&dir);
}
