//! The firmware's protocol state machine: serial receive with real-time command pick-off,
//! line assembly, `$` system commands, G-code execution, alarms, resets and reports.
//! Driven by machine time (seconds); output is queued with the time it may be sent.

use std::collections::VecDeque;

use super::gcode::{self, ParserState};
use super::motion::{self, Motion};
use super::settings::{Settings, N_AXIS};
use super::GrblConfig;
use crate::world::World;

/// GRBL status codes (`error:N`).
pub(crate) mod status {
    pub const EXPECTED_COMMAND_LETTER: u8 = 1;
    pub const BAD_NUMBER_FORMAT: u8 = 2;
    pub const INVALID_STATEMENT: u8 = 3;
    pub const NEGATIVE_VALUE: u8 = 4;
    pub const SETTING_DISABLED: u8 = 5;
    pub const SETTING_STEP_PULSE_MIN: u8 = 6;
    pub const IDLE_ERROR: u8 = 8;
    pub const SYSTEM_GC_LOCK: u8 = 9;
    pub const SOFT_LIMIT_ERROR: u8 = 10;
    pub const OVERFLOW: u8 = 11;
    pub const TRAVEL_EXCEEDED: u8 = 15;
    pub const INVALID_JOG_COMMAND: u8 = 16;
    pub const GCODE_UNSUPPORTED_COMMAND: u8 = 20;
    pub const GCODE_MODAL_GROUP_VIOLATION: u8 = 21;
    pub const GCODE_UNDEFINED_FEED_RATE: u8 = 22;
    pub const GCODE_COMMAND_VALUE_NOT_INTEGER: u8 = 23;
    pub const GCODE_WORD_REPEATED: u8 = 25;
    pub const GCODE_INVALID_LINE_NUMBER: u8 = 27;
    pub const GCODE_VALUE_WORD_MISSING: u8 = 28;
    pub const GCODE_UNUSED_WORDS: u8 = 36;
    pub const GCODE_MAX_VALUE_EXCEEDED: u8 = 38;
}

/// GRBL alarm codes (`ALARM:N`).
pub(crate) mod alarm {
    pub const HARD_LIMIT: u8 = 1;
    pub const SOFT_LIMIT: u8 = 2;
    pub const ABORT_CYCLE: u8 = 3;
    pub const HOMING_FAIL_RESET: u8 = 6;
    pub const HOMING_FAIL_APPROACH: u8 = 9;
}

/// The welcome message, with the firmware's leading line break.
pub(crate) const BANNER: &[u8] = b"\r\nGrbl 1.1h ['$' for help]\r\n";
const MSG_UNLOCK_HINT: &str = "[MSG:'$H'|'$X' to unlock]";
const MSG_UNLOCKED: &str = "[MSG:Caution: Unlocked]";
const MSG_RESET_TO_CONTINUE: &str = "[MSG:Reset to continue]";
const MSG_RESTORING_DEFAULTS: &str = "[MSG:Restoring defaults]";
const HELP: &str = "[HLP:$$ $# $G $I $N $x=val $Nx=line $J=line $SLP $C $X $H ~ ! ? ctrl-x]";
const VERSION: &str = "1.1h.20190830";
const OPTIONS: &str = "[OPT:V,15,128]";

/// Serial receive ring size; it holds one byte less.
const RX_BUFFER_SIZE: usize = 128;
const LINE_BUFFER_SIZE: usize = 80;
/// The firmware pauses this long after printing an alarm, s.
const ALARM_REPORT_DELAY_S: f64 = 0.5;
/// Homing gives up after this multiple of the axis' max travel.
const HOMING_SEARCH_SCALAR: f64 = 1.5;
const MM_PER_INCH: f64 = 25.4;
/// An arm whose motor stops dead coasts to rest this many times faster than the axis'
/// acceleration setting.
const COAST_DECEL_FACTOR: f64 = 4.0;

/// Fixed-point number as the firmware prints it (`-0` prints as `0`).
pub(crate) fn fmt_fixed(value: f64, decimals: usize) -> String {
    let value = if value == 0.0 || !value.is_finite() {
        0.0
    } else {
        value
    };
    format!("{value:.decimals$}")
}

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

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum HomingPhase {
    Seek { fails: bool },
    PullOff,
}

