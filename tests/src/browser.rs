//! A headless Chromium driven over the Chrome DevTools Protocol (a WebSocket, JSON
//! commands), for the tests that look at a page in a real browser. Chromium comes from
//! Debian's `chromium` package, which `scripts/test.sh` installs; without it the tests
//! fail saying so (set `GONIO_CHROMIUM` to use another binary).

use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

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

/// The Chromium to run: `GONIO_CHROMIUM`, else Debian's `/usr/bin/chromium`; fails the
/// test saying how to get it when it is missing.
pub fn chromium_binary() -> PathBuf {
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
pub struct Browser {
    child: Child,
    port: u16,
}

impl Browser {
    pub fn launch(profile: &Path) -> Browser {
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
    pub fn page(&self) -> Cdp {
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
pub struct Cdp {
    socket: WebSocket<MaybeTlsStream<TcpStream>>,
    next_id: u64,
    events: Vec<Value>,
}

impl Cdp {
    pub fn call(&mut self, method: &str, params: Value) -> Value {
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
    pub fn eval(&mut self, expression: &str) -> Value {
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
    pub fn wait_for(&mut self, what: &str, expression: &str, timeout: Duration) -> Value {
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
    pub fn errors(&self) -> Vec<String> {
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

/// Polls `probe` every 50 ms until it gives a value; fails the test after `timeout`.
pub fn wait_until<T>(what: &str, timeout: Duration, mut probe: impl FnMut() -> Option<T>) -> T {
    let start = Instant::now();
    loop {
        if let Some(value) = probe() {
            return value;
        }
        assert!(start.elapsed() < timeout, "timed out waiting for {what}");
        std::thread::sleep(Duration::from_millis(50));
    }
}
