//! Real-time commands as the firmware services them between lines: soft reset (Ctrl-X),
//! feed hold, jog cancel and cycle start, and the Run/Idle changes that follow motion.

use super::{Controller, State};
use crate::grbl::report::alarm;

impl Controller {
    /// Ctrl-X (`mc_reset`): stopping the steppers while they move raises ALARM:3
    /// (ALARM:6 while homing); then the system aborts.
    pub(super) fn soft_reset(&mut self, now: f64) {
        if !self.critical {
            let moving = match self.state {
                State::Run | State::Home | State::Jog => true,
                State::Hold => !self.motion.hold_complete(now),
                State::Idle | State::Alarm => false,
            };
            if moving {
                let code = if self.state == State::Home {
                    alarm::HOMING_FAIL_RESET
                } else {
                    alarm::ABORT_CYCLE
                };
                self.alarm_message(code, now);
            }
        }
        self.abort(now);
    }

    pub(super) fn feed_hold(&mut self, now: f64) {
        match self.state {
            State::Run | State::Idle => {
                self.motion.hold(now);
                self.state = State::Hold;
            }
            State::Jog => self.cancel_jog(now),
            State::Hold | State::Alarm | State::Home => {}
        }
    }

    /// Jog cancel: decelerate to a stop, then drop the rest of the jog.
    pub(super) fn cancel_jog(&mut self, now: f64) {
        self.motion.hold(now);
        self.jog_cancelling = true;
    }

    pub(super) fn finish_jog_cancel(&mut self, now: f64) {
        if self.jog_cancelling && self.motion.hold_complete(now) {
            self.jog_cancelling = false;
            self.parser.position = self.kill_motion(now);
            self.state = State::Idle;
        }
    }

    pub(super) fn cycle_start(&mut self, now: f64) {
        if self.state == State::Hold && self.motion.hold_complete(now) {
            self.motion.resume(now);
            self.motion.update(now, &self.settings.axes);
            self.state = if self.motion.is_idle() {
                State::Idle
            } else {
                State::Run
            };
        }
    }

    /// The main loop is suspended (it executes no line) while a feed hold is complete
    /// and while a jog cancel decelerates; during the deceleration of a feed hold it
    /// still runs.
    pub(super) fn suspended(&self, now: f64) -> bool {
        self.jog_cancelling || self.state == State::Hold && self.motion.hold_complete(now)
    }

    pub(super) fn update_state(&mut self) {
        match self.state {
            State::Run | State::Jog if self.motion.is_idle() => self.state = State::Idle,
            State::Idle if !self.motion.is_idle() => self.state = State::Run,
            _ => {}
        }
    }
}
