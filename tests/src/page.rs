//! The gonio web page as the browser tests drive it: loading it, and reading what its
//! detail panel and queue show of a scan, waiting until they show a given state.

use std::time::{Duration, Instant};

use serde_json::{json, Value};

use crate::browser::Cdp;

/// Opens the page the daemon at `url` serves and waits until it has loaded and its
/// first refresh (scans, sweeps, hardware) has come back.
pub fn open_page(page: &mut Cdp, url: &str) {
    page.call("Page.navigate", json!({"url": format!("{url}/")}));
    page.wait_for(
        "the page and its hardware line",
        "document.readyState === 'complete' && !document.getElementById('arm').textContent.includes('…')",
        Duration::from_secs(30),
    );
}

/// What the detail panel and the queue show of the selected scan `id`.
fn snapshot(page: &mut Cdp, id: i64) -> Value {
    page.eval(&format!(
        r#"(() => {{
            const id = {id};
            const text = (sel) => {{ const e = document.querySelector(sel); return e ? e.textContent : ""; }};
            const img = document.getElementById('thumb');
            const row = document.querySelector(`#scans tr[data-id="${{id}}"]`);
            return {{
                title: text('#dtitle'),
                state: text('#dstate span'),
                rowState: row ? row.children[2].textContent : null,
                rowNote: row ? row.children[4].textContent : null,
                lefts: [...document.querySelectorAll(`.left[data-id="${{id}}"]`)].map((e) => e.textContent),
                work: text('#dwork'),
                why: text('#dwhy'),
                bracket: text('#dbracket'),
                times: text('#dtimes'),
                frame: img.hidden ? null : Number(img.dataset.scan),
                noFrame: !document.getElementById('noframe').hidden,
                enabled: [...document.querySelectorAll('#detail button[data-act]')].filter((b) => !b.disabled).map((b) => b.dataset.act),
                confirmHidden: document.querySelector('#detail button[data-act=confirm]').hidden,
            }};
        }})()"#
    ))
}

/// Selects scan `id` in the queue and waits until the detail shows it in `state` (as
/// the page labels it) and `ready` holds of its snapshot; returns that snapshot.
pub fn select_and_wait(
    page: &mut Cdp,
    id: i64,
    state: &str,
    ready: impl Fn(&Value) -> bool,
    timeout: Duration,
) -> Value {
    page.wait_for(
        &format!("scan {id} in the queue"),
        &format!("document.querySelector('#scans tr[data-id=\"{id}\"]') !== null"),
        Duration::from_secs(30),
    );
    page.eval(&format!(
        "document.querySelector('#scans tr[data-id=\"{id}\"]').click()"
    ));
    wait_shown(page, id, state, ready, timeout)
}

