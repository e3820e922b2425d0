//! The state machine in machine time, byte for byte.

use super::*;

/// The arm board, with reports without the optional fields unless a test turns them on.
fn arm_board() -> GrblConfig {
    GrblConfig {
        status_extras: false,
        ..GrblConfig::arm_board()
    }
}

const LOCKED_BANNER: &str = "\r\nGrbl 1.1h ['$' for help]\r\n[MSG:'$H'|'$X' to unlock]\r\n";

/// A booted controller with the arm physically at −30°, at machine time 0.5.
fn booted_with(config: &GrblConfig) -> (Controller, World) {
    let world = World::new(-30.0);
    let mut c = Controller::new(config, world.clone(), Transcript::default(), 0.0);
    c.tick(0.5);
    (c, world)
}

fn booted() -> (Controller, World) {
    let (mut c, world) = booted_with(&arm_board());
    assert_eq!(take(&mut c, 0.5), LOCKED_BANNER);
    (c, world)
}

/// Bytes arrive one by one, each a checkpoint, as on the serial line.
fn send(c: &mut Controller, text: &str, now: f64) -> String {
    for b in text.bytes() {
        c.receive(b);
        c.tick(now);
    }
    c.tick(now);
    take(c, now)
}

fn take(c: &mut Controller, now: f64) -> String {
    let bytes: Vec<u8> = c.take_output(now).concat();
    String::from_utf8(bytes).unwrap()
}

#[test]
fn locked_until_unlocked_then_moves_in_time() {
    let (mut c, world) = booted();
    assert_eq!(send(&mut c, "G0X-10\n", 1.0), "error:9\r\n");
    assert_eq!(
        send(&mut c, "$X\n", 1.0),
        "[MSG:Caution: Unlocked]\r\nok\r\n"
    );
    // Not homed: MPos counts from power-up, the arm is physically at −30°.
    assert_eq!(send(&mut c, "G0X-10\n", 1.0), "ok\r\n");
    // 10° with 40°/s²: a triangle peaking at √(40·10) = 20°/s (the max rate), 1 s.
    assert_eq!(
        send(&mut c, "?", 1.5),
        "<Run|MPos:-5.000,0.000,0.000|FS:1200,0>\r\n"
    );
    assert!((world.arm_deg() + 35.0).abs() < 1e-9);
    assert_eq!(
        send(&mut c, "?", 2.0),
        "<Idle|MPos:-10.000,0.000,0.000|FS:0,0>\r\n"
    );
    assert!((world.arm_deg() + 40.0).abs() < 1e-9);
}

#[test]
fn homing_answers_nothing_until_done_and_pulls_off() {
    let (mut c, world) = booted();
    assert_eq!(send(&mut c, "$H\n", 1.0), "");
    // No real-time command runs during the cycle: `?` waits for its end.
    assert_eq!(send(&mut c, "?", 2.0), "");
    // Seek 30° at 10°/s (3.25 s), pull off 1° (0.316 s), locate 1° at 100°/min
    // (0.642 s), pull off again, with 0.25 s of debounce after each: 5.52 s.
    assert_eq!(send(&mut c, "", 6.5), "");
    assert_eq!(
        send(&mut c, "", 6.53),
        "<Home|MPos:-1.000,0.000,0.000|FS:0,0>\r\nok\r\n"
    );
    assert!((world.arm_deg() + 1.0).abs() < 1e-9);
    assert_eq!(
        send(&mut c, "?", 6.6),
        "<Idle|MPos:-1.000,0.000,0.000|FS:0,0>\r\n"
    );
    // A target past the soft limits raises ALARM:2 and locks until reset; the firmware
    // then answers nothing at all, not even `?`.
    assert_eq!(send(&mut c, "G0X-181\n", 7.0), "ALARM:2\r\n");
    assert_eq!(send(&mut c, "$X\n?", 7.6), "[MSG:Reset to continue]\r\n");
    assert_eq!(send(&mut c, "?", 9.0), "");
    // The reset answers the line that raised the alarm; the `?` is forgotten.
    assert_eq!(send(&mut c, "\x18", 9.0), format!("ok\r\n{LOCKED_BANNER}"));
    assert_eq!(send(&mut c, "", 10.0), "");
}

