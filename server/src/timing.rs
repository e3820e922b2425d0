//! The timing model a scan's time left is estimated from (docs/ARCHITECTURE.md,
//! "Daemon"): arm moves under the controller's trapezoidal motion profile, captures as
//! shutter time plus download latency, processing steps from fixed priors. Times are
//! wall-clock seconds.

use gonio_mock_hw::camera::CaptureTiming;
use gonio_mock_hw::grbl::{move_duration_s, GrblConfig};

use super::plan::Step;

/// Metering shutter time, seconds (the allowed one at or below it is used).
pub const METER_START_S: f64 = 1.0 / 60.0;
/// The bracket a θL is expected to need before its metering says (seconds).
const EXPECTED_BRACKET_S: [f64; 4] = [0.25, 1.0 / 15.0, 1.0 / 60.0, 1.0 / 250.0];
/// A homing cycle in controller seconds.
const HOMING_S: f64 = 3.0;
/// Processing priors, seconds: one θL's samples and live fits, one full-frame HDR map,
/// gathering the samples, one fit. Replaced by measurement after the first of each.
const SAMPLES_S: f64 = 0.2;
const HDR_S: f64 = 1.0;
const EXTRACT_S: f64 = 0.1;
const FIT_S: f64 = 0.05;

/// What the devices' steps take, before any is measured.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Timing {
    /// The arm's maximum rate, degrees per minute.
    pub arm_rate_deg_per_min: f64,
    /// The arm's acceleration, degrees per second².
    pub arm_accel_deg_per_s2: f64,
    /// Wall seconds per controller second (an emulator's time scale; 1 for a real arm).
    pub arm_time_scale: f64,
    /// The camera's capture timing (its own time scale included).
    pub capture: CaptureTiming,
}

impl Timing {
    /// The emulators' timing, exactly.
    pub fn emulated(grbl: &GrblConfig, capture: CaptureTiming) -> Self {
        Timing {
            arm_rate_deg_per_min: grbl.max_rate_deg_per_min,
            arm_accel_deg_per_s2: grbl.accel_deg_per_s2,
            arm_time_scale: grbl.time_scale,
            capture,
        }
    }

    /// Real devices: the emulated arm board's rates and the emulated camera's timing
    /// in real time, a prior that measurement of the scan's own steps corrects.
    pub fn real() -> Self {
        Self::emulated(
            &GrblConfig::arm_board(),
            CaptureTiming {
                time_scale: 1.0,
                ..CaptureTiming::default()
            },
        )
    }

    /// Expected seconds of one capture at `shutter_s`.
    pub fn capture_s(&self, shutter_s: f64) -> f64 {
        self.capture.capture_duration_s(shutter_s)
    }

    /// Expected seconds of the captures of a bracket the scan has not metered yet.
    pub fn expected_bracket_s(&self) -> f64 {
        EXPECTED_BRACKET_S.iter().map(|&s| self.capture_s(s)).sum()
    }

    /// Expected seconds of `step` with the arm at `from_deg` before it.
    pub fn prior_s(&self, step: &Step, from_deg: f64) -> f64 {
        let travel_s = |to_deg: f64| {
            move_duration_s(
                to_deg - from_deg,
                self.arm_rate_deg_per_min,
                self.arm_accel_deg_per_s2,
            ) * self.arm_time_scale
        };
        match step {
            Step::Home => travel_s(0.0) + HOMING_S * self.arm_time_scale,
            Step::Move { theta_l } => travel_s(*theta_l),
            Step::Meter { .. } => self.capture_s(METER_START_S),
            Step::Capture { shutter_s, .. } => self.capture_s(*shutter_s),
            Step::Samples { .. } => SAMPLES_S,
            Step::Hdr { .. } => HDR_S,
            Step::Extract => EXTRACT_S,
            Step::Fit { .. } => FIT_S,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn priors_follow_the_devices_time_scales() {
        let grbl = GrblConfig {
            time_scale: 0.1,
            ..GrblConfig::arm_board()
        };
        let capture = CaptureTiming {
            time_scale: 0.1,
            ..CaptureTiming::default()
        };
        let fast = Timing::emulated(&grbl, capture);
        let real = Timing::real();
        let move_20 = Step::Move { theta_l: -20.0 };
        let expected = move_duration_s(20.0, 1200.0, 40.0);
        assert!((real.prior_s(&move_20, 0.0) - expected).abs() < 1e-12);
        assert!((fast.prior_s(&move_20, 0.0) - 0.1 * expected).abs() < 1e-12);
        assert_eq!(fast.prior_s(&move_20, -20.0), 0.0);
        let capture = Step::Capture {
            theta_l: -20.0,
            index: 0,
            shutter_s: 0.5,
        };
        assert!((fast.prior_s(&capture, 0.0) - 0.1 * (0.5 + 1.5)).abs() < 1e-12);
        assert!(real.expected_bracket_s() > 4.0 * 1.5);
        assert_eq!(fast.prior_s(&Step::Extract, 0.0), EXTRACT_S);
    }
}
