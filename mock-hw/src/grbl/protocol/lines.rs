//! The main loop's lines: executing each complete line, G-code blocks queued to the
//! planner (soft limits checked), and lines that wait for the machine (sync, dwell, a
//! full planner) answered when done.

use super::{Controller, Pending, State};
use crate::grbl::gcode;
use crate::grbl::motion;
use crate::grbl::report::{alarm, status, N_AXIS};
use crate::grbl::serial::Line;

impl Controller {
    pub(super) fn advance_pending(&mut self, now: f64) {
        let Some(pending) = self.pending else {
            return;
        };
        match pending {
            Pending::Sync { dwell_s, then } => {
                if self.motion.is_idle() && self.state != State::Run {
                    self.pending = Some(Pending::Dwell {
                        until: now + dwell_s,
                        then,
                    });
                    self.advance_pending(now);
                }
            }
            Pending::Dwell { until, then } => {
                if now >= until {
                    self.pending = None;
                    match then {
                        Some(block) => self.queue_block(block, now),
                        None => self.emit_status(now, Ok(())),
                    }
                }
            }
            Pending::Queue(block) => {
                if !self.motion.is_full() {
                    self.pending = None;
                    self.queue_block(block, now);
                }
            }
            Pending::Home { phase, resume_at } => self.homing_step(phase, resume_at, now),
            Pending::SoftLimit => {
                if self.motion.hold_complete(now) {
                    self.pending = Some(Pending::Locked);
                    self.raise_alarm(alarm::SOFT_LIMIT, now);
                }
            }
            Pending::Locked => {}
        }
    }

    /// Execute complete lines while the main loop is free to: no line waiting for the
    /// machine, no alarm pause, no completed feed hold.
    pub(super) fn process_input(&mut self, now: f64) {
        while self.pending.is_none()
            && !self.critical
            && now >= self.stall_until
            && !self.suspended(now)
        {
            let Some(line) = self.input.next_line() else {
                return;
            };
            self.execute_line(&line, now);
        }
    }

    fn execute_line(&mut self, line: &Line, now: f64) {
        let text = &line.text;
        self.transcript.record(String::from_utf8_lossy(text));
        let result = if line.overflow {
            Some(Err(status::OVERFLOW))
        } else if text.is_empty() {
            Some(Ok(()))
        } else if text[0] == b'$' {
            self.system_command(&text[1..], now)
        } else if matches!(self.state, State::Alarm | State::Jog) {
            Some(Err(status::SYSTEM_GC_LOCK))
        } else {
            self.gcode_line(text, now)
        };
        if let Some(result) = result {
            self.emit_status(now, result);
        }
    }

    fn gcode_line(&mut self, line: &[u8], now: f64) -> Option<Result<(), u8>> {
        let from = self.parser.position;
        let parsed = gcode::Block::parse(line);
        let execution = match parsed.and_then(|b| self.parser.execute(&b, &mut self.coords)) {
            Ok(execution) => execution,
            Err(code) => return Some(Err(code)),
        };
        if execution.wco_changed {
            self.counters.wco_changed();
        }
        if execution.accessories_changed {
            self.counters.accessories_changed();
        }
        let block = execution.motion.and_then(|(target, rate)| {
            let target = self.quantize(target);
            (target != self.quantize(from)).then_some(motion::Block { target, rate })
        });
        if let Some(block) = block {
            if self.settings.soft_limits && self.beyond_soft_limits(&block.target) {
                if self.state == State::Run {
                    self.motion.hold(now);
                    self.state = State::Hold;
                    self.pending = Some(Pending::SoftLimit);
                } else {
                    self.pending = Some(Pending::Locked);
                    self.raise_alarm(alarm::SOFT_LIMIT, now);
                }
                return None;
            }
        }
        if execution.sync {
            self.pending = Some(Pending::Sync {
                dwell_s: execution.dwell_s.unwrap_or(0.0),
                then: block,
            });
            self.advance_pending(now);
            return None;
        }
        match block {
            Some(block) if self.motion.is_full() => {
                self.pending = Some(Pending::Queue(block));
                None
            }
            Some(block) => {
                self.motion.push(block);
                self.start_cycle(now);
                Some(Ok(()))
            }
            None => Some(Ok(())),
        }
    }

    /// Queue a block for a waiting line and answer it.
    fn queue_block(&mut self, block: motion::Block, now: f64) {
        self.motion.push(block);
        self.start_cycle(now);
        self.emit_status(now, Ok(()));
    }

    fn start_cycle(&mut self, now: f64) {
        if self.state == State::Idle {
            self.state = State::Run;
        }
        self.motion.update(now, &self.settings.axes);
    }

    pub(super) fn beyond_soft_limits(&self, target: &[f64; N_AXIS]) -> bool {
        target
            .iter()
            .zip(&self.settings.axes)
            .any(|(t, axis)| *t > 0.0 || *t < -axis.max_travel)
    }
}