#[test]
fn homing_failures_alarm_answer_the_line_and_reset() {
    // `$27=0`: the switch stays pressed after the pull-off.
    let (mut c, _) = booted();
    // The seek ends at 4.25, the debounce at 4.5, and the empty pull-off with it.
    assert_eq!(send(&mut c, "$27=0\n$H\n", 1.0), "ok\r\n");
    assert_eq!(send(&mut c, "", 4.45), "");
    assert_eq!(send(&mut c, "", 4.55), "ALARM:8\r\n");
    assert_eq!(send(&mut c, "?", 4.9), "");
    assert_eq!(send(&mut c, "", 5.05), format!("ok\r\n{LOCKED_BANNER}"));
    // Stock cycles (Z first, then X and Y) on a board with nothing wired on Z: the
    // search gives up after 1.5 × $132 = 300 at Z's max rate ($112 = 500/min, ramps
    // at $122 = 10/s²), 36.83 s, with ALARM:9.
    let config = GrblConfig {
        homing_cycles: GrblConfig::default().homing_cycles,
        idle_axis_switch: None,
        ..arm_board()
    };
    let (mut c, _) = booted_with(&config);
    take(&mut c, 0.5);
    assert_eq!(send(&mut c, "$H\n", 1.0), "");
    assert_eq!(send(&mut c, "", 37.7), "");
    assert_eq!(send(&mut c, "", 37.9), "ALARM:9\r\n");
    assert_eq!(send(&mut c, "", 38.4), format!("ok\r\n{LOCKED_BANNER}"));
    assert_eq!(
        send(&mut c, "?", 38.4),
        "<Alarm|MPos:0.000,0.000,300.000|FS:0,0>\r\n"
    );
    // A reset during the cycle: ALARM:6.
    let (mut c, _) = booted();
    send(&mut c, "$H\n", 1.0);
    assert_eq!(send(&mut c, "\x18", 2.0), "ALARM:6\r\n");
    assert_eq!(send(&mut c, "", 2.5), format!("ok\r\n{LOCKED_BANNER}"));
}

#[test]
fn stock_cycles_home_z_then_x_and_y_to_minus_pulloff() {
    let config = GrblConfig {
        homing_cycles: GrblConfig::default().homing_cycles,
        status_extras: true,
        ..arm_board()
    };
    let (mut c, world) = booted_with(&config);
    assert_eq!(take(&mut c, 0.5), LOCKED_BANNER);
    send(&mut c, "$H\n", 1.0);
    assert_eq!(send(&mut c, "", 20.0), "ok\r\n");
    assert!((world.arm_deg() + 1.0).abs() < 1e-9);
    assert_eq!(
        send(&mut c, "?", 20.0),
        "<Idle|MPos:-1.000,-1.000,-1.000|FS:0,0|WCO:0.000,0.000,0.000>\r\n"
    );
}