/// The line being executed while it waits for the machine; answered when done.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Pending {
    /// `G4`: wait for all queued motion to finish, dwell, then queue `then`.
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
    Home(HomingPhase),
    /// Target past the soft limits while moving: feed hold, then `ALARM:2`.
    SoftLimit,
    /// The line that raised a critical alarm, answered after the reset.
    Locked,
}

/// Real-time commands picked off the serial stream, executed at the next checkpoint.
#[derive(Debug, Clone, Copy, Default)]
struct Realtime {
    reset: bool,
    status: bool,
    hold: bool,
    resume: bool,
    jog_cancel: bool,
}

/// The emulated firmware.
#[derive(Debug)]
pub(crate) struct Controller {
    settings: Settings,
    factory_settings: Settings,
    build_info: String,
    parser: ParserState,
    motion: Motion,
    state: State,
    power: Power,
    boot_delay_s: f64,
    /// Physical arm angle minus machine X, degrees: arbitrary until homed.
    offset_deg: f64,
    world: World,
    rx: VecDeque<u8>,
    line: Vec<u8>,
    line_overflow: bool,
    in_paren_comment: bool,
    in_semicolon_comment: bool,
    realtime: Realtime,
    pending: Option<Pending>,
    /// After a hard or soft limit alarm: everything but `?` and reset is blocked.
    critical: bool,
    /// A jog is decelerating to a stop; its remaining blocks are then dropped.
    jog_cancelling: bool,
    /// Machine time until which the firmware pauses (after printing an alarm).
    stall_until: f64,
    /// An injected alarm waiting for the next half-done block.
    armed_alarm: Option<u8>,
    /// Print the stock build's optional status fields (`Pn`, `WCO`, `Ov`, `A`).
    status_extras: bool,
    /// The firmware's refresh counters for the `WCO` and `Ov` fields.
    wco_counter: u8,
    ovr_counter: u8,
    out: VecDeque<(f64, Vec<u8>)>,
}

impl Controller {
    /// A controller that powers up at machine time `now` (banner after the boot delay).
    pub fn new(config: &GrblConfig, world: World, now: f64) -> Self {
        let settings = Settings::from_config(config);
        let mut controller = Controller {
            factory_settings: settings.clone(),
            settings,
            build_info: String::new(),
            parser: ParserState::new([0.0; N_AXIS]),
            motion: Motion::new([0.0; N_AXIS]),
            state: State::Idle,
            power: Power::Off,
            boot_delay_s: config.boot_delay_s.max(0.0),
            offset_deg: 0.0,
            world,
            rx: VecDeque::new(),
            line: Vec::new(),
            line_overflow: false,
            in_paren_comment: false,
            in_semicolon_comment: false,
            realtime: Realtime::default(),
            pending: None,
            critical: false,
            jog_cancelling: false,
            stall_until: 0.0,
            armed_alarm: None,
            status_extras: config.status_extras,
            wco_counter: 0,
            ovr_counter: 0,
            out: VecDeque::new(),
        };
        controller.power_on(now);
        controller
    }

    /// Power lost (USB unplugged): the arm stays where it is, nothing is sent.
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

