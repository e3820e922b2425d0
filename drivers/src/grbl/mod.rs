//! The light arm on a GRBL 1.1 controller over a serial port (115200 8N1).
//!
//! The arm is one controller axis (X by default), configured in degrees: GRBL's "mm" are
//! degrees, `$100` is steps per degree, `$110` the max rate in degrees/minute, `$120` the
//! acceleration in degrees/s², `$130` the max travel. The angle θL is the axis' work
//! position, and `G90 G0 X…` moves there. The driver sets the work offset itself, with
//! `G92` (which GRBL forgets at every reset): after the homing cycle so that θL is the
//! machine position (the switch at 0, the arm at −`$27` after it), or to the angle an
//! operator declares where the controller does not home (`$22=0`).
//!
//! Open the controller by a stable path such as `/dev/serial/by-id/usb-…-if00-port0`
//! (not `/dev/ttyUSB0`, whose number changes between plug-ins); reconnects reopen the
//! same path. Opening resets an Arduino-based board (DTR): every open starts unreferenced.
//!
//! On connecting, the settings that differ from [`GrblArmConfig`] are listed one line
//! each and the controller is refused ([`DeviceError::SettingsDiffer`]), unless
//! `apply_settings` writes them (`$N=`) and `$$` reads them back.
//!
//! Fault handling, all blocking with bounded waits:
//! - One line in flight: every `ok`/`error:N` is paired with the line it answers. When
//!   an answer does not come in time the driver resynchronises before anything else:
//!   feed hold, soft reset, banner (late answers are read and paired, never taken for a
//!   newer line), then `$X` or re-homing as the configuration says and the position
//!   read back; the work offset is restored when the reset did not lose the position.
//!   It never re-sends a line blindly.
//! - A move is given its trapezoid time × `motion_time_factor` + `motion_margin`;
//!   past that it stays alive while `?` shows it progressing, up to `motion_patience`
//!   times that, so a slow controller completes its move. The reports of those `?`
//!   (every `status_interval`) also keep [`Arm::live_angle`] current during the move.
//! - `error:N` → [`DeviceError::Rejected`]; `ALARM:N` → [`DeviceError::Alarm`] with
//!   GRBL's meaning, or [`DeviceError::HomingFailed`] (ALARM:6–10) with its advice. During
//!   a hard or soft limit alarm GRBL answers nothing, not even `?`: the driver resets it
//!   at once instead of waiting. An alarm stays latched until [`Arm::clear_fault`].
//! - A banner means the controller reset: the position is unknown until the arm is
//!   homed or declared again ([`DeviceError::PositionUnknown`]).
//! - A read or write failure drops the port ([`DeviceError::Disconnected`]); the next
//!   call reopens the same path with bounded exponential backoff.
//! - A garbled or truncated answer to an idempotent line (queries, `G90 G0`, `G4 P0`)
//!   is retried a bounded number of times, then reported as [`DeviceError::Protocol`].
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
#![doc = include_str!("../grbl.md")]

mod codes;
mod config;
mod expected;
mod link;
mod protocol;
mod session;

pub use codes::{alarm_meaning, error_meaning, homing_advice};
pub use config::{ArmAxis, GrblArmConfig, Homing};
pub use expected::{Mismatch, Want};
pub use link::BAUD_RATE;
pub use protocol::{move_time_s, parse_line, Line, MachineState, Settings, StatusReport};

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, PoisonError};
use std::thread;
use std::time::Duration;

use serialport::SerialPort;

use crate::{Arm, ArmState, ArmStatus, DeviceError, EmergencyStop, LiveAngle};
use link::{Link, POLL_INTERVAL};
use session::{AngleWatch, Patience, Session, FEED_HOLD, SOFT_RESET};

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
    /// Feed hold, then soft reset. The position is unknown afterwards.
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

/// How the arm's position is known.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Reference {
    Homed { wco: f64 },
    Declared { wco: f64 },
}

