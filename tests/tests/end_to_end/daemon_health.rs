//! What the daemon reports of itself and holds to, on emulated hardware: health with a
//! full disk and a disconnected arm, a confirm that cannot mount its sample, and one
//! daemon per data directory whatever happens to the files in it. Loopback only; each
//! test bounded in time.

use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use gonio_tests::{emulator_config, gonio_bin, temp_dir, with_small_red_sample, Daemon, TOKEN};
use serde_json::{json, Value};

fn health(daemon: &Daemon) -> Value {
    let answer = daemon.get("/api/health");
    assert_eq!(answer.status, 200);
    answer.json
}

/// Health says `disk_full` while the data directory's free space is below the reserve
/// (it said "ok" on a full disk), `degraded` with `arm_disconnected` once the arm is
/// unplugged, `ok` otherwise.
#[test]
fn health_reports_a_full_disk_and_a_disconnected_arm() {
    let dir = temp_dir("health");
    let free = dir.join("free");
    std::fs::write(&free, "100000000000").unwrap();
    let config = format!(
        "{}free_space_file = {:?}\n",
        emulator_config(0.01),
        free.display().to_string()
    );
    let daemon = Daemon::start(&dir, &config);
    // The arm is disconnected until the hardware lane has opened it.
    daemon.wait_for("/api/health", Duration::from_secs(30), |h| {
        h["status"] == "ok"
    });
    std::fs::write(&free, "0").unwrap();
    let full = health(&daemon);
    assert_eq!(full["status"], "disk_full", "{full}");
    assert_eq!(full["problems"], json!(["disk_full"]));
    assert_eq!(full["disk_free_bytes"], 0);
    std::fs::write(&free, "100000000000").unwrap();
    assert_eq!(health(&daemon)["status"], "ok");
    let answer = daemon.post("/api/emulator/fault", &json!({ "fault": "unplug" }));
    assert_eq!(answer.status, 200, "{:?}", answer.json);
    daemon.wait_for("/api/hardware", Duration::from_secs(30), |hw| {
        hw["arm"]["state"] == "disconnected"
    });
    let degraded = health(&daemon);
    assert_eq!(degraded["status"], "degraded", "{degraded}");
    assert!(degraded["problems"]
        .as_array()
        .unwrap()
        .contains(&json!("arm_disconnected")));
    std::fs::remove_dir_all(dir).ok();
}

/// Confirming a sample whose scene file has gone is the operator's to fix: 409 naming
/// the file, no path of the server (it was a 500 with the absolute path).
#[test]
fn a_confirm_that_cannot_mount_its_sample_is_a_conflict_naming_no_server_path() {
    let dir = temp_dir("health-confirm");
    let config = with_small_red_sample(&emulator_config(0.01), &dir);
    let daemon = Daemon::start(&dir, &config);
    let answer = daemon.post(
        "/api/scans",
        &json!({"sample": "red", "theta_l": [-20.0], "bracket": {"shutter_s": [0.5]}}),
    );
    assert_eq!(answer.status, 201, "{:?}", answer.json);
    let id = answer.json["id"].as_i64().unwrap();
    daemon.wait_state(id, &["waiting"], Duration::from_secs(60));
    std::fs::remove_file(dir.join("red.toml")).unwrap();
    let answer = daemon.post(&format!("/api/scans/{id}/confirm"), &json!({}));
    assert_eq!(answer.status, 409, "{:?}", answer.json);
    let error = answer.json["error"].as_str().unwrap();
    assert!(error.contains("red.toml"), "{error}");
    assert!(!error.contains(&dir.display().to_string()), "{error}");
    assert!(!error.contains("/tmp"), "{error}");
    assert_eq!(
        daemon.get(&format!("/api/scans/{id}")).json["state"],
        "waiting"
    );
    std::fs::remove_dir_all(dir).ok();
}

/// A second daemon on the same data directory is refused even after `daemon.lock`
/// (the lock file of earlier versions) is removed: the lock is the OS's, on the
/// directory, not a file's presence.
#[test]
fn a_second_daemon_cannot_share_the_data_directory_without_its_lock_file() {
    let dir = temp_dir("health-lock");
    let first = Daemon::start(&dir, &emulator_config(0.01));
    let _ = std::fs::remove_file(first.data.join("daemon.lock"));
    let mut second = Command::new(gonio_bin())
        .arg("serve")
        .arg("--config")
        .arg(dir.join("gonio.toml"))
        .arg("--data")
        .arg(&first.data)
        .args(["--bind", "127.0.0.1:0"])
        .env("GONIO_TOKEN", TOKEN)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let deadline = Instant::now() + Duration::from_secs(30);
    let status = loop {
        if let Some(status) = second.try_wait().unwrap() {
            break Some(status);
        }
        if Instant::now() > deadline {
            break None;
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    let Some(status) = status else {
        let _ = second.kill();
        let _ = second.wait();
        panic!("a second daemon runs on the same data directory");
    };
    let mut stderr = String::new();
    std::io::Read::read_to_string(&mut second.stderr.take().unwrap(), &mut stderr).unwrap();
    assert!(!status.success());
    assert!(stderr.contains("another gonio serve"), "{stderr}");
    // The first daemon still serves.
    assert_eq!(first.get("/api/health").status, 200);
    std::fs::remove_dir_all(dir).ok();
}
