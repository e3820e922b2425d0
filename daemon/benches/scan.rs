//! The README's 6-θL `gold` scan on the emulators, through a real `gonio serve`: the
//! scan's wall time (started → finished) over the time its hardware steps took (home,
//! moves, metering, captures; from the step journal at `/api/scans/{id}/steps`). With
//! the processing lane beside the hardware lane the ratio's target is ≤ 1.02.
//!
//!     cargo bench -p gonio-daemon --bench scan [-- --runs N --scene gold --time-scale 0.1]
//!
//! Defaults: one run of the builtin `gold` scene at the emulators' default time scale
//! (0.1) with an automatic bracket, as `gonio serve` runs without a configuration.
//! `GONIO_BIN=path` runs another build of `gonio` (to compare with an older one).

mod stats;

use std::io::{BufRead, BufReader, Read};
use std::process::{Child, Command, Stdio};
use std::time::Duration;

use serde_json::{json, Value};
use time::format_description::well_known::Rfc3339;
use time::OffsetDateTime;

const TOKEN: &str = "bench-token";
const THETA_L: [f64; 6] = [-20.0, -25.0, -30.0, -35.0, -40.0, -45.0];
const HARDWARE_KINDS: [&str; 4] = ["home", "move", "meter", "capture"];

struct Options {
    runs: usize,
    scene: String,
    time_scale: f64,
}

fn options() -> Options {
    let mut options = Options {
        runs: 1,
        scene: "gold".into(),
        time_scale: 0.1,
    };
    let mut args = std::env::args().skip(1);
    while let Some(arg) = args.next() {
        let mut value = || args.next().unwrap_or_else(|| panic!("{arg} needs a value"));
        match arg.as_str() {
            "--runs" => options.runs = value().parse().expect("--runs N"),
            "--scene" => options.scene = value(),
            "--time-scale" => options.time_scale = value().parse().expect("--time-scale S"),
            // What cargo bench passes to every bench target.
            "--bench" => {}
            other => panic!("unknown argument {other}"),
        }
    }
    options
}

/// A `gonio serve` on emulators in a temporary data directory.
struct Daemon {
    child: Child,
    url: String,
    _dir: tempfile::TempDir,
}

impl Daemon {
    fn start(options: &Options) -> Daemon {
        let dir = tempfile::tempdir().expect("temp dir");
        let config = dir.path().join("gonio.toml");
        std::fs::write(
            &config,
            format!(
                "[arm]\nkind = \"emulator\"\ntime_scale = {ts}\n\n\
                 [camera]\nkind = \"emulator\"\nscene = \"{scene}\"\ntime_scale = {ts}\n",
                ts = options.time_scale,
                scene = options.scene
            ),
        )
        .expect("writing the config");
        let bin = std::env::var_os("GONIO_BIN").unwrap_or(env!("CARGO_BIN_EXE_gonio").into());
        let mut child = Command::new(bin)
            .arg("serve")
            .arg("--config")
            .arg(&config)
            .arg("--data")
            .arg(dir.path().join("data"))
            .args(["--bind", "127.0.0.1:0"])
            .env("GONIO_TOKEN", TOKEN)
            .env("RUST_LOG", "warn")
            .stdout(Stdio::piped())
            .spawn()
            .expect("starting gonio serve");
        let stdout = child.stdout.take().expect("stdout");
        let url = BufReader::new(stdout)
            .lines()
            .map_while(Result::ok)
            .find_map(|line| line.strip_prefix("gonio: listening on ").map(str::to_owned))
            .expect("the daemon did not start");
        Daemon {
            child,
            url,
            _dir: dir,
        }
    }

    fn get(&self, path: &str) -> Value {
        let response = ureq::get(&format!("{}{path}", self.url))
            .timeout(Duration::from_secs(60))
            .call()
            .unwrap_or_else(|e| panic!("GET {path}: {e}"));
        read_json(response)
    }

    fn post(&self, path: &str, body: &Value) -> Value {
        let response = ureq::post(&format!("{}{path}", self.url))
            .set("Authorization", &format!("Bearer {TOKEN}"))
            .set("Content-Type", "application/json")
            .send_string(&body.to_string())
            .unwrap_or_else(|e| panic!("POST {path}: {e}"));
        read_json(response)
    }
}

fn read_json(response: ureq::Response) -> Value {
    let mut body = String::new();
    response
        .into_reader()
        .read_to_string(&mut body)
        .expect("body");
    serde_json::from_str(&body).expect("JSON")
}