#[test]
fn a_complete_feed_hold_suspends_every_line_until_resumed() {
    let (mut c, world) = booted();
    send(&mut c, "$X\n", 1.0);
    assert_eq!(send(&mut c, "G1X-20F600\nG4P0\n", 1.0), "ok\r\n");
    // 20° at 10°/s, ramps 0.25 s: 2.25 s.
    assert_eq!(send(&mut c, "", 3.2), "");
    assert_eq!(send(&mut c, "", 3.26), "ok\r\n");
    assert_eq!(send(&mut c, "G1X-40\n", 4.0), "ok\r\n");
    // 1 s into the 20° move (0.25 s ramp to 10°/s): 8.75° done; hold takes 0.25 s.
    assert_eq!(send(&mut c, "!", 5.0), "");
    assert_eq!(
        send(&mut c, "?", 5.1),
        "<Hold:1|MPos:-29.550,0.000,0.000|FS:360,0>\r\n"
    );
    // While decelerating the main loop still runs.
    assert_eq!(send(&mut c, "$$\n", 5.1), "error:8\r\n");
    assert_eq!(
        send(&mut c, "?", 5.5),
        "<Hold:0|MPos:-30.000,0.000,0.000|FS:0,0>\r\n"
    );
    // Once the hold is complete nothing runs, and nothing is answered, until `~`.
    let held = world.arm_deg();
    assert_eq!(send(&mut c, "$$\nG4P0\n", 5.5), "");
    assert_eq!(
        send(&mut c, "?", 7.0),
        "<Hold:0|MPos:-30.000,0.000,0.000|FS:0,0>\r\n"
    );
    assert_eq!(world.arm_deg(), held);
    // Resumed, the move runs on: `$$` meets a running machine.
    assert_eq!(send(&mut c, "~", 7.0), "error:8\r\n");
    assert_eq!(
        send(&mut c, "?", 7.5),
        "<Run|MPos:-33.750,0.000,0.000|FS:600,0>\r\n"
    );
    // A reset while moving: ALARM:3, the waiting G4 answered, then the banner.
    assert_eq!(send(&mut c, "\x18", 7.5), "ALARM:3\r\n");
    // Stopped dead at 10°/s: the arm (30° below MPos since power-up) coasts on
    // 10²/(2·4·40) = 0.3125° while the motor slips.
    assert!((world.arm_deg() - (-30.0 - 33.75 - 0.3125)).abs() < 1e-9);
    assert_eq!(send(&mut c, "", 8.0), format!("ok\r\n{LOCKED_BANNER}"));
    assert_eq!(
        send(&mut c, "?", 8.0),
        "<Alarm|MPos:-33.750,0.000,0.000|FS:0,0>\r\n"
    );
    // A hold while idle is complete at once.
    send(&mut c, "$X\n", 8.0);
    assert_eq!(
        send(&mut c, "!?G4P0\n", 8.0),
        "<Hold:0|MPos:-33.750,0.000,0.000|FS:0,0>\r\n"
    );
    assert_eq!(
        send(&mut c, "~?", 8.0),
        "ok\r\n<Idle|MPos:-33.750,0.000,0.000|FS:0,0>\r\n"
    );
}

#[test]
fn jogging_and_jog_cancel() {
    let (mut c, _) = booted();
    assert_eq!(send(&mut c, "$J=G91X-10F600\n", 1.0), "error:8\r\n");
    send(&mut c, "$X\n", 1.0);
    assert_eq!(send(&mut c, "$J=G91X-10\n", 1.0), "error:22\r\n");
    assert_eq!(send(&mut c, "$J=G1X-10F600\n", 1.0), "error:16\r\n");
    assert_eq!(send(&mut c, "$J=G91F600\n", 1.0), "error:16\r\n");
    assert_eq!(send(&mut c, "$J=X-10F600S1\n", 1.0), "error:36\r\n");
    assert_eq!(send(&mut c, "$J=X-200F600\n", 1.0), "error:15\r\n");
    assert_eq!(send(&mut c, "$JX-1F600\n", 1.0), "error:3\r\n");
    // 20° at 10°/s with 0.25 s ramps: 2.25 s.
    assert_eq!(
        send(&mut c, "$J=G91X-20F600\n?", 1.0),
        "ok\r\n<Jog|MPos:0.000,0.000,0.000|FS:0,0>\r\n"
    );
    assert_eq!(send(&mut c, "G0X-5\n", 1.5), "error:9\r\n");
    assert_eq!(
        send(&mut c, "?", 3.3),
        "<Idle|MPos:-20.000,0.000,0.000|FS:0,0>\r\n"
    );
    // The jog kept the parser in G90: this is absolute.
    assert_eq!(
        send(&mut c, "$J=X-40F600\n$J=X-60F600\n", 4.0),
        "ok\r\nok\r\n"
    );
    assert_eq!(send(&mut c, "\u{85}", 5.0), "");
    // Cancelled at 10°/s after 8.75°: 0.25 s and 1.25° to stop, the rest dropped.
    assert_eq!(
        send(&mut c, "?", 5.1),
        "<Jog|MPos:-29.550,0.000,0.000|FS:360,0>\r\n"
    );
    assert_eq!(
        send(&mut c, "?", 5.3),
        "<Idle|MPos:-30.000,0.000,0.000|FS:0,0>\r\n"
    );
    assert_eq!(
        send(&mut c, "G91G0X1\nG4P0\n?", 5.3),
        "ok\r\n<Run|MPos:-30.000,0.000,0.000|FS:0,0>\r\n"
    );
    assert_eq!(send(&mut c, "", 9.0), "ok\r\n");
    assert_eq!(
        send(&mut c, "?", 9.0),
        "<Idle|MPos:-29.000,0.000,0.000|FS:0,0>\r\n"
    );
}