    /// A hardware reset (DTR toggle): reboot, position lost.
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
        if self.power != Power::On {
            return;
        }
        match byte {
            0x18 => self.realtime.reset = true,
            b'?' => self.realtime.status = true,
            b'!' => self.realtime.hold = true,
            b'~' => self.realtime.resume = true,
            0x85 => self.realtime.jog_cancel = true,
            // Extended real-time commands (overrides, safety door) are not emulated; the
            // firmware drops any other byte above 0x7F too.
            0x80.. => {}
            _ => {
                if self.rx.len() < RX_BUFFER_SIZE - 1 {
                    self.rx.push_back(byte);
                }
                // Otherwise the byte is lost, as in the firmware's full receive ring.
            }
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
        match self.power {
            Power::Off => return,
            Power::Booting { at } if now < at => return,
            Power::Booting { .. } => self.boot(now),
            Power::On => {}
        }
        self.motion.update(now, &self.settings.axes);
        self.sync_world(now);
        self.finish_jog_cancel(now);
        self.update_state();
        if now < self.stall_until {
            return;
        }
        if std::mem::take(&mut self.realtime.reset) {
            self.soft_reset(now);
        }
        if std::mem::take(&mut self.realtime.status) {
            let report = self.status_report(now);
            self.emit_line(now, &report);
        }
        if self.critical {
            return;
        }
        self.check_armed_alarm(now);
        if self.critical || now < self.stall_until {
            return;
        }
        if self.state != State::Home {
            if std::mem::take(&mut self.realtime.hold) {
                self.feed_hold(now);
            }
            if std::mem::take(&mut self.realtime.resume) {
                self.cycle_start(now);
            }
            if std::mem::take(&mut self.realtime.jog_cancel) && self.state == State::Jog {
                self.cancel_jog(now);
            }
        }
        self.advance_pending(now);
        self.process_input(now);
    }

    fn boot(&mut self, now: f64) {
        self.power = Power::On;
        self.motion.set_position([0.0; N_AXIS]);
        self.parser = ParserState::new([0.0; N_AXIS]);
        self.offset_deg = self.world.arm_deg();
        self.state = if self.settings.homing {
            State::Alarm
        } else {
            State::Idle
        };
        self.clear_input();
        self.pending = None;
        self.critical = false;
        self.jog_cancelling = false;
        self.stall_until = now;
        self.emit(now, BANNER.to_vec());
        if self.state == State::Alarm {
            self.emit_line(now, MSG_UNLOCK_HINT);
        }
    }

    fn clear_input(&mut self) {
        self.wco_counter = 0;
        self.ovr_counter = 0;
        self.rx.clear();
        self.line.clear();
        self.line_overflow = false;
        self.in_paren_comment = false;
        self.in_semicolon_comment = false;
        self.realtime = Realtime::default();
    }

