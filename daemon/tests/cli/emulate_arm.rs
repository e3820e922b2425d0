//! `gonio emulate-arm`: the emulator alone on a pseudo-terminal at a given path, answering
//! a serial client as GRBL 1.1h does, until interrupted; bad configurations refused.

use std::io::{Read, Write};
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

fn gonio_emulate(link: &Path, config: Option<&Path>) -> std::process::Child {
    let mut command = Command::new(env!("CARGO_BIN_EXE_gonio"));
    command.arg("emulate-arm").arg("--link").arg(link);
    if let Some(config) = config {
        command.arg("--config").arg(config);
    }
    command
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

/// Read from `port` until `expected` has arrived (or 5 s pass).
fn expect(port: &mut dyn serialport::SerialPort, expected: &str) {
    let deadline = Instant::now() + Duration::from_secs(5);
    let mut got = Vec::new();
    let mut buf = [0u8; 256];
    while got.len() < expected.len() && Instant::now() < deadline {
        if let Ok(n) = port.read(&mut buf) {
            got.extend_from_slice(&buf[..n]);
        }
    }
    assert_eq!(String::from_utf8_lossy(&got), expected);
}

#[test]
fn serves_the_configured_board_until_interrupted() {
    let dir = tempfile::tempdir().unwrap();
    let link = dir.path().join("ttyGRBL");
    let config = dir.path().join("board.toml");
    std::fs::write(
        &config,
        "time_scale = 0.01\nhoming_enabled = true\nhoming_cycles = [\"X\"]\nstatus_extras = false\n",
    )
    .unwrap();
    let beside = dir.path().join("ttyGRBL.new");
    std::fs::write(&beside, "keep").unwrap();
    let mut child = gonio_emulate(&link, Some(&config));
    let deadline = Instant::now() + Duration::from_secs(10);
    while !link.exists() {
        assert!(Instant::now() < deadline, "no device link");
        std::thread::sleep(Duration::from_millis(10));
    }
    let mut port = serialport::new(link.to_str().unwrap(), 115_200)
        .timeout(Duration::from_millis(20))
        .open()
        .unwrap();
    // Opening resets the board; homing is on, so it greets locked.
    expect(
        port.as_mut(),
        "\r\nGrbl 1.1h ['$' for help]\r\n[MSG:'$H'|'$X' to unlock]\r\n",
    );
    port.write_all(b"$H\n").unwrap();
    expect(port.as_mut(), "ok\r\n");
    port.write_all(b"?").unwrap();
    expect(port.as_mut(), "<Idle|MPos:-1.000,0.000,0.000|FS:0,0>\r\n");
    // SIGTERM: a clean exit, the device gone.
    let pid = child.id().to_string();
    assert!(Command::new("kill").arg(&pid).status().unwrap().success());
    let status = child.wait().unwrap();
    assert!(status.success(), "{status:?}");
    let mut stdout = String::new();
    child
        .stdout
        .take()
        .unwrap()
        .read_to_string(&mut stdout)
        .unwrap();
    assert!(stdout.contains("GRBL 1.1h emulator on"), "{stdout}");
    assert!(!link.exists() && std::fs::symlink_metadata(&link).is_err());
    // Files beside the link that are not the emulator's stay (`ttyGRBL.new` was once
    // taken for its temporary link and deleted).
    assert_eq!(std::fs::read_to_string(&beside).unwrap(), "keep");
}

#[test]
fn bad_configurations_and_links_are_refused_in_one_line() {
    let dir = tempfile::tempdir().unwrap();
    let link = dir.path().join("ttyGRBL");
    let config = dir.path().join("board.toml");
    for (text, named) in [
        ("time_scale = 0\n", "time_scale"),
        ("steps = 80\n", "steps"),
        ("homing_cycles = [\"XW\"]\n", "'W' is not an axis"),
        ("soft_limits = true\n", "soft_limits"),
    ] {
        std::fs::write(&config, text).unwrap();
        let output = gonio_emulate(&link, Some(&config))
            .wait_with_output()
            .unwrap();
        assert!(!output.status.success());
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert!(stderr.contains(named), "{text}: {stderr}");
        assert_eq!(stderr.trim_end().lines().count(), 1, "{text}: {stderr}");
    }
    // Devices and FIFOs are no configuration: refused unread, at once.
    let fifo = dir.path().join("board.fifo");
    assert!(Command::new("mkfifo")
        .arg(&fifo)
        .status()
        .unwrap()
        .success());
    for (config, what) in [
        (Path::new("/dev/zero"), "a character device"),
        (Path::new("/dev/urandom"), "a character device"),
        (fifo.as_path(), "a FIFO"),
    ] {
        let output = gonio_emulate(&link, Some(config))
            .wait_with_output()
            .unwrap();
        assert!(!output.status.success());
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert!(
            stderr.contains(&format!("not a regular file ({what})")),
            "{stderr}"
        );
        assert_eq!(stderr.trim_end().lines().count(), 1, "{stderr}");
    }
    // A regular file at the link path is left alone.
    std::fs::write(&link, "keep").unwrap();
    let output = gonio_emulate(&link, None).wait_with_output().unwrap();
    assert!(!output.status.success());
    assert!(String::from_utf8_lossy(&output.stderr).contains("not a symlink"));
    assert_eq!(std::fs::read_to_string(&link).unwrap(), "keep");
}
