//! What the emulated firmware prints (GRBL 1.1h's report.c and print.c): status and
//! alarm codes, messages, numbers in the firmware's fixed-point format, and the `?`
//! status report with the refresh counters of its `WCO` and `Ov` fields.

/// Number of axes the firmware drives (X, Y, Z).
pub(crate) const N_AXIS: usize = 3;

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
    pub const GCODE_AXIS_COMMAND_CONFLICT: u8 = 24;
    pub const GCODE_WORD_REPEATED: u8 = 25;
    pub const GCODE_NO_AXIS_WORDS: u8 = 26;
    pub const GCODE_INVALID_LINE_NUMBER: u8 = 27;
    pub const GCODE_VALUE_WORD_MISSING: u8 = 28;
    pub const GCODE_UNSUPPORTED_COORD_SYS: u8 = 29;
    pub const GCODE_UNUSED_WORDS: u8 = 36;
    pub const GCODE_MAX_VALUE_EXCEEDED: u8 = 38;
}

/// GRBL alarm codes (`ALARM:N`).
pub(crate) mod alarm {
    pub const HARD_LIMIT: u8 = 1;
    pub const SOFT_LIMIT: u8 = 2;
    pub const ABORT_CYCLE: u8 = 3;
    pub const HOMING_FAIL_RESET: u8 = 6;
    pub const HOMING_FAIL_PULLOFF: u8 = 8;
    pub const HOMING_FAIL_APPROACH: u8 = 9;
}

/// The welcome message, with the firmware's leading line break.
pub(crate) const BANNER: &[u8] = b"\r\nGrbl 1.1h ['$' for help]\r\n";

/// `[MSG:…]` feedback lines and the other fixed texts, without line endings.
pub(crate) mod text {
    pub const UNLOCK_HINT: &str = "[MSG:'$H'|'$X' to unlock]";
    pub const UNLOCKED: &str = "[MSG:Caution: Unlocked]";
    pub const RESET_TO_CONTINUE: &str = "[MSG:Reset to continue]";
    pub const RESTORING_DEFAULTS: &str = "[MSG:Restoring defaults]";
    pub const CHECK_LIMITS: &str = "[MSG:Check Limits]";
    pub const HELP: &str =
        "[HLP:$$ $# $G $I $N $x=val $Nx=line $J=line $SLP $C $X $H ~ ! ? ctrl-x]";
    pub const VERSION: &str = "1.1h.20190830";
    /// Stock build options: variable spindle, 15 planner blocks, 128-byte receive ring.
    pub const OPTIONS: &str = "[OPT:V,15,128]";
}

const MM_PER_INCH: f64 = 25.4;

/// A number as the firmware's `printFloat` prints it: a `-` for negative values (so
/// −0.0001 prints `-0.000`, −0.0 prints `0.000`), then |value| rounded half up.
pub(crate) fn fmt_fixed(value: f64, decimals: usize) -> String {
    let value = if value.is_finite() { value } else { 0.0 };
    let sign = if value < 0.0 { "-" } else { "" };
    let scale = 10f64.powi(decimals as i32);
    // The firmware's 32-bit integer conversion saturates the same way.
    let digits = (value.abs() * scale + 0.5).min(u32::MAX as f64) as u64;
    let int = digits / scale as u64;
    if decimals == 0 {
        return format!("{sign}{int}");
    }
    let frac = digits % scale as u64;
    format!("{sign}{int}.{frac:0decimals$}")
}

