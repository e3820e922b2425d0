//! The settings the configuration expects of the controller: the comparison with its
//! `$$` listing (one line per difference) and the `$N=value` lines that apply them.

use std::fmt;

use super::config::{GrblArmConfig, Homing};
use super::protocol::Settings;

/// What a setting must be.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Want {
    Exactly(f64),
    Positive,
}

/// A setting that differs from what the configuration expects.
#[derive(Debug, Clone, PartialEq)]
pub struct Mismatch {
    pub key: u32,
    pub what: String,
    /// The controller's value; `None` when `$$` did not list it.
    pub found: Option<f64>,
    pub want: Want,
}

impl Mismatch {
    /// The `$N=value` line that sets what the configuration expects, if it can.
    pub fn fix(&self) -> Option<String> {
        match self.want {
            Want::Exactly(value) => Some(format!("${}={}", self.key, format_value(value))),
            Want::Positive => None,
        }
    }
}

impl fmt::Display for Mismatch {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "${} ({}) ", self.key, self.what)?;
        match (self.found, self.want) {
            (None, _) => write!(f, "is not reported by the controller"),
            (Some(found), Want::Exactly(value)) => write!(
                f,
                "is {}, configuration expects {}",
                format_value(found),
                format_value(value)
            ),
            (Some(found), Want::Positive) => {
                write!(f, "is {}, must be positive", format_value(found))
            }
        }
    }
}

/// A value as `$$` would accept it back: integers without decimals, others with up to
/// three (the firmware stores floats).
fn format_value(value: f64) -> String {
    if value.fract() == 0.0 && value.abs() < 1e9 {
        format!("{value:.0}")
    } else {
        let text = format!("{value:.3}");
        text.trim_end_matches('0').trim_end_matches('.').to_owned()
    }
}

/// Every setting the configuration has an expectation about.
fn expectations(config: &GrblArmConfig) -> Vec<(u32, String, Want)> {
    let i = config.axis.index() as u32;
    let axis = config.axis.letter();
    let or_positive = |value: Option<f64>| value.map_or(Want::Positive, Want::Exactly);
    let mut list = vec![(
        Settings::REPORT_INCHES,
        "report in inches".to_owned(),
        Want::Exactly(0.0),
    )];
    let homing = match config.homing {
        Homing::Required => Some(1.0),
        Homing::Off => Some(0.0),
        Homing::Optional => None,
    };
    if let Some(value) = homing {
        list.push((
            Settings::HOMING_ENABLE,
            "homing cycle enable".to_owned(),
            Want::Exactly(value),
        ));
    }
    list.extend([
        (
            Settings::STEPS_PER_UNIT + i,
            format!("{axis} steps per degree"),
            Want::Exactly(config.steps_per_deg),
        ),
        (
            Settings::MAX_RATE + i,
            format!("{axis} max rate, degrees/min"),
            or_positive(config.max_rate_deg_per_min),
        ),
        (
            Settings::ACCEL + i,
            format!("{axis} acceleration, degrees/s²"),
            or_positive(config.accel_deg_per_s2),
        ),
        (
            Settings::MAX_TRAVEL + i,
            format!("{axis} max travel, degrees"),
            Want::Exactly(config.max_travel_deg),
        ),
    ]);
    list
}

/// The controller's settings that differ from the configuration, in `$N` order.
pub fn mismatches(settings: &Settings, config: &GrblArmConfig) -> Vec<Mismatch> {
    expectations(config)
        .into_iter()
        .filter_map(|(key, what, want)| {
            let found = settings.get(key);
            let ok = match (found, want) {
                (Some(v), Want::Exactly(w)) => (v - w).abs() <= 1e-3 * w.abs().max(1.0),
                (Some(v), Want::Positive) => v > 0.0,
                (None, _) => false,
            };
            (!ok).then_some(Mismatch {
                key,
                what,
                found,
                want,
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grbl::protocol::{parse_line, Line};

    fn stock() -> Settings {
        let lines: Vec<Line> = [
            "$10=1",
            "$13=0",
            "$22=0",
            "$27=1.000",
            "$100=250.000",
            "$101=250.000",
            "$110=500.000",
            "$120=10.000",
            "$130=200.000",
        ]
        .iter()
        .map(|l| parse_line(l))
        .collect();
        Settings::from_lines(&lines)
    }

    #[test]
    fn one_line_per_difference_and_the_lines_that_fix_them() {
        let config = GrblArmConfig {
            accel_deg_per_s2: Some(40.0),
            ..GrblArmConfig::default()
        };
        let found = mismatches(&stock(), &config);
        let lines: Vec<String> = found.iter().map(ToString::to_string).collect();
        assert_eq!(
            lines,
            [
                "$22 (homing cycle enable) is 0, configuration expects 1",
                "$100 (X steps per degree) is 250, configuration expects 80",
                "$120 (X acceleration, degrees/s²) is 10, configuration expects 40",
                "$130 (X max travel, degrees) is 200, configuration expects 180",
            ]
        );
        let fixes: Vec<String> = found.iter().filter_map(Mismatch::fix).collect();
        assert_eq!(fixes, ["$22=1", "$100=80", "$120=40", "$130=180"]);
        // Homing off and the stock board's numbers: nothing to say.
        let config = GrblArmConfig {
            homing: Homing::Off,
            steps_per_deg: 250.0,
            max_travel_deg: 200.0,
            max_rate_deg_per_min: Some(500.0),
            ..GrblArmConfig::default()
        };
        assert!(mismatches(&stock(), &config).is_empty());
        // The arm on Y; a rate that must only be positive; a missing setting.
        let config = GrblArmConfig {
            axis: crate::grbl::config::ArmAxis::Y,
            steps_per_deg: 250.0,
            max_travel_deg: 200.0,
            homing: Homing::Optional,
            ..GrblArmConfig::default()
        };
        let lines: Vec<String> = mismatches(&stock(), &config)
            .iter()
            .map(ToString::to_string)
            .collect();
        assert_eq!(
            lines,
            [
                "$111 (Y max rate, degrees/min) is not reported by the controller",
                "$121 (Y acceleration, degrees/s²) is not reported by the controller",
                "$131 (Y max travel, degrees) is not reported by the controller",
            ]
        );
        assert_eq!(format_value(0.125), "0.125");
        assert_eq!(format_value(1.5), "1.5");
    }
}