impl Reference {
    /// The work offset the driver set on the arm's axis (MPos − θL), degrees.
    fn wco(self) -> f64 {
        match self {
            Reference::Homed { wco } | Reference::Declared { wco } => wco,
        }
    }
}

/// The light arm on a GRBL controller. Blocking: call it from a dedicated thread.
pub struct GrblArm {
    path: PathBuf,
    config: GrblArmConfig,
    session: Session,
    settings: Settings,
    firmware: String,
    /// Since the last power-up, reset or reconnect, if the position is known.
    reference: Option<Reference>,
    /// A latched `ALARM:N` until [`Arm::clear_fault`].
    alarm: Option<u32>,
    last_angle_deg: f64,
    /// The last angle reported, for other threads, also during moves.
    live: LiveAngle,
    /// A resynchronisation is running (its own timeouts do not start another).
    resyncing: bool,
    stop: Arc<GrblStop>,
}

impl GrblArm {
    /// Open the controller at `path`, wait for its banner (soft-resetting it if none
    /// comes), read `$I` and `$$`, and check (or, with `apply_settings`, write) the
    /// settings. The arm then needs homing or a declared position.
    pub fn open(path: &Path, config: GrblArmConfig) -> Result<GrblArm, DeviceError> {
        let problems = config.problems();
        if !problems.is_empty() {
            return Err(DeviceError::Refused(problems.join("\n")));
        }
        let mut arm = GrblArm {
            path: path.to_owned(),
            session: Session::new(config.banner_timeout),
            config,
            settings: Settings::default(),
            firmware: String::new(),
            reference: None,
            alarm: None,
            last_angle_deg: 0.0,
            live: LiveAngle::default(),
            resyncing: false,
            stop: Arc::new(GrblStop {
                port: Mutex::new(None),
            }),
        };
        arm.connect()?;
        Ok(arm)
    }

    /// The `[VER:…]` line of `$I`, e.g. `1.1h.20190830:`.
    pub fn firmware(&self) -> &str {
        &self.firmware
    }

    /// The controller's `$$` settings as last read.
    pub fn settings(&self) -> &Settings {
        &self.settings
    }

    /// Whether the arm's position is known (homed or declared since the last reset).
    pub fn referenced(&self) -> bool {
        self.reference.is_some()
    }

    /// The device path this arm was opened with.
    pub fn path(&self) -> &Path {
        &self.path
    }

    fn axis(&self) -> usize {
        self.config.axis.index()
    }

    fn setting(&self, base: u32) -> f64 {
        self.settings.get(base + self.axis() as u32).unwrap_or(0.0)
    }

    /// Whether the controller runs the homing cycle (`$22`) as this arm uses it.
    fn homes(&self) -> bool {
        match self.config.homing {
            Homing::Required => true,
            Homing::Off => false,
            Homing::Optional => self.settings.get(Settings::HOMING_ENABLE) == Some(1.0),
        }
    }

    /// Expected time of a move of `distance_deg` (trapezoid time × factor + margin).
    pub fn move_timeout(&self, distance_deg: f64) -> Duration {
        let t = move_time_s(
            distance_deg,
            self.setting(Settings::MAX_RATE),
            self.setting(Settings::ACCEL),
        );
        self.motion_time(t)
    }

    fn motion_time(&self, seconds: f64) -> Duration {
        Duration::try_from_secs_f64(seconds * self.config.motion_time_factor)
            .unwrap_or(Duration::from_secs(3600))
            + self.config.motion_margin
    }

    /// Worst-case time of the homing cycle with the controller's settings: up to three
    /// cycles, each seeking 1.5 × the largest travel, locating 5 × the pull-off, pulling
    /// off twice and debouncing four times, plus the ramps.
    pub fn homing_timeout(&self) -> Duration {
        let get = |key: u32| self.settings.get(key).unwrap_or(0.0);
        let travel = (0..3)
            .map(|i| get(Settings::MAX_TRAVEL + i))
            .fold(0.0, f64::max);
        let accel = (0..3)
            .map(|i| get(Settings::ACCEL + i))
            .fold(f64::INFINITY, f64::min);
        let seek = get(Settings::HOMING_SEEK).max(1e-3) / 60.0;
        let feed = get(Settings::HOMING_FEED).max(1e-3) / 60.0;
        let pulloff = get(Settings::HOMING_PULLOFF);
        let debounce = get(Settings::HOMING_DEBOUNCE_MS) / 1000.0;
        let ramps = 8.0 * seek / accel.max(1e-3);
        let cycle = 1.5 * travel / seek
            + 5.0 * pulloff / feed
            + 2.0 * pulloff / seek
            + 4.0 * debounce
            + ramps;
        self.motion_time(3.0 * cycle)
    }

