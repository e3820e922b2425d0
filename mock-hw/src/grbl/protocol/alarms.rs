//! Alarms and resets: stopping the steppers dead (the arm coasting on), `ALARM:N` and the
//! pause after it, the system abort, injected alarms and hard limits.

use super::{Controller, State};
use crate::grbl::gcode::ParserState;
use crate::grbl::report::{alarm, text, N_AXIS};

/// The firmware pauses this long after printing an alarm, s.
const ALARM_REPORT_DELAY_S: f64 = 0.5;
/// An arm whose motor stops dead coasts to rest this many times faster than the axis'
/// acceleration setting.
const COAST_DECEL_FACTOR: f64 = 4.0;

impl Controller {
    /// Stop the steppers dead and drop all queued motion. The arm's inertia carries it
    /// on, decelerating at `COAST_DECEL_FACTOR` times the axis acceleration, while the
    /// motor slips steps: MPos no longer matches the arm until it is homed again.
    pub(super) fn kill_motion(&mut self, now: f64) -> [f64; N_AXIS] {
        let arm = self.arm_axis;
        let v = self.motion.velocity(now)[arm];
        let position = self.motion.kill(now);
        let decel = COAST_DECEL_FACTOR * self.settings.axes[arm].accel.max(1e-9);
        self.offset[arm] += v * v.abs() / (2.0 * decel);
        self.sync_world(now);
        position
    }

    /// Kill motion, enter Alarm and print `ALARM:code`; the firmware then pauses.
    pub(super) fn alarm_message(&mut self, code: u8, now: f64) {
        self.kill_motion(now);
        self.state = State::Alarm;
        self.emit_line(now, &format!("ALARM:{code}"));
        self.stall_until = now.max(self.stall_until) + ALARM_REPORT_DELAY_S;
    }

    /// An alarm raised by the machine. Limit alarms lock everything until a reset; the
    /// others reset at once.
    pub(super) fn raise_alarm(&mut self, code: u8, now: f64) {
        self.alarm_message(code, now);
        if code == alarm::HARD_LIMIT || code == alarm::SOFT_LIMIT {
            self.emit_line(now, text::RESET_TO_CONTINUE);
            self.critical = true;
        } else {
            self.abort(now);
        }
    }

    /// The firmware's system abort: the executing line still gets its `ok`, everything
    /// received is dropped, the parser resets (G92 cleared) and the banner follows.
    pub(super) fn abort(&mut self, now: f64) {
        let position = self.kill_motion(now);
        if self.pending.take().is_some() {
            self.emit_status(now, Ok(()));
        }
        self.parser = ParserState::new(position);
        self.restart(now);
    }

    pub(super) fn check_armed_alarm(&mut self, now: f64) {
        let Some(code) = self.armed_alarm else {
            return;
        };
        let moving = matches!(self.state, State::Run | State::Home | State::Jog);
        if moving && self.motion.block_fraction(now).is_some_and(|f| f >= 0.5) {
            self.armed_alarm = None;
            self.raise_alarm(code, now);
        }
    }

    /// `$21`: a switch changing outside Alarm and homing stops everything (ALARM:1).
    pub(super) fn check_hard_limits(&mut self, now: f64) {
        let pins = self.limit_pins(now);
        let changed = pins != self.pins;
        self.pins = pins;
        if changed
            && self.settings.hard_limits
            && !self.critical
            && !matches!(self.state, State::Alarm | State::Home)
        {
            self.raise_alarm(alarm::HARD_LIMIT, now);
        }
    }
}