/// An axis triple as positions are printed: mm (here degrees) with 3 decimals, or
/// inches with 4 when `$13=1`.
pub(crate) fn axes(values: [f64; N_AXIS], inches: bool) -> String {
    let (scale, decimals) = if inches {
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

/// A rate (units/min) as printed: no decimals, or inches/min with one when `$13=1`.
pub(crate) fn rate(units_per_min: f64, inches: bool) -> String {
    if inches {
        fmt_fixed(units_per_min / MM_PER_INCH, 1)
    } else {
        fmt_fixed(units_per_min, 0)
    }
}

/// The machine state a status report names.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum ReportState {
    Idle,
    Run,
    /// `Hold:0` once the hold is complete, `Hold:1` while decelerating.
    Hold {
        complete: bool,
    },
    Jog,
    Home,
    Alarm,
}

impl ReportState {
    fn word(self) -> &'static str {
        match self {
            ReportState::Idle => "Idle",
            ReportState::Run => "Run",
            ReportState::Hold { complete: true } => "Hold:0",
            ReportState::Hold { complete: false } => "Hold:1",
            ReportState::Jog => "Jog",
            ReportState::Home => "Home",
            ReportState::Alarm => "Alarm",
        }
    }

    /// The states the refresh counters count as busy (slow refresh).
    fn busy(self) -> bool {
        matches!(
            self,
            ReportState::Run | ReportState::Hold { .. } | ReportState::Jog | ReportState::Home
        )
    }
}

/// What one status report shows, in machine units.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct StatusSnapshot {
    pub state: ReportState,
    pub mpos: [f64; N_AXIS],
    /// Work coordinate offset: G54 (or the active system) plus G92.
    pub wco: [f64; N_AXIS],
    /// `$10` bit 0: report MPos (else WPos = MPos − WCO).
    pub report_mpos: bool,
    /// `$10` bit 1: free planner blocks and free receive-ring bytes.
    pub buffer: Option<(usize, usize)>,
    /// Current feed, units/min.
    pub feed: f64,
    pub spindle_rpm: f64,
    /// `$13`: report in inches.
    pub inches: bool,
    /// Limit switches pressed, per axis.
    pub limit_pins: [bool; N_AXIS],
    /// The accessory field: `S`/`C` spindle, `F` flood; empty when all are off.
    pub accessories: String,
}

/// The firmware's refresh counters of the `WCO` and `Ov` fields (reset with the rest of
/// the system state at boot and at every reset), and whether the build prints the
/// optional fields at all.
#[derive(Debug, Clone, Copy)]
pub(crate) struct ReportCounters {
    /// The stock build prints `Pn`, `WCO` and `Ov`/`A` (REPORT_FIELD_* in config.h).
    extras: bool,
    wco: u8,
    ovr: u8,
}

/// Reports between `WCO` fields while busy / idle (REPORT_WCO_REFRESH_*_COUNT).
const WCO_REFRESH_BUSY: u8 = 30;
const WCO_REFRESH_IDLE: u8 = 10;
/// Reports between `Ov` fields while busy / idle (REPORT_OVR_REFRESH_*_COUNT).
const OVR_REFRESH_BUSY: u8 = 20;
const OVR_REFRESH_IDLE: u8 = 10;

impl ReportCounters {
    pub fn new(extras: bool) -> Self {
        ReportCounters {
            extras,
            wco: 0,
            ovr: 0,
        }
    }

    /// Boot or reset: both fields are due on the next reports.
    pub fn reset(&mut self) {
        self.wco = 0;
        self.ovr = 0;
    }

    /// A work offset or `$13` changed: `WCO` on the next report.
    pub fn wco_changed(&mut self) {
        self.wco = 0;
    }

    /// The spindle or coolant changed: `Ov` (and `A`) on the next report.
    pub fn accessories_changed(&mut self) {
        self.ovr = 0;
    }

    /// The `?` report line (without line ending), advancing the counters.
    pub fn status_report(&mut self, s: &StatusSnapshot) -> String {
        let mut position = s.mpos;
        if !s.report_mpos {
            for (p, w) in position.iter_mut().zip(s.wco) {
                *p -= w;
            }
        }
        let label = if s.report_mpos { "MPos" } else { "WPos" };
        let mut report = format!("<{}|{label}:{}", s.state.word(), axes(position, s.inches));
        if let Some((blocks, bytes)) = s.buffer {
            report.push_str(&format!("|Bf:{blocks},{bytes}"));
        }
        report.push_str(&format!(
            "|FS:{},{}",
            rate(s.feed, s.inches),
            fmt_fixed(s.spindle_rpm, 0)
        ));
        if self.extras {
            self.push_extras(&mut report, s);
        }
        report.push('>');
        report
    }

