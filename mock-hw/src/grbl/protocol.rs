//! The firmware's state machine (protocol.c, system.c, motion_control.c of GRBL 1.1h):
//! real-time commands, the main loop executing lines, `$` system commands, G-code
//! execution, feed hold, homing, alarms, resets and reports. Driven by machine time
//! (seconds); output is queued with the time it may be sent.

use std::collections::VecDeque;

use super::config::GrblConfig;
use super::gcode::{self, CoordSystems, ParserState, N_COORDINATE_SYSTEMS};
use super::homing::{self, Switches};
use super::motion::{self, Motion};
use super::report::{
    self, alarm, status, text, ReportCounters, ReportState, StatusSnapshot, BANNER, N_AXIS,
};
use super::serial::{Line, SerialInput};
use super::settings::Settings;
use super::transcript::Transcript;
use crate::world::World;

/// The firmware pauses this long after printing an alarm, s.
const ALARM_REPORT_DELAY_S: f64 = 0.5;
/// An arm whose motor stops dead coasts to rest this many times faster than the axis'
/// acceleration setting.
const COAST_DECEL_FACTOR: f64 = 4.0;

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

    // ---- real-time commands -------------------------------------------------------

    /// Ctrl-X (`mc_reset`): stopping the steppers while they move raises ALARM:3
    /// (ALARM:6 while homing); then the system aborts.
    fn soft_reset(&mut self, now: f64) {
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

    fn feed_hold(&mut self, now: f64) {
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
    fn cancel_jog(&mut self, now: f64) {
        self.motion.hold(now);
        self.jog_cancelling = true;
    }

    fn finish_jog_cancel(&mut self, now: f64) {
        if self.jog_cancelling && self.motion.hold_complete(now) {
            self.jog_cancelling = false;
            self.parser.position = self.kill_motion(now);
            self.state = State::Idle;
        }
    }

    fn cycle_start(&mut self, now: f64) {
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
    fn suspended(&self, now: f64) -> bool {
        self.jog_cancelling || self.state == State::Hold && self.motion.hold_complete(now)
    }

    fn update_state(&mut self) {
        match self.state {
            State::Run | State::Jog if self.motion.is_idle() => self.state = State::Idle,
            State::Idle if !self.motion.is_idle() => self.state = State::Run,
            _ => {}
        }
    }

    // ---- alarms and resets --------------------------------------------------------

    /// Stop the steppers dead and drop all queued motion. The arm's inertia carries it
    /// on, decelerating at `COAST_DECEL_FACTOR` times the axis acceleration, while the
    /// motor slips steps: MPos no longer matches the arm until it is homed again.
    fn kill_motion(&mut self, now: f64) -> [f64; N_AXIS] {
        let arm = self.arm_axis;
        let v = self.motion.velocity(now)[arm];
        let position = self.motion.kill(now);
        let decel = COAST_DECEL_FACTOR * self.settings.axes[arm].accel.max(1e-9);
        self.offset[arm] += v * v.abs() / (2.0 * decel);
        self.sync_world(now);
        position
    }

    /// Kill motion, enter Alarm and print `ALARM:code`; the firmware then pauses.
    fn alarm_message(&mut self, code: u8, now: f64) {
        self.kill_motion(now);
        self.state = State::Alarm;
        self.emit_line(now, &format!("ALARM:{code}"));
        self.stall_until = now.max(self.stall_until) + ALARM_REPORT_DELAY_S;
    }

    /// An alarm raised by the machine. Limit alarms lock everything until a reset; the
    /// others reset at once.
    fn raise_alarm(&mut self, code: u8, now: f64) {
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
    fn abort(&mut self, now: f64) {
        let position = self.kill_motion(now);
        if self.pending.take().is_some() {
            self.emit_status(now, Ok(()));
        }
        self.parser = ParserState::new(position);
        self.restart(now);
    }

    fn check_armed_alarm(&mut self, now: f64) {
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
    fn check_hard_limits(&mut self, now: f64) {
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

    // ---- lines --------------------------------------------------------------------

    fn advance_pending(&mut self, now: f64) {
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
    fn process_input(&mut self, now: f64) {
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

    /// A `$` command (without the `$`). `None`: the line waits for the machine.
    fn system_command(&mut self, rest: &[u8], now: f64) -> Option<Result<(), u8>> {
        match rest.first().copied() {
            None => {
                self.emit_line(now, text::HELP);
                return Some(Ok(()));
            }
            Some(b'$' | b'G' | b'X' | b'C') => {
                if rest.len() != 1 {
                    return Some(Err(status::INVALID_STATEMENT));
                }
                return Some(self.view_or_unlock(rest[0], now));
            }
            Some(b'J') => return self.jog(rest, now),
            _ => {}
        }
        if !matches!(self.state, State::Idle | State::Alarm) {
            return Some(Err(status::IDLE_ERROR));
        }
        match rest {
            b"#" => {
                self.report_parameters(now);
                Some(Ok(()))
            }
            [b'H', ..] => {
                if !self.settings.homing {
                    return Some(Err(status::SETTING_DISABLED));
                }
                if rest.len() != 1 {
                    return Some(Err(status::INVALID_STATEMENT));
                }
                self.start_homing(now);
                None
            }
            b"I" => {
                let version = format!("[VER:{}:{}]", text::VERSION, self.build_info);
                self.emit_line(now, &version);
                self.emit_line(now, text::OPTIONS);
                Some(Ok(()))
            }
            [b'I', b'=', info @ ..] => {
                self.build_info = String::from_utf8_lossy(info).into_owned();
                Some(Ok(()))
            }
            b"N" => {
                self.emit_line(now, "$N0=");
                self.emit_line(now, "$N1=");
                Some(Ok(()))
            }
            b"RST=$" | b"RST=#" | b"RST=*" => {
                if rest != b"RST=#" {
                    self.settings = self.factory_settings.clone();
                }
                if rest != b"RST=$" {
                    self.coords = [[0.0; N_AXIS]; N_COORDINATE_SYSTEMS];
                }
                self.emit_line(now, text::RESTORING_DEFAULTS);
                self.emit_status(now, Ok(()));
                self.soft_reset(now);
                None
            }
            // Startup blocks and sleep are not emulated.
            [b'#' | b'I' | b'N' | b'S' | b'R', ..] => Some(Err(status::INVALID_STATEMENT)),
            _ => Some(self.store_setting(rest)),
        }
    }

    /// `$J=…`: a jog, queued like a G1 move without touching the modal state. Soft
    /// limits refuse it with `error:15` instead of an alarm.
    fn jog(&mut self, rest: &[u8], now: f64) -> Option<Result<(), u8>> {
        if !matches!(self.state, State::Idle | State::Jog) {
            return Some(Err(status::IDLE_ERROR));
        }
        if rest.get(1) != Some(&b'=') {
            return Some(Err(status::INVALID_STATEMENT));
        }
        let jog = gcode::Block::parse(&rest[2..]).and_then(|b| self.parser.jog(&b, &self.coords));
        let (target, feed) = match jog {
            Ok(jog) => jog,
            Err(code) => return Some(Err(code)),
        };
        if self.settings.soft_limits && self.beyond_soft_limits(&target) {
            return Some(Err(status::TRAVEL_EXCEEDED));
        }
        let from = self.quantize(self.parser.position);
        self.parser.position = target;
        let target = self.quantize(target);
        if target == from {
            return Some(Ok(()));
        }
        let block = motion::Block { target, rate: feed };
        self.state = State::Jog;
        if self.motion.is_full() {
            self.pending = Some(Pending::Queue(block));
            return None;
        }
        self.motion.push(block);
        self.motion.update(now, &self.settings.axes);
        Some(Ok(()))
    }

    fn view_or_unlock(&mut self, command: u8, now: f64) -> Result<(), u8> {
        match command {
            b'$' => {
                if matches!(self.state, State::Run | State::Hold) {
                    return Err(status::IDLE_ERROR);
                }
                for line in self.settings.report_lines() {
                    self.emit_line(now, &line);
                }
            }
            b'G' => {
                let report = self.parser.report();
                self.emit_line(now, &report);
            }
            b'X' => {
                if self.state == State::Alarm {
                    self.emit_line(now, text::UNLOCKED);
                    self.state = State::Idle;
                }
            }
            // `$C` check mode is not emulated.
            _ => return Err(status::INVALID_STATEMENT),
        }
        Ok(())
    }

    fn store_setting(&mut self, rest: &[u8]) -> Result<(), u8> {
        let mut pos = 0;
        let parameter = gcode::read_float(rest, &mut pos).ok_or(status::BAD_NUMBER_FORMAT)?;
        if rest.get(pos) != Some(&b'=') {
            return Err(status::INVALID_STATEMENT);
        }
        pos += 1;
        let value = gcode::read_float(rest, &mut pos).ok_or(status::BAD_NUMBER_FORMAT)?;
        if pos != rest.len() || !(0.0..=255.0).contains(&parameter) {
            return Err(status::INVALID_STATEMENT);
        }
        let parameter = parameter as u8;
        self.settings.store(parameter, value)?;
        if parameter == 13 {
            // Positions change units: WCO on the next report.
            self.counters.wco_changed();
        }
        Ok(())
    }

    fn report_parameters(&mut self, now: f64) {
        let inches = self.settings.report_inches;
        let coords = self.coords;
        for (i, system) in coords.iter().enumerate() {
            let line = format!("[G{}:{}]", 54 + i, report::axes(*system, inches));
            self.emit_line(now, &line);
        }
        let zero = report::axes([0.0; N_AXIS], inches);
        for name in ["G28", "G30"] {
            self.emit_line(now, &format!("[{name}:{zero}]"));
        }
        let g92 = report::axes(self.parser.coord_offset(), inches);
        self.emit_line(now, &format!("[G92:{g92}]"));
        self.emit_line(now, &format!("[TLO:{}]", report::fmt_fixed(0.0, 3)));
        self.emit_line(now, &format!("[PRB:{zero}:0]"));
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

    fn quantize(&self, position: [f64; N_AXIS]) -> [f64; N_AXIS] {
        let mut q = position;
        for (p, axis) in q.iter_mut().zip(&self.settings.axes) {
            if axis.steps_per_unit > 0.0 {
                *p = (*p * axis.steps_per_unit).round() / axis.steps_per_unit;
            }
        }
        q
    }

    fn beyond_soft_limits(&self, target: &[f64; N_AXIS]) -> bool {
        target
            .iter()
            .zip(&self.settings.axes)
            .any(|(t, axis)| *t > 0.0 || *t < -axis.max_travel)
    }

    // ---- homing -------------------------------------------------------------------

    fn start_homing(&mut self, now: f64) {
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
    fn homing_step(&mut self, mut phase: homing::Phase, mut resume_at: Option<f64>, now: f64) {
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