/// Waits until the detail shows scan `id` in `state` with `ready` holding.
pub fn wait_shown(
    page: &mut Cdp,
    id: i64,
    state: &str,
    ready: impl Fn(&Value) -> bool,
    timeout: Duration,
) -> Value {
    let start = Instant::now();
    loop {
        let shown = snapshot(page, id);
        // One poll draws the queue and the detail: they never disagree on the state.
        if shown["title"]
            .as_str()
            .is_some_and(|t| t.starts_with(&format!("Scan {id}:")))
            && shown["state"] != ""
            && shown["rowState"].as_str().is_some_and(|r| !r.is_empty())
        {
            assert_eq!(
                shown["state"], shown["rowState"],
                "the queue row and the detail disagree: {shown}"
            );
        }
        if shown["title"]
            .as_str()
            .is_some_and(|t| t.starts_with(&format!("Scan {id}:")))
            && shown["state"] == state
            && shown["rowState"] == state
            && ready(&shown)
        {
            eprintln!(
                "scan {id} shown {state}: after {:.1} s",
                start.elapsed().as_secs_f64()
            );
            return shown;
        }
        assert!(
            start.elapsed() < timeout,
            "timed out waiting for scan {id} shown {state}: {shown}"
        );
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// Selects scan `id` and waits until the detail shows it waiting with a reason that
/// contains `why`: no time left, no frame, and Confirm only when `confirm`.
pub fn shown_waiting(page: &mut Cdp, id: i64, why: &str, confirm: bool) {
    let shown = select_and_wait(
        page,
        id,
        "waiting",
        |s| s["why"].as_str().unwrap().contains(why),
        Duration::from_secs(60),
    );
    assert!(no_time_left(&shown), "{shown}");
    assert_eq!(shown["confirmHidden"], json!(!confirm), "{shown}");
    assert_eq!(shown["frame"], Value::Null, "{shown}");
}

/// No time left anywhere for the scan: the queue row and the detail agree.
pub fn no_time_left(shown: &Value) -> bool {
    let lefts = shown["lefts"].as_array().unwrap();
    lefts.len() == 2 && lefts.iter().all(|l| l == "")
}

/// What the page measures of its own layout at the current width: the document's
/// width (also with every budget table opened), each budget table's right edge and
/// that of its box, the rendered size of every text of the plot (its computed font size
/// times the SVG's scale, px on screen) and the images shown that did not load.
const LAYOUT_FACTS: &str = r#"(() => {
    const shown = (e) => e.getClientRects().length > 0 && getComputedStyle(e).visibility !== 'hidden';
    const broken = [...document.images].filter((i) => shown(i) && !(i.complete && i.naturalWidth > 0))
        .map((i) => i.id || i.alt || 'img');
    const closedWidth = document.documentElement.scrollWidth;
    const closed = [...document.querySelectorAll('details')].filter((d) => !d.open);
    closed.forEach((d) => { d.open = true; });
    const openWidth = document.documentElement.scrollWidth;
    const budgets = [...document.querySelectorAll('.budget table')].map((t) => ({
        table: t.getBoundingClientRect().right, box: t.parentElement.getBoundingClientRect().right }));
    closed.forEach((d) => { d.open = false; });
    const fonts = [...document.querySelectorAll('#plot svg')].flatMap((svg) => {
        const scale = svg.getBoundingClientRect().width / svg.viewBox.baseVal.width;
        return [...svg.querySelectorAll('text')].map((t) => parseFloat(getComputedStyle(t).fontSize) * scale);
    });
    return { width: window.innerWidth, scrollWidth: Math.max(closedWidth, openWidth), budgets, broken,
        minFont: fonts.length ? Math.min(...fonts) : null, texts: fonts.length };
})()"#;

/// Checks that the page fits a 1280 px and a 390 px wide screen as it is now (`what`
/// names the state for the failure message): nothing wider than the screen (a table
/// scrolls inside its own box), every text of the plot at least 10 px on screen, at
/// 1280 px every budget table whole within its box and the screen, and no broken image. Leaves
/// the browser at its own window size; returns the facts measured at each width.
pub fn fits_the_screen(page: &mut Cdp, what: &str) -> Vec<Value> {
    let mut measured = Vec::new();
    for width in [1280u32, 390] {
        page.call(
            "Emulation.setDeviceMetricsOverride",
            json!({"width": width, "height": 844, "deviceScaleFactor": 1, "mobile": width < 800}),
        );
        page.wait_for(
            &format!("the layout at {width} px"),
            &format!("window.innerWidth === {width}"),
            Duration::from_secs(30),
        );
        // A frame or two for the plot to be drawn again at the new width.
        std::thread::sleep(Duration::from_millis(300));
        let facts = page.eval(LAYOUT_FACTS);
        let w = f64::from(width);
        assert!(
            facts["scrollWidth"].as_f64().unwrap() <= w,
            "{what}: page wider than {width} px: {facts}"
        );
        assert_eq!(facts["broken"], json!([]), "{what}: broken image: {facts}");
        if let Some(min) = facts["minFont"].as_f64() {
            assert!(
                min >= 10.0,
                "{what}: plot text below 10 px at {width} px: {facts}"
            );
        }
        for b in facts["budgets"].as_array().unwrap() {
            // At 1280 px the table is whole inside its box; narrower, its box scrolls.
            let (table, scroller) = (b["table"].as_f64().unwrap(), b["box"].as_f64().unwrap());
            let edge = if width >= 1280 {
                table.max(scroller)
            } else {
                scroller
            };
            assert!(
                edge <= w + 0.5 && (width < 1280 || table <= scroller + 0.5),
                "{what}: budget table beyond {width} px: {facts}"
            );
        }
        eprintln!("{what} at {width} px: {facts}");
        measured.push(facts);
    }
    page.call("Emulation.clearDeviceMetricsOverride", json!({}));
    page.wait_for(
        "the browser's own window size",
        "window.innerWidth !== 390",
        Duration::from_secs(30),
    );
    measured
}
