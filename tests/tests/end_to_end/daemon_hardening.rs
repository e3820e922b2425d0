//! The daemon under hostile or careless clients, on emulated hardware: idle sockets,
//! contention on the operator controls, a corrupt capture, kills and a crash loop, a request that
//! would create millions of steps, links in a scan directory, foreign Host headers and
//! the API's error shape. Loopback only; each test bounded in time.

use std::net::TcpStream;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use gonio_tests::{
    allow_open_files, emulator_config, emulator_config_scaled, raw_http, temp_dir, Daemon, TOKEN,
};
use serde_json::{json, Value};

/// Sockets the process `pid` has open (its descriptors that are sockets).
fn open_sockets(pid: u32) -> usize {
    std::fs::read_dir(format!("/proc/{pid}/fd"))
        .map(|entries| {
            entries
                .flatten()
                .filter(|e| {
                    std::fs::read_link(e.path())
                        .is_ok_and(|target| target.to_string_lossy().starts_with("socket:"))
                })
                .count()
        })
        .unwrap_or(0)
}

/// The daemon runs at the usual 1,024-descriptor limit it cannot raise; 2,000 idle
/// sockets are opened against it (they once starved it: health stopped answering and
/// the camera capture failed with "Too many open files"). Health answers and a scan
/// completes meanwhile, with the daemon holding hundreds of the idle sockets.
#[test]
fn two_thousand_idle_sockets_starve_neither_health_nor_a_scan() {
    allow_open_files(4096);
    let dir = temp_dir("harden-idle");
    // Top-level keys must come before the tables of the emulator config.
    let config = format!("idle_timeout_s = 60\n{}", emulator_config(0.02));
    let daemon = Daemon::start_with_fd_limit(&dir, &config, Some(1024));
    let started = Instant::now();
    let mut idle = Vec::new();
    for _ in 0..2000 {
        match TcpStream::connect_timeout(&daemon.addr().parse().unwrap(), Duration::from_secs(5)) {
            Ok(socket) => idle.push(socket),
            Err(err) => panic!("connect {} failed: {err}", idle.len()),
        }
    }
    let connect_s = started.elapsed().as_secs_f64();
    let started = Instant::now();
    // Health answers, and says "ok" once the hardware lane has opened the arm (it is
    // `degraded`, arm disconnected, for a moment after start).
    daemon.wait_for("/api/health", Duration::from_secs(30), |h| {
        h["status"] == "ok"
    });
    let health_s = started.elapsed().as_secs_f64();
    let started = Instant::now();
    let id = daemon.post_gold_scan(&[-20.0, -30.0], &[0.5, 0.05]);
    let mut held = 0;
    let scan = loop {
        held = held.max(open_sockets(daemon.pid()));
        let scan = daemon.get(&format!("/api/scans/{id}")).json;
        if ["done", "failed"].contains(&scan["state"].as_str().unwrap_or("")) {
            break scan;
        }
        assert!(started.elapsed() < Duration::from_secs(120), "{scan}");
        std::thread::sleep(Duration::from_millis(100));
    };
    let scan_s = started.elapsed().as_secs_f64();
    assert_eq!(scan["state"], "done", "{scan}");
    assert_eq!(daemon.get("/api/health").status, 200);
    // The cap (1,024 less the descriptors reserved) was reached, not dodged.
    assert!(held >= 500, "the daemon held only {held} sockets");
    eprintln!(
        "2000 idle sockets opened in {connect_s:.2} s; the daemon (fd limit 1024) held up \
         to {held} sockets while the scan ran; health in {health_s:.3} s; scan done in \
         {scan_s:.1} s"
    );
    drop(idle);
    std::fs::remove_dir_all(dir).ok();
}

