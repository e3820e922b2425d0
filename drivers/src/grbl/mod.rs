//! The light arm on a GRBL 1.1 controller over a serial port (115200 8N1).
//!
//! The arm is the controller's X axis, configured in degrees: GRBL's "mm" are degrees,
//! `$100` is steps per degree, `$110` the max rate in degrees/minute, `$120` the
//! acceleration in degrees/s², `$130` the max travel in degrees. Homing puts the arm at
//! machine X = 0 (the positive end); the work offset must be zero, so the commanded
//! `G90 G0 X…` angle is the machine position θL.
//!
//! Open the controller by a stable path such as `/dev/serial/by-id/usb-…-if00-port0`
//! (not `/dev/ttyUSB0`, whose number changes between plug-ins); reconnects reopen the
//! same path.
//!
//! Fault handling, all blocking with bounded waits:
//! - `error:N` → [`DeviceError::Rejected`], `ALARM:N` → [`DeviceError::Alarm`] with
//!   GRBL's meaning. An alarm stays latched: [`Arm::clear_fault`] (soft reset) and then
//!   [`Arm::home`] are needed before the next move.
//! - A start-up banner after connecting means the controller reset: the position is
//!   unknown, a command in flight fails with [`DeviceError::Reset`], and moves are
//!   refused with `Reset` until the arm is homed again.
//! - A read or write failure drops the port and fails with
//!   [`DeviceError::Disconnected`]; the next call reopens the same path with bounded
//!   exponential backoff, after which the arm must be homed again.
//! - A silent controller gives [`DeviceError::Timeout`]; a garbled or truncated reply
//!   to an idempotent command (queries, `G90 G0`, `G4 P0`, `$H`) is retried a bounded
//!   number of times, then reported as [`DeviceError::Protocol`].
//!
//! ```no_run
//! use gonio_drivers::grbl::{GrblArm, GrblArmConfig};
//! use gonio_drivers::Arm;
//! # fn main() -> Result<(), gonio_drivers::DeviceError> {
//! let path = std::path::Path::new("/dev/serial/by-id/usb-1a86_USB_Serial-if00-port0");
//! let mut arm = GrblArm::open(path, GrblArmConfig::default())?;
//! let stop = arm.emergency_stop(); // hand this to whoever may need to stop the arm
//! arm.home()?;
//! arm.move_to(-20.0)?;
//! # drop(stop);
//! # Ok(())
//! # }
//! ```

mod codes;
mod protocol;

pub use codes::{alarm_meaning, error_meaning};
pub use protocol::{move_time_s, parse_line, Line, MachineState, Settings, StatusReport};

use std::io::{self, Read, Write};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, PoisonError};
use std::thread;
use std::time::{Duration, Instant};

use serialport::SerialPort;

use crate::{Arm, ArmState, ArmStatus, DeviceError, EmergencyStop};

/// Serial speed of GRBL 1.1.
pub const BAUD_RATE: u32 = 115_200;
/// Port read timeout: how often a blocked read checks its deadline.
const POLL_INTERVAL: Duration = Duration::from_millis(20);
/// After a garbled line, how long to wait for a proper reply before giving up on it;
/// also how long a partial line may sit without more bytes before it counts as a
/// truncated line (GRBL sends a whole line within milliseconds).
const GARBLE_GRACE: Duration = Duration::from_millis(200);
/// GRBL's soft-reset real-time byte (Ctrl-X).
const SOFT_RESET: u8 = 0x18;
/// GRBL's feed-hold real-time byte.
const FEED_HOLD: u8 = b'!';