    fn motion_patience(&self, expected: Duration) -> Patience {
        Patience::Motion {
            expected,
            cap: expected.mul_f64(self.config.motion_patience),
            poll: self.config.status_interval,
            stall: self.config.stall_timeout,
        }
    }

    // ---- connection -------------------------------------------------------------

    fn connect(&mut self) -> Result<(), DeviceError> {
        let (link, clone) = Link::open(&self.path)?;
        self.session.attach(link);
        self.stop.replace(Some(clone));
        self.reference = None;
        self.alarm = None;
        let result = self.handshake();
        if result.is_err() {
            self.disconnect();
        }
        result
    }

    fn disconnect(&mut self) {
        self.session.detach();
        self.stop.replace(None);
        self.reference = None;
    }

    fn handshake(&mut self) -> Result<(), DeviceError> {
        // Opening resets an Arduino-based board; anything else gets a soft reset.
        if !self.session.await_banner(self.config.banner_timeout)? {
            self.session.realtime(SOFT_RESET)?;
            if !self.session.await_banner(self.config.banner_timeout)? {
                return Err(DeviceError::Timeout {
                    what: format!("GRBL banner from {}", self.path.display()),
                    seconds: 2.0 * self.config.banner_timeout.as_secs_f64(),
                });
            }
        }
        self.session.take_seen();
        let reply = self.config.reply_timeout;
        self.firmware = self.retrying(|arm| {
            let lines = arm.session.command("$I", Patience::Reply(reply))?;
            lines
                .iter()
                .find_map(|l| match l {
                    Line::Feedback(f) => f.strip_prefix("VER:").map(str::to_owned),
                    _ => None,
                })
                .ok_or_else(|| DeviceError::Protocol("no [VER:…] in the reply to $I".into()))
        })?;
        self.read_settings()?;
        let mismatches = expected::mismatches(&self.settings, &self.config);
        if mismatches.is_empty() {
            return Ok(());
        }
        let fixes: Option<Vec<String>> = mismatches.iter().map(Mismatch::fix).collect();
        match fixes {
            Some(fixes) if self.config.apply_settings => self.apply(&fixes),
            _ => Err(refusal(&mismatches)),
        }
    }

    /// `$$`, read again while settings the checks need are missing (a garbled line).
    fn read_settings(&mut self) -> Result<(), DeviceError> {
        let reply = self.config.reply_timeout;
        let axis = self.axis() as u32;
        self.settings = self.retrying(|arm| {
            let lines = arm.session.command("$$", Patience::Reply(reply))?;
            let settings = Settings::from_lines(&lines);
            let needed = [
                Settings::HOMING_ENABLE,
                Settings::STEPS_PER_UNIT + axis,
                Settings::MAX_RATE + axis,
                Settings::ACCEL + axis,
                Settings::MAX_TRAVEL + axis,
            ];
            match needed.iter().find(|&&k| settings.get(k).is_none()) {
                Some(key) => Err(DeviceError::Protocol(format!("${key} missing from $$"))),
                None => Ok(settings),
            }
        })?;
        Ok(())
    }

    /// Write `$N=value` lines, then verify with `$$`.
    fn apply(&mut self, fixes: &[String]) -> Result<(), DeviceError> {
        for fix in fixes {
            self.session
                .command(fix, Patience::Reply(self.config.reply_timeout))?;
        }
        self.read_settings()?;
        let left = expected::mismatches(&self.settings, &self.config);
        if left.is_empty() {
            Ok(())
        } else {
            Err(refusal(&left))
        }
    }

