//! The web page in a real browser: Debian's headless Chromium driven over the Chrome
//! DevTools Protocol (a WebSocket, JSON commands). The page loads with no console
//! error, a wrong token shows the 401 message, a scan started from the form (its
//! bracket written as the page writes shutters, "1/30") shows its progress and ends
//! with the fit plot (ticks on round values, legend inside the figure, markers, both
//! scales), and a finished scan's controls are disabled. What the page shows of scans
//! in every state is `page_states.rs`.
//!
//! The browser is `gonio_tests::browser`'s headless Chromium.

use std::time::Duration;

use gonio_tests::browser::{Browser, Cdp};
use gonio_tests::page::{fits_the_screen, open_page};
use gonio_tests::{emulator_config, temp_dir, Daemon, TOKEN};
use serde_json::{json, Value};

/// What the page's plot shows: the θr tick values, where the legend sits, the
/// markers' and lines' colours and styles, the y ticks and label.
const PLOT_FACTS: &str = r#"(() => {
    const svg = document.querySelector('#plot svg');
    const box = svg.viewBox.baseVal;
    const axisY = Number(svg.querySelector('line').getAttribute('y1'));
    const axisX = Number(svg.querySelectorAll('line')[1].getAttribute('x1'));
    const degrees = [...svg.querySelectorAll('text')].map((t) => t.textContent)
        .filter((s) => /^-?\d+(\.\d+)?°$/.test(s)).map(parseFloat);
    const legend = svg.querySelector('.legend-box rect');
    const lr = legend.getBBox();
    const markers = [...svg.querySelectorAll('circle.marker')];
    const paths = [...svg.querySelectorAll('path.fit')];
    const firstCt = paths.findIndex((p) => p.classList.contains('fit-cook-torrance'));
    const lastCtf = paths.map((p) => p.classList.contains('fit-cook-torrance-fresnel')).lastIndexOf(true);
    const style = (m) => { const p = svg.querySelector('path.fit-' + m); return p && p.getAttribute('stroke-dasharray'); };
    return {
        degrees,
        legendInside: lr.x >= axisX && lr.x + lr.width <= box.width && lr.y >= 0 && lr.y + lr.height <= axisY,
        legend: [...svg.querySelectorAll('text.legend')].map((t) => t.textContent),
        params: [...document.querySelectorAll('#plot .fitparams')].map((p) => p.textContent).join(' | '),
        budgets: [...document.querySelectorAll('#plot details.budget')].map((d) => ({
            summary: d.querySelector('summary').textContent,
            rows: d.querySelectorAll('tr').length,
            columns: d.querySelector('tr').children.length,
        })),
        markers: markers.length,
        hollow: markers.every((m) => m.getAttribute('fill') === 'none'),
        colours: [...new Set(markers.map((m) => m.getAttribute('stroke')))].length,
        ctOverCtf: firstCt > lastCtf,
        dashes: [style('cook-torrance'), style('cook-torrance-fresnel'), style('ward')],
        yTicks: [...svg.querySelectorAll('text[text-anchor=end]')].map((t) => t.textContent),
        yLabel: (svg.querySelector('text.ylabel') || {}).textContent || '',
        buttonsDisabled: [...document.querySelectorAll('#detail button[data-act]')].map((b) => b.disabled),
        confirmHidden: document.querySelector('#detail button[data-act=confirm]').hidden,
        state: document.querySelector('#dstate span').textContent,
    };
})()"#;

