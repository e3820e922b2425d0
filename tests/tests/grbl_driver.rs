//! The GRBL arm driver against the emulated controller on a pseudo-terminal, opened by
//! its device path like real hardware, through each injected fault.
//!
//! Documented outcomes:
//! - unplug: the next call fails with `Disconnected`; once the controller is back, the
//!   next call reopens the same path, and the arm must be homed before moving (`Reset`).
//! - silent controller: `Timeout`; it works again once the controller answers.
//! - garbled or truncated reply: retried, the move succeeds.
//! - alarm during motion: `Alarm` with GRBL's meaning, latched (moves and homing
//!   refused) until `clear_fault`, then re-home.
//! - unexpected reset banner: `Reset`, position unknown until re-homed.
//! - emergency stop mid-move: the move fails, the arm stops short of its target.

use std::thread;
use std::time::{Duration, Instant};

use gonio_drivers::grbl::{GrblArm, GrblArmConfig};
use gonio_drivers::{Arm, ArmState, DeviceError};
use gonio_mock_hw::grbl::{Fault, GrblConfig, GrblEmulator};
use gonio_mock_hw::world::World;

const SCAN_DEG: [f64; 6] = [-20.0, -25.0, -30.0, -35.0, -40.0, -45.0];

fn driver_config() -> GrblArmConfig {
    GrblArmConfig {
        banner_timeout: Duration::from_millis(500),
        reply_timeout: Duration::from_millis(500),
        homing_timeout: Duration::from_secs(10),
        move_margin: Duration::from_secs(1),
        reconnect_attempts: 6,
        reconnect_backoff: Duration::from_millis(50),
        ..GrblArmConfig::default()
    }
}

fn rig(time_scale: f64) -> (GrblEmulator, World, GrblArm) {
    let world = World::new(-7.5);
    let config = GrblConfig {
        time_scale,
        ..GrblConfig::arm_board()
    };
    let emulator = GrblEmulator::start(config, world.clone()).unwrap();
    let arm = GrblArm::open(emulator.device_path(), driver_config()).unwrap();
    (emulator, world, arm)
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

#[test]
fn homes_and_moves_through_the_scan_angles() {
    let (_emulator, world, mut arm) = rig(0.01);
    assert!(arm.firmware().starts_with("1.1h"), "{}", arm.firmware());
    assert_eq!(arm.status().unwrap().state, ArmState::NeedsHoming);
    assert!(matches!(arm.move_to(-20.0), Err(DeviceError::Reset)));
    arm.home().unwrap();
    assert!((world.arm_deg() + 1.0).abs() < 0.05);
    for deg in SCAN_DEG {
        move_and_check(&mut arm, &world, deg);
    }
    for outside in [0.5, -90.5, f64::NAN] {
        assert!(matches!(
            arm.move_to(outside),
            Err(DeviceError::OutOfRange { .. })
        ));
    }
    assert!((world.arm_deg() + 45.0).abs() < 0.05);
}

#[test]
fn settings_mismatch_is_refused() {
    let emulator = GrblEmulator::start(
        GrblConfig {
            time_scale: 0.01,
            steps_per_deg: 100.0,
            ..GrblConfig::arm_board()
        },
        World::new(0.0),
    )
    .unwrap();
    let Err(DeviceError::Protocol(message)) =
        GrblArm::open(emulator.device_path(), driver_config())
    else {
        panic!("mismatched steps per degree accepted")
    };
    assert!(message.contains("$100"), "{message}");
}

#[test]
fn unplug_then_reconnect_requires_homing() {
    let (emulator, world, mut arm) = rig(0.01);
    arm.home().unwrap();
    move_and_check(&mut arm, &world, -20.0);
    emulator.inject(Fault::Unplug);
    assert!(matches!(arm.status(), Err(DeviceError::Disconnected(_))));
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
    assert!(matches!(arm.move_to(-25.0), Err(DeviceError::Reset)));
    arm.home().unwrap();
    move_and_check(&mut arm, &world, -25.0);
}

#[test]
fn silent_controller_times_out_then_recovers() {
    let (emulator, world, mut arm) = rig(0.01);
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

#[test]
fn garbled_and_truncated_replies_are_survived() {
    let (emulator, world, mut arm) = rig(0.01);
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

#[test]
fn alarm_during_motion_latches_until_cleared_and_rehomed() {
    let (emulator, world, mut arm) = rig(0.01);
    arm.home().unwrap();
    move_and_check(&mut arm, &world, -20.0);
    emulator.inject(Fault::AlarmDuringMotion(1));
    let Err(DeviceError::Alarm { code: 1, meaning }) = arm.move_to(-45.0) else {
        panic!("alarm not reported")
    };
    assert!(meaning.contains("hard limit"), "{meaning}");
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
    assert!(matches!(arm.move_to(-30.0), Err(DeviceError::Reset)));
    arm.home().unwrap();
    move_and_check(&mut arm, &world, -30.0);
}

#[test]
fn unexpected_reset_banner_requires_homing() {
    let (emulator, world, mut arm) = rig(0.01);
    arm.home().unwrap();
    move_and_check(&mut arm, &world, -35.0);
    emulator.inject(Fault::ResetBanner);
    assert!(matches!(arm.move_to(-40.0), Err(DeviceError::Reset)));
    assert_eq!(arm.status().unwrap().state, ArmState::NeedsHoming);
    assert!(matches!(arm.move_to(-40.0), Err(DeviceError::Reset)));
    arm.home().unwrap();
    move_and_check(&mut arm, &world, -40.0);
}

#[test]
fn emergency_stop_halts_a_move_from_another_thread() {
    // Slower time so the stop lands mid-move: 80° at 20°/s is 4 machine s = 0.4 s.
    let (_emulator, world, mut arm) = rig(0.1);
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
    assert!(at < -1.0 && at > -79.0, "arm at {at}");
    assert!(matches!(
        arm.move_to(-20.0),
        Err(DeviceError::Alarm { .. } | DeviceError::Reset)
    ));
    arm.clear_fault().unwrap();
    arm.home().unwrap();
    move_and_check(&mut arm, &world, -20.0);
}