#[test]
fn full_receive_buffer_drops_bytes_and_full_planner_delays_ok() {
    let (mut c, _) = booted();
    send(&mut c, "$X\n$10=3\n", 1.0);
    // While the dwell waits, the 128-byte ring keeps 127 bytes: 25 lines and "G4".
    let flood = "G4P0\n".repeat(30);
    assert_eq!(
        send(&mut c, &format!("G4P10\n{flood}?"), 1.0),
        "<Idle|MPos:0.000,0.000,0.000|Bf:15,1|FS:0,0>\r\n"
    );
    assert_eq!(send(&mut c, "", 11.0), "ok\r\n".repeat(26));
    assert_eq!(send(&mut c, "\n", 11.0), "error:28\r\n");
    // 15 planner blocks; the 16th move is answered when the first one is done.
    let moves = "G91G1X-1F60\n".repeat(16);
    assert_eq!(send(&mut c, &moves, 12.0), "ok\r\n".repeat(15));
    assert_eq!(
        send(&mut c, "?", 12.5125),
        "<Run|MPos:-0.500,0.000,0.000|Bf:0,128|FS:60,0>\r\n"
    );
    assert_eq!(send(&mut c, "", 13.1), "ok\r\n");
}

#[test]
fn stock_status_fields_on_their_refresh_counters() {
    let config = GrblConfig {
        status_extras: true,
        homing_enabled: false,
        soft_limits: false,
        ..arm_board()
    };
    let mut c = Controller::new(&config, World::new(0.0), Transcript::default(), 0.0);
    c.tick(1.0);
    assert_eq!(take(&mut c, 1.0), "\r\nGrbl 1.1h ['$' for help]\r\n");
    // The arm rests on its switch at θ = 0.
    let idle = "<Idle|MPos:0.000,0.000,0.000|FS:0,0|Pn:X";
    assert_eq!(
        send(&mut c, "?", 1.0),
        format!("{idle}|WCO:0.000,0.000,0.000>\r\n")
    );
    assert_eq!(
        send(&mut c, "M3S500M8\n?", 1.0),
        "ok\r\n<Idle|MPos:0.000,0.000,0.000|FS:0,500|Pn:X|Ov:100,100,100|A:SF>\r\n"
    );
    for _ in 0..8 {
        assert_eq!(
            send(&mut c, "?", 1.0),
            "<Idle|MPos:0.000,0.000,0.000|FS:0,500|Pn:X>\r\n"
        );
    }
    assert_eq!(
        send(&mut c, "M5M9G0X-1\n?", 1.0),
        "ok\r\n<Run|MPos:0.000,0.000,0.000|FS:0,0|Pn:X|WCO:0.000,0.000,0.000>\r\n"
    );
    assert_eq!(
        send(&mut c, "?", 2.0),
        "<Idle|MPos:-1.000,0.000,0.000|FS:0,0|Ov:100,100,100>\r\n"
    );
    // A G92 offset: WCO on the very next report; WPos with `$10=0`.
    assert_eq!(
        send(&mut c, "G92X-12\n?", 2.0),
        "ok\r\n<Idle|MPos:-1.000,0.000,0.000|FS:0,0|WCO:11.000,0.000,0.000>\r\n"
    );
    // The overrides were not due: they come after a WCO only when their counter is.
    assert_eq!(
        send(&mut c, "$10=0\n?", 2.0),
        "ok\r\n<Idle|WPos:-12.000,0.000,0.000|FS:0,0>\r\n"
    );
    assert_eq!(send(&mut c, "G0X-20\nG4P0\n", 2.0), "ok\r\n");
    assert_eq!(send(&mut c, "", 5.0), "ok\r\n");
    assert_eq!(
        send(&mut c, "?", 5.0),
        "<Idle|WPos:-20.000,0.000,0.000|FS:0,0>\r\n"
    );
    // G92 is forgotten at a reset, G54 (EEPROM) is not. At MPos −9 with G92 11,
    // G10 L20 P0 X-5 makes G54 −9 − 11 + 5 = −15.
    send(&mut c, "G10L20P0X-5\n", 5.0);
    let parameters = send(&mut c, "$#\n", 5.0);
    assert!(
        parameters.starts_with("[G54:-15.000,0.000,0.000]\r\n[G55:0.000,0.000,0.000]\r\n"),
        "{parameters}"
    );
    assert!(parameters.contains(
        "\r\n[G92:11.000,0.000,0.000]\r\n[TLO:0.000]\r\n[PRB:0.000,0.000,0.000:0]\r\nok\r\n"
    ));
    assert_eq!(
        send(&mut c, "\x18?", 5.0),
        "\r\nGrbl 1.1h ['$' for help]\r\n<Idle|WPos:6.000,0.000,0.000|FS:0,0|WCO:-15.000,0.000,0.000>\r\n"
    );
}