/// What the driver expects of the controller and how patiently it talks to it.
#[derive(Debug, Clone, PartialEq)]
pub struct GrblArmConfig {
    /// Soft limits of the arm angle θL in degrees; targets outside are refused unsent.
    pub min_deg: f64,
    pub max_deg: f64,
    /// Expected `$100` (steps per degree).
    pub steps_per_deg: f64,
    /// Expected `$130` (max travel, degrees).
    pub max_travel_deg: f64,
    /// Expected `$22` (homing cycle enabled).
    pub homing_enabled: bool,
    /// How far the confirmed position may be from the target, degrees.
    pub position_tolerance_deg: f64,
    /// Wait for the start-up banner after opening (and again after a soft reset).
    pub banner_timeout: Duration,
    /// Wait for the reply to a command that does not wait for motion.
    pub reply_timeout: Duration,
    /// Wait for the homing cycle to finish.
    pub homing_timeout: Duration,
    /// A move may take `move_time_factor` × its trapezoid time + `move_margin`.
    pub move_time_factor: f64,
    pub move_margin: Duration,
    /// Retries of an idempotent command after a garbled reply.
    pub garbled_retries: u32,
    /// Reconnect attempts after a disconnect, and the first backoff (doubling each
    /// attempt, capped at 16×).
    pub reconnect_attempts: u32,
    pub reconnect_backoff: Duration,
}

impl Default for GrblArmConfig {
    fn default() -> Self {
        Self {
            min_deg: -90.0,
            max_deg: 0.0,
            steps_per_deg: 80.0,
            max_travel_deg: 180.0,
            homing_enabled: true,
            position_tolerance_deg: 0.01,
            banner_timeout: Duration::from_secs(3),
            reply_timeout: Duration::from_secs(2),
            homing_timeout: Duration::from_secs(90),
            move_time_factor: 1.5,
            move_margin: Duration::from_secs(2),
            garbled_retries: 3,
            reconnect_attempts: 5,
            reconnect_backoff: Duration::from_millis(200),
        }
    }
}

/// What a command's reply ends with.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Until {
    /// `ok` (or `error:N`).
    Ok,
    /// A `<...>` status report (the reply to `?`, which sends no `ok`).
    Status,
}

/// The stop handle: a clone of the port handle, replaced on every reconnect.
struct GrblStop {
    port: Mutex<Option<Box<dyn SerialPort>>>,
}

impl GrblStop {
    fn replace(&self, port: Option<Box<dyn SerialPort>>) {
        *self.port.lock().unwrap_or_else(PoisonError::into_inner) = port;
    }
}

impl EmergencyStop for GrblStop {
    /// Feed hold, then soft reset. The position is unknown afterwards: home again.
    fn stop(&self) -> Result<(), DeviceError> {
        let mut guard = self.port.lock().unwrap_or_else(PoisonError::into_inner);
        let port = guard
            .as_mut()
            .ok_or_else(|| DeviceError::Disconnected("arm controller not connected".into()))?;
        port.write_all(&[FEED_HOLD])
            .and_then(|()| port.write_all(&[SOFT_RESET]))
            .and_then(|()| port.flush())
            .map_err(|e| DeviceError::Disconnected(format!("stop not sent: {e}")))
    }
}

/// The light arm on a GRBL controller. Blocking: call it from a dedicated thread.
pub struct GrblArm {
    path: PathBuf,
    config: GrblArmConfig,
    /// `None` while disconnected.
    port: Option<Box<dyn SerialPort>>,
    /// Received bytes not yet forming a full line, and when the last byte came.
    pending: Vec<u8>,
    last_rx: Instant,
    settings: Settings,
    firmware: String,
    /// Whether the machine position is known (homed since the last reset/reconnect).
    homed: bool,
    /// A latched `ALARM:N` until [`Arm::clear_fault`].
    alarm: Option<u32>,
    last_angle_deg: f64,
    stop: Arc<GrblStop>,
}

impl GrblArm {
    /// Open the controller at `path`, wait for its banner (soft-resetting it if none
    /// comes), read `$I` and `$$`, and check the settings against `config`.
    /// The arm then needs homing.
    pub fn open(path: &Path, config: GrblArmConfig) -> Result<GrblArm, DeviceError> {
        if !(config.min_deg.is_finite() && config.max_deg.is_finite())
            || config.min_deg >= config.max_deg
        {
            return Err(DeviceError::OutOfRange {
                what: "soft limit min_deg".into(),
                value: config.min_deg,
                min: f64::NEG_INFINITY,
                max: config.max_deg,
            });
        }
        let mut arm = GrblArm {
            path: path.to_owned(),
            config,
            port: None,
            pending: Vec::new(),
            last_rx: Instant::now(),
            settings: Settings::default(),
            firmware: String::new(),
            homed: false,
            alarm: None,
            last_angle_deg: 0.0,
            stop: Arc::new(GrblStop {
                port: Mutex::new(None),
            }),
        };
        arm.connect()?;
        Ok(arm)
    }

