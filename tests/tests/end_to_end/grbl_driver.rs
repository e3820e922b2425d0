//! The GRBL arm driver against the emulated controller on a pseudo-terminal, opened by
//! its device path like real hardware, through each injected fault. The suite runs
//! three times: status reports with the stock build's optional fields (`Pn`, `WCO`,
//! `Ov`), without them, and against a controller 5× slower than the driver's timeouts
//! assume.
//!
//! Documented outcomes:
//! - unplug: the next call fails with `Disconnected`; once the controller is back, the
//!   next call reopens the same path, and the arm must be homed before moving.
//! - silent controller: `Timeout`; it works again once the controller answers.
//! - garbled or truncated reply: retried, the move succeeds.
//! - alarm during motion: `Alarm` with GRBL's meaning, latched (moves and homing
//!   refused) until `clear_fault`, then re-home; a hard-limit lock is reset at once.
//! - unexpected reset banner: the position is unknown until re-homed.
//! - emergency stop mid-move: the move fails, the arm stops short of its target.
//! - during a move the driver's live angle follows the arm (status polled).
//! - stock settings: each difference listed, or written with `apply_settings`; with
//!   homing off the operator declares the position.
//! - homing failure: a typed error with GRBL's meaning and advice, not retried.
//! - slow controller: a late move completes while it progresses; past the patience it
//!   fails cleanly, its late `ok` paired with its own line.
//! - a second axis (a sample carousel) homed with the arm moves in machine
//!   coordinates and leaves the arm in place.

use std::thread;
use std::time::{Duration, Instant};

use gonio_drivers::grbl::{ArmAxis, GrblArm, GrblArmConfig, Homing};
use gonio_drivers::{Arm, ArmState, DeviceError};
use gonio_mock_hw::grbl::{AxisSet, Fault, GrblConfig, GrblEmulator};
use gonio_mock_hw::world::World;

const SCAN_DEG: [f64; 6] = [-20.0, -25.0, -30.0, -35.0, -40.0, -45.0];
/// The speed the driver's timeouts assume: 100× faster than real time.
const ASSUMED_TIME_SCALE: f64 = 0.01;

/// How the emulated controller differs between runs of the suite.
#[derive(Debug, Clone, Copy)]
struct Variant {
    extras: bool,
    /// Real seconds per machine second.
    time_scale: f64,
}

const EXTRAS: Variant = Variant {
    extras: true,
    time_scale: ASSUMED_TIME_SCALE,
};
const PLAIN: Variant = Variant {
    extras: false,
    time_scale: ASSUMED_TIME_SCALE,
};
const SLOW: Variant = Variant {
    extras: true,
    time_scale: 5.0 * ASSUMED_TIME_SCALE,
};

/// Timeouts for a controller running at [`ASSUMED_TIME_SCALE`], with a small margin.
fn driver_config() -> GrblArmConfig {
    GrblArmConfig {
        banner_timeout: Duration::from_millis(500),
        reply_timeout: Duration::from_millis(500),
        motion_time_factor: ASSUMED_TIME_SCALE,
        motion_margin: Duration::from_millis(20),
        status_interval: Duration::from_millis(20),
        stall_timeout: Duration::from_secs(1),
        reconnect_attempts: 6,
        reconnect_backoff: Duration::from_millis(50),
        ..GrblArmConfig::default()
    }
}

fn board(variant: Variant) -> GrblConfig {
    GrblConfig {
        time_scale: variant.time_scale,
        status_extras: variant.extras,
        ..GrblConfig::arm_board()
    }
}

fn rig_with(variant: Variant, time_scale: f64) -> (GrblEmulator, World, GrblArm) {
    let world = World::new(-7.5);
    let config = GrblConfig {
        time_scale,
        ..board(variant)
    };
    let emulator = GrblEmulator::start(config, world.clone()).unwrap();
    let arm = GrblArm::open(emulator.device_path(), driver_config()).unwrap();
    (emulator, world, arm)
}

fn rig(variant: Variant) -> (GrblEmulator, World, GrblArm) {
    rig_with(variant, variant.time_scale)
}

/// Move, then check the controller and the physical arm agree on the angle.
fn move_and_check(arm: &mut GrblArm, world: &World, deg: f64) {
    arm.move_to(deg).unwrap();
    let status = arm.status().unwrap();
    assert_eq!(status.state, ArmState::Idle);
    assert!((status.angle_deg - deg).abs() < 0.01, "{status:?} != {deg}");
    assert!(
        (world.arm_deg() - deg).abs() < 0.05,
        "arm at {} != {deg}",
        world.arm_deg()
    );
}

