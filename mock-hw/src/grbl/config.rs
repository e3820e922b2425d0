//! The emulated board: its factory settings (GRBL 1.1h's stock `defaults.h` unless set),
//! its compile-time homing cycles, the world around it, its speed and its faults.
//! Deserialises from TOML (the file of `gonio emulate-arm --config FILE`); every key
//! has a default.

use serde::Deserialize;

use super::faults::Fault;

/// One of the firmware's three axes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
pub enum Axis {
    X,
    Y,
    Z,
}

impl Axis {
    /// Index in the firmware's axis arrays (X = 0).
    pub fn index(self) -> usize {
        match self {
            Axis::X => 0,
            Axis::Y => 1,
            Axis::Z => 2,
        }
    }
}

/// The axes homed together in one homing cycle, as a string of letters (`"XY"`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(try_from = "String")]
pub struct AxisSet {
    /// Bit `i` set: axis `i` takes part.
    pub mask: u8,
}

impl TryFrom<String> for AxisSet {
    type Error = String;

    fn try_from(letters: String) -> Result<Self, String> {
        let mut mask = 0u8;
        for c in letters.chars() {
            let bit = match c.to_ascii_uppercase() {
                'X' => 1,
                'Y' => 2,
                'Z' => 4,
                _ => return Err(format!("homing cycle {letters:?}: {c:?} is not an axis")),
            };
            mask |= bit;
        }
        if mask == 0 {
            return Err("a homing cycle needs at least one axis".into());
        }
        Ok(AxisSet { mask })
    }
}

/// A fault injected `at_s` real seconds after the emulator started.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScheduledFault {
    pub at_s: f64,
    pub fault: Fault,
}

/// Emulator settings. Lengths on the arm's axis are degrees (GRBL's "mm").
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GrblConfig {
    /// Real seconds per machine second (the inverse of grbl-sim's speed factor):
    /// 1.0 = real time, 0.01 = 100× faster, 5.0 = a controller 5× slower.
    pub time_scale: f64,
    /// Machine seconds from power-up or reset (DTR) to the banner.
    pub boot_delay_s: f64,
    /// The axis the arm turns; the other two carry nothing.
    pub arm_axis: Axis,
    /// `$100` (of the arm's axis), steps per degree.
    pub steps_per_deg: f64,
    /// `$110`, degrees per minute.
    pub max_rate_deg_per_min: f64,
    /// `$120`, degrees per second².
    pub accel_deg_per_s2: f64,
    /// `$130`, degrees: soft limits allow [−max_travel, 0].
    pub max_travel_deg: f64,
    /// `$10`: bit 0 reports MPos (else WPos), bit 1 the buffer state.
    pub status_report_mask: u8,
    /// `$20` (refused by the firmware without homing).
    pub soft_limits: bool,
    /// `$21`: any limit switch change outside a homing cycle raises ALARM:1.
    pub hard_limits: bool,
    /// `$22`: homing cycle enabled; the board then powers up locked in Alarm.
    pub homing_enabled: bool,
    /// `$24`, homing locate feed rate, units per minute.
    pub homing_feed_deg_per_min: f64,
    /// `$25`, homing seek rate, units per minute.
    pub homing_seek_deg_per_min: f64,
    /// `$26`, homing switch debounce delay, ms.
    pub homing_debounce_ms: u8,
    /// `$27`, pull-off after homing, units: each homed axis ends at MPos −pull-off.
    pub homing_pulloff_deg: f64,
    /// The homing cycles in order, a compile-time option of the firmware; stock:
    /// Z first, then X and Y together.
    pub homing_cycles: Vec<AxisSet>,
    /// Where the homing switches of the two axes without load sit, in units above
    /// where those axes power up; `None`: no switches wired there (a cycle homing
    /// them fails with ALARM:9). The arm's switch is at θ = 0, the positive end.
    pub idle_axis_switch: Option<f64>,
    /// Status reports carry the stock build's optional fields: `Pn` while a switch is
    /// pressed, `WCO` and `Ov`/`A` on their refresh counters. False emulates a build
    /// compiled without them.
    pub status_extras: bool,
    /// Faults injected on a schedule.
    pub faults: Vec<ScheduledFault>,
}

impl Default for GrblConfig {
    /// A stock GRBL 1.1h board (settings of `defaults.h`, DEFAULTS_GENERIC) in real time.
    fn default() -> Self {
        GrblConfig {
            time_scale: 1.0,
            boot_delay_s: 0.5,
            arm_axis: Axis::X,
            steps_per_deg: 250.0,
            max_rate_deg_per_min: 500.0,
            accel_deg_per_s2: 10.0,
            max_travel_deg: 200.0,
            status_report_mask: 1,
            soft_limits: false,
            hard_limits: false,
            homing_enabled: false,
            homing_feed_deg_per_min: 25.0,
            homing_seek_deg_per_min: 500.0,
            homing_debounce_ms: 250,
            homing_pulloff_deg: 1.0,
            homing_cycles: vec![AxisSet { mask: 4 }, AxisSet { mask: 3 }],
            idle_axis_switch: Some(2.0),
            status_extras: true,
            faults: Vec::new(),
        }
    }
}