    /// The `[VER:…]` line of `$I`, e.g. `1.1h.20190825:`.
    pub fn firmware(&self) -> &str {
        &self.firmware
    }

    /// The controller's `$$` settings as last read.
    pub fn settings(&self) -> &Settings {
        &self.settings
    }

    /// Whether the arm must be homed before it can move.
    pub fn needs_homing(&self) -> bool {
        !self.homed
    }

    /// The device path this arm was opened with.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Time allowed for a move of `distance_deg` with the controller's rate and
    /// acceleration.
    pub fn move_timeout(&self, distance_deg: f64) -> Duration {
        let rate = self.settings.get(Settings::MAX_RATE_X).unwrap_or(0.0);
        let accel = self.settings.get(Settings::ACCEL_X).unwrap_or(0.0);
        let t = move_time_s(distance_deg, rate, accel) * self.config.move_time_factor;
        Duration::try_from_secs_f64(t).unwrap_or(Duration::from_secs(3600))
            + self.config.move_margin
    }

    // ---- connection -------------------------------------------------------------

    fn disconnected(&self, why: impl std::fmt::Display) -> DeviceError {
        DeviceError::Disconnected(format!("{}: {why}", self.path.display()))
    }

    /// Forget the port after an I/O failure.
    fn drop_port(&mut self, error: &io::Error) -> DeviceError {
        self.port = None;
        self.pending.clear();
        self.homed = false;
        self.stop.replace(None);
        self.disconnected(error)
    }

    fn connect(&mut self) -> Result<(), DeviceError> {
        let port = serialport::new(self.path.to_string_lossy(), BAUD_RATE)
            .data_bits(serialport::DataBits::Eight)
            .parity(serialport::Parity::None)
            .stop_bits(serialport::StopBits::One)
            .flow_control(serialport::FlowControl::None)
            .timeout(POLL_INTERVAL)
            .open()
            .map_err(|e| match e.kind() {
                serialport::ErrorKind::NoDevice => DeviceError::NotFound(format!(
                    "no serial device at {}: {e}",
                    self.path.display()
                )),
                _ => self.disconnected(e),
            })?;
        let clone = port.try_clone().map_err(|e| self.disconnected(e))?;
        self.port = Some(port);
        self.pending.clear();
        self.stop.replace(Some(clone));
        self.homed = false;
        self.alarm = None;
        let result = self.handshake();
        if result.is_err() {
            self.port = None;
            self.stop.replace(None);
        }
        result
    }

    fn handshake(&mut self) -> Result<(), DeviceError> {
        if !self.wait_banner()? {
            self.write(&[SOFT_RESET])?;
            if !self.wait_banner()? {
                return Err(DeviceError::Timeout {
                    what: format!("GRBL banner from {}", self.path.display()),
                    seconds: 2.0 * self.config.banner_timeout.as_secs_f64(),
                });
            }
        }
        let info = self.retrying(|arm| arm.transact("$I", Until::Ok, arm.config.reply_timeout))?;
        self.firmware = info
            .iter()
            .find_map(|l| match l {
                Line::Feedback(f) => f.strip_prefix("VER:").map(str::to_owned),
                _ => None,
            })
            .unwrap_or_default();
        let lines = self.retrying(|arm| {
            let lines = arm.transact("$$", Until::Ok, arm.config.reply_timeout)?;
            match Settings::from_lines(&lines) {
                s if s.0.is_empty() => Err(DeviceError::Protocol("empty reply to $$".into())),
                s => Ok(s),
            }
        })?;
        self.settings = lines;
        self.check_settings()
    }