    fn sync_world(&self, now: f64) {
        let (position, _) = self.motion.state(now);
        self.world.set_arm_deg(position[0] + self.offset_deg);
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
        let vx = self.motion.velocity(now)[0];
        let position = self.motion.kill(now);
        let decel = COAST_DECEL_FACTOR * self.settings.axes[0].accel.max(1e-9);
        self.offset_deg += vx * vx.abs() / (2.0 * decel);
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
            self.emit_line(now, MSG_RESET_TO_CONTINUE);
            self.critical = true;
        } else {
            self.abort(now);
        }
    }

    /// The firmware's system abort: the executing line still gets its `ok`, input is
    /// flushed, the parser resets and the banner follows.
    fn abort(&mut self, now: f64) {
        let position = self.kill_motion(now);
        if self.pending.take().is_some() {
            self.emit_status(now, Ok(()));
        }
        self.clear_input();
        self.critical = false;
        self.jog_cancelling = false;
        self.parser = ParserState::new(position);
        self.emit(now, BANNER.to_vec());
        if self.state == State::Alarm {
            self.emit_line(now, MSG_UNLOCK_HINT);
        } else {
            self.state = State::Idle;
        }
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
            Pending::Home(phase) => {
                if self.motion.is_idle() {
                    self.homing_step(phase, now);
                }
            }
            Pending::SoftLimit => {
                if self.motion.hold_complete(now) {
                    self.pending = Some(Pending::Locked);
                    self.raise_alarm(alarm::SOFT_LIMIT, now);
                }
            }
            Pending::Locked => {}
        }
    }

    /// Move received bytes into the line buffer and execute complete lines, as long as
    /// no line is waiting for the machine.
    fn process_input(&mut self, now: f64) {
        while self.pending.is_none() && !self.critical && now >= self.stall_until {
            let Some(c) = self.rx.pop_front() else {
                return;
            };
            if c == b'\n' || c == b'\r' {
                let line = std::mem::take(&mut self.line);
                let overflow = self.line_overflow;
                self.line_overflow = false;
                self.in_paren_comment = false;
                self.in_semicolon_comment = false;
                self.execute_line(&line, overflow, now);
            } else if self.line_overflow || self.in_paren_comment || self.in_semicolon_comment {
                if c == b')' {
                    self.in_paren_comment = false;
                }
            } else if c <= b' ' || c == b'/' {
                // Whitespace and control characters are dropped; block delete is ignored.
            } else if c == b'(' {
                self.in_paren_comment = true;
            } else if c == b';' {
                self.in_semicolon_comment = true;
            } else if self.line.len() >= LINE_BUFFER_SIZE - 1 {
                self.line_overflow = true;
            } else {
                self.line.push(c.to_ascii_uppercase());
            }
        }
    }

    fn execute_line(&mut self, line: &[u8], overflow: bool, now: f64) {
        let result = if overflow {
            Some(Err(status::OVERFLOW))
        } else if line.is_empty() {
            Some(Ok(()))
        } else if line[0] == b'$' {
            self.system_command(&line[1..], now)
        } else if matches!(self.state, State::Alarm | State::Jog) {
            Some(Err(status::SYSTEM_GC_LOCK))
        } else {
            self.gcode_line(line, now)
        };
        if let Some(result) = result {
            self.emit_status(now, result);
        }
    }

    /// A `$` command (without the `$`). `None`: the line waits for the machine.
    fn system_command(&mut self, rest: &[u8], now: f64) -> Option<Result<(), u8>> {
        let first = rest.first().copied();
        match first {
            None => {
                self.emit_line(now, HELP);
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
                let version = format!("[VER:{VERSION}:{}]", self.build_info);
                self.emit_line(now, &version);
                self.emit_line(now, OPTIONS);
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
                self.emit_line(now, MSG_RESTORING_DEFAULTS);
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
        let (target, feed) = match gcode::Block::parse(&rest[2..]).and_then(|b| self.parser.jog(&b))
        {
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
                    self.emit_line(now, MSG_UNLOCKED);
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
        self.settings.store(parameter as u8, value)
    }

    fn report_parameters(&mut self, now: f64) {
        let zero = self.format_axes([0.0; N_AXIS]);
        for name in [
            "G54", "G55", "G56", "G57", "G58", "G59", "G28", "G30", "G92",
        ] {
            self.emit_line(now, &format!("[{name}:{zero}]"));
        }
        self.emit_line(now, "[TLO:0.000]");
        self.emit_line(now, &format!("[PRB:{zero}:0]"));
    }

    fn gcode_line(&mut self, line: &[u8], now: f64) -> Option<Result<(), u8>> {
        let from = self.parser.position;
        let execution = match gcode::Block::parse(line).and_then(|b| self.parser.execute(&b)) {
            Ok(execution) => execution,
            Err(code) => return Some(Err(code)),
        };
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
        if let Some(dwell_s) = execution.dwell_s {
            self.pending = Some(Pending::Sync {
                dwell_s,
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

    /// Seek the X switch (physically at θ = 0, the positive end) at the seek rate, then
    /// pull off at the locate feed rate. The other axes have no hardware and home at once.
    fn start_homing(&mut self, now: f64) {
        self.state = State::Home;
        let (position, _) = self.motion.state(now);
        let to_switch = (-(position[0] + self.offset_deg)).max(0.0);
        let search = HOMING_SEARCH_SCALAR * self.settings.axes[0].max_travel;
        let fails = to_switch > search;
        let mut target = position;
        target[0] += to_switch.min(search);
        self.motion.push(motion::Block {
            target,
            rate: self.settings.homing_seek,
        });
        self.motion.update(now, &self.settings.axes);
        self.pending = Some(Pending::Home(HomingPhase::Seek { fails }));
    }

    fn homing_step(&mut self, phase: HomingPhase, now: f64) {
        let pulloff = self.settings.homing_pulloff;
        match phase {
            HomingPhase::Seek { fails: true } => {
                self.pending = None;
                self.raise_alarm(alarm::HOMING_FAIL_APPROACH, now);
            }
            HomingPhase::Seek { fails: false } if pulloff > 0.0 => {
                let (mut target, _) = self.motion.state(now);
                target[0] -= pulloff;
                self.motion.push(motion::Block {
                    target,
                    rate: self.settings.homing_feed,
                });
                self.motion.update(now, &self.settings.axes);
                self.pending = Some(Pending::Home(HomingPhase::PullOff));
            }
            HomingPhase::Seek { fails: false } | HomingPhase::PullOff => {
                let (position, _) = self.motion.state(now);
                let physical = position[0] + self.offset_deg;
                let home = self.quantize([-pulloff; N_AXIS]);
                self.motion.set_position(home);
                self.parser.position = home;
                self.offset_deg = physical - home[0];
                self.state = State::Idle;
                self.pending = None;
                self.emit_status(now, Ok(()));
            }
        }
    }

    // ---- reports ------------------------------------------------------------------

    fn format_axes(&self, values: [f64; N_AXIS]) -> String {
        let (scale, decimals) = if self.settings.report_inches {
            (1.0 / MM_PER_INCH, 4)
        } else {
            (1.0, 3)
        };
        values
            .iter()
            .map(|v| fmt_fixed(v * scale, decimals))
            .collect::<Vec<_>>()
            .join(",")
    }

    /// The `?` report: `<State|MPos:x,y,z|FS:feed,spindle>` (`WPos` and `Bf` per `$10`).
    fn status_report(&mut self, now: f64) -> String {
        let (position, speed) = self.motion.state(now);
        let state = match self.state {
            State::Idle => "Idle",
            State::Run => "Run",
            State::Hold if self.motion.hold_complete(now) => "Hold:0",
            State::Hold => "Hold:1",
            State::Alarm => "Alarm",
            State::Home => "Home",
            State::Jog => "Jog",
        };
        let mask = self.settings.status_report_mask;
        let label = if mask & 1 != 0 { "MPos" } else { "WPos" };
        let mut report = format!(
            "<{state}|{label}:{}",
            self.format_axes(self.quantize(position))
        );
        if mask & 2 != 0 {
            report.push_str(&format!(
                "|Bf:{},{}",
                self.motion.available(),
                RX_BUFFER_SIZE - self.rx.len()
            ));
        }
        let feed = if self.settings.report_inches {
            fmt_fixed(speed * 60.0 / MM_PER_INCH, 1)
        } else {
            fmt_fixed(speed * 60.0, 0)
        };
        report.push_str(&format!(
            "|FS:{feed},{}",
            fmt_fixed(self.parser.spindle_rpm(), 0)
        ));
        if self.status_extras {
            self.push_status_extras(&mut report, position[0]);
        }
        report.push('>');
        report
    }

    /// `Pn:X` while the arm presses the home switch (physically θ ≥ 0); `WCO` and then
    /// `Ov` (with `A`) on the firmware's refresh counters: every 10th report when idle,
    /// every 30th / 20th while busy.
    fn push_status_extras(&mut self, report: &mut String, x: f64) {
        if x + self.offset_deg >= 0.0 {
            report.push_str("|Pn:X");
        }
        let busy = matches!(
            self.state,
            State::Run | State::Hold | State::Home | State::Jog
        );
        if self.wco_counter > 0 {
            self.wco_counter -= 1;
        } else {
            self.wco_counter = if busy { 29 } else { 9 };
            if self.ovr_counter == 0 {
                self.ovr_counter = 1;
            }
            let zero = self.format_axes([0.0; N_AXIS]);
            report.push_str(&format!("|WCO:{zero}"));
        }
        if self.ovr_counter > 0 {
            self.ovr_counter -= 1;
        } else {
            self.ovr_counter = if busy { 19 } else { 9 };
            report.push_str("|Ov:100,100,100");
            let accessories = self.parser.accessories();
            if !accessories.is_empty() {
                report.push_str(&format!("|A:{accessories}"));
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A booted controller (homing enabled, arm physically at −30°) at machine time 0.5.
    fn booted() -> (Controller, World) {
        let world = World::new(-30.0);
        let mut c = Controller::new(&GrblConfig::default(), world.clone(), 0.0);
        c.tick(0.5);
        assert_eq!(
            take(&mut c, 0.5),
            "\r\nGrbl 1.1h ['$' for help]\r\n[MSG:'$H'|'$X' to unlock]\r\n"
        );
        (c, world)
    }

    /// Bytes arrive one by one, each a checkpoint, as on the serial line.
    fn send(c: &mut Controller, text: &str, now: f64) -> String {
        for b in text.bytes() {
            c.receive(b);
            c.tick(now);
        }
        c.tick(now);
        take(c, now)
    }

    fn take(c: &mut Controller, now: f64) -> String {
        let bytes: Vec<u8> = c.take_output(now).concat();
        String::from_utf8(bytes).unwrap()
    }

    #[test]
    fn locked_until_unlocked_then_moves_in_time() {
        let (mut c, world) = booted();
        assert_eq!(send(&mut c, "G0X-10\n", 1.0), "error:9\r\n");
        assert_eq!(
            send(&mut c, "$X\n", 1.0),
            "[MSG:Caution: Unlocked]\r\nok\r\n"
        );
        // Not homed: MPos counts from power-up, the arm is physically at −30°.
        assert_eq!(send(&mut c, "G0X-10\n", 1.0), "ok\r\n");
        // 10° with 40°/s²: a triangle peaking at √(40·10) = 20°/s (the max rate), 1 s.
        assert_eq!(
            send(&mut c, "?", 1.5),
            "<Run|MPos:-5.000,0.000,0.000|FS:1200,0>\r\n"
        );
        assert!((world.arm_deg() + 35.0).abs() < 1e-9);
        assert_eq!(
            send(&mut c, "?", 2.0),
            "<Idle|MPos:-10.000,0.000,0.000|FS:0,0>\r\n"
        );
        assert!((world.arm_deg() + 40.0).abs() < 1e-9);
    }

    #[test]
    fn homing_finds_the_switch_at_the_positive_end() {
        let (mut c, world) = booted();
        assert_eq!(send(&mut c, "$H\n", 1.0), "");
        assert_eq!(
            send(&mut c, "?", 1.1),
            "<Home|MPos:0.200,0.000,0.000|FS:240,0>\r\n"
        );
        // 30° at 10°/s with 40°/s² ramps: 3.25 s.
        assert_eq!(send(&mut c, "", 4.2), "");
        assert_eq!(send(&mut c, "", 4.3), "ok\r\n");
        assert_eq!(world.arm_deg(), 0.0);
        assert_eq!(
            send(&mut c, "?", 4.3),
            "<Idle|MPos:0.000,0.000,0.000|FS:0,0>\r\n"
        );
        // A target past the soft limits raises ALARM:2 and locks until reset.
        assert_eq!(send(&mut c, "G0X-181\n", 5.0), "ALARM:2\r\n");
        assert_eq!(
            send(&mut c, "$X\n?", 5.6),
            "[MSG:Reset to continue]\r\n<Alarm|MPos:0.000,0.000,0.000|FS:0,0>\r\n"
        );
        assert_eq!(
            send(&mut c, "\x18", 6.0),
            "ok\r\n\r\nGrbl 1.1h ['$' for help]\r\n[MSG:'$H'|'$X' to unlock]\r\n"
        );
    }

    #[test]
    fn dwell_waits_for_motion_and_reset_mid_move_alarms() {
        let (mut c, world) = booted();
        send(&mut c, "$X\n", 1.0);
        assert_eq!(send(&mut c, "G1X-20F600\nG4P0\n", 1.0), "ok\r\n");
        // 20° at 10°/s, ramps 0.25 s: 2.25 s.
        assert_eq!(send(&mut c, "", 3.2), "");
        assert_eq!(send(&mut c, "", 3.26), "ok\r\n");
        assert_eq!(send(&mut c, "G1X-40\n", 4.0), "ok\r\n");
        // 1 s into the 20° move (0.25 s ramp to 10°/s): 8.75° done; hold takes 0.25 s.
        assert_eq!(send(&mut c, "!", 5.0), "");
        assert_eq!(
            send(&mut c, "?", 5.1),
            "<Hold:1|MPos:-29.550,0.000,0.000|FS:360,0>\r\n"
        );
        assert_eq!(
            send(&mut c, "?", 5.5),
            "<Hold:0|MPos:-30.000,0.000,0.000|FS:0,0>\r\n"
        );
        let held = world.arm_deg();
        assert_eq!(send(&mut c, "$$\n", 5.5), "error:8\r\n");
        assert_eq!(
            send(&mut c, "?", 5.5),
            "<Hold:0|MPos:-30.000,0.000,0.000|FS:0,0>\r\n"
        );
        assert_eq!(world.arm_deg(), held);
        assert_eq!(send(&mut c, "~", 5.5), "");
        assert_eq!(
            send(&mut c, "?", 6.0),
            "<Run|MPos:-33.750,0.000,0.000|FS:600,0>\r\n"
        );
        assert_eq!(send(&mut c, "\x18", 6.0), "ALARM:3\r\n");
        // Stopped dead at 10°/s: the arm (30° below MPos since power-up) coasts on
        // 10²/(2·4·40) = 0.3125° while the motor slips.
        assert!((world.arm_deg() - (-30.0 - 33.75 - 0.3125)).abs() < 1e-9);
        assert_eq!(
            send(&mut c, "?", 6.5),
            "\r\nGrbl 1.1h ['$' for help]\r\n[MSG:'$H'|'$X' to unlock]\r\n<Alarm|MPos:-33.750,0.000,0.000|FS:0,0>\r\n"
        );
    }

    #[test]
    fn jogging_and_jog_cancel() {
        let (mut c, _) = booted();
        assert_eq!(send(&mut c, "$J=G91X-10F600\n", 1.0), "error:8\r\n");
        send(&mut c, "$X\n", 1.0);
        assert_eq!(send(&mut c, "$J=G91X-10\n", 1.0), "error:22\r\n");
        assert_eq!(send(&mut c, "$J=G1X-10F600\n", 1.0), "error:16\r\n");
        assert_eq!(send(&mut c, "$J=G91F600\n", 1.0), "error:16\r\n");
        assert_eq!(send(&mut c, "$J=X-10F600S1\n", 1.0), "error:36\r\n");
        assert_eq!(send(&mut c, "$J=X-200F600\n", 1.0), "error:15\r\n");
        assert_eq!(send(&mut c, "$JX-1F600\n", 1.0), "error:3\r\n");
        // 20° at 10°/s with 0.25 s ramps: 2.25 s.
        assert_eq!(
            send(&mut c, "$J=G91X-20F600\n?", 1.0),
            "ok\r\n<Jog|MPos:0.000,0.000,0.000|FS:0,0>\r\n"
        );
        assert_eq!(send(&mut c, "G0X-5\n", 1.5), "error:9\r\n");
        assert_eq!(
            send(&mut c, "?", 3.3),
            "<Idle|MPos:-20.000,0.000,0.000|FS:0,0>\r\n"
        );
        // The jog kept the parser in G90: this is absolute.
        assert_eq!(
            send(&mut c, "$J=X-40F600\n$J=X-60F600\n", 4.0),
            "ok\r\nok\r\n"
        );
        assert_eq!(send(&mut c, "\u{85}", 5.0), "");
        // Cancelled at 10°/s after 8.75°: 0.25 s and 1.25° to stop, the rest dropped.
        assert_eq!(
            send(&mut c, "?", 5.1),
            "<Jog|MPos:-29.550,0.000,0.000|FS:360,0>\r\n"
        );
        assert_eq!(
            send(&mut c, "?", 5.3),
            "<Idle|MPos:-30.000,0.000,0.000|FS:0,0>\r\n"
        );
        assert_eq!(
            send(&mut c, "G91G0X1\nG4P0\n?", 5.3),
            "ok\r\n<Run|MPos:-30.000,0.000,0.000|FS:0,0>\r\n"
        );
        assert_eq!(send(&mut c, "", 9.0), "ok\r\n");
        assert_eq!(
            send(&mut c, "?", 9.0),
            "<Idle|MPos:-29.000,0.000,0.000|FS:0,0>\r\n"
        );
    }

    #[test]
    fn full_receive_buffer_drops_bytes_and_full_planner_delays_ok() {
        let (mut c, _) = booted();
        send(&mut c, "$X\n$10=3\n", 1.0);
        // While the dwell waits, the 128-byte ring keeps 127 bytes: 25 lines and "G4".
        let flood = "G4P0\n".repeat(30);
        assert_eq!(
            send(&mut c, &format!("G4P10\n{flood}?"), 1.0),
            "<Idle|MPos:0.000,0.000,0.000|Bf:15,1|FS:0,0>\r\n"
        );
        assert_eq!(send(&mut c, "", 11.0), "ok\r\n".repeat(26));
        assert_eq!(send(&mut c, "\n", 11.0), "error:28\r\n");
        // 15 planner blocks; the 16th move is answered when the first one is done.
        let moves = "G91G1X-1F60\n".repeat(16);
        assert_eq!(send(&mut c, &moves, 12.0), "ok\r\n".repeat(15));
        assert_eq!(
            send(&mut c, "?", 12.5125),
            "<Run|MPos:-0.500,0.000,0.000|Bf:0,128|FS:60,0>\r\n"
        );
        assert_eq!(send(&mut c, "", 13.1), "ok\r\n");
    }

    #[test]
    fn stock_status_fields_on_their_refresh_counters() {
        let config = GrblConfig {
            status_extras: true,
            homing_enabled: false,
            ..GrblConfig::default()
        };
        let mut c = Controller::new(&config, World::new(0.0), 0.0);
        c.tick(1.0);
        assert_eq!(take(&mut c, 1.0), "\r\nGrbl 1.1h ['$' for help]\r\n");
        let idle = "<Idle|MPos:0.000,0.000,0.000|FS:0,0|Pn:X";
        assert_eq!(
            send(&mut c, "?", 1.0),
            format!("{idle}|WCO:0.000,0.000,0.000>\r\n")
        );
        assert_eq!(
            send(&mut c, "M3S500M8\n?", 1.0),
            format!("ok\r\n<Idle|MPos:0.000,0.000,0.000|FS:0,500|Pn:X|Ov:100,100,100|A:SF>\r\n")
        );
        for _ in 0..8 {
            assert_eq!(
                send(&mut c, "?", 1.0),
                "<Idle|MPos:0.000,0.000,0.000|FS:0,500|Pn:X>\r\n"
            );
        }
        assert_eq!(
            send(&mut c, "M5M9G0X-1\n?", 1.0),
            "ok\r\n<Run|MPos:0.000,0.000,0.000|FS:0,0|Pn:X|WCO:0.000,0.000,0.000>\r\n"
        );
        assert_eq!(
            send(&mut c, "?", 2.0),
            "<Idle|MPos:-1.000,0.000,0.000|FS:0,0|Ov:100,100,100>\r\n"
        );
    }

    #[test]
    fn line_endings_settings_and_errors() {
        let (mut c, _) = booted();
        // The firmware ends a line at \r and at \n: CRLF answers twice.
        assert_eq!(
            send(&mut c, "$X\r\n", 1.0),
            "[MSG:Caution: Unlocked]\r\nok\r\nok\r\n"
        );
        assert_eq!(
            send(&mut c, "$110=600\n$0=1\n$130=-1\n$99=1\n", 1.0),
            "ok\r\nerror:6\r\nerror:4\r\nerror:3\r\n"
        );
        assert_eq!(
            send(&mut c, "$100=x\n$100\n$H1\n", 1.0),
            "error:2\r\nerror:3\r\nerror:3\r\n"
        );
        let settings = send(&mut c, "$$\n", 1.0);
        assert!(settings.starts_with("$0=10\r\n$1=25\r\n"));
        assert!(settings.contains("\r\n$22=1\r\n") && settings.contains("\r\n$110=600.000\r\n"));
        assert!(settings.ends_with("$132=200.000\r\nok\r\n"));
        assert_eq!(
            send(&mut c, "$I\n", 1.0),
            "[VER:1.1h.20190830:]\r\n[OPT:V,15,128]\r\nok\r\n"
        );
        assert_eq!(send(&mut c, "g0 x-1 (comment) ; rest\n", 1.0), "ok\r\n");
        let long = format!("G0X{}\n", "1".repeat(90));
        assert_eq!(send(&mut c, &long, 1.0), "error:11\r\n");
    }
}
