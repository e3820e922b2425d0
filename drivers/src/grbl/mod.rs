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
//!
//! [`Arm::live_angle`]: crate::Arm::live_angle
//! [`Arm::clear_fault`]: crate::Arm::clear_fault
#![doc = include_str!("../grbl.md")]

mod arm;
mod codes;
mod config;
mod connection;
mod exchanges;
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
use std::time::Duration;

use serialport::SerialPort;

use crate::{DeviceError, EmergencyStop, LiveAngle};
use session::{Patience, Session, FEED_HOLD, SOFT_RESET};

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
    /// A latched `ALARM:N` until [`Arm::clear_fault`](crate::Arm::clear_fault).
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
}

#[cfg(test)]
mod tests;