    /// Reopen the port if it was lost, with bounded exponential backoff.
    fn ensure_connected(&mut self) -> Result<(), DeviceError> {
        if self.session.connected() {
            return Ok(());
        }
        self.disconnect();
        let mut backoff = self.config.reconnect_backoff;
        let attempts = self.config.reconnect_attempts.max(1);
        let mut last = DeviceError::Disconnected("not connected".into());
        for attempt in 0..attempts {
            if attempt > 0 {
                thread::sleep(backoff);
                backoff = (backoff * 2).min(self.config.reconnect_backoff * 16);
            }
            match self.connect() {
                Ok(()) => return Ok(()),
                // A controller that answers but is refused will not get better.
                Err(
                    e @ (DeviceError::Refused(_)
                    | DeviceError::SettingsDiffer(_)
                    | DeviceError::Protocol(_)),
                ) => return Err(e),
                Err(e) => last = e,
            }
        }
        Err(DeviceError::Disconnected(format!(
            "{}: reconnect failed after {attempts} attempts: {last}",
            self.path.display()
        )))
    }

    // ---- exchanges ----------------------------------------------------------------

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

    /// Take note of resets and alarms the session saw: either loses the position; an
    /// alarm stays latched.
    fn absorb(&mut self) {
        let seen = self.session.take_seen();
        if seen.reset || seen.alarm.is_some() {
            self.reference = None;
        }
        if let Some(code) = seen.alarm {
            self.alarm = Some(code);
        }
    }

    /// Before an operation: reconnect, read what came unasked, and resynchronise if a
    /// line is still unanswered.
    fn prepare(&mut self) -> Result<(), DeviceError> {
        self.ensure_connected()?;
        let drained = self.session.drain();
        self.absorb();
        drained?;
        if self.session.in_flight().is_some() {
            self.resyncing = true;
            let resynced = self.resync();
            self.resyncing = false;
            self.absorb();
            resynced?;
        }
        Ok(())
    }

    /// A line with its answer. After a timeout (the answer may still come, and must not
    /// be taken for a newer line's) stop and resynchronise at once, unless this is
    /// already part of a resynchronisation (the next operation then starts with one).
    fn command(&mut self, line: &str, patience: Patience) -> Result<Vec<Line>, DeviceError> {
        let result = self.session.command(line, patience);
        self.absorb();
        if let (Err(DeviceError::Timeout { what, seconds }), false) = (&result, self.resyncing) {
            self.resyncing = true;
            let resynced = self.resync();
            self.resyncing = false;
            self.absorb();
            let note = match resynced {
                Ok(()) => "controller stopped and resynchronised".to_owned(),
                Err(e) => format!("resynchronising failed: {e}"),
            };
            return Err(DeviceError::Timeout {
                what: format!("{what} ({note})"),
                seconds: *seconds,
            });
        }
        result
    }

    /// `?`. A banner met meanwhile means the controller reset: the position is unknown.
    fn query_status(&mut self) -> Result<StatusReport, DeviceError> {
        let reply = self.config.reply_timeout;
        let result = self.retrying(|arm| arm.session.status(reply));
        self.absorb();
        let report = match result {
            Err(DeviceError::Reset) => return Err(self.position_unknown()),
            other => other?,
        };
        if let Some(angle) = report.work(self.axis(), self.known_wco()) {
            self.note_angle(angle);
        }
        Ok(report)
    }

    /// Records the arm's angle as the controller reported it.
    fn note_angle(&mut self, angle: f64) {
        self.last_angle_deg = angle;
        self.live.set(angle);
    }

    /// The work offset in force: the session's last reported one, else the driver's own.
    fn known_wco(&self) -> Option<[f64; 3]> {
        self.session.wco().or_else(|| {
            let wco = self.reference?.wco();
            let mut triple = [0.0; 3];
            triple[self.axis()] = wco;
            Some(triple)
        })
    }

