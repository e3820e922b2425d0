//! The daemon under hostile or careless clients, on emulated hardware: idle sockets,
//! contention on the operator controls, a corrupt capture, a crash loop, a request that
//! would create millions of steps, links in a scan directory, foreign Host headers and
//! the API's error shape. Loopback only; each test bounded in time.

use std::net::TcpStream;
use std::time::{Duration, Instant};

use gonio_tests::{emulator_config, raw_http, temp_dir, Daemon, TOKEN};
use serde_json::{json, Value};

fn post_scan(daemon: &Daemon, theta_l: &[f64], shutter_s: &[f64]) -> i64 {
    let answer = daemon.post(
        "/api/scans",
        &json!({"sample": "gold", "theta_l": theta_l, "bracket": {"shutter_s": shutter_s}}),
    );
    assert_eq!(answer.status, 201, "{:?}", answer.json);
    answer.json["id"].as_i64().unwrap()
}

/// Raises this test process's own descriptor limit so it can hold `n` sockets.
fn allow_open_files(n: u64) {
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

/// The daemon runs at the usual 1,024-descriptor limit it cannot raise; 2,000 idle
/// sockets are opened against it (they once starved it: health stopped answering and
/// the camera capture failed with "Too many open files"). Health answers and a scan
/// completes meanwhile.
#[test]
fn two_thousand_idle_sockets_starve_neither_health_nor_a_scan() {
    allow_open_files(4096);
    let dir = temp_dir("harden-idle");
    // Top-level keys must come before the tables of the emulator config.
    let config = format!("idle_timeout_s = 30\n{}", emulator_config(0.02));
    let daemon = Daemon::start_with_fd_limit(&dir, &config, Some(1024));
    let mut idle = Vec::new();
    for _ in 0..2000 {
        match TcpStream::connect_timeout(&daemon.addr().parse().unwrap(), Duration::from_secs(5)) {
            Ok(socket) => idle.push(socket),
            Err(err) => panic!("connect {} failed: {err}", idle.len()),
        }
    }
    let started = Instant::now();
    assert_eq!(daemon.get("/api/health").json, json!({"status": "ok"}));
    let health_s = started.elapsed().as_secs_f64();
    assert!(
        health_s < 5.0,
        "health took {health_s} s with 2000 idle sockets"
    );
    let id = post_scan(&daemon, &[-20.0, -30.0], &[0.5, 0.05]);
    let scan = daemon.wait_state(id, &["done", "failed"], Duration::from_secs(120));
    assert_eq!(scan["state"], "done", "{scan}");
    assert_eq!(daemon.get("/api/health").status, 200);
    eprintln!("2000 idle sockets held by the client; health in {health_s:.3} s; scan done");
    drop(idle);
    std::fs::remove_dir_all(dir).ok();
}

/// Pause, resume and cancel from 8 threads while a scan runs: every answer is 200 or
/// 409 (never "database is locked").
#[test]
fn controls_from_eight_threads_during_a_scan_never_error() {
    let dir = temp_dir("harden-controls");
    let daemon = Daemon::start(&dir, &emulator_config(0.05));
    let ids: Vec<i64> = (0..3)
        .map(|_| post_scan(&daemon, &[-20.0, -25.0], &[0.5, 0.05]))
        .collect();
    let started = Instant::now();
    let answers: Vec<(u16, Value)> = std::thread::scope(|scope| {
        let workers: Vec<_> = (0..8)
            .map(|t| {
                let (daemon, ids) = (&daemon, &ids);
                scope.spawn(move || {
                    let mut out = Vec::new();
                    for k in 0..40 {
                        let id = ids[(t + k) % ids.len()];
                        let verb = ["pause", "resume", "cancel", "resume"][(t * 7 + k) % 4];
                        let answer = daemon.post(&format!("/api/scans/{id}/{verb}"), &json!({}));
                        out.push((answer.status, answer.json));
                    }
                    out
                })
            })
            .collect();
        workers
            .into_iter()
            .flat_map(|w| w.join().unwrap())
            .collect()
    });
    let seconds = started.elapsed().as_secs_f64();
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
    eprintln!(
        "{} controls in {seconds:.2} s ({:.0}/s), 0 errors",
        answers.len(),
        answers.len() as f64 / seconds
    );
    std::fs::remove_dir_all(dir).ok();
}

/// A capture overwritten by one whose header claims 4 billion × 5 pixels: the HDR step
/// fails with a clear error (no panic, no abort, no wedged queue) and the next scan
/// runs.
#[test]
fn a_corrupt_frame_fails_its_step_and_the_queue_goes_on() {
    let dir = temp_dir("harden-corrupt");
    let daemon = Daemon::start(&dir, &emulator_config(0.05));
    let first = post_scan(&daemon, &[-20.0], &[0.5, 0.05]);
    // Pause once both captures are done, corrupt one, resume.
    daemon.wait_for(
        &format!("/api/scans/{first}"),
        Duration::from_secs(60),
        |scan| {
            scan["current_step"]
                .as_str()
                .is_some_and(|s| s.starts_with("capture θL -20.0° exposure 1"))
        },
    );
    assert_eq!(
        daemon
            .post(&format!("/api/scans/{first}/pause"), &json!({}))
            .status,
        200
    );
    let paused = daemon.wait_state(first, &["paused"], Duration::from_secs(30));
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
    let second = post_scan(&daemon, &[-25.0], &[0.5, 0.05]);
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
        error.contains("HDR merge") && error.contains("allowed"),
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

/// A daemon killed three times while the same step runs fails that scan on the next
/// start ("crashed the daemon 3 times") and runs the next one.
#[test]
fn a_step_that_kills_the_daemon_three_times_fails_its_scan() {
    let dir = temp_dir("harden-crashloop");
    // Slow motion: the move step lasts long enough to be killed in.
    let mut daemon = Daemon::start(&dir, &emulator_config(1.0));
    let looping = post_scan(&daemon, &[-80.0], &[0.5]);
    let next = post_scan(&daemon, &[-20.0], &[0.5]);
    for _ in 0..3 {
        daemon.wait_for(
            &format!("/api/scans/{looping}"),
            Duration::from_secs(60),
            |scan| {
                scan["current_step"].as_str() == Some("move to θL -80.0°")
                    && scan["progress"]["done"].as_u64() >= Some(1)
            },
        );
        // The move step is recorded as started before the arm moves.
        std::thread::sleep(Duration::from_millis(300));
        daemon.kill9();
        daemon = Daemon::restart(&dir);
    }
    let scan = daemon.get(&format!("/api/scans/{looping}")).json;
    assert_eq!(scan["state"], "failed", "{scan}");
    assert_eq!(
        scan["error"], "step \"move to θL -80.0°\" crashed the daemon 3 times",
        "{scan}"
    );
    let next = daemon.wait_state(next, &["done", "failed"], Duration::from_secs(120));
    assert_eq!(next["state"], "done", "{next}");
    std::fs::remove_dir_all(dir).ok();
}

/// The largest body allowed (64 KB) asking for billions of steps is refused with 422
/// naming the field, fast, and nothing is queued.
#[test]
fn an_amplifying_sweep_is_refused_before_anything_is_inserted() {
    let dir = temp_dir("harden-amplify");
    let daemon = Daemon::start(&dir, &emulator_config(0.01));
    let theta: Vec<f64> = (0..181).map(|k| -(k as f64) / 2.0).collect();
    let mut samples: Vec<String> = Vec::new();
    let mut body = json!({});
    for k in 0.. {
        samples.push(format!("s{k:05}"));
        let candidate = json!({"samples": samples, "theta_l_sets": [theta], "repeats": 1000});
        if candidate.to_string().len() > 60_000 {
            break;
        }
        body = candidate;
    }
    let started = Instant::now();
    let answer = daemon.post("/api/sweeps", &body);
    let ms = started.elapsed().as_secs_f64() * 1e3;
    assert_eq!(answer.status, 422, "{:?}", answer.json);
    // One round of the samples × θL sets already exceeds the bound: not `repeats`.
    assert_eq!(answer.json["field"], "samples", "{:?}", answer.json);
    assert!(ms < 2000.0, "refusal took {ms} ms");
    assert_eq!(daemon.get("/api/scans").json, json!([]));
    eprintln!(
        "a {}-byte sweep for {} samples × 181 θL × 1000 repeats refused in {ms:.1} ms",
        body.to_string().len(),
        samples.len() - 1
    );
    std::fs::remove_dir_all(dir).ok();
}

/// Links in a scan directory are neither served nor listed.
#[test]
fn the_files_route_follows_no_link() {
    let dir = temp_dir("harden-links");
    let daemon = Daemon::start(&dir, &emulator_config(0.01));
    let id = post_scan(&daemon, &[-20.0], &[0.5]);
    daemon.wait_state(id, &["done", "failed"], Duration::from_secs(60));
    let secret = dir.join("secret");
    std::fs::create_dir_all(&secret).unwrap();
    std::fs::write(secret.join("shadow"), "root:x").unwrap();
    let scan_dir = daemon.data.join(format!("scans/{id}"));
    std::os::unix::fs::symlink(secret.join("shadow"), scan_dir.join("shadow.csv")).unwrap();
    std::os::unix::fs::symlink(&secret, scan_dir.join("etc")).unwrap();
    for path in ["shadow.csv", "etc/shadow"] {
        let answer = daemon.get(&format!("/api/scans/{id}/files/{path}"));
        assert_eq!(answer.status, 404, "{path}: {:?}", answer.bytes);
        assert!(answer.json["error"].is_string());
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
    let daemon = Daemon::start(&dir, &emulator_config(0.01));
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

    // axum's own rejections, in the API's JSON shape.
    for (head, want) in [
        ("GET /api/scans/abc HTTP/1.1", 400),
        ("GET /api/nothing-here HTTP/1.1", 404),
        ("DELETE /api/scans HTTP/1.1", 405),
    ] {
        let (status, body) = request(&format!("{head}\r\nHost: {addr}"), "");
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

    let answer = daemon.post("/api/scans", &json!({"sample": "g", "theta_l": [0, -0.0]}));
    assert_eq!(answer.status, 422);
    assert_eq!(answer.json["field"], "theta_l[1]");
    std::fs::remove_dir_all(dir).ok();
}