fn homes_and_moves_through_the_scan_angles(variant: Variant) {
    let (emulator, world, mut arm) = rig(variant);
    assert!(arm.firmware().starts_with("1.1h"), "{}", arm.firmware());
    assert_eq!(arm.status().unwrap().state, ArmState::NeedsHoming);
    assert!(matches!(
        arm.move_to(-20.0),
        Err(DeviceError::PositionUnknown(_))
    ));
    arm.home().unwrap();
    // Homed: the arm pulled off the switch by $27.
    assert!((world.arm_deg() + 1.0).abs() < 0.05);
    for deg in SCAN_DEG {
        move_and_check(&mut arm, &world, deg);
    }
    for outside in [0.5, -0.5, -90.5, f64::NAN] {
        assert!(matches!(
            arm.move_to(outside),
            Err(DeviceError::OutOfRange { .. })
        ));
    }
    assert!((world.arm_deg() + 45.0).abs() < 0.05);
    // Each line once, none re-sent, no reset.
    let transcript = emulator.transcript();
    let moves: Vec<&String> = transcript.iter().filter(|l| l.starts_with("G90")).collect();
    assert_eq!(moves.len(), SCAN_DEG.len(), "{transcript:?}");
    assert!(!transcript.contains(&"^X".to_owned()), "{transcript:?}");
}

fn unplug_then_reconnect_requires_homing(variant: Variant) {
    let (emulator, world, mut arm) = rig(variant);
    arm.home().unwrap();
    move_and_check(&mut arm, &world, -20.0);
    emulator.inject(Fault::Unplug);
    let status = arm.status();
    assert!(
        matches!(status, Err(DeviceError::Disconnected(_))),
        "{status:?}"
    );
    // Still unplugged: bounded reconnect attempts, then Disconnected again.
    let started = Instant::now();
    assert!(matches!(
        arm.move_to(-25.0),
        Err(DeviceError::Disconnected(_))
    ));
    assert!(started.elapsed() < Duration::from_secs(5));
    // Plugged back in while the driver is retrying with backoff.
    let status = thread::scope(|scope| {
        scope.spawn(|| {
            thread::sleep(Duration::from_millis(120));
            emulator.reconnect().unwrap();
        });
        arm.status()
    });
    assert_eq!(status.unwrap().state, ArmState::NeedsHoming);
    assert!(matches!(
        arm.move_to(-25.0),
        Err(DeviceError::PositionUnknown(_))
    ));
    arm.home().unwrap();
    move_and_check(&mut arm, &world, -25.0);
}

fn silent_controller_times_out_then_recovers(variant: Variant) {
    let (emulator, world, mut arm) = rig(variant);
    arm.home().unwrap();
    emulator.inject(Fault::Silent);
    let started = Instant::now();
    assert!(matches!(
        arm.move_to(-30.0),
        Err(DeviceError::Timeout { .. })
    ));
    assert!(started.elapsed() < Duration::from_secs(5));
    assert!(matches!(arm.status(), Err(DeviceError::Timeout { .. })));
    emulator.inject(Fault::Responsive);
    move_and_check(&mut arm, &world, -30.0);
}

fn garbled_and_truncated_replies_are_survived(variant: Variant) {
    let (emulator, world, mut arm) = rig(variant);
    arm.home().unwrap();
    for (fault, deg) in [
        (Fault::Garble, -20.0),
        (Fault::Truncate, -25.0),
        (Fault::Garble, -40.0),
        (Fault::Truncate, -45.0),
    ] {
        emulator.inject(fault);
        move_and_check(&mut arm, &world, deg);
    }
    emulator.inject(Fault::Truncate);
    assert_eq!(arm.status().unwrap().state, ArmState::Idle);
}

