//! Scripted sessions against the emulated GRBL controller over its pseudo-terminal,
//! replies checked byte for byte. The stock-board bytes are those GRBL 1.1h
//! (1.1h.20190830) sends.

use crate::grbl_support;

use std::time::{Duration, Instant};

use gonio_mock_hw::grbl::{move_duration_s, GrblConfig};
use grbl_support::{fast_config, mpos_x, start, Client, BANNER, LOCKED_BANNER};

/// `$$` of a stock board (defaults.h, DEFAULTS_GENERIC), as the firmware prints it.
const STOCK_SETTINGS: &str = "$0=10\r\n$1=25\r\n$2=0\r\n$3=0\r\n$4=0\r\n$5=0\r\n$6=0\r\n\
$10=1\r\n$11=0.010\r\n$12=0.002\r\n$13=0\r\n$20=0\r\n$21=0\r\n$22=0\r\n$23=0\r\n\
$24=25.000\r\n$25=500.000\r\n$26=250\r\n$27=1.000\r\n$30=1000\r\n$31=0\r\n$32=0\r\n\
$100=250.000\r\n$101=250.000\r\n$102=250.000\r\n$110=500.000\r\n$111=500.000\r\n\
$112=500.000\r\n$120=10.000\r\n$121=10.000\r\n$122=10.000\r\n$130=200.000\r\n\
$131=200.000\r\n$132=200.000\r\nok\r\n";

/// `$$` of the board the other tests use ([`fast_config`]).
const ARM_SETTINGS: &str = "$0=10\r\n$1=25\r\n$2=0\r\n$3=0\r\n$4=0\r\n$5=0\r\n$6=0\r\n\
$10=1\r\n$11=0.010\r\n$12=0.002\r\n$13=0\r\n$20=1\r\n$21=0\r\n$22=1\r\n$23=0\r\n\
$24=100.000\r\n$25=600.000\r\n$26=250\r\n$27=1.000\r\n$30=1000\r\n$31=0\r\n$32=0\r\n\
$100=80.000\r\n$101=250.000\r\n$102=250.000\r\n$110=1200.000\r\n$111=500.000\r\n\
$112=500.000\r\n$120=40.000\r\n$121=10.000\r\n$122=10.000\r\n$130=180.000\r\n\
$131=200.000\r\n$132=200.000\r\nok\r\n";

#[test]
fn stock_board_session_byte_for_byte() {
    let (emulator, _world) = start(
        GrblConfig {
            time_scale: 0.01,
            ..GrblConfig::default()
        },
        0.0,
    );
    let mut grbl = Client::open(emulator.device_path());
    // Homing is off: the board greets unlocked.
    grbl.expect(BANNER);
    grbl.exchange("$$\n", STOCK_SETTINGS);
    grbl.exchange("$I\n", "[VER:1.1h.20190830:]\r\n[OPT:V,15,128]\r\nok\r\n");
    grbl.exchange("$H\n", "error:5\r\n");
    grbl.exchange("$X\n", "ok\r\n");
    // The first report after boot carries WCO, the next one the overrides; the arm
    // rests on its switch at θ = 0.
    grbl.exchange(
        "?",
        "<Idle|MPos:0.000,0.000,0.000|FS:0,0|Pn:X|WCO:0.000,0.000,0.000>\r\n",
    );
    grbl.exchange(
        "?",
        "<Idle|MPos:0.000,0.000,0.000|FS:0,0|Pn:X|Ov:100,100,100>\r\n",
    );
    grbl.exchange("?", "<Idle|MPos:0.000,0.000,0.000|FS:0,0|Pn:X>\r\n");
    // An operator declares where the arm is: the offset shows at once.
    grbl.exchange("G92X-12\n", "ok\r\n");
    grbl.exchange(
        "?",
        "<Idle|MPos:0.000,0.000,0.000|FS:0,0|Pn:X|WCO:12.000,0.000,0.000>\r\n",
    );
    grbl.exchange(
        "$#\n",
        "[G54:0.000,0.000,0.000]\r\n[G55:0.000,0.000,0.000]\r\n[G56:0.000,0.000,0.000]\r\n\
[G57:0.000,0.000,0.000]\r\n[G58:0.000,0.000,0.000]\r\n[G59:0.000,0.000,0.000]\r\n\
[G28:0.000,0.000,0.000]\r\n[G30:0.000,0.000,0.000]\r\n[G92:12.000,0.000,0.000]\r\n\
[TLO:0.000]\r\n[PRB:0.000,0.000,0.000:0]\r\nok\r\n",
    );
    // A soft reset forgets G92; the first report after it carries WCO again.
    grbl.send(b"\x18");
    grbl.expect(BANNER);
    grbl.exchange(
        "?",
        "<Idle|MPos:0.000,0.000,0.000|FS:0,0|Pn:X|WCO:0.000,0.000,0.000>\r\n",
    );
}