/// Pause, resume and cancel from 8 threads while scans run: every answer is 200 or 409
/// (never "database is locked"). The controls go on until the runner has finished
/// several steps meanwhile, so its writes really interleave with theirs; then every
/// thread cancels every scan at once.
#[test]
fn controls_from_eight_threads_during_a_scan_never_error() {
    let dir = temp_dir("harden-controls");
    let daemon = Daemon::start(&dir, &emulator_config(0.05));
    let ids: Vec<i64> = (0..3)
        .map(|_| daemon.post_gold_scan(&[-20.0, -25.0, -30.0, -35.0, -40.0], &[0.5, 0.05]))
        .collect();
    daemon.wait_state(ids[0], &["running"], Duration::from_secs(60));
    let steps_done = || -> u64 {
        ids.iter()
            .map(|id| {
                daemon.get(&format!("/api/scans/{id}")).json["progress"]["done"]
                    .as_u64()
                    .unwrap_or(0)
            })
            .sum()
    };
    let before = steps_done();
    let stop = AtomicBool::new(false);
    let started = Instant::now();
    let (answers, advanced) = std::thread::scope(|scope| {
        let workers: Vec<_> = (0..8)
            .map(|t| {
                let (daemon, ids, stop) = (&daemon, &ids, &stop);
                scope.spawn(move || {
                    let mut out = Vec::new();
                    let mut k = t;
                    while !stop.load(Ordering::Acquire) {
                        let id = ids[k % ids.len()];
                        // Mostly resumed, so the scans keep running.
                        let verb = ["pause", "resume", "resume"][(k / ids.len()) % 3];
                        let answer = daemon.post(&format!("/api/scans/{id}/{verb}"), &json!({}));
                        out.push((answer.status, answer.json));
                        k += 1;
                    }
                    for &id in ids {
                        let answer = daemon.post(&format!("/api/scans/{id}/cancel"), &json!({}));
                        out.push((answer.status, answer.json));
                    }
                    out
                })
            })
            .collect();
        let deadline = Instant::now() + Duration::from_secs(120);
        let mut advanced = 0;
        while advanced < 12 && Instant::now() < deadline {
            std::thread::sleep(Duration::from_millis(200));
            advanced = steps_done().saturating_sub(before);
        }
        stop.store(true, Ordering::Release);
        let answers: Vec<(u16, Value)> = workers
            .into_iter()
            .flat_map(|w| w.join().unwrap())
            .collect();
        (answers, advanced)
    });
    let seconds = started.elapsed().as_secs_f64();
    assert!(
        advanced >= 12,
        "the scans advanced {advanced} steps under the controls"
    );
    let errors: Vec<&(u16, Value)> = answers
        .iter()
        .filter(|(status, _)| ![200, 409].contains(status))
        .collect();
    assert!(
        errors.is_empty(),
        "{} errors, e.g. {:?}",
        errors.len(),
        errors.first()
    );
    let applied = answers.iter().filter(|(status, _)| *status == 200).count();
    assert!(applied >= 8, "only {applied} controls applied");
    for id in &ids {
        let scan = daemon.wait_state(*id, &["cancelled", "done"], Duration::from_secs(30));
        assert_eq!(scan["error"], Value::Null, "{scan}");
    }
    eprintln!(
        "{} controls ({applied} applied) in {seconds:.2} s ({:.0}/s) while the runner \
         finished {advanced} steps, 0 errors",
        answers.len(),
        answers.len() as f64 / seconds
    );
    std::fs::remove_dir_all(dir).ok();
}

/// Waits until the journal of scan `id` has a step record (state, times, step) for
/// which `which` holds, and returns it.
fn wait_step(daemon: &Daemon, id: i64, which: impl Fn(&Value) -> bool) -> Value {
    let steps = daemon.wait_for(
        &format!("/api/scans/{id}/steps"),
        Duration::from_secs(60),
        |steps| {
            steps
                .as_array()
                .is_some_and(|steps| steps.iter().any(&which))
        },
    );
    steps
        .as_array()
        .unwrap()
        .iter()
        .find(|s| which(s))
        .unwrap()
        .clone()
}

/// Three times: waits until this daemon has started the move step of scan `id` (the
/// arm then moves for ≥ 4 s at time scale 1), ends it with `end` (given the round), and
/// starts a new daemon on `dir`, which it returns. A move step an earlier daemon left
/// started does not count: its started time must be new.
fn end_three_times_during_the_move(
    dir: &std::path::Path,
    mut daemon: Daemon,
    id: i64,
    end: impl Fn(Daemon, usize),
) -> Daemon {
    let mut before = Value::Null;
    for round in 0..3 {
        let step = wait_step(&daemon, id, |s| {
            s["step"]["kind"] == "move" && s["state"] == "started" && s["started"] != before
        });
        before = step["started"].clone();
        end(daemon, round);
        daemon = Daemon::restart(dir);
    }
    daemon
}