    /// Compare the controller's settings with the configuration.
    fn check_settings(&self) -> Result<(), DeviceError> {
        let get = |key: u32, what: &str| {
            self.settings.get(key).ok_or_else(|| {
                DeviceError::Protocol(format!("controller did not report ${key} ({what})"))
            })
        };
        let mismatch = |key: u32, what: &str, found: String, expected: String| {
            DeviceError::Protocol(format!(
                "controller setting ${key} ({what}) is {found}, configuration expects {expected}"
            ))
        };
        let steps = get(Settings::STEPS_PER_UNIT_X, "X steps per degree")?;
        if (steps - self.config.steps_per_deg).abs() > 1e-3 {
            return Err(mismatch(
                Settings::STEPS_PER_UNIT_X,
                "X steps per degree",
                steps.to_string(),
                self.config.steps_per_deg.to_string(),
            ));
        }
        let travel = get(Settings::MAX_TRAVEL_X, "X max travel, degrees")?;
        if (travel - self.config.max_travel_deg).abs() > 1e-3 {
            return Err(mismatch(
                Settings::MAX_TRAVEL_X,
                "X max travel, degrees",
                travel.to_string(),
                self.config.max_travel_deg.to_string(),
            ));
        }
        let homing = get(Settings::HOMING_ENABLE, "homing cycle enable")? != 0.0;
        if homing != self.config.homing_enabled {
            return Err(mismatch(
                Settings::HOMING_ENABLE,
                "homing cycle enable",
                homing.to_string(),
                self.config.homing_enabled.to_string(),
            ));
        }
        for (key, what) in [
            (Settings::MAX_RATE_X, "X max rate, degrees/min"),
            (Settings::ACCEL_X, "X acceleration, degrees/s²"),
        ] {
            if get(key, what)? <= 0.0 {
                return Err(DeviceError::Protocol(format!(
                    "controller setting ${key} ({what}) must be positive"
                )));
            }
        }
        Ok(())
    }

    /// Reopen the port if it was lost, with bounded exponential backoff.
    fn ensure_connected(&mut self) -> Result<(), DeviceError> {
        if self.port.is_some() {
            return Ok(());
        }
        let mut backoff = self.config.reconnect_backoff;
        let attempts = self.config.reconnect_attempts.max(1);
        let mut last = self.disconnected("not connected");
        for attempt in 0..attempts {
            if attempt > 0 {
                thread::sleep(backoff);
                backoff = (backoff * 2).min(self.config.reconnect_backoff * 16);
            }
            match self.connect() {
                Ok(()) => return Ok(()),
                // A controller that answers but is misconfigured will not get better.
                Err(e @ DeviceError::Protocol(_)) => return Err(e),
                Err(e) => last = e,
            }
        }
        Err(self.disconnected(format_args!(
            "reconnect failed after {attempts} attempts: {last}"
        )))
    }

    // ---- line I/O ----------------------------------------------------------------

    fn write(&mut self, bytes: &[u8]) -> Result<(), DeviceError> {
        let port = self
            .port
            .as_mut()
            .ok_or_else(|| DeviceError::Disconnected("arm controller not connected".into()))?;
        match port.write_all(bytes).and_then(|()| port.flush()) {
            Ok(()) => Ok(()),
            Err(e) => Err(self.drop_port(&e)),
        }
    }

    /// The next complete line, or `None` once `deadline` passes.
    fn read_line(&mut self, deadline: Instant) -> Result<Option<String>, DeviceError> {
        loop {
            if let Some(end) = self.pending.iter().position(|&b| b == b'\n') {
                let raw: Vec<u8> = self.pending.drain(..=end).collect();
                let line = String::from_utf8_lossy(&raw).trim().to_owned();
                if line.is_empty() {
                    continue;
                }
                return Ok(Some(line));
            }
            if !self.pending.is_empty() && self.last_rx.elapsed() >= GARBLE_GRACE {
                let line = String::from_utf8_lossy(&self.pending).trim().to_owned();
                self.pending.clear();
                if !line.is_empty() {
                    return Ok(Some(line));
                }
            }
            if Instant::now() >= deadline {
                return Ok(None);
            }
            let port = self
                .port
                .as_mut()
                .ok_or_else(|| DeviceError::Disconnected("arm controller not connected".into()))?;
            let mut buf = [0u8; 256];
            match port.read(&mut buf) {
                Ok(0) => {
                    let eof = io::Error::new(io::ErrorKind::UnexpectedEof, "port closed");
                    return Err(self.drop_port(&eof));
                }
                Ok(n) => {
                    self.pending.extend_from_slice(&buf[..n]);
                    self.last_rx = Instant::now();
                }
                Err(e)
                    if matches!(
                        e.kind(),
                        io::ErrorKind::TimedOut | io::ErrorKind::Interrupted
                    ) => {}
                Err(e) => return Err(self.drop_port(&e)),
            }
        }
    }

