//! The G-code subset the emulated firmware executes, parsed and checked with GRBL's
//! status codes: G0 G1 G4 G17 G20 G21 G53 G54 G90 G91 G94, M3 M4 M5 M8 M9, words
//! F N P S T X Y Z, and `$J=` jog blocks.
//! Lines arrive upper-cased and without spaces or comments (the protocol strips them).

use super::protocol::{fmt_fixed, status};
use super::settings::N_AXIS;

const MM_PER_INCH: f64 = 25.4;
const MAX_LINE_NUMBER: f64 = 10_000_000.0;
const MAX_TOOL_NUMBER: f64 = 255.0;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum MotionMode {
    Seek,
    Linear,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Spindle {
    Off,
    Cw,
    Ccw,
}

/// The words of one block, before checking them against the modal state.
#[derive(Debug, Clone, Default, PartialEq)]
pub(crate) struct Block {
    motion: Option<MotionMode>,
    dwell: bool,
    /// G53: machine coordinates, absolute, for this block only.
    machine_coords: bool,
    /// G17, G54 or G94 given (modal commands that change nothing here).
    fixed_modal: bool,
    incremental: Option<bool>,
    inches: Option<bool>,
    spindle: Option<Spindle>,
    coolant: Option<bool>,
    axes: [Option<f64>; N_AXIS],
    f: Option<f64>,
    n: Option<f64>,
    p: Option<f64>,
    s: Option<f64>,
    t: Option<f64>,
}

/// What a checked block asks the machine to do, in order: dwell, then move.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Execution {
    /// `G4 P…` seconds (after all queued motion has finished).
    pub dwell_s: Option<f64>,
    /// Target in machine units and requested rate in units/min (`INFINITY` = rapid).
    pub motion: Option<([f64; N_AXIS], f64)>,
}

/// GRBL's `read_float`: optional sign, digits with at most one point, no exponent.
/// Advances `pos` past the number; `None` when no digit was found.
pub(crate) fn read_float(line: &[u8], pos: &mut usize) -> Option<f64> {
    let start = *pos;
    let mut i = start;
    if matches!(line.get(i), Some(b'-' | b'+')) {
        i += 1;
    }
    let mut digits = 0;
    let mut point = false;
    while let Some(&c) = line.get(i) {
        if c.is_ascii_digit() {
            digits += 1;
        } else if c == b'.' && !point {
            point = true;
        } else {
            break;
        }
        i += 1;
    }
    if digits == 0 {
        return None;
    }
    let text = std::str::from_utf8(&line[start..i]).ok()?;
    let value = text.parse::<f64>().ok()?;
    *pos = i;
    Some(value)
}

impl Block {
    /// Split a preprocessed line into words, with GRBL's word-level errors.
    pub fn parse(line: &[u8]) -> Result<Block, u8> {
        let mut block = Block::default();
        let mut groups = 0u16;
        let mut pos = 0;
        while pos < line.len() {
            let letter = line[pos];
            if !letter.is_ascii_uppercase() {
                return Err(status::EXPECTED_COMMAND_LETTER);
            }
            pos += 1;
            let value = read_float(line, &mut pos).ok_or(status::BAD_NUMBER_FORMAT)?;
            match letter {
                b'G' | b'M' => block.command(letter, value, &mut groups)?,
                _ => block.word(letter, value)?,
            }
        }
        Ok(block)
    }

    fn command(&mut self, letter: u8, value: f64, groups: &mut u16) -> Result<(), u8> {
        let int = value.trunc();
        let code = if (0.0..=255.0).contains(&int) {
            int as u16
        } else {
            return Err(status::GCODE_UNSUPPORTED_COMMAND);
        };
        // (modal group bit, effect)
        let group = match (letter, code) {
            (b'G', 0 | 1) => 0,
            (b'G', 4 | 53) => 1,
            (b'G', 17) => 2,
            (b'G', 20 | 21) => 3,
            (b'G', 54) => 4,
            (b'G', 90 | 91) => 5,
            (b'G', 94) => 6,
            (b'M', 3..=5) => 7,
            (b'M', 8 | 9) => 8,
            _ => return Err(status::GCODE_UNSUPPORTED_COMMAND),
        };
        if (value - int).abs() > 1e-6 {
            return Err(status::GCODE_COMMAND_VALUE_NOT_INTEGER);
        }
        if *groups & (1 << group) != 0 {
            return Err(status::GCODE_MODAL_GROUP_VIOLATION);
        }
        *groups |= 1 << group;
        match (letter, code) {
            (b'G', 0) => self.motion = Some(MotionMode::Seek),
            (b'G', 1) => self.motion = Some(MotionMode::Linear),
            (b'G', 4) => self.dwell = true,
            (b'G', 53) => self.machine_coords = true,
            (b'G', 20) => self.inches = Some(true),
            (b'G', 21) => self.inches = Some(false),
            (b'G', 90) => self.incremental = Some(false),
            (b'G', 91) => self.incremental = Some(true),
            (b'M', 3) => self.spindle = Some(Spindle::Cw),
            (b'M', 4) => self.spindle = Some(Spindle::Ccw),
            (b'M', 5) => self.spindle = Some(Spindle::Off),
            (b'M', 8) => self.coolant = Some(true),
            (b'M', 9) => self.coolant = Some(false),
            // G17, G54, G94: the only plane, coordinate system and feed mode.
            _ => self.fixed_modal = true,
        }
        Ok(())
    }