#[test]
fn scripted_session_byte_for_byte() {
    let (emulator, world) = start(fast_config(), -30.0);
    let mut grbl = Client::open(emulator.device_path());
    grbl.expect(LOCKED_BANNER);

    // Homing is enabled: motion is locked until $H or $X.
    grbl.exchange("G0X-10\n", "error:9\r\n");
    grbl.exchange("$$\n", ARM_SETTINGS);
    grbl.exchange(
        "$G\n",
        "[GC:G0 G54 G17 G21 G90 G94 M5 M9 T0 F0 S0]\r\nok\r\n",
    );
    grbl.exchange("?", "<Alarm|MPos:0.000,0.000,0.000|FS:0,0>\r\n");

    // Homing runs to the switch at the positive end (the arm is physically at −30°)
    // and pulls off by $27. The `?` sent during the cycle is answered at its end.
    grbl.send(b"$H\n?");
    grbl.expect("<Home|MPos:-1.000,0.000,0.000|FS:0,0>\r\nok\r\n");
    grbl.exchange("?", "<Idle|MPos:-1.000,0.000,0.000|FS:0,0>\r\n");
    assert!((world.arm_deg() + 1.0).abs() < 1e-9);

    // Settings: format and range errors as the firmware reports them.
    grbl.exchange("$110=abc\n", "error:2\r\n");
    grbl.exchange("$110\n", "error:3\r\n");
    grbl.exchange("$0=2\n", "error:6\r\n");
    grbl.exchange("$120=-5\n", "error:4\r\n");
    grbl.exchange("$130=180\n", "ok\r\n");
    grbl.exchange("G1X-10\n", "error:22\r\n");
    grbl.exchange("G5X1\n", "error:20\r\n");

    // An absolute move, answered at once; MPos follows the profile.
    grbl.exchange("G90G0X-45\n", "ok\r\n");
    let moving = grbl.wait_for_state("Run");
    let x = mpos_x(&moving);
    assert!((-45.0..=-1.0).contains(&x), "{moving}");
    grbl.wait_for_state("Idle");
    grbl.exchange("?", "<Idle|MPos:-45.000,0.000,0.000|FS:0,0>\r\n");
    assert_eq!(world.arm_deg(), -45.0);
    grbl.exchange("G91G0X5\nG90\n", "ok\r\nok\r\n");
    grbl.exchange("G4P0\n", "ok\r\n");
    grbl.exchange("?", "<Idle|MPos:-40.000,0.000,0.000|FS:0,0>\r\n");

    // A target past the soft limit: ALARM:2, then nothing is answered, not even `?`,
    // until a soft reset, which answers the line that raised the alarm.
    grbl.exchange("G0X-181\n", "ALARM:2\r\n[MSG:Reset to continue]\r\n");
    grbl.send(b"$X\n?");
    grbl.expect_silence(Duration::from_millis(50));
    grbl.send(b"\x18");
    grbl.expect("ok\r\n");
    grbl.expect(LOCKED_BANNER);
    grbl.exchange("$X\n", "[MSG:Caution: Unlocked]\r\nok\r\n");
    grbl.exchange("?", "<Idle|MPos:-40.000,0.000,0.000|FS:0,0>\r\n");
    assert_eq!(world.arm_deg(), -40.0);
}

