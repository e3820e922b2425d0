//! End-to-end tests across gonio's crates live in `tests/tests/`; this library holds
//! their shared helpers: locating the `gonio` binary, running the daemon as a real
//! process, and a small HTTP client for its API; `browser` and `page` drive the web
//! page in a headless Chromium.

use std::io::{BufRead, BufReader, Read};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

use serde_json::Value;

pub mod browser;
mod described;
pub mod page;

/// The `gonio` binary of the profile the tests were built with, brought up to date on
/// first use, so `cargo test --workspace` works on a clean checkout. The update runs
/// `cargo test --workspace --no-run`: the same feature resolution as the workspace test
/// run that is executing us, so there it finds the binary fresh and rebuilds nothing.
/// `GONIO_BIN=/path/to/gonio` uses that binary as it is (running one test file without
/// building the whole workspace).
pub fn gonio_bin() -> &'static Path {
    static BIN: OnceLock<PathBuf> = OnceLock::new();
    BIN.get_or_init(|| {
        if let Some(bin) = std::env::var_os("GONIO_BIN") {
            let bin = PathBuf::from(bin);
            assert!(bin.is_file(), "GONIO_BIN={} is not a file", bin.display());
            return bin;
        }
        // The test executable lives in <target>/<profile-dir>/deps/.
        let exe = std::env::current_exe().expect("test executable path");
        let profile_dir = exe
            .parent()
            .and_then(Path::parent)
            .expect("test executable inside <target>/<profile>/deps")
            .to_path_buf();
        let target_dir = profile_dir.parent().expect("target directory");
        let profile = match profile_dir.file_name().and_then(|n| n.to_str()) {
            Some("debug") => "dev".to_owned(),
            Some(other) => other.to_owned(),
            None => "dev".to_owned(),
        };
        let status = Command::new(env!("CARGO"))
            .args(["test", "--quiet", "--workspace", "--no-run"])
            .arg("--profile")
            .arg(&profile)
            .arg("--target-dir")
            .arg(target_dir)
            .status()
            .expect("running cargo build for the gonio binary");
        assert!(status.success(), "building the gonio binary failed");
        let bin = profile_dir.join(format!("gonio{}", std::env::consts::EXE_SUFFIX));
        assert!(bin.is_file(), "{} missing after the build", bin.display());
        bin
    })
}

/// Runs `gonio ARGS` and returns its standard output; panics with its standard error
/// if it fails.
pub fn gonio(args: &[&str]) -> String {
    let output = Command::new(gonio_bin()).args(args).output().unwrap();
    assert!(
        output.status.success(),
        "gonio {args:?}: {}",
        String::from_utf8_lossy(&output.stderr)
    );
    String::from_utf8_lossy(&output.stdout).into_owned()
}

