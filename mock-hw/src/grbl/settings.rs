//! GRBL's `$` settings: storage with the firmware's range checks and error codes, and the
//! `$$` listing in GRBL 1.1h's exact format.

use super::config::GrblConfig;
use super::report::{fmt_fixed, status, N_AXIS};

/// Per-axis settings `$100+i`, `$110+i`, `$120+i`, `$130+i`. Units are the machine unit
/// (degrees for the arm axis): steps/unit, units/min, units/s², units.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct AxisSettings {
    pub steps_per_unit: f64,
    pub max_rate: f64,
    pub accel: f64,
    pub max_travel: f64,
}

impl AxisSettings {
    /// GRBL's compiled-in defaults (`defaults.h`), used for the axes without hardware.
    const GRBL_DEFAULT: AxisSettings = AxisSettings {
        steps_per_unit: 250.0,
        max_rate: 500.0,
        accel: 10.0,
        max_travel: 200.0,
    };
}

/// The EEPROM settings of the emulated controller.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Settings {
    pub pulse_us: u8,
    pub idle_delay_ms: u8,
    pub step_invert_mask: u8,
    pub dir_invert_mask: u8,
    pub step_enable_invert: bool,
    pub limit_pins_invert: bool,
    pub probe_pin_invert: bool,
    /// `$10`: bit 0 = report MPos (else WPos), bit 1 = report buffer state.
    pub status_report_mask: u8,
    pub junction_deviation: f64,
    pub arc_tolerance: f64,
    pub report_inches: bool,
    pub soft_limits: bool,
    pub hard_limits: bool,
    pub homing: bool,
    pub homing_dir_mask: u8,
    /// `$24` locate feed and `$25` seek rate, units/min.
    pub homing_feed: f64,
    pub homing_seek: f64,
    /// `$26`, ms.
    pub homing_debounce_ms: u8,
    /// `$27` pull-off distance after homing, units.
    pub homing_pulloff: f64,
    pub rpm_max: f64,
    pub rpm_min: f64,
    pub laser_mode: bool,
    pub axes: [AxisSettings; N_AXIS],
}

impl Settings {
    /// Factory settings of the emulated controller: GRBL's defaults, with the arm's
    /// axis and the other settings `config` names.
    pub fn from_config(config: &GrblConfig) -> Self {
        let mut axes = [AxisSettings::GRBL_DEFAULT; N_AXIS];
        axes[config.arm_axis.index()] = AxisSettings {
            steps_per_unit: config.steps_per_deg,
            max_rate: config.max_rate_deg_per_min,
            accel: config.accel_deg_per_s2,
            max_travel: config.max_travel_deg,
        };
        Settings {
            pulse_us: 10,
            idle_delay_ms: 25,
            step_invert_mask: 0,
            dir_invert_mask: 0,
            step_enable_invert: false,
            limit_pins_invert: false,
            probe_pin_invert: false,
            status_report_mask: config.status_report_mask,
            junction_deviation: 0.010,
            arc_tolerance: 0.002,
            report_inches: false,
            soft_limits: config.soft_limits && config.homing_enabled,
            hard_limits: config.hard_limits,
            homing: config.homing_enabled,
            homing_dir_mask: 0,
            homing_feed: config.homing_feed_deg_per_min,
            homing_seek: config.homing_seek_deg_per_min,
            homing_debounce_ms: config.homing_debounce_ms,
            homing_pulloff: config.homing_pulloff_deg,
            rpm_max: 1000.0,
            rpm_min: 0.0,
            laser_mode: false,
            axes,
        }
    }

