//! The `$H` homing cycle run in machine time: each phase's move, the debounce delay
//! between phases, the alarm of a failed phase, and the machine position set at the end.

use super::{Controller, Pending, State};
use crate::grbl::homing;
use crate::grbl::report::N_AXIS;

impl Controller {
    pub(super) fn start_homing(&mut self, now: f64) {
        self.state = State::Home;
        let (position, _) = self.motion.state(now);
        let next = homing::start(
            &self.homing_cycles,
            position,
            &self.switches(),
            &self.settings,
        );
        self.homing_next(next, now, now);
    }

    /// After a phase's move: fail with its alarm, or wait out the debounce delay and go
    /// on with the next phase, in machine time (however far `now` has run ahead).
    pub(super) fn homing_step(
        &mut self,
        mut phase: homing::Phase,
        mut resume_at: Option<f64>,
        now: f64,
    ) {
        while self.motion.is_idle() {
            let at = match resume_at {
                Some(at) => at,
                None => {
                    let end = self.motion.idle_since().max(phase.started_at);
                    if let Some(code) = phase.fails {
                        // The alarm, then the `$H` line's `ok`, then the reset's banner.
                        self.raise_alarm(code, end);
                        return;
                    }
                    end + f64::from(self.settings.homing_debounce_ms) / 1000.0
                }
            };
            if now < at {
                self.pending = Some(Pending::Home {
                    phase,
                    resume_at: Some(at),
                });
                return;
            }
            let (position, _) = self.motion.state(at);
            let next = homing::after(
                &self.homing_cycles,
                phase,
                position,
                &self.switches(),
                &self.settings,
            );
            match self.homing_next(next, at, now) {
                Some(started) => (phase, resume_at) = (started, None),
                None => return,
            }
        }
        self.pending = Some(Pending::Home { phase, resume_at });
    }

    /// Start the next phase at machine time `at`, or finish the cycle. Returns the phase
    /// started.
    fn homing_next(&mut self, next: homing::Next, at: f64, now: f64) -> Option<homing::Phase> {
        match next {
            homing::Next::Run(mut phase, block) => {
                phase.started_at = at;
                if let Some(block) = block {
                    self.motion.start_at(block, at, &self.settings.axes);
                    self.motion.update(now, &self.settings.axes);
                }
                self.pending = Some(Pending::Home {
                    phase,
                    resume_at: None,
                });
                Some(phase)
            }
            homing::Next::Homed { mask, position } => {
                let (before, _) = self.motion.state(at);
                let home = self.quantize(position);
                for i in (0..N_AXIS).filter(|i| mask & (1 << i) != 0) {
                    self.offset[i] += before[i] - home[i];
                }
                self.motion.set_position(home);
                self.parser.position = home;
                self.sync_world(now);
                self.pins = self.limit_pins(now);
                // A `?` received during the cycle is answered now, still in Home.
                if std::mem::take(&mut self.input.realtime.status) {
                    self.emit_status_report(at);
                }
                // Holds and cycle starts received during the cycle come to nothing.
                self.input.realtime.hold = false;
                self.input.realtime.resume = false;
                self.state = State::Idle;
                self.pending = None;
                self.emit_status(at, Ok(()));
                None
            }
        }
    }
}
