//! The daemon's files on disk, on emulated hardware: temporaries of writes cut short
//! are removed from every scan, finished ones included.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use gonio_tests::{emulator_config_scaled, temp_dir, Daemon};
use serde_json::json;

fn post_scan(daemon: &Daemon, theta_l: &[f64], shutter_s: &[f64]) -> i64 {
    let answer = daemon.post(
        "/api/scans",
        &json!({"sample": "gold", "theta_l": theta_l, "bracket": {"shutter_s": shutter_s}}),
    );
    assert_eq!(answer.status, 201, "{:?}", answer.json);
    answer.json["id"].as_i64().unwrap()
}

/// The id of a process that has ended (free until the system reuses it).
fn ended_process() -> u32 {
    let mut child = std::process::Command::new("true").spawn().unwrap();
    let pid = child.id();
    child.wait().unwrap();
    pid
}

/// Leaves the temporary of a write by `pid`, cut short, in `dir`; returns its path.
fn leftover(dir: &Path, pid: u32) -> PathBuf {
    std::fs::create_dir_all(dir).unwrap();
    let path = dir.join(format!(".exp_00.tiff.{pid}.0.partial"));
    std::fs::write(&path, b"half a frame").unwrap();
    path
}

fn wait_gone(path: &Path, timeout: Duration) {
    let deadline = Instant::now() + timeout;
    while path.exists() {
        assert!(
            Instant::now() < deadline,
            "{} still there after {timeout:?}",
            path.display()
        );
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// A temporary left in a scan that ended (cancelled, here) is removed when it ends,
/// and one found in an ended scan at start is removed then (only active scans were
/// cleaned: it stayed forever). A temporary of a writer still running stays.
#[test]
fn temporaries_of_ended_scans_are_removed() {
    let dir = temp_dir("storage-partials");
    // The camera in real time: a 2 s exposure leaves time to cancel.
    let daemon = Daemon::start(&dir, &emulator_config_scaled(0.05, 1.0));
    let id = post_scan(&daemon, &[-20.0], &[2.0, 1.0]);
    daemon.wait_state(id, &["running"], Duration::from_secs(30));
    let scan_dir = daemon.data.join(format!("scans/{id}"));
    let frames = scan_dir.join("theta_l_-20.0");
    let cut_short = leftover(&frames, ended_process());
    // This test process stands for a writer still at work (a `gonio` command, say).
    let in_flight = leftover(&scan_dir, std::process::id());
    assert_eq!(
        daemon
            .post(&format!("/api/scans/{id}/cancel"), &json!({}))
            .status,
        200
    );
    daemon.wait_state(id, &["cancelled"], Duration::from_secs(30));
    wait_gone(&cut_short, Duration::from_secs(10));
    assert!(in_flight.exists());

    // A daemon dies with a write of the ended scan cut short; the next one removes it
    // before it runs anything.
    let cut_short = leftover(&frames, ended_process());
    daemon.kill9();
    let daemon = Daemon::restart(&dir);
    assert!(!cut_short.exists(), "left at start");
    assert!(in_flight.exists());
    assert_eq!(
        daemon.get(&format!("/api/scans/{id}")).json["state"],
        "cancelled"
    );
    drop(daemon);
    std::fs::remove_dir_all(dir).ok();
}