impl Drop for Daemon {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn time(value: &Value) -> OffsetDateTime {
    OffsetDateTime::parse(value.as_str().expect("a time"), &Rfc3339).expect("RFC 3339")
}

fn seconds(from: OffsetDateTime, to: OffsetDateTime) -> f64 {
    (to - from).as_seconds_f64()
}

/// What one scan's journal says.
struct Run {
    wall_s: f64,
    hardware_s: f64,
    processing_s: f64,
    /// Between the hardware steps, summed: the hardware lane's own bookkeeping.
    gaps_s: f64,
    /// From the end of the last hardware step to the end of the scan, and the
    /// processing steps that ran in it (kind, seconds).
    tail_s: f64,
    tail: Vec<(String, f64)>,
    /// Seconds in hardware steps by kind, with their count.
    by_kind: Vec<(&'static str, f64, usize)>,
    steps: usize,
}

fn run_scan(daemon: &Daemon) -> Run {
    let created = daemon.post(
        "/api/scans",
        &json!({ "sample": "gold", "theta_l": THETA_L }),
    );
    let id = created["id"].as_i64().expect("scan id");
    let scan = loop {
        let scan = daemon.get(&format!("/api/scans/{id}"));
        match scan["state"].as_str() {
            Some("done") => break scan,
            Some("failed" | "cancelled") => panic!("scan {id} did not complete: {scan}"),
            _ => std::thread::sleep(Duration::from_millis(200)),
        }
    };
    let steps = daemon.get(&format!("/api/scans/{id}/steps"));
    let steps = steps.as_array().expect("steps");
    let (started, finished) = (time(&scan["started"]), time(&scan["finished"]));
    let (mut hardware_s, mut processing_s, mut gaps_s) = (0.0, 0.0, 0.0);
    let mut hardware_end = started;
    let mut processing = Vec::new();
    let mut by_kind: Vec<(&'static str, f64, usize)> =
        HARDWARE_KINDS.iter().map(|k| (*k, 0.0, 0)).collect();
    for step in steps {
        let (from, to) = (time(&step["started"]), time(&step["finished"]));
        let kind = step["step"]["kind"].as_str().unwrap_or_default();
        if let Some(entry) = by_kind.iter_mut().find(|(k, _, _)| *k == kind) {
            entry.1 += seconds(from, to);
            entry.2 += 1;
            hardware_s += seconds(from, to);
            gaps_s += seconds(hardware_end, from);
            hardware_end = to;
        } else {
            processing_s += seconds(from, to);
            processing.push((kind.to_owned(), from, to));
        }
    }
    let tail = processing
        .into_iter()
        .filter(|(_, _, to)| *to > hardware_end)
        .map(|(kind, from, to)| (kind, seconds(from.max(hardware_end), to)))
        .collect();
    Run {
        wall_s: seconds(started, finished),
        hardware_s,
        processing_s,
        gaps_s,
        tail_s: seconds(hardware_end, finished),
        tail,
        by_kind,
        steps: steps.len(),
    }
}

fn main() {
    let options = options();
    let daemon = Daemon::start(&options);
    println!(
        "scan: {} scene, θL {THETA_L:?}, auto bracket, time scale {}",
        options.scene, options.time_scale
    );
    println!("run  steps  wall s  hardware s  processing s  gaps s  tail s  wall/hardware");
    let mut ratios = Vec::new();
    for n in 1..=options.runs {
        let run = run_scan(&daemon);
        let ratio = run.wall_s / run.hardware_s;
        ratios.push((ratio, run.wall_s, run.hardware_s));
        println!(
            "{n:>3}  {:>5}  {:>6.2}  {:>10.2}  {:>12.2}  {:>6.2}  {:>6.2}  {ratio:>13.3}",
            run.steps, run.wall_s, run.hardware_s, run.processing_s, run.gaps_s, run.tail_s
        );
        let tail: Vec<String> = run
            .tail
            .iter()
            .map(|(kind, s)| format!("{kind} {s:.2} s"))
            .collect();
        println!("     tail after the last capture: {}", tail.join(", "));
        let kinds: Vec<String> = run
            .by_kind
            .iter()
            .map(|(kind, s, n)| format!("{n} {kind} {s:.2} s"))
            .collect();
        println!("     hardware steps: {}", kinds.join(", "));
    }
    let walls: Vec<f64> = ratios.iter().map(|r| r.0).collect();
    let spread = stats::spread(&walls);
    ratios.sort_by(|a, b| a.0.total_cmp(&b.0));
    let (ratio, wall_s, hardware_s) = ratios[ratios.len() / 2];
    println!(
        "median wall/hardware over {} run(s): {ratio:.3} (target ≤ 1.02)",
        ratios.len(),
    );
    // The line scripts/bench.sh keeps for the README's table: the median run.
    println!(
        "{}",
        json!({
            "bench": "scan",
            "ratio": ratio,
            "wall_s": wall_s,
            "hardware_s": hardware_s,
            "spread": spread,
        })
    );
}