    /// `$N=value`: store one setting, with GRBL's checks. Errors are GRBL status codes.
    pub fn store(&mut self, parameter: u8, value: f64) -> Result<(), u8> {
        if value < 0.0 {
            return Err(status::NEGATIVE_VALUE);
        }
        if parameter >= 100 {
            let offset = usize::from(parameter - 100);
            let (group, axis) = (offset / 10, offset % 10);
            if axis >= N_AXIS || group >= 4 {
                return Err(status::INVALID_STATEMENT);
            }
            let settings = &mut self.axes[axis];
            match group {
                0 => settings.steps_per_unit = value,
                1 => settings.max_rate = value,
                2 => settings.accel = value,
                _ => settings.max_travel = value,
            }
            return Ok(());
        }
        // The firmware converts to an unsigned byte for the integer settings.
        let int_value = (value.trunc() as u64 % 256) as u8;
        match parameter {
            0 => {
                if int_value < 3 {
                    return Err(status::SETTING_STEP_PULSE_MIN);
                }
                self.pulse_us = int_value;
            }
            1 => self.idle_delay_ms = int_value,
            2 => self.step_invert_mask = int_value,
            3 => self.dir_invert_mask = int_value,
            4 => self.step_enable_invert = int_value != 0,
            5 => self.limit_pins_invert = int_value != 0,
            6 => self.probe_pin_invert = int_value != 0,
            10 => self.status_report_mask = int_value,
            11 => self.junction_deviation = value,
            12 => self.arc_tolerance = value,
            13 => self.report_inches = int_value != 0,
            20 => {
                if int_value != 0 && !self.homing {
                    return Err(status::SOFT_LIMIT_ERROR);
                }
                self.soft_limits = int_value != 0;
            }
            21 => self.hard_limits = int_value != 0,
            22 => {
                self.homing = int_value != 0;
                if !self.homing {
                    // The firmware forces soft limits off with homing.
                    self.soft_limits = false;
                }
            }
            23 => self.homing_dir_mask = int_value,
            24 => self.homing_feed = value,
            25 => self.homing_seek = value,
            26 => self.homing_debounce_ms = int_value,
            27 => self.homing_pulloff = value,
            30 => self.rpm_max = value,
            31 => self.rpm_min = value,
            32 => self.laser_mode = int_value != 0,
            _ => return Err(status::INVALID_STATEMENT),
        }
        Ok(())
    }

    /// The `$$` listing, one `$N=value` line each (without line endings).
    pub fn report_lines(&self) -> Vec<String> {
        let int = |n: u8, v: u8| format!("${n}={v}");
        let flag = |n: u8, v: bool| format!("${n}={}", u8::from(v));
        let float = |n: u8, v: f64| format!("${n}={}", fmt_fixed(v, 3));
        let rpm = |n: u8, v: f64| format!("${n}={}", fmt_fixed(v, 0));
        let mut lines = vec![
            int(0, self.pulse_us),
            int(1, self.idle_delay_ms),
            int(2, self.step_invert_mask),
            int(3, self.dir_invert_mask),
            flag(4, self.step_enable_invert),
            flag(5, self.limit_pins_invert),
            flag(6, self.probe_pin_invert),
            int(10, self.status_report_mask),
            float(11, self.junction_deviation),
            float(12, self.arc_tolerance),
            flag(13, self.report_inches),
            flag(20, self.soft_limits),
            flag(21, self.hard_limits),
            flag(22, self.homing),
            int(23, self.homing_dir_mask),
            float(24, self.homing_feed),
            float(25, self.homing_seek),
            int(26, self.homing_debounce_ms),
            float(27, self.homing_pulloff),
            rpm(30, self.rpm_max),
            rpm(31, self.rpm_min),
            flag(32, self.laser_mode),
        ];
        let groups: [fn(&AxisSettings) -> f64; 4] = [
            |a| a.steps_per_unit,
            |a| a.max_rate,
            |a| a.accel,
            |a| a.max_travel,
        ];
        for (group, value_of) in groups.iter().enumerate() {
            for (axis, settings) in self.axes.iter().enumerate() {
                let n = 100 + 10 * group as u8 + axis as u8;
                lines.push(float(n, value_of(settings)));
            }
        }
        lines
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn store_checks_like_the_firmware() {
        let mut settings = Settings::from_config(&GrblConfig::default());
        assert_eq!(settings.store(0, 2.0), Err(status::SETTING_STEP_PULSE_MIN));
        assert_eq!(settings.store(110, -1.0), Err(status::NEGATIVE_VALUE));
        assert_eq!(settings.store(103, 1.0), Err(status::INVALID_STATEMENT));
        assert_eq!(settings.store(140, 1.0), Err(status::INVALID_STATEMENT));
        assert_eq!(settings.store(7, 1.0), Err(status::INVALID_STATEMENT));
        assert_eq!(settings.store(22, 0.0), Ok(()));
        assert!(!settings.soft_limits);
        assert_eq!(settings.store(20, 1.0), Err(status::SOFT_LIMIT_ERROR));
        assert_eq!(settings.store(130, 90.0), Ok(()));
        assert_eq!(settings.axes[0].max_travel, 90.0);
        assert!(settings.report_lines().contains(&"$130=90.000".to_string()));
    }
}
