//! The driver against a scripted controller on a pseudo-terminal.

use super::*;
use serialport::TTYPort;

/// How the scripted controller misbehaves.
#[derive(Default)]
struct Script {
    silent: bool,
    /// Reply `ALARM:N` instead of finishing the next move.
    alarm_on_move: Option<u32>,
    /// Garble this many upcoming replies.
    garble: u32,
    steps_per_deg: f64,
    /// Every line received, in order.
    received: Vec<String>,
}

struct Fake {
    script: Arc<Mutex<Script>>,
    path: PathBuf,
}

fn fake() -> Fake {
    let (mut master, slave) = TTYPort::pair().unwrap();
    let path = PathBuf::from(slave.name().unwrap());
    drop(slave);
    let script = Arc::new(Mutex::new(Script {
        steps_per_deg: 80.0,
        ..Script::default()
    }));
    let shared = script.clone();
    thread::spawn(move || {
        let mut x = 0.0f64;
        let mut target = 0.0f64;
        let mut line = Vec::new();
        let mut buf = [0u8; 64];
        loop {
            let n = match master.read(&mut buf) {
                Ok(n) => n,
                Err(e) if e.kind() == io::ErrorKind::TimedOut => continue,
                // No slave open (yet): wait for the driver.
                Err(_) => {
                    thread::sleep(Duration::from_millis(5));
                    continue;
                }
            };
            for &b in &buf[..n] {
                let mut s = shared.lock().unwrap();
                let reply = match b {
                    _ if s.silent => continue,
                    SOFT_RESET => "\r\nGrbl 1.1h ['$' for help]\r\n".to_string(),
                    b'?' => format!("<Idle|MPos:{x:.3},0.000,0.000|FS:0,0>\r\n"),
                    b'\n' => {
                        let text = String::from_utf8_lossy(&line).trim().to_string();
                        line.clear();
                        s.received.push(text.clone());
                        match text.as_str() {
                            "$I" => "[VER:1.1h.fake:]\r\nok\r\n".into(),
                            "$$" => format!(
                                "$22=1\r\n$100={:.3}\r\n$110=6000.000\r\n$120=500.000\r\n$130=180.000\r\nok\r\n",
                                s.steps_per_deg
                            ),
                            "$H" => {
                                x = 0.0;
                                "ok\r\n".into()
                            }
                            "G4 P0" => match s.alarm_on_move.take() {
                                Some(code) => format!("ALARM:{code}\r\n"),
                                None => {
                                    x = target;
                                    "ok\r\n".into()
                                }
                            },
                            t => match t.strip_prefix("G90 G0 X").map(str::parse::<f64>) {
                                Some(Ok(v)) => {
                                    target = v;
                                    "ok\r\n".into()
                                }
                                _ => "error:20\r\n".into(),
                            },
                        }
                    }
                    _ => {
                        line.push(b);
                        continue;
                    }
                };
                let reply = if s.garble > 0 {
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

fn config() -> GrblArmConfig {
    GrblArmConfig {
        banner_timeout: Duration::from_millis(100),
        reply_timeout: Duration::from_millis(300),
        homing_timeout: Duration::from_secs(2),
        move_margin: Duration::from_millis(500),
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
    assert!(arm.needs_homing());
    assert_eq!(arm.status().unwrap().state, ArmState::NeedsHoming);
    assert!(matches!(arm.move_to(-20.0), Err(DeviceError::Reset)));
    arm.home().unwrap();
    for deg in [-20.0, -32.5, -45.0] {
        arm.move_to(deg).unwrap();
        let status = arm.status().unwrap();
        assert_eq!(status.state, ArmState::Idle);
        assert!((status.angle_deg - deg).abs() < 1e-9);
    }
    let received = fake.script.lock().unwrap().received.clone();
    assert_eq!(
        received,
        [
            "$I",
            "$$",
            "$H",
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
    let mut arm = GrblArm::open(&fake.path, config()).unwrap();
    arm.home().unwrap();
    let before = fake.script.lock().unwrap().received.len();
    for deg in [0.5, -90.01, f64::NAN, f64::NEG_INFINITY] {
        assert!(
            matches!(arm.move_to(deg), Err(DeviceError::OutOfRange { .. })),
            "{deg}"
        );
    }
    assert_eq!(fake.script.lock().unwrap().received.len(), before);
}

#[test]
fn reports_a_settings_mismatch() {
    let fake = fake();
    fake.script.lock().unwrap().steps_per_deg = 100.0;
    let Err(DeviceError::Protocol(message)) = GrblArm::open(&fake.path, config()) else {
        panic!("mismatch not reported")
    };
    assert!(
        message.contains("$100") && message.contains("100") && message.contains("80"),
        "{message}"
    );
}

#[test]
fn silent_controller_times_out() {
    let fake = fake();
    let mut arm = GrblArm::open(&fake.path, config()).unwrap();
    arm.home().unwrap();
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
    let mut arm = GrblArm::open(&fake.path, config()).unwrap();
    arm.home().unwrap();
    fake.script.lock().unwrap().garble = 2;
    arm.move_to(-25.0).unwrap();
    assert!((arm.status().unwrap().angle_deg + 25.0).abs() < 1e-9);
    fake.script.lock().unwrap().garble = 100;
    assert!(matches!(arm.status(), Err(DeviceError::Protocol(_))));
}

#[test]
fn alarm_latches_until_cleared_and_rehomed() {
    let fake = fake();
    let mut arm = GrblArm::open(&fake.path, config()).unwrap();
    arm.home().unwrap();
    fake.script.lock().unwrap().alarm_on_move = Some(1);
    let Err(DeviceError::Alarm { code: 1, meaning }) = arm.move_to(-30.0) else {
        panic!("alarm not reported")
    };
    assert!(meaning.contains("hard limit"));
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
    assert!(matches!(arm.move_to(-30.0), Err(DeviceError::Reset)));
    arm.home().unwrap();
    arm.move_to(-30.0).unwrap();
}

#[test]
fn emergency_stop_resets_the_controller() {
    let fake = fake();
    let mut arm = GrblArm::open(&fake.path, config()).unwrap();
    arm.home().unwrap();
    arm.move_to(-20.0).unwrap();
    let stop = arm.emergency_stop();
    thread::spawn(move || stop.stop()).join().unwrap().unwrap();
    assert!(matches!(arm.move_to(-25.0), Err(DeviceError::Reset)));
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
