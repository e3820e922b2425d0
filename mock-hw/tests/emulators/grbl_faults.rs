//! Every fault the GRBL emulator can inject, seen from a driver's side of the line.

use crate::grbl_support;

use std::io::ErrorKind;
use std::time::Duration;

use gonio_mock_hw::grbl::{Fault, GrblConfig, GrblEmulator};
use gonio_mock_hw::world::World;
use grbl_support::{fast_config, mpos_x, start, Client, LOCKED_BANNER};

/// A homed controller with a driver attached.
fn homed(arm_deg: f64) -> (GrblEmulator, World, Client) {
    // Slow enough that moves outlast a busy test machine's scheduling delays.
    let config = GrblConfig {
        time_scale: 0.03,
        ..fast_config()
    };
    let (emulator, world) = start(config, arm_deg);
    let mut grbl = Client::open(emulator.device_path());
    grbl.expect(LOCKED_BANNER);
    grbl.exchange("$H\n", "ok\r\n");
    (emulator, world, grbl)
}

#[test]
fn unplug_breaks_the_line_and_reconnect_reuses_the_path() {
    let (emulator, world, mut grbl) = homed(-10.0);
    grbl.exchange("G0X-20\nG4P0\n", "ok\r\nok\r\n");
    let link = emulator.device_path().to_path_buf();

    emulator.inject(Fault::Unplug);
    let mut buf = [0u8; 16];
    let read = grbl.port().read(&mut buf);
    let err = read.expect_err("read from an unplugged device");
    assert!(
        matches!(err.kind(), ErrorKind::BrokenPipe) || err.raw_os_error() == Some(5),
        "{err:?}"
    );
    assert!(grbl
        .port()
        .write_all(b"?")
        .and_then(|()| grbl.port().flush())
        .is_err());
    assert!(!link.exists(), "the device node disappears on unplug");
    assert!(serialport::new(link.to_str().unwrap(), 115_200)
        .open()
        .is_err());

    emulator.reconnect().unwrap();
    assert_eq!(emulator.device_path(), link);
    assert!(std::fs::read_link(&link).unwrap().exists());
    // The board powered up again: locked, machine position restarted at zero, while
    // the arm did not move.
    let mut grbl = Client::open(&link);
    grbl.expect(LOCKED_BANNER);
    grbl.exchange("?", "<Alarm|MPos:0.000,0.000,0.000|FS:0,0>\r\n");
    assert_eq!(world.arm_deg(), -20.0);
    grbl.exchange("$H\n", "ok\r\n");
    assert!((world.arm_deg() + 1.0).abs() < 1e-9);
}

/// A process started while the controller is plugged in (the daemon starts decode
/// workers and notification commands) must not keep the line up after an unplug.
#[test]
fn an_unplug_breaks_the_line_while_a_child_process_runs() {
    let (emulator, _world, mut grbl) = homed(-10.0);
    let mut child = std::process::Command::new("sleep")
        .arg("30")
        .spawn()
        .expect("sleep runs");
    emulator.inject(Fault::Unplug);
    let mut buf = [0u8; 16];
    let read = grbl.port().read(&mut buf);
    let _ = child.kill();
    let _ = child.wait();
    let err = read.expect_err("read from an unplugged device");
    assert!(
        matches!(err.kind(), ErrorKind::BrokenPipe) || err.raw_os_error() == Some(5),
        "{err:?}"
    );
}

#[test]
fn silent_controller_ignores_everything_until_responsive() {
    let (emulator, _world, mut grbl) = homed(0.0);
    emulator.inject(Fault::Silent);
    grbl.send(b"?$I\n");
    grbl.expect_silence(Duration::from_millis(100));
    emulator.inject(Fault::Responsive);
    grbl.exchange("?", "<Idle|MPos:-1.000,0.000,0.000|FS:0,0>\r\n");
    grbl.exchange("G4P0\n", "ok\r\n");
    // A hardware reset also ends a hang.
    emulator.inject(Fault::Silent);
    grbl.send(b"?");
    grbl.expect_silence(Duration::from_millis(50));
    emulator.inject(Fault::ResetBanner);
    grbl.expect(LOCKED_BANNER);
}

#[test]
fn garbled_and_truncated_replies_hit_one_line_each() {
    let (emulator, _world, mut grbl) = homed(0.0);
    emulator.inject(Fault::Garble);
    grbl.send(b"?");
    let mut garbled: Vec<u8> = b"<Idle|MPos:-1.000,0.000,0.000|FS:0,0>"
        .iter()
        .map(|b| b ^ 0xA5)
        .collect();
    garbled.extend_from_slice(b"\r\n");
    grbl.expect_bytes(&garbled);
    grbl.exchange("?", "<Idle|MPos:-1.000,0.000,0.000|FS:0,0>\r\n");

    emulator.inject(Fault::Truncate);
    // "[VER:1.1h.20190830:]" is cut to its first half, with no line ending.
    grbl.exchange("$I\n", "[VER:1.1h.[OPT:V,15,128]\r\nok\r\n");
    grbl.exchange("G4P0\n", "ok\r\n");
}

#[test]
fn hard_limit_alarm_during_motion_locks_until_reset() {
    let (emulator, world, mut grbl) = homed(0.0);
    emulator.inject(Fault::AlarmDuringMotion(1));
    grbl.exchange("G0X-90\nG4P0\n", "ok\r\n");
    grbl.expect("ALARM:1\r\n[MSG:Reset to continue]\r\n");
    // Nothing is answered, not even `?`, until the reset; the waiting dwell is then.
    grbl.send(b"?$X\n?");
    grbl.expect_silence(Duration::from_millis(30));
    grbl.send(b"\x18");
    grbl.expect("ok\r\n");
    grbl.expect(LOCKED_BANNER);
    let report = grbl.status();
    let x = mpos_x(&report);
    assert!(report.starts_with("<Alarm|"), "{report}");
    assert!((-50.0..=-44.0).contains(&x), "stopped half way: {report}");
    // The steppers stopped dead at 20°/s: the arm coasts 20²/(2·4·40) = 1.25° further
    // and the motor slips those steps.
    assert!(
        (x - world.arm_deg() - 1.25).abs() < 0.0125 + 1e-9,
        "{report}"
    );
    grbl.exchange("$X\n", "[MSG:Caution: Unlocked]\r\nok\r\n");
}

#[test]
fn unexpected_reset_banner_mid_run_loses_position() {
    let (emulator, world, mut grbl) = homed(0.0);
    grbl.exchange("G0X-60\n", "ok\r\n");
    grbl.wait_for_state("Run");
    emulator.inject(Fault::ResetBanner);
    grbl.expect(LOCKED_BANNER);
    let arm = world.arm_deg();
    assert!(
        arm < 0.0 && arm > -60.0,
        "stopped where the reset hit: {arm}"
    );
    grbl.exchange("?", "<Alarm|MPos:0.000,0.000,0.000|FS:0,0>\r\n");
    grbl.exchange("G0X-10\n", "error:9\r\n");
}

#[test]
fn drop_stops_the_emulator_and_removes_the_device() {
    let (emulator, _world) = start(fast_config(), 0.0);
    let link = emulator.device_path().to_path_buf();
    let mut grbl = Client::open(&link);
    grbl.expect(LOCKED_BANNER);
    drop(emulator);
    assert!(!link.exists());
    let mut buf = [0u8; 4];
    assert!(grbl.port().read(&mut buf).is_err());
}