/// A capture overwritten by one whose header claims 4 billion × 5 pixels: the first
/// processing step that reads it (θL's samples, journaled before its HDR merge) fails
/// with a clear error (no panic, no abort, no wedged queue) and the next scan runs.
#[test]
fn a_corrupt_frame_fails_its_step_and_the_queue_goes_on() {
    let dir = temp_dir("harden-corrupt");
    // The camera in real time: the second exposure (2 s) leaves time to pause.
    let daemon = Daemon::start(&dir, &emulator_config_scaled(0.05, 1.0));
    let first = daemon.post_gold_scan(&[-20.0], &[0.01, 2.0]);
    // Pause during the second capture (it completes, the merge waits), corrupt the
    // first frame, resume.
    wait_step(&daemon, first, |s| {
        s["step"]["kind"] == "capture" && s["step"]["index"] == 1 && s["state"] == "started"
    });
    assert_eq!(
        daemon
            .post(&format!("/api/scans/{first}/pause"), &json!({}))
            .status,
        200
    );
    let paused = daemon.wait_state(first, &["paused"], Duration::from_secs(30));
    let steps = daemon.get(&format!("/api/scans/{first}/steps")).json;
    let hdr = steps
        .as_array()
        .unwrap()
        .iter()
        .find(|s| s["step"]["kind"] == "hdr")
        .unwrap();
    assert_eq!(hdr["state"], "pending", "paused too late: {steps}");
    let frame = daemon
        .data
        .join(format!("scans/{first}/theta_l_-20.0/exp_00.tiff"));
    assert!(frame.is_file(), "{paused}");
    let hostile = std::fs::read(gonio_fuzz_seed(
        "tiff_sidecar",
        "regression_huge_width_u32max",
    ))
    .unwrap();
    // The seed is a 2-byte sidecar length, the sidecar, then the TIFF.
    let len = usize::from(u16::from_le_bytes([hostile[0], hostile[1]]));
    std::fs::write(&frame, &hostile[2 + len..]).unwrap();
    let second = daemon.post_gold_scan(&[-25.0], &[0.01, 0.02]);
    assert_eq!(
        daemon
            .post(&format!("/api/scans/{first}/resume"), &json!({}))
            .status,
        200
    );
    let scan = daemon.wait_state(first, &["done", "failed"], Duration::from_secs(60));
    assert_eq!(scan["state"], "failed", "{scan}");
    let error = scan["error"].as_str().unwrap();
    assert!(
        error.starts_with("extract θL -20.0°") && error.contains("allowed"),
        "{error}"
    );
    let next = daemon.wait_state(second, &["done", "failed"], Duration::from_secs(60));
    assert_eq!(next["state"], "done", "{next}");
    std::fs::remove_dir_all(dir).ok();
}

fn gonio_fuzz_seed(target: &str, name: &str) -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../fuzz/corpus")
        .join(target)
        .join(name)
}

/// A daemon killed three times while the same step runs (an impatient operator, a
/// power cut) has not crashed: the step left no fault, and the scan completes (it
/// once failed, "crashed the daemon 3 times", with no bad input at all).
#[test]
fn kills_while_a_step_runs_are_not_crashes() {
    let dir = temp_dir("harden-kills");
    // Slow motion: the move step lasts long enough to be killed in.
    let daemon = Daemon::start(&dir, &emulator_config_scaled(1.0, 0.05));
    let id = daemon.post_gold_scan(&[-80.0], &[0.01]);
    let daemon = end_three_times_during_the_move(&dir, daemon, id, |daemon, _| daemon.kill9());
    let scan = daemon.wait_state(id, &["done", "failed"], Duration::from_secs(120));
    assert_eq!(scan["state"], "done", "{scan}");
    std::fs::remove_dir_all(dir).ok();
}