    fn word(&mut self, letter: u8, value: f64) -> Result<(), u8> {
        let slot = match letter {
            b'F' => &mut self.f,
            b'N' => &mut self.n,
            b'P' => &mut self.p,
            b'S' => &mut self.s,
            b'T' => &mut self.t,
            b'X' => &mut self.axes[0],
            b'Y' => &mut self.axes[1],
            b'Z' => &mut self.axes[2],
            _ => return Err(status::GCODE_UNSUPPORTED_COMMAND),
        };
        if slot.is_some() {
            return Err(status::GCODE_WORD_REPEATED);
        }
        if matches!(letter, b'F' | b'N' | b'P' | b'S' | b'T') && value < 0.0 {
            return Err(status::NEGATIVE_VALUE);
        }
        *slot = Some(value);
        Ok(())
    }
}

/// The parser's modal state (`$G`) and the planned position (end of queued motion).
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct ParserState {
    motion: MotionMode,
    incremental: bool,
    inches: bool,
    spindle: Spindle,
    coolant: bool,
    tool: u8,
    /// Feed rate, machine units/min.
    feed: f64,
    spindle_speed: f64,
    /// Planned position, machine units.
    pub position: [f64; N_AXIS],
}

impl ParserState {
    /// Power-up / reset state at `position`.
    pub fn new(position: [f64; N_AXIS]) -> Self {
        ParserState {
            motion: MotionMode::Seek,
            incremental: false,
            inches: false,
            spindle: Spindle::Off,
            coolant: false,
            tool: 0,
            feed: 0.0,
            spindle_speed: 0.0,
            position,
        }
    }

    /// Spindle speed while the spindle runs (for the status report), rpm.
    pub fn spindle_rpm(&self) -> f64 {
        if self.spindle == Spindle::Off {
            0.0
        } else {
            self.spindle_speed
        }
    }

    /// Check `block` against the modal state; on success commit its modal changes and
    /// return what to execute. On error nothing changes.
    pub fn execute(&mut self, block: &Block) -> Result<Execution, u8> {
        if block.n.is_some_and(|n| n > MAX_LINE_NUMBER) {
            return Err(status::GCODE_INVALID_LINE_NUMBER);
        }
        if block.t.is_some_and(|t| t > MAX_TOOL_NUMBER) {
            return Err(status::GCODE_MAX_VALUE_EXCEEDED);
        }
        let inches = block.inches.unwrap_or(self.inches);
        let scale = if inches { MM_PER_INCH } else { 1.0 };
        let feed = block.f.map_or(self.feed, |f| f * scale);
        let dwell_s = if block.dwell {
            Some(block.p.ok_or(status::GCODE_VALUE_WORD_MISSING)?)
        } else if block.p.is_some() {
            return Err(status::GCODE_UNUSED_WORDS);
        } else {
            None
        };
        let motion_mode = block.motion.unwrap_or(self.motion);
        let has_axes = block.axes.iter().any(Option::is_some);
        let moves = block.motion.is_some() || has_axes;
        if moves && motion_mode == MotionMode::Linear && feed == 0.0 {
            return Err(status::GCODE_UNDEFINED_FEED_RATE);
        }
        let incremental = block.incremental.unwrap_or(self.incremental);
        let motion = if has_axes {
            let target = self.target(block, incremental, scale);
            let rate = match motion_mode {
                MotionMode::Seek => f64::INFINITY,
                MotionMode::Linear => feed,
            };
            Some((target, rate))
        } else {
            None
        };

        self.motion = motion_mode;
        self.incremental = incremental;
        self.inches = inches;
        self.feed = feed;
        if let Some(s) = block.s {
            self.spindle_speed = s;
        }
        if let Some(t) = block.t {
            self.tool = t as u8;
        }
        if let Some(spindle) = block.spindle {
            self.spindle = spindle;
        }
        if let Some(coolant) = block.coolant {
            self.coolant = coolant;
        }
        if let Some((target, _)) = motion {
            self.position = target;
        }
        Ok(Execution { dwell_s, motion })
    }

    /// The status report's accessory field (`S`/`C` spindle, `F` flood), empty if off.
    pub fn accessories(&self) -> String {
        let spindle = match self.spindle {
            Spindle::Cw => "S",
            Spindle::Ccw => "C",
            Spindle::Off => "",
        };
        let flood = if self.coolant { "F" } else { "" };
        format!("{spindle}{flood}")
    }

