//! The web page in a real browser: Debian's headless Chromium driven over the Chrome
//! DevTools Protocol (a WebSocket, JSON commands). The page loads with no console
//! error, a wrong token shows the 401 message, a scan started from the form shows its
//! progress and ends with the fit plot (ticks on round values, legend below the data),
//! and a finished scan's controls are disabled.
//!
//! Chromium comes from Debian's `chromium` package, which `scripts/test.sh` installs;
//! without it this test fails saying so (set `GONIO_CHROMIUM` to use another binary).

use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use gonio_tests::{emulator_config, temp_dir, Daemon, TOKEN};
use serde_json::{json, Value};
use tungstenite::stream::MaybeTlsStream;
use tungstenite::{Message, WebSocket};

/// Flags that work in this sandbox (no network but loopback, running as root).
const FLAGS: &[&str] = &[
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--remote-debugging-port=0",
];

fn chromium_binary() -> PathBuf {
    let path = std::env::var_os("GONIO_CHROMIUM")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("/usr/bin/chromium"));
    assert!(
        path.is_file(),
        "{} not found: the page's browser test needs Debian's `chromium` package \
         (`apt-get install chromium`, which scripts/test.sh does) or GONIO_CHROMIUM=/path",
        path.display()
    );
    path
}

/// A headless Chromium with a fresh profile, killed on drop.
struct Browser {
    child: Child,
    port: u16,
}

impl Browser {
    fn launch(profile: &Path) -> Browser {
        let child = Command::new(chromium_binary())
            .args(FLAGS)
            .arg(format!("--user-data-dir={}", profile.display()))
            .arg("about:blank")
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("starting chromium");
        // Chromium writes the port it chose into the profile.
        let active = profile.join("DevToolsActivePort");
        let port = wait_until("chromium's DevTools port", Duration::from_secs(60), || {
            std::fs::read_to_string(&active)
                .ok()
                .and_then(|text| text.lines().next()?.trim().parse::<u16>().ok())
        });
        Browser { child, port }
    }

    /// The DevTools connection of the first page (the about:blank tab).
    fn page(&self) -> Cdp {
        let url = format!("http://127.0.0.1:{}/json/list", self.port);
        let ws = wait_until("a page target", Duration::from_secs(30), || {
            let text = ureq::get(&url).call().ok()?.into_string().ok()?;
            let list: Value = serde_json::from_str(&text).ok()?;
            list.as_array()?.iter().find(|t| t["type"] == "page")?["webSocketDebuggerUrl"]
                .as_str()
                .map(str::to_owned)
        });
        let (socket, _) = tungstenite::connect(ws.as_str()).expect("DevTools WebSocket");
        if let MaybeTlsStream::Plain(stream) = socket.get_ref() {
            stream
                .set_read_timeout(Some(Duration::from_secs(30)))
                .expect("read timeout");
        }
        let mut cdp = Cdp {
            socket,
            next_id: 0,
            events: Vec::new(),
        };
        for domain in ["Page", "Runtime", "Log"] {
            cdp.call(&format!("{domain}.enable"), json!({}));
        }
        cdp
    }
}

impl Drop for Browser {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// One DevTools session: commands answered by id, events kept in arrival order.
struct Cdp {
    socket: WebSocket<MaybeTlsStream<TcpStream>>,
    next_id: u64,
    events: Vec<Value>,
}

impl Cdp {
    fn call(&mut self, method: &str, params: Value) -> Value {
        self.next_id += 1;
        let id = self.next_id;
        let request = json!({"id": id, "method": method, "params": params});
        self.socket
            .send(Message::text(request.to_string()))
            .expect("sending a DevTools command");
        loop {
            let message = self.socket.read().expect("reading from DevTools");
            let Message::Text(text) = message else {
                continue;
            };
            let value: Value = serde_json::from_str(text.as_str()).expect("DevTools JSON");
            if value["id"] == json!(id) {
                assert!(value.get("error").is_none(), "{method}: {value}");
                return value["result"].clone();
            }
            self.events.push(value);
        }
    }