    /// Feed hold, soft reset, banner; then unlock or re-home as configured and restore
    /// the work offset if the position survived; finally read the position back.
    fn resync(&mut self) -> Result<(), DeviceError> {
        let kept = self.reference.filter(|_| self.alarm.is_none());
        self.session.realtime(FEED_HOLD)?;
        // Let a move decelerate so the reset does not lose the position; a locked or
        // silent controller answers nothing, and is reset all the same.
        let rate = self.setting(Settings::MAX_RATE) / 60.0;
        let accel = self.setting(Settings::ACCEL).max(1e-3);
        let settle = Duration::try_from_secs_f64(rate / accel).unwrap_or(Duration::ZERO);
        let deadline = std::time::Instant::now() + settle + self.config.reply_timeout;
        while std::time::Instant::now() < deadline {
            match self.session.status(self.config.reply_timeout) {
                Ok(report) if report.at_rest() => break,
                Ok(_) => thread::sleep(POLL_INTERVAL),
                Err(DeviceError::Disconnected(e)) => return Err(DeviceError::Disconnected(e)),
                Err(_) => break,
            }
        }
        let settling = self.session.take_seen();
        self.session.realtime(SOFT_RESET)?;
        if !self.session.await_banner(self.config.banner_timeout)? {
            return Err(DeviceError::Timeout {
                what: format!("GRBL banner after a soft reset on {}", self.path.display()),
                seconds: self.config.banner_timeout.as_secs_f64(),
            });
        }
        let lost = settling.alarm.or(self.session.take_seen().alarm).is_some();
        self.alarm = None;
        self.reference = None;
        let reply = self.config.reply_timeout;
        let report = self.retrying(|arm| arm.session.status(reply))?;
        match kept.filter(|_| !lost) {
            Some(reference) => {
                if report.state == MachineState::Alarm {
                    self.command("$X", Patience::Reply(reply))?;
                }
                let mpos = report
                    .machine(self.axis(), self.session.wco())
                    .ok_or_else(|| DeviceError::Protocol("no position after a reset".into()))?;
                self.set_work_position(mpos - reference.wco())?;
                self.reference = Some(reference);
            }
            None if self.homes() => self.run_homing()?,
            None => {
                if report.state == MachineState::Alarm {
                    self.command("$X", Patience::Reply(reply))?;
                }
            }
        }
        self.query_status().map(drop)
    }

    /// `G92`: make the arm's work position `angle`; returns the work offset set.
    fn set_work_position(&mut self, angle: f64) -> Result<f64, DeviceError> {
        let reply = self.config.reply_timeout;
        let line = format!("G92 {}{angle:.3}", self.config.axis.letter());
        self.command(&line, Patience::Reply(reply))?;
        let report = self.query_status()?;
        let mpos = report
            .machine(self.axis(), self.session.wco())
            .ok_or_else(|| DeviceError::Protocol("no position in the status report".into()))?;
        self.note_angle(angle);
        Ok(mpos - angle)
    }

    /// `$H`, then θL = machine position.
    fn run_homing(&mut self) -> Result<(), DeviceError> {
        let timeout = self.homing_timeout();
        self.retrying(|arm| arm.command("$H", Patience::Reply(timeout)))?;
        let report = self.query_status()?;
        if report.state != MachineState::Idle {
            return Err(DeviceError::Protocol(format!(
                "controller is {:?} after homing, expected Idle",
                report.state
            )));
        }
        let mpos = report
            .machine(self.axis(), self.session.wco())
            .ok_or_else(|| DeviceError::Protocol("no position after homing".into()))?;
        let wco = self.set_work_position(mpos)?;
        self.reference = Some(Reference::Homed { wco });
        Ok(())
    }

    fn latched_alarm(&self) -> Result<(), DeviceError> {
        match self.alarm {
            Some(code) => Err(DeviceError::Alarm {
                code,
                meaning: alarm_meaning(code).into(),
            }),
            None => Ok(()),
        }
    }