fn alarm_during_motion_latches_until_cleared_and_rehomed(variant: Variant) {
    let (emulator, world, mut arm) = rig(variant);
    arm.home().unwrap();
    move_and_check(&mut arm, &world, -20.0);
    emulator.inject(Fault::AlarmDuringMotion(1));
    let started = Instant::now();
    let Err(DeviceError::Alarm { code: 1, meaning }) = arm.move_to(-45.0) else {
        panic!("alarm not reported")
    };
    assert!(meaning.contains("hard limit"), "{meaning}");
    // GRBL answers nothing, not even `?`, during the lock: the driver reset it at once
    // instead of waiting for a status report.
    assert!(started.elapsed() < Duration::from_secs(2));
    let transcript = emulator.transcript();
    assert_eq!(
        transcript[transcript.len() - 3..],
        ["G90G0X-45.000", "G4P0", "^X"],
        "{transcript:?}"
    );
    // Stopped part-way.
    assert!(world.arm_deg() > -45.0 + 1.0, "arm at {}", world.arm_deg());
    assert_eq!(arm.status().unwrap().state, ArmState::Alarm);
    assert!(matches!(
        arm.move_to(-30.0),
        Err(DeviceError::Alarm { code: 1, .. })
    ));
    assert!(matches!(
        arm.home(),
        Err(DeviceError::Alarm { code: 1, .. })
    ));
    arm.clear_fault().unwrap();
    assert_eq!(arm.status().unwrap().state, ArmState::NeedsHoming);
    assert!(matches!(
        arm.move_to(-30.0),
        Err(DeviceError::PositionUnknown(_))
    ));
    arm.home().unwrap();
    move_and_check(&mut arm, &world, -30.0);
}

fn unexpected_reset_banner_requires_homing(variant: Variant) {
    let (emulator, world, mut arm) = rig(variant);
    arm.home().unwrap();
    move_and_check(&mut arm, &world, -35.0);
    emulator.inject(Fault::ResetBanner);
    assert!(matches!(
        arm.move_to(-40.0),
        Err(DeviceError::PositionUnknown(_))
    ));
    assert_eq!(arm.status().unwrap().state, ArmState::NeedsHoming);
    arm.home().unwrap();
    move_and_check(&mut arm, &world, -40.0);
}

fn emergency_stop_halts_a_move_from_another_thread(variant: Variant) {
    // Real time stretched so the stop lands mid-move: 79° at 20°/s is 4.5 machine s.
    let (_emulator, world, mut arm) = rig_with(variant, 0.1);
    arm.home().unwrap();
    let stop = arm.emergency_stop();
    let stopper = thread::spawn(move || {
        thread::sleep(Duration::from_millis(150));
        stop.stop()
    });
    let result = arm.move_to(-80.0);
    stopper.join().unwrap().unwrap();
    assert!(
        matches!(result, Err(DeviceError::Alarm { .. } | DeviceError::Reset)),
        "{result:?}"
    );
    let at = world.arm_deg();
    assert!(at < -1.5 && at > -79.0, "arm at {at}");
    assert!(matches!(
        arm.move_to(-20.0),
        Err(DeviceError::Alarm { .. } | DeviceError::PositionUnknown(_))
    ));
    arm.clear_fault().unwrap();
    arm.home().unwrap();
    move_and_check(&mut arm, &world, -20.0);
}

