//! The driver against a scripted controller on a pseudo-terminal.

use std::collections::BTreeMap;
use std::io::{Read, Write};
use std::thread;
use std::time::Instant;

use super::*;
use crate::{Arm, ArmState};
use serialport::TTYPort;

/// How the scripted controller behaves.
struct Script {
    silent: bool,
    /// Reply `ALARM:N` instead of finishing the next move.
    alarm_on_move: Option<u32>,
    /// Garble this many upcoming replies.
    garble: u32,
    /// Answer `G4 P0` only when reset (the move never ends by itself).
    stuck: bool,
    settings: BTreeMap<u32, f64>,
    /// Every line received, in order.
    received: Vec<String>,
}

struct Fake {
    script: Arc<Mutex<Script>>,
    path: PathBuf,
}

/// The controller's state as the fake keeps it.
#[derive(Default)]
struct Machine {
    x: f64,
    target: f64,
    /// G92 work offset.
    wco: f64,
    /// A `G4 P0` waiting for the stuck move.
    waiting: bool,
    line: Vec<u8>,
}

impl Machine {
    /// The reply to one received byte, if it completes something.
    fn byte(&mut self, b: u8, s: &mut Script) -> Option<String> {
        let banner = "\r\nGrbl 1.1h ['$' for help]\r\n";
        match b {
            SOFT_RESET => {
                self.wco = 0.0;
                // The executing line is answered before the banner.
                let ok = if std::mem::take(&mut self.waiting) {
                    "ok\r\n"
                } else {
                    ""
                };
                Some(format!("{ok}{banner}"))
            }
            b'?' => Some(format!("<Idle|MPos:{:.3},0.000,0.000|FS:0,0>\r\n", self.x)),
            b'!' => None,
            b'\n' => {
                let text = String::from_utf8_lossy(&self.line).trim().to_string();
                self.line.clear();
                s.received.push(text.clone());
                Some(self.execute(&text, s))
            }
            _ => {
                self.line.push(b);
                None
            }
        }
    }

    fn execute(&mut self, text: &str, s: &mut Script) -> String {
        if let Some((key, value)) = text.strip_prefix('$').and_then(|t| t.split_once('=')) {
            if let (Ok(key), Ok(value)) = (key.parse(), value.parse()) {
                s.settings.insert(key, value);
                return "ok\r\n".into();
            }
        }
        match text {
            "$I" => "[VER:1.1h.fake:]\r\nok\r\n".into(),
            "$$" => {
                let mut reply = String::new();
                for (key, value) in &s.settings {
                    reply.push_str(&format!("${key}={value:.3}\r\n"));
                }
                reply + "ok\r\n"
            }
            "$H" => {
                self.x = -1.0;
                "ok\r\n".into()
            }
            "$X" => "ok\r\n".into(),
            "G4 P0" => match s.alarm_on_move.take() {
                Some(code) => format!("ALARM:{code}\r\n"),
                None if s.stuck => {
                    self.waiting = true;
                    String::new()
                }
                None => {
                    self.x = self.target;
                    "ok\r\n".into()
                }
            },
            t => {
                let value = |prefix: &str| t.strip_prefix(prefix).map(str::parse::<f64>);
                if let Some(Ok(v)) = value("G90 G0 X") {
                    self.target = v + self.wco;
                    "ok\r\n".into()
                } else if let Some(Ok(v)) = value("G92 X") {
                    self.wco = self.x - v;
                    "ok\r\n".into()
                } else {
                    "error:20\r\n".into()
                }
            }
        }
    }
}

fn fake() -> Fake {
    let (mut master, slave) = TTYPort::pair().unwrap();
    let path = PathBuf::from(slave.name().unwrap());
    drop(slave);
    let settings = [
        (13, 0.0),
        (22, 1.0),
        (100, 80.0),
        (110, 6000.0),
        (120, 500.0),
        (130, 180.0),
    ];
    let script = Arc::new(Mutex::new(Script {
        silent: false,
        alarm_on_move: None,
        garble: 0,
        stuck: false,
        settings: settings.into_iter().collect(),
        received: Vec::new(),
    }));
    let shared = script.clone();
    thread::spawn(move || {
        let mut machine = Machine::default();
        let mut buf = [0u8; 64];
        loop {
            let n = match master.read(&mut buf) {
                Ok(n) => n,
                Err(e) if e.kind() == std::io::ErrorKind::TimedOut => continue,
                // No slave open (yet): wait for the driver.
                Err(_) => {
                    thread::sleep(Duration::from_millis(5));
                    continue;
                }
            };
            for &b in &buf[..n] {
                let mut s = shared.lock().unwrap();
                if s.silent {
                    continue;
                }
                let Some(reply) = machine.byte(b, &mut s) else {
                    continue;
                };
                let reply = if s.garble > 0 && !reply.is_empty() {
                    s.garble -= 1;
                    format!("{}\r\n", &reply.trim()[..reply.trim().len() / 2])
                } else {
                    reply
                };
                drop(s);
                let _ = master.write_all(reply.as_bytes());
            }
        }
    });
    Fake { script, path }
}