/// A fresh, empty directory under the system temp dir, unique to this process and name,
/// removed when dropped, unless its test is failing (a panic is under way: what it
/// holds tells why) or `GONIO_KEEP_TEST_DIRS` is set (to keep a run's data directory,
/// e.g. a journal to record).
pub fn temp_dir(name: &str) -> TempDir {
    let dir = std::env::temp_dir().join(format!("gonio-test-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("creating a temp dir");
    TempDir(dir)
}

/// A test's directory ([`temp_dir`]); it is used as the path it holds.
#[derive(Debug)]
pub struct TempDir(PathBuf);

impl std::ops::Deref for TempDir {
    type Target = PathBuf;
    fn deref(&self) -> &PathBuf {
        &self.0
    }
}

impl AsRef<Path> for TempDir {
    fn as_ref(&self) -> &Path {
        &self.0
    }
}

impl AsRef<std::ffi::OsStr> for TempDir {
    fn as_ref(&self) -> &std::ffi::OsStr {
        self.0.as_os_str()
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        if !std::thread::panicking() && std::env::var_os("GONIO_KEEP_TEST_DIRS").is_none() {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }
}

/// A small, fast variant of the builtin `gold` scene (480×320 pixels, same field of
/// view and material), for tests that run whole scans.
pub const SMALL_GOLD_SCENE: &str = r#"
name = "small-gold"

[setup]
cylinder_radius_mm = 40.0
camera_distance_mm = 700.0
light_distance_mm = 1000.0
focal_length_mm = 85.0
pixel_pitch_um = 49.2
image_width = 480
image_height = 320
sample_rows = [124, 148]
white_rows = [171, 195]

[scan]
theta_l_deg = [-20.0, -25.0, -30.0, -35.0, -40.0, -45.0]
bracket_s = [0.5, 0.125, 0.033333333333333333, 0.01]

[sample]
model = "cook-torrance"
kd = [9.0, 6.5, 2.0]
ks = [25.0, 20.0, 7.0]
m = [0.07]

[white]
reflectance = 0.99

[light]
spectrum = "illuminant-a"
intensity = 6000.0

[camera]
model = "Nikon D200 (emulated)"
sensitivities = "nikon-d5100"
bit_depth = 12
black_level = 0
white_level = 4095
iso = 100

[effects]
seed = 1
"#;

/// The token every test daemon uses.
pub const TOKEN: &str = "test-token-0123456789";

/// A `gonio serve` process on emulated hardware, listening on a free port.
pub struct Daemon {
    child: Child,
    /// Base URL, e.g. `http://127.0.0.1:40123`.
    pub url: String,
    pub data: PathBuf,
    /// The daemon's stderr (its log).
    pub log: PathBuf,
    stdout_lines: Vec<String>,
    /// The daemon's OpenAPI description, fetched on first use.
    spec: OnceLock<Value>,
}

/// An HTTP answer: status and JSON body (`Value::Null` if the body is not JSON).
#[derive(Debug)]
pub struct Answer {
    pub status: u16,
    pub json: Value,
    pub bytes: Vec<u8>,
    pub content_type: String,
}

impl Daemon {
    /// Submits a scan of the `gold` sample at `theta_l` with the fixed bracket
    /// `shutter_s` (seconds); asserts 201 and returns the scan's id.
    pub fn post_gold_scan(&self, theta_l: &[f64], shutter_s: &[f64]) -> i64 {
        let answer = self.post(
            "/api/scans",
            &serde_json::json!({"sample": "gold", "theta_l": theta_l, "bracket": {"shutter_s": shutter_s}}),
        );
        assert_eq!(answer.status, 201, "{:?}", answer.json);
        answer.json["id"].as_i64().unwrap()
    }

    /// Waits until a capture of scan `id` is done.
    pub fn wait_for_a_capture(&self, id: i64, timeout: Duration) {
        self.wait_for(&format!("/api/scans/{id}/steps"), timeout, |steps| {
            steps.as_array().is_some_and(|steps| {
                steps
                    .iter()
                    .any(|s| s["step"]["kind"] == "capture" && s["state"] == "done")
            })
        });
    }

    /// Writes the scene and `config` (TOML; `SCENE` in it is replaced by the scene
    /// file's path) into `dir`, and starts the daemon with data in `dir/data`.
    pub fn start(dir: &Path, config: &str) -> Daemon {
        Self::start_with_fd_limit(dir, config, None)
    }

    /// As [`Daemon::start`], with the daemon's file-descriptor limit (soft and hard)
    /// set to `fd_limit`, so that it cannot raise it.
    pub fn start_with_fd_limit(dir: &Path, config: &str, fd_limit: Option<u64>) -> Daemon {
        let config_path = Self::write_config(dir, config);
        Self::spawn(dir, &config_path, fd_limit, &[])
    }

    /// As [`Daemon::start`], with `env` added to the daemon's environment.
    pub fn start_with_env(dir: &Path, config: &str, env: &[(&str, &str)]) -> Daemon {
        let config_path = Self::write_config(dir, config);
        Self::spawn(dir, &config_path, None, env)
    }

    /// Writes the scene and `config` into `dir`; returns the config's path.
    fn write_config(dir: &Path, config: &str) -> PathBuf {
        let scene = dir.join("scene.toml");
        std::fs::write(&scene, SMALL_GOLD_SCENE).expect("writing the scene");
        let config_path = dir.join("gonio.toml");
        let config = config.replace("SCENE", &scene.display().to_string());
        std::fs::write(&config_path, config).expect("writing the config");
        config_path
    }

    /// Starts the daemon again on the same directory and configuration.
    pub fn restart(dir: &Path) -> Daemon {
        Self::spawn(dir, &dir.join("gonio.toml"), None, &[])
    }

    /// As [`Daemon::start`], running the program at `bin` (a copy of [`gonio_bin`]).
    pub fn start_from(bin: &Path, dir: &Path, config: &str) -> Daemon {
        let config_path = Self::write_config(dir, config);
        Self::spawn_program(bin, dir, &config_path, None, &[])
    }

    /// The address the daemon listens on, e.g. `127.0.0.1:40123`.
    pub fn addr(&self) -> &str {
        self.url.trim_start_matches("http://")
    }

    fn spawn(dir: &Path, config: &Path, fd_limit: Option<u64>, env: &[(&str, &str)]) -> Daemon {
        Self::spawn_program(gonio_bin(), dir, config, fd_limit, env)
    }

    fn spawn_program(
        bin: &Path,
        dir: &Path,
        config: &Path,
        fd_limit: Option<u64>,
        env: &[(&str, &str)],
    ) -> Daemon {
        let data = dir.join("data");
        let log_path = dir.join(format!(
            "daemon-{}.log",
            std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map(|d| d.as_millis())
                .unwrap_or(0)
        ));
        let log = std::fs::File::create(&log_path).expect("creating the daemon log");
        let mut command = Command::new(bin);
        if let Some(limit) = fd_limit {
            use std::os::unix::process::CommandExt;
            // SAFETY: setrlimit is async-signal-safe and touches only this child.
            unsafe {
                command.pre_exec(move || {
                    let rlimit = libc::rlimit {
                        rlim_cur: limit,
                        rlim_max: limit,
                    };
                    if libc::setrlimit(libc::RLIMIT_NOFILE, &rlimit) == 0 {
                        Ok(())
                    } else {
                        Err(std::io::Error::last_os_error())
                    }
                });
            }
        }
        let mut child = command
            .arg("serve")
            .arg("--config")
            .arg(config)
            .arg("--data")
            .arg(&data)
            .args(["--bind", "127.0.0.1:0"])
            .env("GONIO_TOKEN", TOKEN)
            .env("RUST_LOG", "info")
            .envs(env.iter().copied())
            .stdout(Stdio::piped())
            .stderr(Stdio::from(log))
            .spawn()
            .expect("starting gonio serve");
        let stdout = child.stdout.take().expect("daemon stdout");
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            for line in BufReader::new(stdout).lines().map_while(Result::ok) {
                if tx.send(line).is_err() {
                    break;
                }
            }
        });
        let mut stdout_lines = Vec::new();
        let deadline = Instant::now() + Duration::from_secs(60);
        let url = loop {
            let left = deadline.saturating_duration_since(Instant::now());
            match rx.recv_timeout(left) {
                Ok(line) => {
                    if let Some(url) = line.strip_prefix("gonio: listening on ") {
                        break url.trim().to_owned();
                    }
                    stdout_lines.push(line);
                }
                Err(_) => {
                    let _ = child.kill();
                    panic!(
                        "daemon did not start; stdout {stdout_lines:?}; see logs in {}",
                        dir.display()
                    );
                }
            }
        };
        Daemon {
            child,
            url,
            data,
            log: log_path,
            stdout_lines,
            spec: OnceLock::new(),
        }
    }

    /// The daemon's process id.
    pub fn pid(&self) -> u32 {
        self.child.id()
    }

    /// Lines the daemon printed before it listened.
    pub fn startup_output(&self) -> &[String] {
        &self.stdout_lines
    }

    /// Sends `signal` (e.g. `libc::SIGTERM`) and waits for the process to end, at most
    /// `timeout`; returns its exit status.
    pub fn stop_with(mut self, signal: i32, timeout: Duration) -> std::process::ExitStatus {
        let pid = i32::try_from(self.child.id()).expect("a pid");
        // SAFETY: kill only sends a signal to our own child process.
        assert_eq!(
            unsafe { libc::kill(pid, signal) },
            0,
            "signalling the daemon"
        );
        self.ended_within(timeout, &format!("{timeout:?} after signal {signal}"))
    }

    /// Waits for the process to end by itself, at most `timeout`; returns its exit
    /// status.
    pub fn wait_exit(mut self, timeout: Duration) -> std::process::ExitStatus {
        self.ended_within(timeout, &format!("after {timeout:?}"))
    }

    /// The exit status once the process has ended, at most `timeout` from now; panics
    /// with "the daemon still runs `when`" otherwise.
    fn ended_within(&mut self, timeout: Duration, when: &str) -> std::process::ExitStatus {
        let deadline = Instant::now() + timeout;
        loop {
            if let Some(status) = self.child.try_wait().expect("waiting for the daemon") {
                return status;
            }
            assert!(Instant::now() < deadline, "the daemon still runs {when}");
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    /// Kills the process with SIGKILL (no chance to clean up) and waits for it.
    pub fn kill9(mut self) {
        self.child.kill().expect("killing the daemon");
        self.child.wait().expect("reaping the daemon");
    }

    /// Sends SIGINT (Ctrl-C) and waits for the process to end, at most `timeout`.
    pub fn interrupt(self, timeout: Duration) -> std::process::ExitStatus {
        self.stop_with(libc::SIGINT, timeout)
    }

    /// Sends a request; panics, naming the method, path and status, when the daemon's
    /// OpenAPI description does not describe the answer (see `described`).
    fn request(&self, method: &str, path: &str, token: Option<&str>, body: Option<&str>) -> Answer {
        let answer = self.send(method, path, token, body);
        let spec = self.spec.get_or_init(|| {
            let spec = self.send("GET", "/api/openapi.json", None, None);
            assert_eq!(spec.status, 200, "GET /api/openapi.json");
            spec.json
        });
        if let Err(undescribed) = described::check(spec, method, path, answer.status) {
            panic!("{undescribed}");
        }
        answer
    }

    fn send(&self, method: &str, path: &str, token: Option<&str>, body: Option<&str>) -> Answer {
        let mut request =
            ureq::request(method, &format!("{}{path}", self.url)).timeout(Duration::from_secs(30));
        if let Some(token) = token {
            request = request.set("Authorization", &format!("Bearer {token}"));
        }
        let result = match body {
            Some(body) => request
                .set("Content-Type", "application/json")
                .send_string(body),
            None => request.call(),
        };
        let response = match result {
            Ok(response) | Err(ureq::Error::Status(_, response)) => response,
            Err(err) => panic!("{method} {path}: {err}"),
        };
        let status = response.status();
        let content_type = response.content_type().to_owned();
        let mut bytes = Vec::new();
        response
            .into_reader()
            .take(100 << 20)
            .read_to_end(&mut bytes)
            .expect("reading the body");
        let json = serde_json::from_slice(&bytes).unwrap_or(Value::Null);
        Answer {
            status,
            json,
            bytes,
            content_type,
        }
    }

    pub fn get(&self, path: &str) -> Answer {
        self.request("GET", path, None, None)
    }

    /// POST with the daemon's token.
    pub fn post(&self, path: &str, body: &Value) -> Answer {
        self.request("POST", path, Some(TOKEN), Some(&body.to_string()))
    }

    /// PATCH with the daemon's token and a JSON body.
    pub fn patch(&self, path: &str, body: &Value) -> Answer {
        self.request("PATCH", path, Some(TOKEN), Some(&body.to_string()))
    }

    /// DELETE with the daemon's token.
    pub fn delete(&self, path: &str) -> Answer {
        self.request("DELETE", path, Some(TOKEN), None)
    }

    /// POST with an explicit token (or none) and raw body.
    pub fn post_raw(&self, path: &str, token: Option<&str>, body: &str) -> Answer {
        self.request("POST", path, token, Some(body))
    }

    /// Polls `GET path` until `done` holds for its JSON, or panics after `timeout`.
    pub fn wait_for(&self, path: &str, timeout: Duration, done: impl Fn(&Value) -> bool) -> Value {
        let deadline = Instant::now() + timeout;
        loop {
            let answer = self.get(path);
            if answer.status == 200 && done(&answer.json) {
                return answer.json;
            }
            assert!(
                Instant::now() < deadline,
                "timed out waiting on {path}; last: {}",
                answer.json
            );
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    /// Waits until scan `id` reaches a state in `states`.
    pub fn wait_state(&self, id: i64, states: &[&str], timeout: Duration) -> Value {
        self.wait_for(&format!("/api/scans/{id}"), timeout, |scan| {
            states.contains(&scan["state"].as_str().unwrap_or(""))
        })
    }
}

impl Drop for Daemon {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// One raw HTTP/1.1 exchange on a new connection to `addr` (for requests a client
/// library would not send: any Host, any header): the status and the body.
pub fn raw_http(addr: &str, request: &str) -> (u16, String) {
    use std::io::Write;
    let mut stream = std::net::TcpStream::connect(addr).expect("connecting to the daemon");
    stream
        .set_read_timeout(Some(Duration::from_secs(30)))
        .expect("read timeout");
    stream
        .write_all(request.as_bytes())
        .expect("sending the request");
    let mut answer = String::new();
    let _ = stream.read_to_string(&mut answer);
    let status = answer
        .split_whitespace()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(0);
    let body = answer
        .split_once("\r\n\r\n")
        .map_or("", |(_, b)| b)
        .to_owned();
    (status, body)
}

/// A daemon configuration on emulators with the small scene, `time_scale` for both
/// devices, fast retries and fault injection on, and no timing probe (its minute of
/// processor time at each new daemon's start is for time left alone).
pub fn emulator_config(time_scale: f64) -> String {
    emulator_config_scaled(time_scale, time_scale)
}

/// As [`emulator_config`], with the arm's and the camera's time scales apart.
pub fn emulator_config_scaled(arm_time_scale: f64, camera_time_scale: f64) -> String {
    format!(
        r#"
[arm]
kind = "emulator"
time_scale = {arm_time_scale}

[camera]
kind = "emulator"
scene = "SCENE"
time_scale = {camera_time_scale}

[retry]
attempts = 3
backoff_ms = 50

[processing]
timing_probe = false

[emulator]
fault_injection = true
"#
    )
}

/// The small gold scene with another material: a red, rougher sample.
pub fn small_red_scene() -> String {
    let red = SMALL_GOLD_SCENE
        .replace("name = \"small-gold\"", "name = \"small-red\"")
        .replace("kd = [9.0, 6.5, 2.0]", "kd = [12.0, 2.5, 1.5]")
        .replace("ks = [25.0, 20.0, 7.0]", "ks = [18.0, 5.0, 3.0]")
        .replace("m = [0.07]", "m = [0.1]");
    assert_ne!(red, SMALL_GOLD_SCENE);
    red
}

/// `config` (an emulator configuration) with the small gold scene mounted as `gold` and
/// the small red scene (written into `dir`) as the sample `red`.
pub fn with_small_red_sample(config: &str, dir: &Path) -> String {
    let red = dir.join("red.toml");
    std::fs::create_dir_all(dir).expect("creating the test directory");
    std::fs::write(&red, small_red_scene()).expect("writing the red scene");
    config.replace(
        "scene = \"SCENE\"",
        &format!(
            "scene = \"SCENE\"\nsample = \"gold\"\nsamples = {{ red = \"{}\" }}",
            red.display()
        ),
    )
}

/// The ids of a created sweep's scans (`POST /api/sweeps`' answer), in order.
pub fn sweep_scans(sweep: &Value) -> Vec<i64> {
    sweep["scans"]
        .as_array()
        .expect("the sweep's scans")
        .iter()
        .map(|v| v.as_i64().expect("a scan id"))
        .collect()
}

/// Every file under `dir`, relative, sorted.
pub fn files_under(dir: &Path) -> Vec<String> {
    fn walk(base: &Path, dir: &Path, out: &mut Vec<String>) {
        for entry in std::fs::read_dir(dir).into_iter().flatten().flatten() {
            let path = entry.path();
            if path.is_dir() {
                walk(base, &path, out);
            } else if let Ok(rel) = path.strip_prefix(base) {
                out.push(rel.to_string_lossy().into_owned());
            }
        }
    }
    let mut out = Vec::new();
    walk(dir, dir, &mut out);
    out.sort();
    out
}

/// Raises this test process's own descriptor limit so it can hold `n` sockets.
pub fn allow_open_files(n: u64) {
    let mut limit = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: plain struct in, plain struct out.
    unsafe {
        assert_eq!(libc::getrlimit(libc::RLIMIT_NOFILE, &mut limit), 0);
        if limit.rlim_cur < n {
            limit.rlim_cur = n.min(limit.rlim_max).max(n);
            limit.rlim_max = limit.rlim_max.max(n);
            assert_eq!(
                libc::setrlimit(libc::RLIMIT_NOFILE, &limit),
                0,
                "raising the test's own file limit to {n}"
            );
        }
    }
}

/// A memory figure of process `pid` from `/proc/PID/status`, KiB: `VmRSS` (resident
/// now) or `VmHWM` (the most it was resident).
pub fn memory_kib(pid: u32, field: &str) -> u64 {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).expect("/proc status");
    status
        .lines()
        .find_map(|line| line.strip_prefix(field)?.strip_prefix(':'))
        .and_then(|rest| rest.trim().trim_end_matches("kB").trim().parse().ok())
        .unwrap_or_else(|| panic!("{field} of process {pid}"))
}
