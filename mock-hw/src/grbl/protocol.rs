//! The firmware's state machine (protocol.c, system.c, motion_control.c of GRBL 1.1h):
//! the controller's state, power-up and restart, the main loop's step in machine time
//! (seconds), status reports and the output queue, each reply with the time it may be
//! sent. The rest of the machine is in submodules, each an `impl Controller` block:
//! `realtime` (real-time commands), `alarms` (alarms and resets), `lines` (the main
//! loop's lines and G-code), `system` (`$` commands) and `homing_cycle` (`$H`).

mod alarms;
mod homing_cycle;
mod lines;
mod realtime;
mod system;

use std::collections::VecDeque;

use super::config::GrblConfig;
use super::gcode::{CoordSystems, ParserState, N_COORDINATE_SYSTEMS};
use super::homing::{self, Switches};
use super::motion::{self, Motion};
use super::report::{text, ReportCounters, ReportState, StatusSnapshot, BANNER, N_AXIS};
use super::serial::SerialInput;
use super::settings::Settings;
use super::transcript::Transcript;
use crate::world::World;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum State {
    Idle,
    Run,
    Hold,
    Alarm,
    Home,
    Jog,
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Power {
    Off,
    Booting { at: f64 },
    On,
}

/// The line being executed while it waits for the machine; answered when done.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Pending {
    /// Wait for all queued motion to finish, dwell, then queue `then`.
    Sync {
        dwell_s: f64,
        then: Option<motion::Block>,
    },
    Dwell {
        until: f64,
        then: Option<motion::Block>,
    },
    /// Planner full: queue the block when a slot frees.
    Queue(motion::Block),
    /// `$H`: running `phase`; after it, the debounce delay until `resume_at`.
    Home {
        phase: homing::Phase,
        resume_at: Option<f64>,
    },
    /// Target past the soft limits while moving: feed hold, then `ALARM:2`.
    SoftLimit,
    /// The line that raised a critical alarm, answered after the reset.
    Locked,
}

/// The emulated firmware.
#[derive(Debug)]
pub(crate) struct Controller {
    settings: Settings,
    factory_settings: Settings,
    /// Work coordinate systems G54–G59, kept in EEPROM.
    coords: CoordSystems,
    build_info: String,
    parser: ParserState,
    motion: Motion,
    state: State,
    power: Power,
    boot_delay_s: f64,
    homing_cycles: Vec<u8>,
    arm_axis: usize,
    /// Physical position minus machine position, per axis: arbitrary until homed. Each
    /// axis' switch closes at physical 0 and above (the arm's at θ = 0).
    offset: [f64; N_AXIS],
    /// Which axes have a homing switch wired.
    wired: [bool; N_AXIS],
    world: World,
    input: SerialInput,
    pending: Option<Pending>,
    /// After a hard or soft limit alarm: nothing but a reset is serviced.
    critical: bool,
    /// A reset happened during an alarm pause: the firmware really restarts when the
    /// pause ends, dropping what arrived meanwhile.
    flush_after_stall: bool,
    /// A jog is decelerating to a stop; its remaining blocks are then dropped.
    jog_cancelling: bool,
    /// Machine time until which the firmware pauses (after printing an alarm).
    stall_until: f64,
    /// An injected alarm waiting for the next half-done block.
    armed_alarm: Option<u8>,
    /// Limit switches as last seen (hard limits trigger on a change).
    pins: [bool; N_AXIS],
    counters: ReportCounters,
    transcript: Transcript,
    out: VecDeque<(f64, Vec<u8>)>,
}