    /// The axis words of `block` as a machine target.
    fn target(&self, block: &Block, incremental: bool, scale: f64) -> [f64; N_AXIS] {
        let incremental = incremental && !block.machine_coords;
        let mut target = self.position;
        for (t, word) in target.iter_mut().zip(block.axes) {
            if let Some(v) = word {
                *t = if incremental {
                    *t + v * scale
                } else {
                    v * scale
                };
            }
        }
        target
    }

    /// Check a `$J=` block: only G20/G21, G90/G91, G53, axis words, a required F and N.
    /// Returns the target (machine units) and feed (units/min); the modal state is kept.
    pub fn jog(&self, block: &Block) -> Result<([f64; N_AXIS], f64), u8> {
        if block.motion.is_some()
            || block.dwell
            || block.fixed_modal
            || block.spindle.is_some()
            || block.coolant.is_some()
        {
            return Err(status::INVALID_JOG_COMMAND);
        }
        let inches = block.inches.unwrap_or(self.inches);
        let scale = if inches { MM_PER_INCH } else { 1.0 };
        let feed = block.f.ok_or(status::GCODE_UNDEFINED_FEED_RATE)? * scale;
        if block.n.is_some_and(|n| n > MAX_LINE_NUMBER) {
            return Err(status::GCODE_INVALID_LINE_NUMBER);
        }
        if block.p.is_some() || block.s.is_some() || block.t.is_some() {
            return Err(status::GCODE_UNUSED_WORDS);
        }
        if block.axes.iter().all(Option::is_none) {
            return Err(status::INVALID_JOG_COMMAND);
        }
        let incremental = block.incremental.unwrap_or(self.incremental);
        Ok((self.target(block, incremental, scale), feed))
    }

    /// The `$G` report line (without line ending).
    pub fn report(&self) -> String {
        let motion = match self.motion {
            MotionMode::Seek => 0,
            MotionMode::Linear => 1,
        };
        let units = if self.inches { 20 } else { 21 };
        let distance = if self.incremental { 91 } else { 90 };
        let spindle = match self.spindle {
            Spindle::Cw => 3,
            Spindle::Ccw => 4,
            Spindle::Off => 5,
        };
        let coolant = if self.coolant { 8 } else { 9 };
        let feed = if self.inches {
            fmt_fixed(self.feed / MM_PER_INCH, 1)
        } else {
            fmt_fixed(self.feed, 0)
        };
        format!(
            "[GC:G{motion} G54 G17 G{units} G{distance} G94 M{spindle} M{coolant} T{} F{feed} S{}]",
            self.tool,
            fmt_fixed(self.spindle_speed, 0)
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run(state: &mut ParserState, line: &str) -> Result<Execution, u8> {
        state.execute(&Block::parse(line.as_bytes())?)
    }

    #[test]
    fn words_and_errors_follow_grbl() {
        let mut state = ParserState::new([0.0; N_AXIS]);
        assert_eq!(
            run(&mut state, "G1X-10"),
            Err(status::GCODE_UNDEFINED_FEED_RATE)
        );
        assert_eq!(
            run(&mut state, "G0G1X1"),
            Err(status::GCODE_MODAL_GROUP_VIOLATION)
        );
        assert_eq!(run(&mut state, "X1X2"), Err(status::GCODE_WORD_REPEATED));
        assert_eq!(run(&mut state, "G4"), Err(status::GCODE_VALUE_WORD_MISSING));
        assert_eq!(run(&mut state, "P1"), Err(status::GCODE_UNUSED_WORDS));
        assert_eq!(
            run(&mut state, "G2X1"),
            Err(status::GCODE_UNSUPPORTED_COMMAND)
        );
        assert_eq!(
            run(&mut state, "G1.5"),
            Err(status::GCODE_COMMAND_VALUE_NOT_INTEGER)
        );
        assert_eq!(run(&mut state, "1"), Err(status::EXPECTED_COMMAND_LETTER));
        assert_eq!(run(&mut state, "GX"), Err(status::BAD_NUMBER_FORMAT));
        assert_eq!(run(&mut state, "F-1"), Err(status::NEGATIVE_VALUE));
        let e = run(&mut state, "G1X-10F300").unwrap();
        assert_eq!(e.motion, Some(([-10.0, 0.0, 0.0], 300.0)));
        let e = run(&mut state, "G91X-5").unwrap();
        assert_eq!(e.motion, Some(([-15.0, 0.0, 0.0], 300.0)));
        let e = run(&mut state, "G4P0.5").unwrap();
        assert_eq!((e.dwell_s, e.motion), (Some(0.5), None));
        assert_eq!(
            state.report(),
            "[GC:G1 G54 G17 G21 G91 G94 M5 M9 T0 F300 S0]"
        );
    }
}
