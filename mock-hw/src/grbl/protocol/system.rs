//! `$` system commands: help, settings (`$$`, `$N=`), the parser state (`$G`),
//! parameters (`$#`), build info (`$I`), unlock (`$X`), homing (`$H`), restoring
//! defaults (`$RST=`) and jogging (`$J=`).

use super::{Controller, Pending, State};
use crate::grbl::gcode::{self, N_COORDINATE_SYSTEMS};
use crate::grbl::motion;
use crate::grbl::report::{self, status, text, N_AXIS};

impl Controller {
    /// A `$` command (without the `$`). `None`: the line waits for the machine.
    pub(super) fn system_command(&mut self, rest: &[u8], now: f64) -> Option<Result<(), u8>> {
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
}