    fn push_extras(&mut self, report: &mut String, s: &StatusSnapshot) {
        if s.limit_pins.iter().any(|&p| p) {
            report.push_str("|Pn:");
            for (pressed, letter) in s.limit_pins.iter().zip(['X', 'Y', 'Z']) {
                if *pressed {
                    report.push(letter);
                }
            }
        }
        let busy = s.state.busy();
        if self.wco > 0 {
            self.wco -= 1;
        } else {
            self.wco = if busy {
                WCO_REFRESH_BUSY
            } else {
                WCO_REFRESH_IDLE
            } - 1;
            if self.ovr == 0 {
                // The overrides follow on the next report.
                self.ovr = 1;
            }
            report.push_str(&format!("|WCO:{}", axes(s.wco, s.inches)));
        }
        if self.ovr > 0 {
            self.ovr -= 1;
        } else {
            self.ovr = if busy {
                OVR_REFRESH_BUSY
            } else {
                OVR_REFRESH_IDLE
            } - 1;
            report.push_str("|Ov:100,100,100");
            if !s.accessories.is_empty() {
                report.push_str(&format!("|A:{}", s.accessories));
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numbers_print_like_print_float() {
        assert_eq!(fmt_fixed(-0.0, 3), "0.000");
        assert_eq!(fmt_fixed(-0.0001, 3), "-0.000");
        assert_eq!(fmt_fixed(1.0005, 3), "1.001");
        assert_eq!(fmt_fixed(-12.5, 0), "-13");
        assert_eq!(fmt_fixed(250.0, 3), "250.000");
        assert_eq!(fmt_fixed(f64::NAN, 3), "0.000");
        assert_eq!(rate(254.0, true), "10.0");
        assert_eq!(axes([25.4, 0.0, -2.54], true), "1.0000,0.0000,-0.1000");
    }

    fn snapshot(state: ReportState) -> StatusSnapshot {
        StatusSnapshot {
            state,
            mpos: [-1.0, 0.0, 0.0],
            wco: [12.0, 0.0, 0.0],
            report_mpos: true,
            buffer: None,
            feed: 0.0,
            spindle_rpm: 0.0,
            inches: false,
            limit_pins: [false; N_AXIS],
            accessories: String::new(),
        }
    }

    #[test]
    fn wco_then_ov_on_the_refresh_counters() {
        let mut counters = ReportCounters::new(true);
        let idle = snapshot(ReportState::Idle);
        let lines: Vec<String> = (0..12).map(|_| counters.status_report(&idle)).collect();
        let plain = "<Idle|MPos:-1.000,0.000,0.000|FS:0,0";
        assert_eq!(lines[0], format!("{plain}|WCO:12.000,0.000,0.000>"));
        assert_eq!(lines[1], format!("{plain}|Ov:100,100,100>"));
        for line in &lines[2..10] {
            assert_eq!(line, &format!("{plain}>"));
        }
        assert_eq!(lines[10], format!("{plain}|WCO:12.000,0.000,0.000>"));
        assert_eq!(lines[11], format!("{plain}|Ov:100,100,100>"));
        // Busy: WCO every 30th report, Ov every 20th.
        let mut run = snapshot(ReportState::Run);
        run.report_mpos = false;
        run.limit_pins = [true, false, true];
        counters.reset();
        let first = counters.status_report(&run);
        assert_eq!(
            first,
            "<Run|WPos:-13.000,0.000,0.000|FS:0,0|Pn:XZ|WCO:12.000,0.000,0.000>"
        );
        let marks: Vec<(bool, bool)> = (1..61)
            .map(|_| {
                let line = counters.status_report(&run);
                (line.contains("WCO"), line.contains("Ov"))
            })
            .collect();
        let wco: Vec<usize> = (0..60).filter(|&i| marks[i].0).map(|i| i + 1).collect();
        let ov: Vec<usize> = (0..60).filter(|&i| marks[i].1).map(|i| i + 1).collect();
        assert_eq!(wco, [30, 60]);
        assert_eq!(ov, [1, 21, 41]);
        // A build without the optional fields.
        let mut bare = ReportCounters::new(false);
        assert_eq!(
            bare.status_report(&run),
            "<Run|WPos:-13.000,0.000,0.000|FS:0,0>"
        );
    }
}