/// The HDR maps of scan `id` whose step is done, with their inode and modification time.
fn maps_done(daemon: &Daemon, id: i64) -> Vec<(String, (u64, std::time::SystemTime))> {
    use std::os::unix::fs::MetadataExt;
    let steps = daemon.get(&format!("/api/scans/{id}/steps")).json;
    steps
        .as_array()
        .unwrap()
        .iter()
        .filter(|s| s["step"]["kind"] == "hdr" && s["state"] == "done")
        .map(|s| {
            let rel = s["result"]["path"].as_str().unwrap().to_owned();
            let meta = std::fs::metadata(daemon.data.join(format!("scans/{id}/{rel}"))).unwrap();
            (rel, (meta.ino(), meta.modified().unwrap()))
        })
        .collect()
}

/// Whether an HDR step of scan `id` runs now.
fn hdr_running(daemon: &Daemon, id: i64) -> bool {
    let steps = daemon.get(&format!("/api/scans/{id}/steps")).json;
    steps
        .as_array()
        .unwrap()
        .iter()
        .any(|s| s["step"]["kind"] == "hdr" && s["state"] == "started")
}

/// kill -9 while the background HDR merges of a six-θL scan run, three times, each once
/// more maps are done: the maps made before each kill are kept (same inode, same
/// modification time: not merged again), the scan ends done, and every map is exactly
/// what `gonio hdr` makes of its frames, as an uninterrupted merge would be, and
/// `samples.csv` what `gonio extract` makes of the scan.
#[test]
fn kills_during_the_hdr_merges_keep_the_maps_already_made() {
    let dir = temp_dir("harden-hdr-kills");
    let mut daemon = Daemon::start(&dir, &emulator_config(0.05));
    let theta_l = [-20.0, -25.0, -30.0, -35.0, -40.0, -45.0];
    let id = daemon.post_gold_scan(&theta_l, &[0.5, 0.1, 0.02]);
    let mut kept: Vec<(String, (u64, std::time::SystemTime))> = Vec::new();
    let mut during_merge = 0;
    for round in 0..3 {
        let deadline = Instant::now() + Duration::from_secs(60);
        let done = loop {
            let done = maps_done(&daemon, id);
            if done.len() > kept.len() && hdr_running(&daemon, id) {
                break done;
            }
            assert!(
                done.len() < theta_l.len() && Instant::now() < deadline,
                "round {round}: no merge to kill after {} maps: {done:?}",
                kept.len()
            );
            std::thread::sleep(Duration::from_millis(5));
        };
        daemon.kill9();
        during_merge += 1;
        kept = done;
        daemon = Daemon::restart(&dir);
        // What was done before the kill is still done, and the map is the same file.
        let now = maps_done(&daemon, id);
        for map in &kept {
            assert!(
                now.contains(map),
                "round {round}: {map:?} not kept in {now:?}"
            );
        }
    }
    let scan = daemon.wait_state(id, &["done", "failed"], Duration::from_secs(120));
    assert_eq!(scan["state"], "done", "{scan}");
    assert_eq!(during_merge, 3);
    let all = maps_done(&daemon, id);
    assert_eq!(all.len(), theta_l.len(), "{all:?}");
    for map in &kept {
        assert!(all.contains(map), "{map:?} merged again: {all:?}");
    }
    // Every map equals a merge of its frames in one go.
    let scan_dir = daemon.data.join(format!("scans/{id}"));
    for theta in theta_l {
        let frames: Vec<String> =
            gonio_tests::files_under(&scan_dir.join(format!("theta_l_{theta:.1}")))
                .into_iter()
                .filter(|f| f.ends_with(".tiff"))
                .map(|f| {
                    scan_dir
                        .join(format!("theta_l_{theta:.1}/{f}"))
                        .display()
                        .to_string()
                })
                .collect();
        assert_eq!(frames.len(), 3, "{frames:?}");
        let fresh = dir.join(format!("fresh_{theta:.1}.exr"));
        let mut args = vec!["hdr", "--out", fresh.to_str().unwrap()];
        args.extend(frames.iter().map(String::as_str));
        gonio_tests::gonio(&args);
        let made = std::fs::read(scan_dir.join(format!("hdr/theta_l_{theta:.1}.exr"))).unwrap();
        assert!(
            made == std::fs::read(&fresh).unwrap(),
            "θL {theta}: the map differs"
        );
    }
    // And the samples are those of the whole scan extracted in one go.
    let extracted = dir.join("extracted.csv");
    let scan_arg = scan_dir.display().to_string();
    gonio_tests::gonio(&["extract", &scan_arg, "--out", extracted.to_str().unwrap()]);
    assert!(
        std::fs::read(scan_dir.join("samples.csv")).unwrap() == std::fs::read(&extracted).unwrap(),
        "samples.csv differs from gonio extract's"
    );
    std::fs::remove_dir_all(dir).ok();
}