impl Controller {
    /// A controller that powers up at machine time `now` (banner after the boot delay).
    pub fn new(config: &GrblConfig, world: World, transcript: Transcript, now: f64) -> Self {
        let settings = Settings::from_config(config);
        let arm_axis = config.arm_axis.index();
        let idle = config.idle_axis_switch;
        // Where each axis physically is (kept across the board's power cycles).
        let mut offset: [f64; N_AXIS] = std::array::from_fn(|i| {
            let placed = world.axis(i);
            if placed.is_finite() {
                placed
            } else {
                -idle.unwrap_or(0.0)
            }
        });
        offset[arm_axis] = world.arm_deg();
        let mut wired = [idle.is_some(); N_AXIS];
        wired[arm_axis] = true;
        let mut controller = Controller {
            factory_settings: settings.clone(),
            settings,
            coords: [[0.0; N_AXIS]; N_COORDINATE_SYSTEMS],
            build_info: String::new(),
            parser: ParserState::new([0.0; N_AXIS]),
            motion: Motion::new([0.0; N_AXIS]),
            state: State::Idle,
            power: Power::Off,
            boot_delay_s: config.boot_delay_s.max(0.0),
            homing_cycles: config.homing_cycles.iter().map(|c| c.mask).collect(),
            arm_axis,
            offset,
            wired,
            world,
            input: SerialInput::default(),
            pending: None,
            critical: false,
            flush_after_stall: false,
            jog_cancelling: false,
            stall_until: 0.0,
            armed_alarm: None,
            pins: [false; N_AXIS],
            counters: ReportCounters::new(config.status_extras),
            transcript,
            out: VecDeque::new(),
        };
        controller.sync_world(now);
        controller.power_on(now);
        controller
    }

    /// Power lost (USB unplugged): the machine stays where it is, nothing is sent.
    pub fn power_off(&mut self, now: f64) {
        if self.power == Power::On {
            self.kill_motion(now);
        }
        self.power = Power::Off;
        self.out.clear();
        self.pending = None;
    }

    /// Power applied: the firmware boots and greets after the boot delay.
    pub fn power_on(&mut self, now: f64) {
        self.power = Power::Booting {
            at: now + self.boot_delay_s,
        };
    }

    /// A hardware reset (DTR toggles as the port opens): the microcontroller restarts,
    /// the machine position is lost.
    pub fn hard_reset(&mut self, now: f64) {
        self.power_off(now);
        self.power_on(now);
    }

    /// Raise `ALARM:code` when the next (or current) block is half done.
    pub fn arm_alarm(&mut self, code: u8) {
        self.armed_alarm = Some(code);
    }

    /// One byte from the serial line.
    pub fn receive(&mut self, byte: u8) {
        if self.power == Power::On {
            self.input.receive(byte);
        }
    }

    /// Output due at `now`, one reply line per entry.
    pub fn take_output(&mut self, now: f64) -> Vec<Vec<u8>> {
        let mut due = Vec::new();
        while self.out.front().is_some_and(|(t, _)| *t <= now) {
            if let Some((_, bytes)) = self.out.pop_front() {
                due.push(bytes);
            }
        }
        due
    }

    /// Something changes with time: motion, a waiting line, a boot or queued output.
    pub fn busy(&self) -> bool {
        matches!(self.power, Power::Booting { .. })
            || !self.motion.is_idle()
            || self.pending.is_some()
            || !self.out.is_empty()
    }

    /// Advance the machine to `now` and execute whatever is ready.
    pub fn tick(&mut self, now: f64) {
        self.step(now);
        // A stall that ended by `now` (an alarm raised for a moment this tick caught up
        // with) has nothing left to flush: its input was cleared by the reset, and every
        // byte from here on arrives after it, in answer to what it sent.
        if now >= self.stall_until {
            self.flush_after_stall = false;
        }
    }

    fn step(&mut self, now: f64) {
        match self.power {
            Power::Off => return,
            Power::Booting { at } if now < at => return,
            Power::Booting { .. } => self.boot(now),
            Power::On => {}
        }
        self.motion.update(now, &self.settings.axes);
        self.sync_world(now);
        self.check_hard_limits(now);
        self.finish_jog_cancel(now);
        self.update_state();
        if now < self.stall_until {
            return;
        }
        if std::mem::take(&mut self.flush_after_stall) {
            self.input.clear();
        }
        if std::mem::take(&mut self.input.realtime.reset) {
            self.transcript.record("^X");
            self.soft_reset(now);
        }
        // During a critical alarm the firmware spins waiting for a reset and answers
        // nothing, not even `?`; during homing it runs no real-time commands.
        if self.critical {
            return;
        }
        if self.state == State::Home && self.pending.is_some() {
            self.advance_pending(now);
            return;
        }
        if std::mem::take(&mut self.input.realtime.status) {
            self.emit_status_report(now);
        }
        self.check_armed_alarm(now);
        if self.critical || now < self.stall_until {
            return;
        }
        if std::mem::take(&mut self.input.realtime.hold) {
            self.feed_hold(now);
        }
        if std::mem::take(&mut self.input.realtime.resume) {
            self.cycle_start(now);
        }
        if std::mem::take(&mut self.input.realtime.jog_cancel) && self.state == State::Jog {
            self.cancel_jog(now);
        }
        self.advance_pending(now);
        self.process_input(now);
    }