    /// Note what an unsolicited line says about the controller.
    fn note(&mut self, line: &Line) {
        match line {
            Line::Banner(_) => self.homed = false,
            Line::Alarm(code) => {
                self.alarm = Some(*code);
                self.homed = false;
            }
            _ => {}
        }
    }

    /// Read what arrived unasked (late replies, banners, alarms) before a command.
    fn drain(&mut self) -> Result<(), DeviceError> {
        let now = Instant::now();
        while let Some(line) = self.read_line(now)? {
            let line = parse_line(&line);
            self.note(&line);
        }
        Ok(())
    }

    /// Wait up to the banner timeout for the start-up banner, then until the line has
    /// been quiet for [`GARBLE_GRACE`] (a reset can leave a second banner in flight,
    /// e.g. after a stop's own reset).
    fn wait_banner(&mut self) -> Result<bool, DeviceError> {
        let deadline = Instant::now() + self.config.banner_timeout;
        while let Some(line) = self.read_line(deadline)? {
            if matches!(parse_line(&line), Line::Banner(_)) {
                while let Some(line) = self.read_line(Instant::now() + GARBLE_GRACE)? {
                    let line = parse_line(&line);
                    self.note(&line);
                }
                return Ok(true);
            }
        }
        Ok(false)
    }

    /// Send `command` and collect the reply lines up to its terminator.
    fn transact(
        &mut self,
        command: &str,
        until: Until,
        timeout: Duration,
    ) -> Result<Vec<Line>, DeviceError> {
        self.drain()?;
        match until {
            Until::Ok => self.write(format!("{command}\n").as_bytes())?,
            Until::Status => self.write(command.as_bytes())?,
        }
        let mut deadline = Instant::now() + timeout;
        let mut lines = Vec::new();
        let mut garbled = Vec::new();
        loop {
            let Some(text) = self.read_line(deadline)? else {
                return Err(if garbled.is_empty() {
                    DeviceError::Timeout {
                        what: format!("reply to {command:?} from {}", self.path.display()),
                        seconds: timeout.as_secs_f64(),
                    }
                } else {
                    DeviceError::Protocol(format!("garbled reply to {command:?}: {garbled:?}"))
                });
            };
            let line = parse_line(&text);
            self.note(&line);
            match line {
                Line::Ok if until == Until::Ok => return Ok(lines),
                Line::Status(_) if until == Until::Status => return Ok(vec![line]),
                Line::Error(code) => {
                    return Err(DeviceError::Rejected {
                        code,
                        meaning: error_meaning(code).into(),
                    })
                }
                Line::Alarm(code) => {
                    return Err(DeviceError::Alarm {
                        code,
                        meaning: alarm_meaning(code).into(),
                    })
                }
                Line::Banner(_) => return Err(DeviceError::Reset),
                Line::Garbled(text) => {
                    garbled.push(text);
                    deadline = deadline.min(Instant::now() + GARBLE_GRACE);
                }
                other => lines.push(other),
            }
        }
    }

    /// Run an idempotent exchange again after a garbled reply, a bounded number of times.
    fn retrying<T>(
        &mut self,
        mut exchange: impl FnMut(&mut Self) -> Result<T, DeviceError>,
    ) -> Result<T, DeviceError> {
        let mut attempt = 0;
        loop {
            match exchange(self) {
                Err(DeviceError::Protocol(_)) if attempt < self.config.garbled_retries => {
                    attempt += 1;
                    thread::sleep(POLL_INTERVAL * attempt);
                }
                result => return result,
            }
        }
    }

    fn query_status(&mut self) -> Result<StatusReport, DeviceError> {
        self.retrying(|arm| {
            match arm
                .transact("?", Until::Status, arm.config.reply_timeout)?
                .pop()
            {
                Some(Line::Status(report)) => Ok(report),
                _ => Err(DeviceError::Protocol("no status report".into())),
            }
        })
        .inspect(|report| {
            if let Some(x) = report.machine_x() {
                self.last_angle_deg = x;
            }
        })
    }