/// A step that crashes the daemon (the camera library aborts at its capture) three
/// times fails its scan at the next start ("crashed the daemon 3 times"), and the next
/// scan runs. The daemon records each fault with the lane it happened in.
#[test]
fn a_step_that_crashes_the_daemon_three_times_fails_its_scan() {
    use std::os::unix::process::ExitStatusExt;
    let dir = temp_dir("harden-crashloop");
    // A slow arm: after each start it homes and moves for seconds before the capture
    // runs again, time to inject the fault again.
    let mut daemon = Daemon::start(&dir, &emulator_config_scaled(1.0, 0.05));
    let looping = daemon.post_gold_scan(&[-80.0], &[0.01]);
    let next = daemon.post_gold_scan(&[-20.0], &[0.01]);
    for _ in 0..3 {
        let answer = daemon.post("/api/emulator/fault", &json!({"fault": "camera_abort"}));
        assert_eq!(answer.status, 200, "{:?}", answer.json);
        let status = daemon.wait_exit(Duration::from_secs(120));
        assert_eq!(status.signal(), Some(libc::SIGABRT), "{status}");
        let record = std::fs::read_to_string(dir.join("data/daemon.fault")).unwrap();
        assert_eq!(record, "hardware signal 6\n");
        daemon = Daemon::restart(&dir);
    }
    let scan = daemon.get(&format!("/api/scans/{looping}")).json;
    assert_eq!(scan["state"], "failed", "{scan}");
    let error = scan["error"].as_str().unwrap();
    assert!(
        error.starts_with("step \"capture θL -80.0° exposure 0")
            && error.ends_with("crashed the daemon 3 times"),
        "{error}"
    );
    let next = daemon.wait_state(next, &["done", "failed"], Duration::from_secs(120));
    assert_eq!(next["state"], "done", "{next}");
    std::fs::remove_dir_all(dir).ok();
}

/// A daemon stopped on SIGINT or SIGTERM while a step runs has not crashed: three such
/// stops during the same step leave its scan to complete at the next start.
#[test]
fn stops_on_a_signal_are_not_crashes() {
    let dir = temp_dir("harden-stops");
    // Slow motion: the move step lasts long enough to be stopped in.
    let daemon = Daemon::start(&dir, &emulator_config_scaled(1.0, 0.05));
    let id = daemon.post_gold_scan(&[-80.0], &[0.01]);
    let daemon = end_three_times_during_the_move(&dir, daemon, id, |daemon, round| {
        let signal = [libc::SIGINT, libc::SIGTERM, libc::SIGINT][round];
        let status = daemon.stop_with(signal, Duration::from_secs(60));
        assert!(status.success(), "stopped on signal {signal}: {status}");
    });
    let scan = daemon.wait_state(id, &["done", "failed"], Duration::from_secs(120));
    assert_eq!(scan["state"], "done", "{scan}");
    std::fs::remove_dir_all(dir).ok();
}

/// The largest body allowed (64 KB) asking for billions of steps is refused with 422
/// naming the field, and nothing is queued (how fast is printed, as a figure).
#[test]
fn an_amplifying_sweep_is_refused_before_anything_is_inserted() {
    let dir = temp_dir("harden-amplify");
    let daemon = Daemon::start(&dir, &emulator_config(0.01));
    // The 179 angles -1°, -1.5°, ..., -90° (the default soft limits).
    let theta: Vec<f64> = (2..=180).map(|k| -(k as f64) / 2.0).collect();
    let sweep =
        |samples: &[String]| json!({"samples": samples, "theta_l_sets": [theta], "repeats": 1000});
    // Each sample name adds 9 bytes (`"s00000",`): as many as fit in 60,000 bytes.
    let room = 60_000 - sweep(&[]).to_string().len();
    let samples: Vec<String> = (0..room / 9).map(|k| format!("s{k:05}")).collect();
    let body = sweep(&samples);
    assert!(body.to_string().len() <= 60_000);
    let started = Instant::now();
    let answer = daemon.post("/api/sweeps", &body);
    let ms = started.elapsed().as_secs_f64() * 1e3;
    assert_eq!(answer.status, 422, "{:?}", answer.json);
    // One round of the samples × θL sets already exceeds the bound: not `repeats`.
    assert_eq!(answer.json["field"], "samples", "{:?}", answer.json);
    assert_eq!(daemon.get("/api/scans").json, json!([]));
    eprintln!(
        "a {}-byte sweep for {} samples × 179 θL × 1000 repeats refused in {ms:.1} ms",
        body.to_string().len(),
        samples.len()
    );
    std::fs::remove_dir_all(dir).ok();
}