#[test]
fn feed_hold_resume_and_soft_reset_mid_motion() {
    // Slow enough that the moves outlast a busy test machine's scheduling delays.
    let config = GrblConfig {
        time_scale: 0.03,
        ..fast_config()
    };
    let (emulator, world) = start(config, 0.0);
    let mut grbl = Client::open(emulator.device_path());
    grbl.expect(LOCKED_BANNER);
    grbl.exchange("$H\n", "ok\r\n");

    // 134° at 20°/s: about 210 ms of real time.
    grbl.exchange("G1X-135F1200\n", "ok\r\n");
    grbl.wait_for_state("Run");
    std::thread::sleep(Duration::from_millis(15));
    grbl.send(b"!");
    let held = grbl.wait_for_state("Hold:0");
    let x_held = mpos_x(&held);
    assert!(x_held < -1.0 && x_held > -135.0, "{held}");
    // A complete hold suspends the main loop: no line runs, none is answered.
    grbl.send(b"$$\nG0X-10\n");
    grbl.expect_silence(Duration::from_millis(30));
    grbl.exchange("?", &format!("{held}\r\n"));
    assert!((world.arm_deg() - x_held).abs() < 0.0125 + 1e-9);
    // Resumed: `$$` meets the running move, then G0X-10 is queued behind it.
    grbl.send(b"~");
    grbl.expect("error:8\r\nok\r\n");
    grbl.wait_for_state("Idle");
    grbl.exchange("?", "<Idle|MPos:-10.000,0.000,0.000|FS:0,0>\r\n");

    // A soft reset while moving: ALARM:3, banner, position no longer trusted.
    grbl.exchange("G0X-100\n", "ok\r\n");
    let running = grbl.wait_for_state("Run");
    grbl.send(b"\x18");
    grbl.expect("ALARM:3\r\n");
    grbl.expect(LOCKED_BANNER);
    let alarm = grbl.wait_for_state("Alarm");
    let stopped = mpos_x(&alarm);
    assert!(
        stopped <= mpos_x(&running) && stopped > -100.0,
        "{running} then {alarm}"
    );
    grbl.exchange("G0X-20\n", "error:9\r\n");

    // Jogging, and a jog cancel (0x85) that stops it short.
    grbl.exchange("$X\n", "[MSG:Caution: Unlocked]\r\nok\r\n");
    grbl.exchange("$J=G91X-300F1200\n", "error:15\r\n");
    grbl.exchange("$J=G53X-150F300\n", "ok\r\n");
    grbl.wait_for_state("Jog");
    grbl.exchange("G0X-20\n", "error:9\r\n");
    grbl.send(&[0x85]);
    let cancelled = grbl.wait_for_state("Idle");
    let x = mpos_x(&cancelled);
    assert!(x <= stopped && x > -150.0, "from {stopped}: {cancelled}");

    // A soft reset after a completed feed hold keeps the position and raises no alarm.
    grbl.exchange("!", "");
    grbl.wait_for_state("Hold:0");
    grbl.send(b"\x18");
    grbl.expect(BANNER);
    grbl.wait_for_state("Idle");
}

#[test]
fn dwell_answers_after_the_motion_and_profile_timing() {
    // 90° at 20°/s with 40°/s²: 0.5 s ramps and 4 s cruise.
    assert!((move_duration_s(90.0, 1200.0, 40.0) - 5.0).abs() < 1e-12);
    // 5° never reaches 20°/s: a triangle of 2·√(5/40) s.
    assert!((move_duration_s(-5.0, 1200.0, 40.0) - 2.0 * (5.0f64 / 40.0).sqrt()).abs() < 1e-12);
    assert_eq!(move_duration_s(0.0, 1200.0, 40.0), 0.0);

    let config = GrblConfig {
        time_scale: 0.02,
        homing_enabled: false,
        soft_limits: false,
        ..fast_config()
    };
    let expected = move_duration_s(90.0, 1200.0, 40.0) * config.time_scale;
    let (emulator, world) = start(config, 0.0);
    let mut grbl = Client::open(emulator.device_path());
    grbl.expect(BANNER);
    let sent = Instant::now();
    grbl.exchange("G0X-90\nG4P0\n", "ok\r\n");
    let mut last = 1.0;
    // World follows the arm continuously and monotonically while the dwell waits.
    while sent.elapsed().as_secs_f64() < expected * 0.8 {
        let arm = world.arm_deg();
        assert!(arm <= last && arm >= -90.0);
        last = arm;
        std::thread::sleep(Duration::from_millis(5));
    }
    assert!(last < 0.0 && last > -90.0, "{last}");
    grbl.expect("ok\r\n");
    let elapsed = sent.elapsed().as_secs_f64();
    assert!(elapsed >= expected * 0.98, "{elapsed} s < {expected} s");
    assert_eq!(world.arm_deg(), -90.0);
    grbl.exchange("?", "<Idle|MPos:-90.000,0.000,0.000|FS:0,0>\r\n");
}
