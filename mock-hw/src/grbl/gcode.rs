//! The G-code subset the emulated firmware executes, parsed and checked with GRBL's
//! status codes: G0 G1 G4 G10 (L2, L20) G17 G20 G21 G53 G54–G59 G90 G91 G92 G92.1 G94,
//! M3 M4 M5 M8 M9, words F L N P S T X Y Z, and `$J=` jog blocks.
//! Lines arrive upper-cased and without spaces or comments (the protocol strips them).

use super::report::{self, status, N_AXIS};

const MM_PER_INCH: f64 = 25.4;
const MAX_LINE_NUMBER: f64 = 10_000_000.0;
const MAX_TOOL_NUMBER: f64 = 255.0;
/// Work coordinate systems G54–G59.
pub(crate) const N_COORDINATE_SYSTEMS: usize = 6;

/// The work coordinate systems G54–G59 the firmware keeps in EEPROM, machine units.
pub(crate) type CoordSystems = [[f64; N_AXIS]; N_COORDINATE_SYSTEMS];

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

/// The non-modal command of a block (GRBL's modal group 0).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum NonModal {
    /// G4.
    Dwell,
    /// G10: set coordinate data (L2 values, L20 from the current position).
    SetCoordinateData,
    /// G53: machine coordinates, absolute, for this block only.
    MachineCoordinates,
    /// G92: offset the work position to the given values.
    SetOffset,
    /// G92.1: clear the G92 offset.
    ResetOffset,
}

/// The words of one block, before checking them against the modal state.
#[derive(Debug, Clone, Default, PartialEq)]
pub(crate) struct Block {
    motion: Option<MotionMode>,
    non_modal: Option<NonModal>,
    /// G54–G59 as 0–5.
    coord_select: Option<usize>,
    /// G17 or G94 given (modal commands that change nothing here).
    fixed_modal: bool,
    incremental: Option<bool>,
    inches: Option<bool>,
    spindle: Option<Spindle>,
    coolant: Option<bool>,
    axes: [Option<f64>; N_AXIS],
    f: Option<f64>,
    l: Option<f64>,
    n: Option<f64>,
    p: Option<f64>,
    s: Option<f64>,
    t: Option<f64>,
}