/// Links in a scan directory are neither served nor listed; a FIFO is refused at
/// once (opening it once blocked a thread for good: ~530 of them starved every route
/// but health).
#[test]
fn the_files_route_follows_no_link() {
    let dir = temp_dir("harden-links");
    let daemon = Daemon::start(&dir, &emulator_config(0.01));
    let id = daemon.post_gold_scan(&[-20.0], &[0.5]);
    daemon.wait_state(id, &["done", "failed"], Duration::from_secs(60));
    let secret = dir.join("secret");
    std::fs::create_dir_all(&secret).unwrap();
    std::fs::write(secret.join("shadow"), "root:x").unwrap();
    let scan_dir = daemon.data.join(format!("scans/{id}"));
    std::os::unix::fs::symlink(secret.join("shadow"), scan_dir.join("shadow.csv")).unwrap();
    std::os::unix::fs::symlink(&secret, scan_dir.join("etc")).unwrap();
    let fifo = scan_dir.join("fifo.csv");
    assert!(std::process::Command::new("mkfifo")
        .arg(&fifo)
        .status()
        .unwrap()
        .success());
    for path in ["shadow.csv", "etc/shadow", "fifo.csv"] {
        let asked = Instant::now();
        let answer = daemon.get(&format!("/api/scans/{id}/files/{path}"));
        assert_eq!(answer.status, 404, "{path}: {:?}", answer.bytes);
        assert!(answer.json["error"].is_string());
        assert!(
            asked.elapsed() < Duration::from_secs(10),
            "{path} took {:?}",
            asked.elapsed()
        );
    }
    let listing = daemon.get(&format!("/api/scans/{id}/files")).json;
    let names: Vec<&str> = listing
        .as_array()
        .unwrap()
        .iter()
        .filter_map(Value::as_str)
        .collect();
    assert!(names.contains(&"samples.csv"), "{names:?}");
    assert!(!names.iter().any(|n| n.contains("shadow")), "{names:?}");
    std::fs::remove_dir_all(dir).ok();
}