impl Fake {
    fn received(&self) -> Vec<String> {
        self.script.lock().unwrap().received.clone()
    }
}

/// An arm on `fake`, homed.
fn homed(fake: &Fake) -> GrblArm {
    let mut arm = GrblArm::open(&fake.path, config()).unwrap();
    arm.home().unwrap();
    arm
}

fn config() -> GrblArmConfig {
    GrblArmConfig {
        banner_timeout: Duration::from_millis(100),
        reply_timeout: Duration::from_millis(300),
        motion_margin: Duration::from_millis(500),
        stall_timeout: Duration::from_millis(300),
        reconnect_attempts: 2,
        reconnect_backoff: Duration::from_millis(10),
        ..GrblArmConfig::default()
    }
}

#[test]
fn connects_homes_and_moves() {
    let fake = fake();
    let mut arm = GrblArm::open(&fake.path, config()).unwrap();
    assert_eq!(arm.firmware(), "1.1h.fake:");
    assert!(!arm.referenced());
    assert_eq!(arm.status().unwrap().state, ArmState::NeedsHoming);
    assert!(matches!(
        arm.move_to(-20.0),
        Err(DeviceError::PositionUnknown(_))
    ));
    arm.home().unwrap();
    for deg in [-20.0, -32.5, -45.0] {
        arm.move_to(deg).unwrap();
        let status = arm.status().unwrap();
        assert_eq!(status.state, ArmState::Idle);
        assert!((status.angle_deg - deg).abs() < 1e-9);
    }
    assert_eq!(
        fake.received(),
        [
            "$I",
            "$$",
            "$H",
            "G92 X-1.000",
            "G90 G0 X-20.000",
            "G4 P0",
            "G90 G0 X-32.500",
            "G4 P0",
            "G90 G0 X-45.000",
            "G4 P0"
        ]
    );
}

#[test]
fn refuses_out_of_range_targets_without_sending() {
    let fake = fake();
    let mut arm = homed(&fake);
    let before = fake.received().len();
    for deg in [-0.5, -90.01, f64::NAN, f64::NEG_INFINITY] {
        assert!(
            matches!(arm.move_to(deg), Err(DeviceError::OutOfRange { .. })),
            "{deg}"
        );
    }
    assert_eq!(fake.received().len(), before);
}

#[test]
fn settings_mismatches_are_listed_or_applied() {
    let fake = fake();
    fake.script.lock().unwrap().settings.insert(100, 250.0);
    fake.script.lock().unwrap().settings.insert(22, 0.0);
    let Err(DeviceError::SettingsDiffer(lines)) = GrblArm::open(&fake.path, config()) else {
        panic!("mismatch not reported")
    };
    assert_eq!(
        lines,
        [
            "$22 (homing cycle enable) is 0, configuration expects 1",
            "$100 (X steps per degree) is 250, configuration expects 80",
        ]
    );
    let apply = GrblArmConfig {
        apply_settings: true,
        ..config()
    };
    GrblArm::open(&fake.path, apply).unwrap();
    let received = fake.received();
    assert_eq!(received[received.len() - 3..], ["$22=1", "$100=80", "$$"]);
}

