//! What GRBL 1.1h sends, and when, for the behaviours drivers trip over: the reset on
//! every open of the port, homing failures, the stock homing cycles, silence during a
//! critical alarm. Each states the exact bytes.

use crate::grbl_support;

use std::time::Duration;

use gonio_mock_hw::grbl::{AxisSet, GrblConfig};
use grbl_support::{fast_config, start, Client, BANNER, LOCKED_BANNER};

#[test]
fn opening_the_port_resets_the_board_every_time() {
    let (emulator, world) = start(fast_config(), -30.0);
    let path = emulator.device_path().to_path_buf();
    let mut grbl = Client::open(&path);
    grbl.expect(LOCKED_BANNER);
    grbl.exchange("$X\n", "[MSG:Caution: Unlocked]\r\nok\r\n");
    grbl.exchange("G0X-5\nG4P0\n", "ok\r\nok\r\n");
    grbl.exchange("?", "<Idle|MPos:-5.000,0.000,0.000|FS:0,0>\r\n");
    drop(grbl);
    // DTR: the board restarts, locked again, counting MPos from zero; the arm stays.
    std::thread::sleep(Duration::from_millis(30));
    let mut grbl = Client::open(&path);
    grbl.expect(LOCKED_BANNER);
    grbl.exchange("?", "<Alarm|MPos:0.000,0.000,0.000|FS:0,0>\r\n");
    assert_eq!(world.arm_deg(), -35.0);
    // What is sent while the board boots is lost in its boot loader.
    drop(grbl);
    std::thread::sleep(Duration::from_millis(30));
    let mut grbl = Client::open(&path);
    grbl.send(b"$I\n");
    grbl.expect(LOCKED_BANNER);
    grbl.expect_silence(Duration::from_millis(50));
}

#[test]
fn homing_without_pulloff_fails_with_alarm_8_then_ok_then_banner() {
    let (emulator, _world) = start(fast_config(), -10.0);
    let mut grbl = Client::open(emulator.device_path());
    grbl.expect(LOCKED_BANNER);
    grbl.exchange("$27=0\n", "ok\r\n");
    grbl.send(b"$H\n");
    grbl.expect(&format!("ALARM:8\r\nok\r\n{LOCKED_BANNER}"));
    grbl.exchange("?", "<Alarm|MPos:10.000,0.000,0.000|FS:0,0>\r\n");
}

#[test]
fn stock_cycles_home_z_then_x_and_y_each_to_minus_pulloff() {
    let config = GrblConfig {
        time_scale: 0.002,
        homing_enabled: true,
        status_extras: true,
        ..GrblConfig::default()
    };
    let (emulator, world) = start(config.clone(), -3.0);
    let mut grbl = Client::open(emulator.device_path());
    grbl.expect(LOCKED_BANNER);
    grbl.exchange("$H\n", "ok\r\n");
    grbl.exchange(
        "?",
        "<Idle|MPos:-1.000,-1.000,-1.000|FS:0,0|WCO:0.000,0.000,0.000>\r\n",
    );
    assert!((world.arm_deg() + 1.0).abs() < 1e-9);
    // Nothing wired on Z: the stock first cycle searches 1.5 × $132 and gives up.
    let config = GrblConfig {
        idle_axis_switch: None,
        ..config
    };
    let (emulator, _world) = start(config, -3.0);
    let mut grbl = Client::open(emulator.device_path());
    grbl.expect(LOCKED_BANNER);
    grbl.send(b"$H\n");
    grbl.expect(&format!("ALARM:9\r\nok\r\n{LOCKED_BANNER}"));
    grbl.exchange(
        "?",
        "<Alarm|MPos:0.000,0.000,300.000|FS:0,0|WCO:0.000,0.000,0.000>\r\n",
    );
    // A board built for the arm homes X alone.
    let (emulator, _world) = start(
        GrblConfig {
            homing_cycles: vec![AxisSet { mask: 1 }],
            idle_axis_switch: None,
            time_scale: 0.01,
            homing_enabled: true,
            ..GrblConfig::default()
        },
        -3.0,
    );
    let mut grbl = Client::open(emulator.device_path());
    grbl.expect(LOCKED_BANNER);
    grbl.exchange("$H\n", "ok\r\n");
}

#[test]
fn a_hard_limit_locks_the_board_silent_until_reset() {
    let config = GrblConfig {
        hard_limits: true,
        homing_enabled: false,
        soft_limits: false,
        ..fast_config()
    };
    let (emulator, world) = start(config, -5.0);
    let mut grbl = Client::open(emulator.device_path());
    grbl.expect(BANNER);
    // Into the switch at θ = 0: ALARM:1, and from then on not even `?` is answered.
    grbl.send(b"G0X10\nG4P0\n");
    grbl.expect("ok\r\nALARM:1\r\n[MSG:Reset to continue]\r\n");
    grbl.send(b"?$X\n?");
    grbl.expect_silence(Duration::from_millis(50));
    assert!(world.arm_deg() >= 0.0);
    // The reset answers the waiting G4, and the board reports the pressed switch.
    grbl.send(b"\x18");
    grbl.expect(
        "ok\r\n\r\nGrbl 1.1h ['$' for help]\r\n[MSG:Check Limits]\r\n[MSG:'$H'|'$X' to unlock]\r\n",
    );
    grbl.expect_silence(Duration::from_millis(30));
}