/// Why a configuration text was refused.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// The text is no TOML of a configuration (position and reason, on one line).
    #[error("{0}")]
    Toml(String),
    #[error("{0}")]
    Problems(String),
}

impl GrblConfig {
    /// Parse a TOML configuration and check it.
    pub fn from_toml_str(text: &str) -> Result<GrblConfig, ConfigError> {
        let config: GrblConfig = toml::from_str(text)
            .map_err(|e| ConfigError::Toml(crate::toml_error::one_line(text, &e)))?;
        let problems = config.problems();
        if problems.is_empty() {
            Ok(config)
        } else {
            Err(ConfigError::Problems(problems.join("; ")))
        }
    }

    /// A board set up for gonio's arm: 80 steps/°, 1200 °/min, 40 °/s², 180° of travel,
    /// homing enabled with the soft limits, X homed alone (built with
    /// `HOMING_CYCLE_0 (1<<X_AXIS)`), seek 600 °/min, locate 100 °/min, the stock
    /// pull-off and debounce, in real time.
    pub fn arm_board() -> Self {
        GrblConfig {
            steps_per_deg: 80.0,
            max_rate_deg_per_min: 1200.0,
            accel_deg_per_s2: 40.0,
            max_travel_deg: 180.0,
            homing_enabled: true,
            soft_limits: true,
            homing_seek_deg_per_min: 600.0,
            homing_feed_deg_per_min: 100.0,
            homing_cycles: vec![AxisSet { mask: 1 }],
            ..GrblConfig::default()
        }
    }

    /// Reasons this configuration cannot run, one line each; empty when it can.
    pub fn problems(&self) -> Vec<String> {
        let mut problems = Vec::new();
        let positive = [
            ("time_scale", self.time_scale),
            ("steps_per_deg", self.steps_per_deg),
            ("max_rate_deg_per_min", self.max_rate_deg_per_min),
            ("accel_deg_per_s2", self.accel_deg_per_s2),
            ("max_travel_deg", self.max_travel_deg),
            ("homing_feed_deg_per_min", self.homing_feed_deg_per_min),
            ("homing_seek_deg_per_min", self.homing_seek_deg_per_min),
        ];
        for (name, value) in positive {
            if !(value.is_finite() && value > 0.0) {
                problems.push(format!("{name} must be positive, got {value}"));
            }
        }
        let non_negative = [
            ("boot_delay_s", self.boot_delay_s),
            ("homing_pulloff_deg", self.homing_pulloff_deg),
            ("idle_axis_switch", self.idle_axis_switch.unwrap_or(0.0)),
        ];
        for (name, value) in non_negative {
            if !(value.is_finite() && value >= 0.0) {
                problems.push(format!("{name} must be zero or positive, got {value}"));
            }
        }
        if self.soft_limits && !self.homing_enabled {
            problems
                .push("soft_limits need homing_enabled, as in the firmware ($20 needs $22)".into());
        }
        for fault in &self.faults {
            if !(fault.at_s.is_finite() && fault.at_s >= 0.0) {
                problems.push(format!(
                    "fault at_s must be zero or positive, got {}",
                    fault.at_s
                ));
            }
        }
        problems
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn toml_with_cycles_faults_and_unknown_keys() {
        let config: GrblConfig = toml::from_str(
            "time_scale = 0.2\nhoming_cycles = [\"X\"]\nhoming_enabled = true\n\
             [[faults]]\nat_s = 3.0\nfault = \"silent\"\n\
             [[faults]]\nat_s = 4.0\nfault = { alarm_during_motion = 1 }\n",
        )
        .unwrap();
        assert_eq!(config.homing_cycles, [AxisSet { mask: 1 }]);
        assert_eq!(config.faults[1].fault, Fault::AlarmDuringMotion(1));
        assert!(config.problems().is_empty());
        let err = toml::from_str::<GrblConfig>("homing_cycles = [\"XQ\"]\n").unwrap_err();
        assert!(err.to_string().contains("'Q' is not an axis"), "{err}");
        assert!(toml::from_str::<GrblConfig>("steps = 3\n").is_err());
        let bad = GrblConfig {
            time_scale: 0.0,
            soft_limits: true,
            ..GrblConfig::default()
        };
        assert_eq!(bad.problems().len(), 2, "{:?}", bad.problems());
    }
}
