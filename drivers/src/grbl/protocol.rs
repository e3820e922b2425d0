//! GRBL 1.1 line protocol: classifying received lines, status reports, `$$` settings,
//! and the motion time of a trapezoidal move.

use std::collections::BTreeMap;

/// Machine state word of a status report (`<Idle|...>`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MachineState {
    Idle,
    Run,
    Jog,
    Home,
    Hold,
    Door,
    Alarm,
    Check,
    Sleep,
}

/// A parsed `?` status report. Positions are machine units (degrees on the arm's axis).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StatusReport {
    pub state: MachineState,
    /// The number after the state word (`Hold:0` = hold complete, `Hold:1` = holding).
    pub substate: Option<u8>,
    /// Machine position, if reported (`MPos`, `$10` bit 0 set).
    pub mpos: Option<[f64; 3]>,
    /// Work position, if reported (`WPos`).
    pub wpos: Option<[f64; 3]>,
    /// Work coordinate offset, on the reports that carry it (`WCO`).
    pub wco: Option<[f64; 3]>,
    /// Current feed rate (`FS` or `F`), units/min.
    pub feed: Option<f64>,
    /// Limit switches pressed (`Pn:` letters X, Y, Z).
    pub limit_pins: [bool; 3],
}

impl StatusReport {
    /// Machine position of axis `i`: `MPos`, else `WPos + wco` (the report's own WCO,
    /// else the `known_wco` from an earlier report).
    pub fn machine(&self, i: usize, known_wco: Option<[f64; 3]>) -> Option<f64> {
        let wco = self.wco.or(known_wco);
        self.mpos
            .map(|m| m[i])
            .or_else(|| Some(self.wpos?[i] + wco?[i]))
    }

    /// Work position of axis `i`: `WPos`, else `MPos − wco`.
    pub fn work(&self, i: usize, known_wco: Option<[f64; 3]>) -> Option<f64> {
        let wco = self.wco.or(known_wco);
        self.wpos
            .map(|w| w[i])
            .or_else(|| Some(self.mpos?[i] - wco?[i]))
    }

    /// Whether the machine is at rest (idle, alarm, or a completed hold).
    pub fn at_rest(&self) -> bool {
        match self.state {
            MachineState::Idle
            | MachineState::Alarm
            | MachineState::Check
            | MachineState::Sleep => true,
            MachineState::Hold => self.substate == Some(0),
            _ => false,
        }
    }
}

/// One line received from the controller.
#[derive(Debug, Clone, PartialEq)]
pub enum Line {
    Ok,
    Error(u32),
    Alarm(u32),
    /// The start-up banner (`Grbl 1.1h ['$' for help]`): the controller has reset.
    Banner(String),
    Status(StatusReport),
    /// A `[...]` feedback message (`[VER:...]`, `[MSG:...]`, ...), brackets removed.
    Feedback(String),
    /// A `$N=value` setting line.
    Setting(u32, f64),
    /// Anything else: noise, a truncated or garbled reply.
    Garbled(String),
}

/// Classify one line (without its line terminator).
pub fn parse_line(line: &str) -> Line {
    let line = line.trim();
    if line == "ok" {
        return Line::Ok;
    }
    if let Some(code) = line.strip_prefix("error:") {
        return code
            .parse()
            .map_or_else(|_| Line::Garbled(line.to_owned()), Line::Error);
    }
    if let Some(code) = line.strip_prefix("ALARM:") {
        return code
            .parse()
            .map_or_else(|_| Line::Garbled(line.to_owned()), Line::Alarm);
    }
    if (line.starts_with("Grbl ") || line.starts_with("GrblHAL ")) && line.contains("for help") {
        return Line::Banner(line.to_owned());
    }
    if let Some(body) = line.strip_prefix('<').and_then(|l| l.strip_suffix('>')) {
        return parse_status(body).map_or_else(|| Line::Garbled(line.to_owned()), Line::Status);
    }
    if let Some(body) = line.strip_prefix('[').and_then(|l| l.strip_suffix(']')) {
        return Line::Feedback(body.to_owned());
    }
    if let Some((key, value)) = line.strip_prefix('$').and_then(|l| l.split_once('=')) {
        if let (Ok(key), Ok(value)) = (key.parse(), value.trim().parse::<f64>()) {
            if value.is_finite() {
                return Line::Setting(key, value);
            }
        }
    }
    Line::Garbled(line.to_owned())
}