    fn boot(&mut self, now: f64) {
        self.power = Power::On;
        let (position, _) = self.motion.state(now);
        for (o, p) in self.offset.iter_mut().zip(position) {
            *o += p;
        }
        self.motion.set_position([0.0; N_AXIS]);
        self.parser = ParserState::new([0.0; N_AXIS]);
        // HOMING_INIT_LOCK: a board with homing enabled powers up locked.
        self.state = if self.settings.homing {
            State::Alarm
        } else {
            State::Idle
        };
        self.pending = None;
        self.stall_until = now;
        self.pins = self.limit_pins(now);
        self.restart(now);
    }

    /// What the firmware's `main` does after power-up and after every reset: clear the
    /// system state and input, greet, and tell why it is locked.
    fn restart(&mut self, now: f64) {
        self.input.clear();
        self.flush_after_stall = now < self.stall_until;
        self.counters.reset();
        self.critical = false;
        self.jog_cancelling = false;
        self.emit(now, BANNER.to_vec());
        // CHECK_LIMITS_AT_INIT.
        if self.settings.hard_limits && self.pins.iter().any(|&p| p) {
            self.state = State::Alarm;
            self.emit_line(now, text::CHECK_LIMITS);
        }
        if self.state == State::Alarm {
            self.emit_line(now, text::UNLOCK_HINT);
        } else {
            self.state = State::Idle;
        }
    }

    /// Where each switch closes, in machine coordinates.
    fn switches(&self) -> Switches {
        std::array::from_fn(|i| self.wired[i].then_some(-self.offset[i]))
    }

    fn limit_pins(&self, now: f64) -> [bool; N_AXIS] {
        let (position, _) = self.motion.state(now);
        homing::pressed(&self.switches(), &position)
    }

    fn sync_world(&self, now: f64) {
        let (position, _) = self.motion.state(now);
        let arm = self.arm_axis;
        self.world.set_arm_deg(position[arm] + self.offset[arm]);
        for (i, (p, o)) in position.iter().zip(self.offset).enumerate() {
            self.world.set_axis(i, p + o);
        }
    }

    /// `position` rounded to whole steps of each axis.
    fn quantize(&self, position: [f64; N_AXIS]) -> [f64; N_AXIS] {
        let mut q = position;
        for (p, axis) in q.iter_mut().zip(&self.settings.axes) {
            if axis.steps_per_unit > 0.0 {
                *p = (*p * axis.steps_per_unit).round() / axis.steps_per_unit;
            }
        }
        q
    }

    fn emit(&mut self, now: f64, bytes: Vec<u8>) {
        self.out.push_back((now.max(self.stall_until), bytes));
    }

    fn emit_line(&mut self, now: f64, text: &str) {
        let mut bytes = text.as_bytes().to_vec();
        bytes.extend_from_slice(b"\r\n");
        self.emit(now, bytes);
    }

    fn emit_status(&mut self, now: f64, result: Result<(), u8>) {
        match result {
            Ok(()) => self.emit_line(now, "ok"),
            Err(code) => self.emit_line(now, &format!("error:{code}")),
        }
    }

    // ---- reports ------------------------------------------------------------------

    fn emit_status_report(&mut self, now: f64) {
        let (position, speed) = self.motion.state(now);
        let state = match self.state {
            State::Idle => ReportState::Idle,
            State::Run => ReportState::Run,
            State::Hold => ReportState::Hold {
                complete: self.motion.hold_complete(now),
            },
            State::Alarm => ReportState::Alarm,
            State::Home => ReportState::Home,
            State::Jog => ReportState::Jog,
        };
        let mask = self.settings.status_report_mask;
        let snapshot = StatusSnapshot {
            state,
            mpos: self.quantize(position),
            wco: self.parser.wco(&self.coords),
            report_mpos: mask & 1 != 0,
            buffer: (mask & 2 != 0).then(|| (self.motion.available(), self.input.available())),
            feed: speed * 60.0,
            spindle_rpm: self.parser.spindle_rpm(),
            inches: self.settings.report_inches,
            limit_pins: self.limit_pins(now),
            accessories: self.parser.accessories(),
        };
        let report = self.counters.status_report(&snapshot);
        self.emit_line(now, &report);
    }
}

#[cfg(test)]
mod tests;