    /// Why the arm cannot move yet, if it cannot.
    fn check_ready(&self) -> Result<(), DeviceError> {
        self.latched_alarm()?;
        if self.reference.is_none() {
            return Err(self.position_unknown());
        }
        Ok(())
    }

    fn position_unknown(&self) -> DeviceError {
        DeviceError::PositionUnknown(if self.homes() {
            "the controller reset or reconnected: home the arm".into()
        } else {
            "the controller does not home ($22=0) and reset or reconnected: declare where \
             the arm is"
                .into()
        })
    }
}

/// The refusal listing each differing setting on its own line.
fn refusal(mismatches: &[Mismatch]) -> DeviceError {
    DeviceError::SettingsDiffer(mismatches.iter().map(ToString::to_string).collect())
}

impl Arm for GrblArm {
    /// Reference the arm: the homing cycle (`$H`) where the controller homes, refused
    /// while an alarm is latched (clear it first); where it does not, the position an
    /// operator declared, else [`DeviceError::PositionUnknown`].
    fn home(&mut self) -> Result<(), DeviceError> {
        self.prepare()?;
        self.latched_alarm()?;
        if !self.homes() {
            return self.check_ready();
        }
        self.run_homing()
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
        self.prepare()?;
        self.check_ready()?;
        let start = self.query_status()?;
        self.check_ready()?;
        let from = start
            .work(self.axis(), self.known_wco())
            .unwrap_or(self.last_angle_deg);
        let expected = self.move_timeout(angle_deg - from);
        let reply = self.config.reply_timeout;
        let line = format!("G90 G0 {}{angle_deg:.3}", self.config.axis.letter());
        self.retrying(|arm| arm.command(&line, Patience::Reply(reply)))?;
        // `G4 P0` is answered once the planner has finished the move; the status
        // reports asked for meanwhile keep the live angle current.
        let patience = self.motion_patience(expected);
        self.session.watch(AngleWatch {
            angle: self.live.clone(),
            axis: self.axis(),
            known_wco: self.known_wco(),
        });
        let finished = self.retrying(|arm| arm.command("G4 P0", patience));
        self.session.unwatch();
        finished?;
        let report = self.query_status()?;
        let at = report
            .work(self.axis(), self.known_wco())
            .unwrap_or(f64::NAN);
        let on_target = (at - angle_deg).abs() <= self.config.position_tolerance_deg;
        if report.state != MachineState::Idle || !on_target {
            return Err(DeviceError::Protocol(format!(
                "after moving to {angle_deg:.3}° the controller reports {:?} at {at:.3}°",
                report.state
            )));
        }
        Ok(())
    }

    /// `G90 G53 G0` on `axis` (machine coordinates: the work offset the driver sets is
    /// the arm's), then `G4 P0`, and the position read back.
    fn move_axis(&mut self, axis: ArmAxis, position: f64) -> Result<(), DeviceError> {
        if axis == self.config.axis {
            return Err(DeviceError::Refused(format!(
                "the {} axis is the arm's",
                axis.letter()
            )));
        }
        let i = axis.index();
        let travel = self.settings.get(Settings::MAX_TRAVEL + i as u32);
        let min = -travel.unwrap_or(f64::INFINITY);
        if !(position.is_finite() && (min..=0.0).contains(&position)) {
            return Err(DeviceError::OutOfRange {
                what: format!("{} axis position", axis.letter()),
                value: position,
                min,
                max: 0.0,
            });
        }
        self.prepare()?;
        self.check_ready()?;
        let start = self.query_status()?;
        self.check_ready()?;
        let from = start.machine(i, self.known_wco()).unwrap_or(0.0);
        let rate = self.settings.get(Settings::MAX_RATE + i as u32);
        let accel = self.settings.get(Settings::ACCEL + i as u32);
        let expected = self.motion_time(move_time_s(
            position - from,
            rate.unwrap_or(0.0),
            accel.unwrap_or(0.0),
        ));
        let reply = self.config.reply_timeout;
        let line = format!("G90 G53 G0 {}{position:.3}", axis.letter());
        self.retrying(|arm| arm.command(&line, Patience::Reply(reply)))?;
        let patience = self.motion_patience(expected);
        self.retrying(|arm| arm.command("G4 P0", patience))?;
        let report = self.query_status()?;
        let at = report.machine(i, self.known_wco()).unwrap_or(f64::NAN);
        if report.state != MachineState::Idle
            || (at - position).abs() > self.config.position_tolerance_deg
        {
            return Err(DeviceError::Protocol(format!(
                "after moving the {} axis to {position:.3} the controller reports {:?} at {at:.3}",
                axis.letter(),
                report.state
            )));
        }
        Ok(())
    }