/// Checks a plot of [`PLOT_FACTS`] with `colours` marker colours (θL or channels).
fn check_plot(plot: &Value, colours: u64) {
    let degrees: Vec<f64> = serde_json::from_value(plot["degrees"].clone()).unwrap();
    assert!(degrees.len() >= 3, "{plot}");
    assert!(
        degrees.iter().all(|d| d % 5.0 == 0.0),
        "ticks off round values: {degrees:?}"
    );
    assert_eq!(plot["legendInside"], json!(true), "{plot}");
    let legend = plot["legend"].to_string();
    assert!(
        ["Cook–Torrance", "Cook–Torrance–Fresnel", "Ward", "measured"]
            .iter()
            .all(|name| legend.contains(name)),
        "{legend}"
    );
    let params = plot["params"].as_str().unwrap();
    assert!(
        params.contains("cook-torrance") && params.contains("ward") && params.contains("ρd"),
        "{params}"
    );
    // Every fit shows its uncertainty budget: a header and one row per parameter (7 for
    // Cook–Torrance and Ward, 10 for Cook–Torrance–Fresnel), a column per source.
    let budgets = plot["budgets"].as_array().unwrap();
    assert_eq!(budgets.len(), 3, "{plot}");
    for budget in budgets {
        let summary = budget["summary"].as_str().unwrap();
        assert!(
            summary.contains("uncertainty budget") && summary.contains("k = 2"),
            "{summary}"
        );
        let rows = budget["rows"].as_u64().unwrap();
        assert!(rows == 8 || rows == 11, "{budget}");
        // label, value, noise, misfit, 10 sources, u_c, U, interval
        assert_eq!(budget["columns"], json!(17), "{budget}");
    }
    assert!(plot["markers"].as_u64().unwrap() > 20, "{plot}");
    assert_eq!(plot["hollow"], json!(true), "{plot}");
    assert_eq!(plot["colours"], json!(colours), "{plot}");
    // Cook–Torrance is drawn over the Fresnel variant, each in its own line style.
    assert_eq!(plot["ctOverCtf"], json!(true), "{plot}");
    let dashes: Vec<String> = serde_json::from_value(plot["dashes"].clone()).unwrap();
    assert!(
        dashes[0] != dashes[1] && dashes[1] != dashes[2] && dashes[0] != dashes[2],
        "{plot}"
    );
    let y_label = plot["yLabel"].as_str().unwrap();
    assert!(y_label.contains('β') && y_label.contains('%'), "{plot}");
}

/// Fills the scan form with `token` and submits it.
fn submit_scan(page: &mut Cdp, token: &str) {
    page.eval(&format!(
        r##"(() => {{
            const t = document.getElementById("token");
            t.value = {token};
            t.dispatchEvent(new Event("change"));
            document.getElementById("theta").value = "-20,-35";
            document.getElementById("bracket").value = "1/2, 1/30";
            document.getElementById("scanmsg").textContent = "";
            document.querySelector("#scanform button[type=submit]").click();
        }})()"##,
        token = json!(token)
    ));
}