/// A foreign Host (a DNS-rebinding page) gets 421; non-JSON bodies 415; every 4xx is
/// JSON; 0 and -0.0 are one angle; the bearer scheme is case-insensitive.
#[test]
fn host_content_type_error_shape_and_scheme() {
    let dir = temp_dir("harden-http");
    // θL up to 0 allowed, so that 0 and -0.0 can be asked for.
    let config = format!(
        "header_timeout_s = 2.0\n{}\n[limits]\nmin_deg = -90.0\nmax_deg = 0.0\n",
        emulator_config(0.01)
    );
    let daemon = Daemon::start(&dir, &config);
    let addr = daemon.addr();
    let request = |head: &str, body: &str| {
        raw_http(
            addr,
            &format!(
                "{head}\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{body}",
                body.len()
            ),
        )
    };
    let (status, body) = request("GET /api/scans HTTP/1.1\r\nHost: rebind.evil.example", "");
    assert_eq!(status, 421, "{body}");
    assert!(body.contains("rebind.evil.example"), "{body}");
    let (status, _) = request(&format!("GET /api/scans HTTP/1.1\r\nHost: {addr}"), "");
    assert_eq!(status, 200);
    let (status, _) = request("GET /api/health HTTP/1.1\r\nHost: localhost:1", "");
    assert_eq!(status, 200);

    let scan = r#"{"sample":"gold","theta_l":[-20]}"#;
    let post = |content_type: &str, auth: &str| {
        request(
            &format!(
                "POST /api/scans HTTP/1.1\r\nHost: {addr}\r\nAuthorization: {auth}\r\n{content_type}"
            ),
            scan,
        )
    };
    let (status, body) = post("Content-Type: text/plain", &format!("Bearer {TOKEN}"));
    assert_eq!(status, 415, "{body}");
    let (status, body) = post("X-None: 1", &format!("Bearer {TOKEN}"));
    assert_eq!(status, 415, "{body}");
    let (status, body) = post(
        "Content-Type: application/json; charset=utf-8",
        &format!("bearer {TOKEN}"),
    );
    assert_eq!(status, 201, "{body}");

    // axum's own rejections, in the API's JSON shape (on a route that needs the
    // token, the token is checked before the method), and hyper's own answers to what
    // it cannot parse (a bad header, a URI too long), in the same shape.
    let long_uri = format!("GET /{} HTTP/1.1", "a".repeat(70_000));
    for (head, want) in [
        ("GET /api/scans/abc HTTP/1.1", 400),
        ("GET /api/nothing-here HTTP/1.1", 404),
        ("DELETE /api/hardware HTTP/1.1", 405),
        ("DELETE /api/scans HTTP/1.1", 401),
        ("GET /api/scans HTTP/1.1\r\nBad Header", 400),
        (&long_uri, 414),
    ] {
        let (status, body) = request(&format!("{head}\r\nHost: {addr}"), "");
        let head = &head[..head.len().min(40)];
        assert_eq!(status, want, "{head}: {body}");
        let value: Value = serde_json::from_str(&body).unwrap_or_else(|_| panic!("{head}: {body}"));
        assert!(
            value["error"].as_str().is_some_and(|e| !e.is_empty()),
            "{body}"
        );
    }
    let big = "x".repeat(70_000);
    let (status, body) = request(
        &format!("POST /api/scans HTTP/1.1\r\nHost: {addr}\r\nAuthorization: Bearer {TOKEN}\r\nContent-Type: application/json"),
        &big,
    );
    assert_eq!(status, 413, "{body}");
    assert!(serde_json::from_str::<Value>(&body).is_ok(), "{body}");
    // A method a JSON route does not serve is 405, whatever its Content-Type.
    let (status, body) = request(
        &format!("DELETE /api/sweeps/1 HTTP/1.1\r\nHost: {addr}\r\nAuthorization: Bearer {TOKEN}"),
        "",
    );
    assert_eq!(status, 405, "{body}");
    // A body that stops coming: 408 once header_timeout_s has passed, not a wait
    // without end.
    {
        use std::io::{Read, Write};
        let mut socket = TcpStream::connect(addr).unwrap();
        socket
            .set_read_timeout(Some(Duration::from_secs(30)))
            .unwrap();
        let started = Instant::now();
        write!(
            socket,
            "POST /api/scans HTTP/1.1\r\nHost: {addr}\r\nAuthorization: Bearer {TOKEN}\r\n\
             Content-Type: application/json\r\nContent-Length: 100\r\n\r\n{{\"sample\":"
        )
        .unwrap();
        let mut answer = String::new();
        socket.read_to_string(&mut answer).unwrap();
        assert!(answer.starts_with("HTTP/1.1 408"), "{answer}");
        assert!(answer.contains("header_timeout_s"), "{answer}");
        assert!(
            started.elapsed().as_secs_f64() < 20.0,
            "{:?}",
            started.elapsed()
        );
    }

    let answer = daemon.post("/api/scans", &json!({"sample": "g", "theta_l": [0, -0.0]}));
    assert_eq!(answer.status, 422);
    assert_eq!(answer.json["field"], "theta_l[1]");

    // The emergency stop needs no token, but a browser's page of another site cannot
    // make it (its Origin is not the daemon's); the daemon's own page can.
    let (status, body) = request(
        &format!("POST /api/arm/stop HTTP/1.1\r\nHost: {addr}\r\nOrigin: http://evil.example"),
        "",
    );
    assert_eq!(status, 403, "{body}");
    assert_eq!(daemon.get("/api/hardware").json["halted"], false);
    let (status, body) = request(
        &format!("POST /api/arm/stop HTTP/1.1\r\nHost: {addr}\r\nOrigin: http://{addr}"),
        "",
    );
    assert_eq!(status, 200, "{body}");
    assert_eq!(daemon.get("/api/hardware").json["halted"], true);

    // The API's description lists these answers where they apply.
    let paths = &daemon.get("/api/openapi.json").json["paths"];
    for (path, method, code) in [
        ("/api/scans", "post", "415"),
        ("/api/scans", "post", "421"),
        ("/api/scans", "get", "421"),
        ("/api/scans/{id}/events", "get", "503"),
    ] {
        assert!(
            paths[path][method]["responses"][code].is_object(),
            "{method} {path} lacks {code}"
        );
    }
    std::fs::remove_dir_all(dir).ok();
}

