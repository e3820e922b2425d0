//! Exchanges with a connected controller: retrying idempotent lines, taking note of the
//! resets and alarms the session saw, resynchronising after an unanswered line, the
//! status query, the work offset (`G92`), the homing cycle, and why the arm cannot move.

use std::thread;
use std::time::Duration;

use super::codes::alarm_meaning;
use super::link::POLL_INTERVAL;
use super::session::{Patience, FEED_HOLD, SOFT_RESET};
use super::{GrblArm, Line, MachineState, Reference, Settings, StatusReport};
use crate::DeviceError;

impl GrblArm {
    /// Run an idempotent exchange again after a garbled reply, a bounded number of times.
    pub(super) fn retrying<T>(
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
    pub(super) fn prepare(&mut self) -> Result<(), DeviceError> {
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
    pub(super) fn command(
        &mut self,
        line: &str,
        patience: Patience,
    ) -> Result<Vec<Line>, DeviceError> {
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
    pub(super) fn query_status(&mut self) -> Result<StatusReport, DeviceError> {
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
    pub(super) fn known_wco(&self) -> Option<[f64; 3]> {
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
    pub(super) fn set_work_position(&mut self, angle: f64) -> Result<f64, DeviceError> {
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
    pub(super) fn run_homing(&mut self) -> Result<(), DeviceError> {
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

    pub(super) fn latched_alarm(&self) -> Result<(), DeviceError> {
        match self.alarm {
            Some(code) => Err(DeviceError::Alarm {
                code,
                meaning: alarm_meaning(code).into(),
            }),
            None => Ok(()),
        }
    }

    /// Why the arm cannot move yet, if it cannot.
    pub(super) fn check_ready(&self) -> Result<(), DeviceError> {
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