/// Each scenario once per variant of the controller.
macro_rules! suite {
    ($($scenario:ident),* $(,)?) => {
        mod with_status_extras {
            $(#[test] fn $scenario() { super::$scenario(super::EXTRAS) })*
        }
        mod without_status_extras {
            $(#[test] fn $scenario() { super::$scenario(super::PLAIN) })*
        }
        mod slow_controller {
            $(#[test] fn $scenario() { super::$scenario(super::SLOW) })*
        }
    };
}

suite!(
    homes_and_moves_through_the_scan_angles,
    unplug_then_reconnect_requires_homing,
    silent_controller_times_out_then_recovers,
    garbled_and_truncated_replies_are_survived,
    alarm_during_motion_latches_until_cleared_and_rehomed,
    unexpected_reset_banner_requires_homing,
    emergency_stop_halts_a_move_from_another_thread,
);

/// A stock board: GRBL 1.1h's factory settings (`$100=250`, `$22=0`, stock homing
/// cycles), 100× faster than real time.
fn stock_board(arm_deg: f64) -> (GrblEmulator, World) {
    let world = World::new(arm_deg);
    let config = GrblConfig {
        time_scale: ASSUMED_TIME_SCALE,
        ..GrblConfig::default()
    };
    (GrblEmulator::start(config, world.clone()).unwrap(), world)
}

#[test]
fn stock_settings_are_listed_one_line_each_or_written_and_read_back() {
    let (emulator, world) = stock_board(-10.0);
    let Err(DeviceError::SettingsDiffer(lines)) =
        GrblArm::open(emulator.device_path(), driver_config())
    else {
        panic!("stock settings accepted")
    };
    assert_eq!(
        lines,
        [
            "$22 (homing cycle enable) is 0, configuration expects 1",
            "$100 (X steps per degree) is 250, configuration expects 80",
            "$130 (X max travel, degrees) is 200, configuration expects 180",
        ]
    );
    let apply = GrblArmConfig {
        apply_settings: true,
        ..driver_config()
    };
    let mut arm = GrblArm::open(emulator.device_path(), apply).unwrap();
    let transcript = emulator.transcript();
    assert_eq!(
        transcript[transcript.len() - 4..],
        ["$22=1", "$100=80", "$130=180", "$$"]
    );
    // The stock homing cycles: Z, then X and Y; the arm ends −$27 off its switch.
    arm.home().unwrap();
    assert!((world.arm_deg() + 1.0).abs() < 0.05);
    move_and_check(&mut arm, &world, -20.0);
}

#[test]
fn homing_off_takes_the_position_the_operator_declares() {
    let (emulator, world) = stock_board(-10.0);
    let off = GrblArmConfig {
        homing: Homing::Off,
        steps_per_deg: 250.0,
        max_travel_deg: 200.0,
        ..driver_config()
    };
    let mut arm = GrblArm::open(emulator.device_path(), off.clone()).unwrap();
    assert_eq!(arm.status().unwrap().state, ArmState::NeedsPosition);
    assert!(matches!(arm.home(), Err(DeviceError::PositionUnknown(_))));
    assert!(matches!(
        arm.move_to(-20.0),
        Err(DeviceError::PositionUnknown(_))
    ));
    arm.declare_position(-10.0).unwrap();
    arm.home().unwrap();
    for deg in [-20.0, -45.0, -12.5] {
        move_and_check(&mut arm, &world, deg);
    }
    assert!(!emulator.transcript().contains(&"$H".to_owned()));
    // Reopening resets the board (DTR): the declaration is gone with it.
    drop(arm);
    let mut arm = GrblArm::open(emulator.device_path(), off).unwrap();
    assert!(matches!(
        arm.move_to(-20.0),
        Err(DeviceError::PositionUnknown(_))
    ));
}

#[test]
fn homing_failures_are_typed_with_advice_and_not_retried() {
    // `$27=0`: the switch stays pressed after the pull-off.
    let world = World::new(-7.5);
    let config = GrblConfig {
        homing_pulloff_deg: 0.0,
        ..board(EXTRAS)
    };
    let emulator = GrblEmulator::start(config, world).unwrap();
    let mut arm = GrblArm::open(emulator.device_path(), driver_config()).unwrap();
    let Err(DeviceError::HomingFailed {
        code: 8,
        meaning,
        advice,
    }) = arm.home()
    else {
        panic!("no typed homing failure")
    };
    assert!(meaning.contains("pull-off"), "{meaning}");
    assert!(advice.contains("$27"), "{advice}");
    // One `$H`: GRBL reset itself, the driver sent no reset of its own.
    let transcript = emulator.transcript();
    assert_eq!(transcript.iter().filter(|l| *l == "$H").count(), 1);
    assert!(!transcript.contains(&"^X".to_owned()), "{transcript:?}");
    // The stock cycles with nothing wired on Z: ALARM:9, the advice names the cycles.
    let config = GrblConfig {
        time_scale: 0.002,
        homing_cycles: GrblConfig::default().homing_cycles,
        idle_axis_switch: None,
        ..board(EXTRAS)
    };
    let emulator = GrblEmulator::start(config, World::new(-7.5)).unwrap();
    let mut arm = GrblArm::open(emulator.device_path(), driver_config()).unwrap();
    let Err(DeviceError::HomingFailed {
        code: 9, advice, ..
    }) = arm.home()
    else {
        panic!("no typed homing failure")
    };
    assert!(advice.contains("Z first"), "{advice}");
}

#[test]
fn slow_controller_late_ok_is_paired_with_its_own_line() {
    // 5× slower than the timeouts assume: a 39° move takes 2.45 machine s, 0.12 s here,
    // while the driver expects 0.025 s (+ 0.02 s margin).
    let (emulator, world, mut arm) = rig(SLOW);
    arm.home().unwrap();
    let before = emulator.transcript().len();
    move_and_check(&mut arm, &world, -40.0);
    assert_eq!(
        emulator.transcript()[before..],
        ["G90G0X-40.000", "G4P0"],
        "a line was re-sent"
    );
    // Without the patience to wait for it, the late move fails cleanly: feed hold and
    // reset answer the old `G4 P0` (paired with it, not with a newer line), and the
    // work offset is restored from where the arm stopped.
    let impatient = GrblArmConfig {
        motion_patience: 1.0,
        ..driver_config()
    };
    let (emulator, world) = {
        let world = World::new(-7.5);
        let emulator = GrblEmulator::start(board(SLOW), world.clone()).unwrap();
        (emulator, world)
    };
    let mut arm = GrblArm::open(emulator.device_path(), impatient).unwrap();
    arm.home().unwrap();
    let before = emulator.transcript().len();
    let Err(DeviceError::Timeout { what, .. }) = arm.move_to(-80.0) else {
        panic!("the late move did not time out")
    };
    assert!(what.contains("resynchronised"), "{what}");
    let transcript = emulator.transcript()[before..].to_vec();
    assert_eq!(
        transcript[..3],
        ["G90G0X-80.000", "G4P0", "^X"],
        "{transcript:?}"
    );
    assert!(
        transcript[3].starts_with("G92X") && transcript.len() == 4,
        "{transcript:?}"
    );
    let stopped = arm.status().unwrap();
    assert_eq!(stopped.state, ArmState::Idle);
    assert!(
        (stopped.angle_deg - world.arm_deg()).abs() < 0.05,
        "{stopped:?}"
    );
    assert!(stopped.angle_deg > -80.0 && stopped.angle_deg < -1.0);
    // Still referenced: moves go on from there, no homing needed.
    assert!(arm.referenced());
}

#[test]
fn live_angle_follows_the_arm_during_a_move() {
    // Half real time: a 59° move takes about 1.7 s; a report is asked for every 200 ms.
    let world = World::new(-7.5);
    let board = GrblConfig {
        time_scale: 0.5,
        ..board(EXTRAS)
    };
    let emulator = GrblEmulator::start(board, world.clone()).unwrap();
    let config = GrblArmConfig {
        motion_time_factor: 0.75,
        status_interval: Duration::from_millis(200),
        ..driver_config()
    };
    let mut arm = GrblArm::open(emulator.device_path(), config).unwrap();
    arm.home().unwrap();
    let live = arm.live_angle();
    let homed = arm.status().unwrap().angle_deg;
    assert_eq!(live.get(), Some(homed));
    let mover = thread::spawn(move || {
        arm.move_to(-60.0).unwrap();
        arm
    });
    let mut seen = Vec::new();
    while !mover.is_finished() {
        if let Some(angle) = live.get() {
            // Never further from the physical arm than one report interval's travel.
            assert!(
                (angle - world.arm_deg()).abs() < 10.0,
                "{angle} vs {}",
                world.arm_deg()
            );
            seen.push(angle);
        }
        thread::sleep(Duration::from_millis(50));
    }
    let mut arm = mover.join().unwrap();
    let mut between: Vec<f64> = seen
        .into_iter()
        .filter(|a| *a < homed - 1.0 && *a > -59.0)
        .collect();
    between.dedup();
    assert!(between.len() >= 5, "angles seen mid-move: {between:?}");
    assert!(between.windows(2).all(|w| w[1] <= w[0]), "{between:?}");
    assert!((live.get().unwrap() + 60.0).abs() < 0.01);
    assert!((arm.status().unwrap().angle_deg + 60.0).abs() < 0.01);
}

/// A second axis on the arm's board (a sample carousel), homed with the arm: it moves
/// in machine coordinates and leaves the arm where it is; the arm's own axis and
/// positions off the axis' travel are refused.
#[test]
fn a_carousel_axis_moves_in_machine_coordinates_beside_the_arm() {
    let world = World::new(-7.5);
    let config = GrblConfig {
        homing_cycles: vec![AxisSet { mask: 0b011 }],
        ..board(EXTRAS)
    };
    let emulator = GrblEmulator::start(config, world.clone()).unwrap();
    let mut arm = GrblArm::open(emulator.device_path(), driver_config()).unwrap();
    arm.home().unwrap();
    move_and_check(&mut arm, &world, -20.0);
    arm.move_axis(ArmAxis::Y, -100.0).unwrap();
    assert!((world.arm_deg() + 20.0).abs() < 0.05, "{}", world.arm_deg());
    move_and_check(&mut arm, &world, -30.0);
    arm.move_axis(ArmAxis::Y, -10.0).unwrap();
    assert!(matches!(
        arm.move_axis(ArmAxis::X, -10.0),
        Err(DeviceError::Refused(_))
    ));
    for outside in [5.0, -250.0, f64::NAN] {
        assert!(matches!(
            arm.move_axis(ArmAxis::Y, outside),
            Err(DeviceError::OutOfRange { .. })
        ));
    }
    let transcript = emulator.transcript();
    for line in ["G90G53G0Y-100.000", "G90G53G0Y-10.000"] {
        assert!(transcript.contains(&line.to_owned()), "{transcript:?}");
    }
}