/// Event streams beyond `max_event_streams` get a clear 503 in the API's error shape;
/// the streams already open go on, and end with the scan's final state (they once
/// stayed open until another event of that scan came), as does a stream opened on an
/// ended scan.
#[test]
fn event_streams_beyond_the_cap_get_503() {
    use std::io::{Read, Write};
    let dir = temp_dir("harden-sse");
    let config = format!("max_event_streams = 2\n{}", emulator_config(0.01));
    let daemon = Daemon::start(&dir, &config);
    // A paused scan: its stream stays open.
    let id = daemon.post_gold_scan(&[-20.0], &[0.5]);
    daemon.post(&format!("/api/scans/{id}/pause"), &json!({}));
    daemon.wait_state(id, &["paused"], Duration::from_secs(30));
    let request = format!(
        "GET /api/scans/{id}/events HTTP/1.1\r\nHost: {}\r\n\r\n",
        daemon.addr()
    );
    let open_stream = || {
        let mut stream = TcpStream::connect(daemon.addr()).unwrap();
        stream
            .set_read_timeout(Some(Duration::from_secs(30)))
            .unwrap();
        stream.write_all(request.as_bytes()).unwrap();
        let mut head = Vec::new();
        let mut byte = [0u8];
        while !head.ends_with(b"\r\n\r\n") && stream.read(&mut byte).unwrap() == 1 {
            head.push(byte[0]);
        }
        (stream, String::from_utf8_lossy(&head).into_owned())
    };
    let streams: Vec<_> = (0..2).map(|_| open_stream()).collect();
    for (_, head) in &streams {
        assert!(head.starts_with("HTTP/1.1 200"), "{head}");
        assert!(head.contains("text/event-stream"), "{head}");
    }
    let (status, body) = raw_http(
        daemon.addr(),
        &format!(
            "GET /api/scans/{id}/events HTTP/1.1\r\nHost: {}\r\nConnection: close\r\n\r\n",
            daemon.addr()
        ),
    );
    assert_eq!(status, 503, "{body}");
    let error: Value = serde_json::from_str(&body).unwrap();
    assert!(
        error["error"]
            .as_str()
            .is_some_and(|e| e.contains("max_event_streams")),
        "{body}"
    );
    // The open streams still deliver: a cancel reaches both, and ends them.
    daemon.post(&format!("/api/scans/{id}/cancel"), &json!({}));
    // The body is chunked: it ends with the last, empty chunk.
    let read_to_end = |mut stream: TcpStream| {
        stream
            .set_read_timeout(Some(Duration::from_secs(10)))
            .unwrap();
        let mut seen = Vec::new();
        let mut chunk = [0u8; 4096];
        while !seen.ends_with(b"\r\n0\r\n\r\n") {
            match stream.read(&mut chunk) {
                Ok(n) if n > 0 => seen.extend_from_slice(&chunk[..n]),
                other => panic!(
                    "the stream did not end: {other:?}, {}",
                    String::from_utf8_lossy(&seen)
                ),
            }
        }
        String::from_utf8_lossy(&seen).into_owned()
    };
    for (stream, _) in streams {
        let seen = read_to_end(stream);
        assert!(
            seen.contains("cancelled"),
            "stream ended without the cancel: {seen}"
        );
    }
    let (stream, head) = open_stream();
    assert!(head.starts_with("HTTP/1.1 200"), "{head}");
    let seen = read_to_end(stream);
    assert_eq!(seen.matches("event: progress").count(), 1, "{seen}");
    assert!(seen.contains("cancelled"), "{seen}");
    std::fs::remove_dir_all(dir).ok();
}