/// Parse the inside of `<...>`; `None` when any part is malformed. Fields the driver
/// does not use (`Bf`, `Ov`, `A`, `Ln`, …) are skipped.
fn parse_status(body: &str) -> Option<StatusReport> {
    let mut fields = body.split('|');
    let mut state_word = fields.next()?.split(':');
    let state = match state_word.next()? {
        "Idle" => MachineState::Idle,
        "Run" => MachineState::Run,
        "Jog" => MachineState::Jog,
        "Home" => MachineState::Home,
        "Hold" => MachineState::Hold,
        "Door" => MachineState::Door,
        "Alarm" => MachineState::Alarm,
        "Check" => MachineState::Check,
        "Sleep" => MachineState::Sleep,
        _ => return None,
    };
    let substate = match state_word.next() {
        Some(code) => Some(code.parse().ok()?),
        None => None,
    };
    let mut report = StatusReport {
        state,
        substate,
        mpos: None,
        wpos: None,
        wco: None,
        feed: None,
        limit_pins: [false; 3],
    };
    for field in fields {
        let (name, value) = field.split_once(':')?;
        match name {
            "MPos" => report.mpos = Some(triple(value)?),
            "WPos" => report.wpos = Some(triple(value)?),
            "WCO" => report.wco = Some(triple(value)?),
            "FS" | "F" => {
                let feed = value.split(',').next()?.parse::<f64>().ok()?;
                report.feed = Some(feed).filter(|f| f.is_finite());
                report.feed?;
            }
            "Pn" => {
                for (pin, letter) in report.limit_pins.iter_mut().zip(['X', 'Y', 'Z']) {
                    *pin = value.contains(letter);
                }
            }
            _ => {}
        }
    }
    if report.mpos.is_none() && report.wpos.is_none() {
        return None;
    }
    Some(report)
}

/// An `x,y,z` triple; every component must be a finite number.
fn triple(text: &str) -> Option<[f64; 3]> {
    let values: Vec<f64> = text
        .split(',')
        .map(|v| v.parse::<f64>().ok().filter(|v| v.is_finite()))
        .collect::<Option<_>>()?;
    (values.len() == 3).then(|| [values[0], values[1], values[2]])
}

/// The controller's `$$` settings, by number.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Settings(pub BTreeMap<u32, f64>);

impl Settings {
    pub const STATUS_MASK: u32 = 10;
    pub const REPORT_INCHES: u32 = 13;
    pub const HOMING_ENABLE: u32 = 22;
    pub const HOMING_FEED: u32 = 24;
    pub const HOMING_SEEK: u32 = 25;
    pub const HOMING_DEBOUNCE_MS: u32 = 26;
    pub const HOMING_PULLOFF: u32 = 27;
    /// Per-axis settings: add the axis index (X = 0).
    pub const STEPS_PER_UNIT: u32 = 100;
    pub const MAX_RATE: u32 = 110;
    pub const ACCEL: u32 = 120;
    pub const MAX_TRAVEL: u32 = 130;

    /// Collect the `$N=value` lines of a `$$` reply.
    pub fn from_lines<'a>(lines: impl IntoIterator<Item = &'a Line>) -> Self {
        Settings(
            lines
                .into_iter()
                .filter_map(|line| match line {
                    Line::Setting(key, value) => Some((*key, *value)),
                    _ => None,
                })
                .collect(),
        )
    }

    pub fn get(&self, key: u32) -> Option<f64> {
        self.0.get(&key).copied()
    }
}