/// What a checked block asks the machine to do, in order: wait for the queued motion
/// (then dwell), then move.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Execution {
    /// Wait until all queued motion has finished before answering: `G4`, and the
    /// blocks that change a work offset, the spindle or the coolant (the stock build
    /// synchronises those).
    pub sync: bool,
    /// `G4 P…` seconds, after the sync.
    pub dwell_s: Option<f64>,
    /// Target in machine units and requested rate in units/min (`INFINITY` = rapid).
    pub motion: Option<([f64; N_AXIS], f64)>,
    /// The work coordinate offset changed (`WCO` on the next report).
    pub wco_changed: bool,
    /// The spindle or coolant changed (`Ov`/`A` on the next report).
    pub accessories_changed: bool,
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
        // Hundredths after the point, as the firmware reads them (G92.1 → 10).
        let mantissa = (100.0 * (value - int)).round() as i64;
        let group = match (letter, code) {
            (b'G', 0 | 1) => 0,
            (b'G', 4 | 10 | 53 | 92) => 1,
            (b'G', 17) => 2,
            (b'G', 20 | 21) => 3,
            (b'G', 54..=59) => 4,
            (b'G', 90 | 91) => 5,
            (b'G', 94) => 6,
            (b'M', 3..=5) => 7,
            (b'M', 8 | 9) => 8,
            _ => return Err(status::GCODE_UNSUPPORTED_COMMAND),
        };
        let reset_offset = letter == b'G' && code == 92 && mantissa == 10;
        if mantissa != 0 && !reset_offset {
            return Err(status::GCODE_COMMAND_VALUE_NOT_INTEGER);
        }
        if *groups & (1 << group) != 0 {
            return Err(status::GCODE_MODAL_GROUP_VIOLATION);
        }
        *groups |= 1 << group;
        match (letter, code) {
            (b'G', 0) => self.motion = Some(MotionMode::Seek),
            (b'G', 1) => self.motion = Some(MotionMode::Linear),
            (b'G', 4) => self.non_modal = Some(NonModal::Dwell),
            (b'G', 10) => self.non_modal = Some(NonModal::SetCoordinateData),
            (b'G', 53) => self.non_modal = Some(NonModal::MachineCoordinates),
            (b'G', 92) if reset_offset => self.non_modal = Some(NonModal::ResetOffset),
            (b'G', 92) => self.non_modal = Some(NonModal::SetOffset),
            (b'G', 20) => self.inches = Some(true),
            (b'G', 21) => self.inches = Some(false),
            (b'G', 54..=59) => self.coord_select = Some(usize::from(code - 54)),
            (b'G', 90) => self.incremental = Some(false),
            (b'G', 91) => self.incremental = Some(true),
            (b'M', 3) => self.spindle = Some(Spindle::Cw),
            (b'M', 4) => self.spindle = Some(Spindle::Ccw),
            (b'M', 5) => self.spindle = Some(Spindle::Off),
            (b'M', 8) => self.coolant = Some(true),
            (b'M', 9) => self.coolant = Some(false),
            // G17, G94: the only plane and feed mode.
            _ => self.fixed_modal = true,
        }
        Ok(())
    }

    fn word(&mut self, letter: u8, value: f64) -> Result<(), u8> {
        let slot = match letter {
            b'F' => &mut self.f,
            b'L' => &mut self.l,
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

    fn has_axes(&self) -> bool {
        self.axes.iter().any(Option::is_some)
    }
}

/// The parser's modal state (`$G`), its G92 offset and the planned position (end of
/// queued motion). Reset with the firmware (G92 is not kept; G54–G59 are in EEPROM).
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
    /// Active work coordinate system, 0 = G54.
    coord_select: usize,
    /// G92 offset, machine units.
    coord_offset: [f64; N_AXIS],
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
            coord_select: 0,
            coord_offset: [0.0; N_AXIS],
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

    /// The work coordinate offset (active system plus G92), machine units.
    pub fn wco(&self, coords: &CoordSystems) -> [f64; N_AXIS] {
        let mut wco = coords[self.coord_select];
        for (w, o) in wco.iter_mut().zip(self.coord_offset) {
            *w += o;
        }
        wco
    }

    /// The G92 offset, machine units.
    pub fn coord_offset(&self) -> [f64; N_AXIS] {
        self.coord_offset
    }

    /// Check `block` against the modal state; on success commit its modal changes (and
    /// G10's coordinate data to `coords`) and return what to execute. On error nothing
    /// changes.
    pub fn execute(&mut self, block: &Block, coords: &mut CoordSystems) -> Result<Execution, u8> {
        if block.n.is_some_and(|n| n > MAX_LINE_NUMBER) {
            return Err(status::GCODE_INVALID_LINE_NUMBER);
        }
        if block.t.is_some_and(|t| t > MAX_TOOL_NUMBER) {
            return Err(status::GCODE_MAX_VALUE_EXCEEDED);
        }
        let inches = block.inches.unwrap_or(self.inches);
        let scale = if inches { MM_PER_INCH } else { 1.0 };
        let feed = block.f.map_or(self.feed, |f| f * scale);
        let coord_select = block.coord_select.unwrap_or(self.coord_select);
        let axis_words = block.has_axes();
        // G10 and G92 take the axis words; a motion command may not have them too.
        let offsets = matches!(
            block.non_modal,
            Some(NonModal::SetCoordinateData | NonModal::SetOffset)
        );
        if offsets && block.motion.is_some() {
            return Err(status::GCODE_AXIS_COMMAND_CONFLICT);
        }
        if offsets && !axis_words {
            return Err(status::GCODE_NO_AXIS_WORDS);
        }
        let uses_p = matches!(
            block.non_modal,
            Some(NonModal::Dwell | NonModal::SetCoordinateData)
        );
        if block.p.is_some() && !uses_p
            || block.l.is_some() && block.non_modal != Some(NonModal::SetCoordinateData)
        {
            return Err(status::GCODE_UNUSED_WORDS);
        }
        let dwell_s = match block.non_modal {
            Some(NonModal::Dwell) => Some(block.p.ok_or(status::GCODE_VALUE_WORD_MISSING)?),
            _ => None,
        };
        let new_coords = match block.non_modal {
            Some(NonModal::SetCoordinateData) => {
                Some(self.coordinate_data(block, coord_select, scale, coords)?)
            }
            _ => None,
        };
        let new_offset = match block.non_modal {
            Some(NonModal::SetOffset) => {
                let system = coords[coord_select];
                let mut offset = self.coord_offset;
                for i in 0..N_AXIS {
                    if let Some(v) = block.axes[i] {
                        offset[i] = self.position[i] - system[i] - v * scale;
                    }
                }
                Some(offset)
            }
            Some(NonModal::ResetOffset) => Some([0.0; N_AXIS]),
            _ => None,
        };
        let motion_mode = block.motion.unwrap_or(self.motion);
        let moves = !offsets && (block.motion.is_some() || axis_words);
        if moves && motion_mode == MotionMode::Linear && feed == 0.0 {
            return Err(status::GCODE_UNDEFINED_FEED_RATE);
        }
        let incremental = block.incremental.unwrap_or(self.incremental);
        let motion = (moves && axis_words).then(|| {
            let mut wco = coords[coord_select];
            for (w, o) in wco.iter_mut().zip(new_offset.unwrap_or(self.coord_offset)) {
                *w += o;
            }
            let machine = block.non_modal == Some(NonModal::MachineCoordinates);
            let target = self.target(block, incremental && !machine, scale, wco, machine);
            let rate = match motion_mode {
                MotionMode::Seek => f64::INFINITY,
                MotionMode::Linear => feed,
            };
            (target, rate)
        });

        let spindle = block.spindle.unwrap_or(self.spindle);
        let speed = block.s.unwrap_or(self.spindle_speed);
        let spindle_changed =
            spindle != self.spindle || (spindle != Spindle::Off && speed != self.spindle_speed);
        let coolant_changed = block.coolant.is_some_and(|c| c != self.coolant);
        let wco_changed = new_offset.is_some()
            || coord_select != self.coord_select
            || new_coords.is_some_and(|(index, _)| index == coord_select);

        self.motion = motion_mode;
        self.incremental = incremental;
        self.inches = inches;
        self.feed = feed;
        self.spindle_speed = speed;
        self.spindle = spindle;
        self.coord_select = coord_select;
        if let Some(t) = block.t {
            self.tool = t as u8;
        }
        if let Some(coolant) = block.coolant {
            self.coolant = coolant;
        }
        if let Some((index, data)) = new_coords {
            coords[index] = data;
        }
        if let Some(offset) = new_offset {
            self.coord_offset = offset;
        }
        if let Some((target, _)) = motion {
            self.position = target;
        }
        let accessories_changed = spindle_changed || coolant_changed;
        Ok(Execution {
            sync: dwell_s.is_some() || wco_changed || accessories_changed,
            dwell_s,
            motion,
            wco_changed,
            accessories_changed,
        })
    }

    /// G10 L2 / L20: the coordinate system it writes and its new values.
    fn coordinate_data(
        &self,
        block: &Block,
        active: usize,
        scale: f64,
        coords: &CoordSystems,
    ) -> Result<(usize, [f64; N_AXIS]), u8> {
        let (Some(p), Some(l)) = (block.p, block.l) else {
            return Err(status::GCODE_VALUE_WORD_MISSING);
        };
        let p = p.trunc() as usize;
        if p > N_COORDINATE_SYSTEMS {
            return Err(status::GCODE_UNSUPPORTED_COORD_SYS);
        }
        let from_position = match l.trunc() as i64 {
            2 => false,
            20 => true,
            _ => return Err(status::GCODE_UNSUPPORTED_COMMAND),
        };
        // P0 is the active system, P1–P6 are G54–G59.
        let index = if p == 0 { active } else { p - 1 };
        let mut data = coords[index];
        for (i, (d, word)) in data.iter_mut().zip(block.axes).enumerate() {
            if let Some(v) = word {
                *d = if from_position {
                    // WPos = MPos − WCS − G92  →  WCS = MPos − G92 − WPos.
                    self.position[i] - self.coord_offset[i] - v * scale
                } else {
                    v * scale
                };
            }
        }
        Ok((index, data))
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

    /// The axis words of `block` as a machine target: work coordinates (offset by
    /// `wco`) unless `machine` (G53); relative to the planned position if `incremental`.
    fn target(
        &self,
        block: &Block,
        incremental: bool,
        scale: f64,
        wco: [f64; N_AXIS],
        machine: bool,
    ) -> [f64; N_AXIS] {
        let mut target = self.position;
        for i in 0..N_AXIS {
            if let Some(v) = block.axes[i] {
                target[i] = if incremental {
                    target[i] + v * scale
                } else if machine {
                    v * scale
                } else {
                    v * scale + wco[i]
                };
            }
        }
        target
    }

    /// Check a `$J=` block: only G20/G21, G90/G91, G53, axis words, a required F and N.
    /// Returns the target (machine units) and feed (units/min); the modal state is kept.
    pub fn jog(&self, block: &Block, coords: &CoordSystems) -> Result<([f64; N_AXIS], f64), u8> {
        let machine = match block.non_modal {
            None => false,
            Some(NonModal::MachineCoordinates) => true,
            Some(_) => return Err(status::INVALID_JOG_COMMAND),
        };
        if block.motion.is_some()
            || block.fixed_modal
            || block.coord_select.is_some()
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
        if block.l.is_some() || block.p.is_some() || block.s.is_some() || block.t.is_some() {
            return Err(status::GCODE_UNUSED_WORDS);
        }
        if !block.has_axes() {
            return Err(status::INVALID_JOG_COMMAND);
        }
        let incremental = block.incremental.unwrap_or(self.incremental) && !machine;
        let wco = self.wco(coords);
        Ok((self.target(block, incremental, scale, wco, machine), feed))
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
        format!(
            "[GC:G{motion} G{} G17 G{units} G{distance} G94 M{spindle} M{coolant} T{} F{} S{}]",
            54 + self.coord_select,
            self.tool,
            report::rate(self.feed, self.inches),
            report::fmt_fixed(self.spindle_speed, 0)
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run_with(
        state: &mut ParserState,
        coords: &mut CoordSystems,
        line: &str,
    ) -> Result<Execution, u8> {
        state.execute(&Block::parse(line.as_bytes())?, coords)
    }

    fn run(state: &mut ParserState, line: &str) -> Result<Execution, u8> {
        run_with(state, &mut [[0.0; N_AXIS]; N_COORDINATE_SYSTEMS], line)
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

    #[test]
    fn work_offsets_move_the_work_position() {
        let mut coords = [[0.0; N_AXIS]; N_COORDINATE_SYSTEMS];
        let mut state = ParserState::new([-3.0, 0.0, 0.0]);
        // G92 X-12 at MPos −3: WCO 9, so X-20 in work coordinates is MPos −11.
        let e = run_with(&mut state, &mut coords, "G92X-12").unwrap();
        assert!(e.sync && e.wco_changed && e.motion.is_none());
        assert_eq!(state.coord_offset(), [9.0, 0.0, 0.0]);
        let e = run_with(&mut state, &mut coords, "G0X-20").unwrap();
        assert_eq!(e.motion, Some(([-11.0, 0.0, 0.0], f64::INFINITY)));
        let e = run_with(&mut state, &mut coords, "G53G0X-20").unwrap();
        assert_eq!(e.motion, Some(([-20.0, 0.0, 0.0], f64::INFINITY)));
        assert_eq!(
            run_with(&mut state, &mut coords, "G0G92X1"),
            Err(status::GCODE_AXIS_COMMAND_CONFLICT)
        );
        assert_eq!(
            run_with(&mut state, &mut coords, "G92"),
            Err(status::GCODE_NO_AXIS_WORDS)
        );
        assert_eq!(
            run_with(&mut state, &mut coords, "G92.2X1"),
            Err(status::GCODE_COMMAND_VALUE_NOT_INTEGER)
        );
        // G10 L20 P0 at MPos −20 with G92 9: G54 = −20 − 9 − (−30) = 1.
        run_with(&mut state, &mut coords, "G10L20P0X-30").unwrap();
        run_with(&mut state, &mut coords, "G92.1").unwrap();
        assert_eq!(state.coord_offset(), [0.0; N_AXIS]);
        assert_eq!(coords[0], [1.0, 0.0, 0.0]);
        assert_eq!(
            run_with(&mut state, &mut coords, "G10L2P7X0"),
            Err(status::GCODE_UNSUPPORTED_COORD_SYS)
        );
        assert_eq!(
            run_with(&mut state, &mut coords, "G10L3P1X0"),
            Err(status::GCODE_UNSUPPORTED_COMMAND)
        );
        assert_eq!(
            run_with(&mut state, &mut coords, "G10P1X0"),
            Err(status::GCODE_VALUE_WORD_MISSING)
        );
        assert_eq!(
            run_with(&mut state, &mut coords, "L2X0"),
            Err(status::GCODE_UNUSED_WORDS)
        );
        run_with(&mut state, &mut coords, "G10L2P2X5").unwrap();
        let e = run_with(&mut state, &mut coords, "G55").unwrap();
        assert!(e.wco_changed);
        assert_eq!(state.wco(&coords), [5.0, 0.0, 0.0]);
        assert_eq!(state.report(), "[GC:G0 G55 G17 G21 G90 G94 M5 M9 T0 F0 S0]");
    }
}