    /// Evaluates `expression` in the page (awaiting a promise) and returns its value.
    fn eval(&mut self, expression: &str) -> Value {
        let result = self.call(
            "Runtime.evaluate",
            json!({"expression": expression, "returnByValue": true, "awaitPromise": true}),
        );
        assert!(
            result.get("exceptionDetails").is_none(),
            "{expression}: {result}"
        );
        result["result"]["value"].clone()
    }

    /// Polls `expression` until it is truthy.
    fn wait_for(&mut self, what: &str, expression: &str, timeout: Duration) -> Value {
        let start = Instant::now();
        loop {
            let value = self.eval(expression);
            if !(value.is_null() || value == json!(false) || value == json!("")) {
                eprintln!("{what}: after {:.1} s", start.elapsed().as_secs_f64());
                return value;
            }
            assert!(
                start.elapsed() < timeout,
                "timed out waiting for {what}; page: {}",
                self.eval("document.body.innerText")
            );
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    /// Console errors, uncaught exceptions and error log entries seen so far.
    fn errors(&self) -> Vec<String> {
        self.events
            .iter()
            .filter_map(|e| match e["method"].as_str()? {
                "Runtime.exceptionThrown" => Some(e["params"]["exceptionDetails"].to_string()),
                "Runtime.consoleAPICalled" if e["params"]["type"] == "error" => {
                    Some(e["params"]["args"].to_string())
                }
                "Log.entryAdded" if e["params"]["entry"]["level"] == "error" => {
                    let entry = &e["params"]["entry"];
                    Some(format!("{} {}", entry["text"], entry["url"]))
                }
                _ => None,
            })
            .collect()
    }
}

fn wait_until<T>(what: &str, timeout: Duration, mut probe: impl FnMut() -> Option<T>) -> T {
    let start = Instant::now();
    loop {
        if let Some(value) = probe() {
            return value;
        }
        assert!(start.elapsed() < timeout, "timed out waiting for {what}");
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// Fills the scan form with `token` and submits it.
fn submit_scan(page: &mut Cdp, token: &str) {
    page.eval(&format!(
        r##"(() => {{
            const t = document.getElementById("token");
            t.value = {token};
            t.dispatchEvent(new Event("change"));
            document.getElementById("theta").value = "-20,-35";
            document.getElementById("bracket").value = "0.5,0.03";
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

    page.call("Page.navigate", json!({"url": format!("{}/", daemon.url)}));
    // Loaded, and the first refresh (scans, sweeps, hardware) has come back.
    page.wait_for(
        "the page and its hardware line",
        "document.readyState === 'complete' && !document.getElementById('arm').textContent.includes('…')",
        Duration::from_secs(30),
    );
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
    let plot = page.eval(
        r#"(() => {
            const svg = document.querySelector('#plot svg');
            const axis = Number(svg.querySelector('line').getAttribute('y1'));
            const degrees = [...svg.querySelectorAll('text')].map((t) => t.textContent)
                .filter((s) => /^-?\d+(\.\d+)?°$/.test(s)).map(parseFloat);
            const legend = [...svg.querySelectorAll('text.legend')];
            return {
                degrees,
                legendBelow: legend.length > 0 && legend.every((t) => Number(t.getAttribute('y')) > axis),
                legend: legend.map((t) => t.textContent),
                buttonsDisabled: [...document.querySelectorAll('#detail button[data-act]')].map((b) => b.disabled),
                state: document.querySelector('#dstate span').textContent,
            };
        })()"#,
    );
    assert_eq!(plot["state"], "done", "{plot}");
    let degrees: Vec<f64> = serde_json::from_value(plot["degrees"].clone()).unwrap();
    assert!(degrees.len() >= 3, "{plot}");
    assert!(
        degrees.iter().all(|d| d % 5.0 == 0.0),
        "ticks off round values: {degrees:?}"
    );
    assert_eq!(plot["legendBelow"], json!(true), "{plot}");
    let legend = plot["legend"].to_string();
    assert!(
        legend.contains("cook-torrance") && legend.contains("ward") && legend.contains("ρd"),
        "{legend}"
    );
    assert_eq!(plot["buttonsDisabled"], json!([true, true, true]), "{plot}");

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