    fn homes(&self) -> bool {
        GrblArm::homes(self)
    }

    /// `$13N` of `axis` as last read.
    fn axis_travel(&self, axis: ArmAxis) -> Option<f64> {
        self.settings
            .get(Settings::MAX_TRAVEL + axis.index() as u32)
    }

    fn status(&mut self) -> Result<ArmStatus, DeviceError> {
        self.prepare()?;
        let report = self.query_status()?;
        let state = match report.state {
            _ if self.alarm.is_some() => ArmState::Alarm,
            MachineState::Home => ArmState::Homing,
            MachineState::Run | MachineState::Jog => ArmState::Moving,
            MachineState::Hold | MachineState::Door => ArmState::Hold,
            _ if self.reference.is_none() && self.homes() => ArmState::NeedsHoming,
            _ if self.reference.is_none() => ArmState::NeedsPosition,
            MachineState::Alarm => ArmState::Alarm,
            MachineState::Idle | MachineState::Check | MachineState::Sleep => ArmState::Idle,
        };
        Ok(ArmStatus {
            state,
            angle_deg: self.last_angle_deg,
        })
    }

    /// Soft reset, wait for the banner, forget the alarm; the arm must then be homed or
    /// declared again.
    fn clear_fault(&mut self) -> Result<(), DeviceError> {
        self.prepare()?;
        self.session.realtime(SOFT_RESET)?;
        let greeted = self.session.await_banner(self.config.banner_timeout)?;
        self.session.take_seen();
        if !greeted {
            return Err(DeviceError::Timeout {
                what: format!("GRBL banner after soft reset on {}", self.path.display()),
                seconds: self.config.banner_timeout.as_secs_f64(),
            });
        }
        self.alarm = None;
        self.reference = None;
        Ok(())
    }

    /// `$X` if locked, then `G92` so the arm's angle is `angle_deg`; refused where the
    /// arm is homed ([`Homing::Required`]) or while it moves.
    fn declare_position(&mut self, angle_deg: f64) -> Result<(), DeviceError> {
        if self.config.homing == Homing::Required {
            return Err(DeviceError::Refused(
                "homing is required: the homing cycle references the arm, a declared \
                 position is not accepted"
                    .into(),
            ));
        }
        // The arm is somewhere on its travel: [−$130, 0], the switch at 0.
        let (min, max) = (-self.config.max_travel_deg, 0.0);
        if !(angle_deg.is_finite() && (min..=max).contains(&angle_deg)) {
            return Err(DeviceError::OutOfRange {
                what: "declared arm angle (degrees, on the travel)".into(),
                value: angle_deg,
                min,
                max,
            });
        }
        self.prepare()?;
        if self.alarm.is_some() {
            self.clear_fault()?;
        }
        let report = self.query_status()?;
        match report.state {
            MachineState::Alarm => {
                self.command("$X", Patience::Reply(self.config.reply_timeout))?;
            }
            MachineState::Idle => {}
            state => {
                return Err(DeviceError::Refused(format!(
                    "the controller is {state:?}: declare the position at rest"
                )))
            }
        }
        let wco = self.set_work_position(angle_deg)?;
        self.reference = Some(Reference::Declared { wco });
        Ok(())
    }

    fn emergency_stop(&self) -> Arc<dyn EmergencyStop> {
        self.stop.clone()
    }

    fn live_angle(&self) -> LiveAngle {
        self.live.clone()
    }
}

#[cfg(test)]
mod tests;