    /// Refuse to move while an alarm is latched or the position is unknown.
    fn check_ready(&self) -> Result<(), DeviceError> {
        if let Some(code) = self.alarm {
            return Err(DeviceError::Alarm {
                code,
                meaning: alarm_meaning(code).into(),
            });
        }
        if !self.homed {
            return Err(DeviceError::Reset);
        }
        Ok(())
    }
}

impl Arm for GrblArm {
    /// `$H`; refused while an alarm is latched (clear it first).
    fn home(&mut self) -> Result<(), DeviceError> {
        self.ensure_connected()?;
        self.drain()?;
        if let Some(code) = self.alarm {
            return Err(DeviceError::Alarm {
                code,
                meaning: alarm_meaning(code).into(),
            });
        }
        self.retrying(|arm| arm.transact("$H", Until::Ok, arm.config.homing_timeout))?;
        let report = self.query_status()?;
        if report.state != MachineState::Idle {
            return Err(DeviceError::Protocol(format!(
                "controller is {:?} after homing, expected Idle",
                report.state
            )));
        }
        self.homed = true;
        Ok(())
    }

    fn move_to(&mut self, angle_deg: f64) -> Result<(), DeviceError> {
        let (min, max) = (self.config.min_deg, self.config.max_deg);
        if !(angle_deg.is_finite() && (min..=max).contains(&angle_deg)) {
            return Err(DeviceError::OutOfRange {
                what: "arm angle (degrees)".into(),
                value: angle_deg,
                min,
                max,
            });
        }
        self.ensure_connected()?;
        self.drain()?;
        self.check_ready()?;
        let start = self.query_status()?;
        self.check_ready()?;
        let from = start.machine_x().unwrap_or(self.last_angle_deg);
        let timeout = self.move_timeout(angle_deg - from);
        let command = format!("G90 G0 X{angle_deg:.3}");
        self.retrying(|arm| arm.transact(&command, Until::Ok, arm.config.reply_timeout))?;
        // `G4 P0` is acknowledged only once the planner has finished the move.
        self.retrying(|arm| arm.transact("G4 P0", Until::Ok, timeout))?;
        let report = self.query_status()?;
        let at = report.machine_x().unwrap_or(f64::NAN);
        let on_target = (at - angle_deg).abs() <= self.config.position_tolerance_deg;
        if report.state != MachineState::Idle || !on_target {
            return Err(DeviceError::Protocol(format!(
                "after moving to {angle_deg:.3}° the controller reports {:?} at {at:.3}°",
                report.state
            )));
        }
        Ok(())
    }

    fn status(&mut self) -> Result<ArmStatus, DeviceError> {
        self.ensure_connected()?;
        let report = self.query_status()?;
        let state = match report.state {
            _ if self.alarm.is_some() => ArmState::Alarm,
            MachineState::Home => ArmState::Homing,
            MachineState::Run | MachineState::Jog => ArmState::Moving,
            MachineState::Hold | MachineState::Door => ArmState::Hold,
            _ if !self.homed => ArmState::NeedsHoming,
            MachineState::Alarm => ArmState::Alarm,
            MachineState::Idle | MachineState::Check | MachineState::Sleep => ArmState::Idle,
        };
        Ok(ArmStatus {
            state,
            angle_deg: self.last_angle_deg,
        })
    }

    /// Soft reset, wait for the banner, forget the alarm; home before the next move.
    fn clear_fault(&mut self) -> Result<(), DeviceError> {
        self.ensure_connected()?;
        self.drain()?;
        self.write(&[SOFT_RESET])?;
        if !self.wait_banner()? {
            return Err(DeviceError::Timeout {
                what: format!("GRBL banner after soft reset on {}", self.path.display()),
                seconds: self.config.banner_timeout.as_secs_f64(),
            });
        }
        self.alarm = None;
        self.homed = false;
        Ok(())
    }

    fn emergency_stop(&self) -> Arc<dyn EmergencyStop> {
        self.stop.clone()
    }
}

#[cfg(test)]
mod tests;