#[test]
fn declared_position_where_the_controller_does_not_home() {
    let fake = fake();
    fake.script.lock().unwrap().settings.insert(22, 0.0);
    let off = GrblArmConfig {
        homing: Homing::Off,
        ..config()
    };
    let mut arm = GrblArm::open(&fake.path, off).unwrap();
    assert_eq!(arm.status().unwrap().state, ArmState::NeedsPosition);
    assert!(matches!(arm.home(), Err(DeviceError::PositionUnknown(_))));
    // Off the travel [−$130, 0]: refused unsent.
    let sent = fake.received().len();
    for angle in [10.0, 0.5, -180.5, 359.0, f64::NAN] {
        assert!(
            matches!(
                arm.declare_position(angle),
                Err(DeviceError::OutOfRange { min, max, .. }) if (min, max) == (-180.0, 0.0)
            ),
            "{angle}"
        );
    }
    assert_eq!(fake.received().len(), sent);
    arm.declare_position(-12.0).unwrap();
    arm.home().unwrap();
    arm.move_to(-20.0).unwrap();
    assert!((arm.status().unwrap().angle_deg + 20.0).abs() < 1e-9);
    assert!(fake.received().ends_with(&[
        "G92 X-12.000".to_owned(),
        "G90 G0 X-20.000".to_owned(),
        "G4 P0".to_owned()
    ]));
    // Where homing is required, declaring is refused.
    let homing = self::fake();
    let mut arm = GrblArm::open(&homing.path, config()).unwrap();
    assert!(matches!(
        arm.declare_position(-12.0),
        Err(DeviceError::Refused(_))
    ));
}

#[test]
fn an_unanswered_line_is_never_followed_by_another_before_a_reset() {
    let fake = fake();
    let mut arm = homed(&fake);
    arm.move_to(-20.0).unwrap();
    // The move never ends by itself: `G4 P0` goes unanswered, the position stays.
    fake.script.lock().unwrap().stuck = true;
    let started = Instant::now();
    let Err(DeviceError::Timeout { what, .. }) = arm.move_to(-30.0) else {
        panic!("no timeout")
    };
    assert!(what.contains("resynchronised"), "{what}");
    assert!(started.elapsed() < Duration::from_secs(5));
    // Feed hold and reset answered the old `G4 P0` (paired, not taken for a newer
    // line); the work offset was restored; nothing was sent twice.
    let received = fake.received();
    let tail: Vec<&str> = received
        .iter()
        .rev()
        .take(3)
        .rev()
        .map(String::as_str)
        .collect();
    assert_eq!(tail, ["G90 G0 X-30.000", "G4 P0", "G92 X-20.000"]);
    fake.script.lock().unwrap().stuck = false;
    arm.move_to(-30.0).unwrap();
}

#[test]
fn silent_controller_times_out() {
    let fake = fake();
    let mut arm = homed(&fake);
    fake.script.lock().unwrap().silent = true;
    assert!(matches!(
        arm.move_to(-20.0),
        Err(DeviceError::Timeout { .. })
    ));
    assert!(matches!(arm.status(), Err(DeviceError::Timeout { .. })));
    fake.script.lock().unwrap().silent = false;
    arm.move_to(-20.0).unwrap();
}

#[test]
fn garbled_replies_are_retried() {
    let fake = fake();
    let mut arm = homed(&fake);
    fake.script.lock().unwrap().garble = 2;
    arm.move_to(-25.0).unwrap();
    assert!((arm.status().unwrap().angle_deg + 25.0).abs() < 1e-9);
    fake.script.lock().unwrap().garble = 100;
    assert!(matches!(arm.status(), Err(DeviceError::Protocol(_))));
}

#[test]
fn alarm_latches_until_cleared_and_rehomed() {
    let fake = fake();
    let mut arm = homed(&fake);
    fake.script.lock().unwrap().alarm_on_move = Some(1);
    let Err(DeviceError::Alarm { code: 1, meaning }) = arm.move_to(-30.0) else {
        panic!("alarm not reported")
    };
    assert!(meaning.contains("hard limit"));
    // GRBL answers nothing during a hard-limit lock: the driver reset it at once.
    assert!(fake.received().ends_with(&["G4 P0".to_owned()]));
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
    assert!(matches!(
        arm.move_to(-30.0),
        Err(DeviceError::PositionUnknown(_))
    ));
    arm.home().unwrap();
    arm.move_to(-30.0).unwrap();
}

#[test]
fn emergency_stop_resets_the_controller() {
    let fake = fake();
    let mut arm = homed(&fake);
    arm.move_to(-20.0).unwrap();
    let stop = arm.emergency_stop();
    thread::spawn(move || stop.stop()).join().unwrap().unwrap();
    assert!(matches!(
        arm.move_to(-25.0),
        Err(DeviceError::PositionUnknown(_))
    ));
    assert_eq!(arm.status().unwrap().state, ArmState::NeedsHoming);
}

#[test]
fn missing_device_is_reported() {
    let result = GrblArm::open(Path::new("/nonexistent/serial/by-id/grbl"), config());
    assert!(matches!(
        result,
        Err(DeviceError::NotFound(_) | DeviceError::Disconnected(_))
    ));
}