#[test]
fn hard_limits_alarm_on_a_switch_change_and_at_start_up() {
    let config = GrblConfig {
        hard_limits: true,
        homing_enabled: false,
        soft_limits: false,
        ..arm_board()
    };
    let world = World::new(-5.0);
    let mut c = Controller::new(&config, world.clone(), Transcript::default(), 0.0);
    c.tick(0.5);
    assert_eq!(take(&mut c, 0.5), "\r\nGrbl 1.1h ['$' for help]\r\n");
    // Driven into its switch at θ = 0.
    assert_eq!(send(&mut c, "G0X10\n", 1.0), "ok\r\n");
    assert_eq!(send(&mut c, "", 1.5), "ALARM:1\r\n");
    assert_eq!(send(&mut c, "?", 2.0), "[MSG:Reset to continue]\r\n");
    // It came to rest on the switch: after the reset the firmware says so and locks.
    assert_eq!(
        send(&mut c, "\x18", 2.0),
        "\r\nGrbl 1.1h ['$' for help]\r\n[MSG:Check Limits]\r\n[MSG:'$H'|'$X' to unlock]\r\n"
    );
    assert!(world.arm_deg() >= 0.0);
}

#[test]
fn line_endings_settings_and_errors() {
    let (mut c, _) = booted();
    // The firmware ends a line at \r and at \n: CRLF answers twice.
    assert_eq!(
        send(&mut c, "$X\r\n", 1.0),
        "[MSG:Caution: Unlocked]\r\nok\r\nok\r\n"
    );
    assert_eq!(
        send(&mut c, "$110=600\n$0=1\n$130=-1\n$99=1\n", 1.0),
        "ok\r\nerror:6\r\nerror:4\r\nerror:3\r\n"
    );
    assert_eq!(
        send(&mut c, "$100=x\n$100\n$H1\n", 1.0),
        "error:2\r\nerror:3\r\nerror:3\r\n"
    );
    let settings = send(&mut c, "$$\n", 1.0);
    assert!(settings.starts_with("$0=10\r\n$1=25\r\n"));
    assert!(settings.contains("\r\n$22=1\r\n") && settings.contains("\r\n$110=600.000\r\n"));
    assert!(settings.ends_with("$132=200.000\r\nok\r\n"));
    assert_eq!(
        send(&mut c, "$I\n", 1.0),
        "[VER:1.1h.20190830:]\r\n[OPT:V,15,128]\r\nok\r\n"
    );
    assert_eq!(send(&mut c, "g0 x-1 (comment) ; rest\n", 1.0), "ok\r\n");
    let long = format!("G0X{}\n", "1".repeat(90));
    assert_eq!(send(&mut c, &long, 1.0), "error:11\r\n");
}