/// Time in seconds of a point-to-point move of `distance_deg` with a trapezoidal
/// velocity profile (max rate in degrees/minute, acceleration in degrees/s²).
/// Non-positive rate or acceleration gives `f64::INFINITY`.
pub fn move_time_s(distance_deg: f64, max_rate_deg_per_min: f64, accel_deg_per_s2: f64) -> f64 {
    let distance = distance_deg.abs();
    let v = max_rate_deg_per_min / 60.0;
    if !(v > 0.0 && accel_deg_per_s2 > 0.0) {
        return f64::INFINITY;
    }
    let ramp_distance = v * v / accel_deg_per_s2;
    if distance >= ramp_distance {
        distance / v + v / accel_deg_per_s2
    } else {
        2.0 * (distance / accel_deg_per_s2).sqrt()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn classifies_replies() {
        assert_eq!(parse_line("ok\r"), Line::Ok);
        assert_eq!(parse_line("error:9"), Line::Error(9));
        assert_eq!(parse_line("ALARM:1"), Line::Alarm(1));
        assert!(matches!(
            parse_line("Grbl 1.1h ['$' for help]"),
            Line::Banner(_)
        ));
        assert_eq!(
            parse_line("[VER:1.1h.20190825:]"),
            Line::Feedback("VER:1.1h.20190825:".into())
        );
        assert_eq!(parse_line("$100=250.000"), Line::Setting(100, 250.0));
        assert_eq!(parse_line("$22=1"), Line::Setting(22, 1.0));
    }

    #[test]
    fn garbled_and_truncated_lines_are_not_mistaken() {
        for text in [
            "o",
            "okk",
            "error:",
            "error:x",
            "ALARM:",
            "<Idle|MPos:-20.000,0.0",
            "<Idle|MPos:-20.000,0.000,0.000",
            "<Idle|MPos:-2x.000,0.000,0.000>",
            "<Idle|MPos:NaN,0.000,0.000>",
            "<Walk|MPos:0.000,0.000,0.000>",
            "<Idle|FS:0,0>",
            "<Hold:x|MPos:0.000,0.000,0.000>",
            "<Idle|MPos:0.000,0.000,0.000,0.000>",
            "<Idle|MPos:0.000,0.000,0.000|FS:x,0>",
            "$100=abc",
            "\u{fffd}\u{fffd}k",
            "Grbl",
        ] {
            assert!(
                matches!(parse_line(text), Line::Garbled(_)),
                "{text:?} -> {:?}",
                parse_line(text)
            );
        }
    }

    #[test]
    fn parses_status_reports() {
        let Line::Status(s) =
            parse_line("<Idle|MPos:-20.000,0.000,0.000|FS:0,0|WCO:0.000,0.000,0.000>")
        else {
            panic!("not a status")
        };
        assert_eq!(s.state, MachineState::Idle);
        assert_eq!(s.machine(0, None), Some(-20.0));
        assert_eq!(s.work(0, None), Some(-20.0));

        let Line::Status(s) = parse_line("<Hold:1|WPos:-5.500,0.000,0.000|WCO:-1.000,0.000,0.000>")
        else {
            panic!("not a status")
        };
        assert_eq!((s.state, s.substate), (MachineState::Hold, Some(1)));
        assert!(!s.at_rest());
        assert_eq!(s.machine(0, None), Some(-6.5));

        // The stock build's optional fields: pins, overrides, accessories.
        let Line::Status(s) = parse_line(
            "<Run|MPos:-33.125,0.000,0.000|Bf:15,128|FS:500,0|Pn:XZ|Ov:100,100,100|A:SF>",
        ) else {
            panic!("not a status")
        };
        assert_eq!((s.state, s.feed), (MachineState::Run, Some(500.0)));
        assert_eq!(s.limit_pins, [true, false, true]);
        // Without a WCO of its own, the work position needs one seen earlier.
        assert_eq!(s.work(0, None), None);
        assert_eq!(s.work(0, Some([12.0, 0.0, 0.0])), Some(-45.125));
        let Line::Status(s) = parse_line("<Hold:0|MPos:1.000,2.000,3.000|F:0>") else {
            panic!("not a status")
        };
        assert!(s.at_rest() && s.machine(2, None) == Some(3.0));
    }

    #[test]
    fn collects_settings() {
        let lines: Vec<Line> = ["$22=1", "$100=80.000", "ok", "[MSG:x]", "$130=95.5"]
            .iter()
            .map(|l| parse_line(l))
            .collect();
        let s = Settings::from_lines(&lines);
        assert_eq!(s.get(Settings::HOMING_ENABLE), Some(1.0));
        assert_eq!(s.get(Settings::STEPS_PER_UNIT), Some(80.0));
        assert_eq!(s.get(Settings::MAX_TRAVEL), Some(95.5));
        assert_eq!(s.get(Settings::ACCEL), None);
    }

    #[test]
    fn trapezoid_and_triangle_move_times() {
        // 600 deg/min = 10 deg/s, 10 deg/s²: ramps cover 10 deg in total.
        let long = move_time_s(30.0, 600.0, 10.0);
        assert!((long - (3.0 + 1.0)).abs() < 1e-12);
        // Short move never reaches full speed: t = 2 sqrt(d/a).
        let short = move_time_s(2.5, 600.0, 10.0);
        assert!((short - 1.0).abs() < 1e-12);
        // Continuous at the switch-over distance, symmetric in direction.
        assert!((move_time_s(10.0, 600.0, 10.0) - 2.0).abs() < 1e-12);
        assert_eq!(move_time_s(-30.0, 600.0, 10.0), long);
        assert_eq!(move_time_s(0.0, 600.0, 10.0), 0.0);
        assert!(move_time_s(1.0, 0.0, 10.0).is_infinite());
        assert!(move_time_s(1.0, 600.0, -1.0).is_infinite());
    }
}