#[test]
fn page_drives_a_scan_in_a_real_browser() {
    let dir = temp_dir("browser");
    let daemon = Daemon::start(&dir, &emulator_config(0.01));
    let browser = Browser::launch(&dir.join("profile"));
    let mut page = browser.page();

    open_page(&mut page, &daemon.url);
    assert_eq!(
        page.errors(),
        Vec::<String>::new(),
        "console errors on load"
    );

    // A wrong token: the form says 401 and nothing is queued.
    submit_scan(&mut page, "not-the-token");
    let message = page.wait_for(
        "the 401 message",
        "document.getElementById('scanmsg').textContent",
        Duration::from_secs(30),
    );
    assert!(message.as_str().unwrap().starts_with("401"), "{message}");
    assert_eq!(daemon.get("/api/scans").json, json!([]));
    let after_401 = page.errors();

    // The right token: the scan starts, shows progress, ends with the plot.
    submit_scan(&mut page, TOKEN);
    let queued = page.wait_for(
        "the scan to be queued",
        "document.getElementById('scanmsg').textContent.includes('queued') && document.getElementById('scanmsg').textContent",
        Duration::from_secs(30),
    );
    assert!(
        queued.as_str().unwrap().contains("scan 1 queued"),
        "{queued}"
    );
    let shutters = daemon.get("/api/scans/1").json["bracket"]["shutter_s"].clone();
    let shutters: Vec<f64> = serde_json::from_value(shutters).unwrap();
    assert_eq!(shutters.len(), 2);
    assert!((shutters[0] - 0.5).abs() < 1e-12 && (shutters[1] - 1.0 / 30.0).abs() < 1e-12);
    page.wait_for(
        "progress in the detail view",
        "(() => { const b = document.querySelector('#dstate .bar > div'); return b && parseFloat(b.style.width) > 0; })()",
        Duration::from_secs(60),
    );
    page.wait_for(
        "the fit plot",
        "document.querySelector('#plot svg path') !== null",
        Duration::from_secs(120),
    );
    let plot = page.eval(PLOT_FACTS);
    assert_eq!(plot["state"], "done", "{plot}");
    let degrees: Vec<f64> = serde_json::from_value(plot["degrees"].clone()).unwrap();
    assert!(degrees.len() >= 3, "{plot}");
    assert!(
        degrees.iter().all(|d| d % 5.0 == 0.0),
        "ticks off round values: {degrees:?}"
    );
    check_plot(&plot, 2);
    fits_the_screen(&mut page, "a done scan with its plot");
    // The latest frame's caption (its θL and exposure) and the model the scan's `auto`
    // fit chose, with its reason and colour-shift verdict, as the scan's view gives them.
    let view = daemon.get("/api/scans/1").json;
    let shown = page.eval(
        "({ caption: document.getElementById('framecap').hidden ? null : document.getElementById('framecap').textContent, \
            choice: document.getElementById('choice').textContent })",
    );
    let (theta, shutter) = (
        view["frame"]["theta_l"].as_f64().unwrap(),
        view["frame"]["shutter_s"].as_f64().unwrap(),
    );
    let exposure = if (shutter - 0.5).abs() < 1e-12 {
        "0.5 s"
    } else {
        "1/30 s"
    };
    assert_eq!(
        shown["caption"],
        json!(format!("θL {theta}° · exposure {exposure}")),
        "{shown} vs {view}"
    );
    let choice = &view["choice"];
    let text = shown["choice"].as_str().unwrap();
    assert!(
        text.contains(&format!(
            "model chosen: {}",
            choice["model"].as_str().unwrap()
        )) && text.contains(choice["reason"].as_str().unwrap())
            && text.contains(if choice["colour_shift"] == json!(true) {
                "colour shift reported"
            } else {
                "colour shift not reported"
            }),
        "{shown} vs {choice}"
    );
    assert_eq!(
        plot["buttonsDisabled"],
        json!([true, true, true, true]),
        "{plot}"
    );
    assert_eq!(plot["confirmHidden"], json!(true), "{plot}");
    // All three channels: one colour each; a linear β axis on demand.
    page.eval("(() => { const c = document.getElementById('plotchannel'); c.value = 'all'; c.dispatchEvent(new Event('change')); })()");
    let all = page.eval(PLOT_FACTS);
    check_plot(&all, 3);
    page.eval("(() => { const c = document.getElementById('plotscale'); c.value = 'linear'; c.dispatchEvent(new Event('change')); })()");
    let linear = page.eval(PLOT_FACTS);
    check_plot(&linear, 3);
    assert_ne!(linear["yTicks"], all["yTicks"], "{linear}");
    assert!(
        linear["yTicks"]
            .as_array()
            .unwrap()
            .iter()
            .any(|t| t == "0"),
        "{linear}"
    );

    // "all files" lists the scan's files as links in the page.
    page.eval("document.getElementById('allfiles').click()");
    let links = page.wait_for(
        "the file listing",
        "document.querySelectorAll('#files a').length > 0 && document.querySelectorAll('#files a').length",
        Duration::from_secs(30),
    );
    assert!(links.as_u64().unwrap() >= 8, "{links}");
    assert!(page
        .eval("[...document.querySelectorAll('#files a')].some((a) => a.textContent === 'samples.csv')")
        .as_bool()
        .unwrap());

    // The only error the whole session logged is the browser's note of the 401.
    let errors = page.errors();
    assert!(
        after_401.iter().all(|e| e.contains("401")) && errors.len() == after_401.len(),
        "{errors:?}"
    );
    drop(browser);
    drop(daemon);
    let _ = std::fs::remove_dir_all(&dir);
}
