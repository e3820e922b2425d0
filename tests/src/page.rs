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
