//! Acquisition time of a scan from the hardware timing model: arm travel under the GRBL
//! controller's trapezoidal motion profile, then at each θL one capture per bracket
//! exposure (shutter time plus the camera's download latency).

use crate::camera::CaptureTiming;
use crate::grbl::{move_duration_s, GrblConfig};

/// The arm and camera timing a scan is costed with (real time, seconds).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HardwareTiming {
    pub max_rate_deg_per_min: f64,
    pub accel_deg_per_s2: f64,
    /// Arm angle at the start of a scan (after homing), degrees.
    pub start_deg: f64,
    pub capture: CaptureTiming,
}

impl Default for HardwareTiming {
    /// The emulated arm board's and camera's defaults in real time; the scan starts at
    /// the home position θL = 0.
    fn default() -> Self {
        let grbl = GrblConfig::arm_board();
        HardwareTiming {
            max_rate_deg_per_min: grbl.max_rate_deg_per_min,
            accel_deg_per_s2: grbl.accel_deg_per_s2,
            start_deg: 0.0,
            capture: CaptureTiming {
                time_scale: 1.0,
                ..CaptureTiming::default()
            },
        }
    }
}

/// Seconds spent moving and capturing in one scan.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AcquisitionTime {
    pub travel_s: f64,
    pub capture_s: f64,
}

impl AcquisitionTime {
    pub fn total_s(&self) -> f64 {
        self.travel_s + self.capture_s
    }
}

impl HardwareTiming {
    /// Time to visit `theta_l_deg` in order from the start angle and capture `shutters_s`
    /// at each.
    pub fn scan(&self, theta_l_deg: &[f64], shutters_s: &[f64]) -> AcquisitionTime {
        let mut at = self.start_deg;
        let mut travel_s = 0.0;
        for &target in theta_l_deg {
            travel_s += move_duration_s(
                target - at,
                self.max_rate_deg_per_min,
                self.accel_deg_per_s2,
            );
            at = target;
        }
        let per_position: f64 = shutters_s
            .iter()
            .map(|&t| self.capture.capture_duration_s(t))
            .sum();
        AcquisitionTime {
            travel_s,
            capture_s: per_position * theta_l_deg.len() as f64,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scan_time_adds_moves_and_captures() {
        let timing = HardwareTiming::default();
        let rate = timing.max_rate_deg_per_min;
        let accel = timing.accel_deg_per_s2;
        let latency = timing.capture.download_latency_s;
        let t = timing.scan(&[-20.0, -30.0], &[0.5, 0.01]);
        let travel = move_duration_s(20.0, rate, accel) + move_duration_s(10.0, rate, accel);
        assert!((t.travel_s - travel).abs() < 1e-12);
        assert!((t.capture_s - 2.0 * (0.51 + 2.0 * latency)).abs() < 1e-12);
        // More directions and longer brackets cost more.
        let more = timing.scan(&[-20.0, -30.0, -40.0], &[0.5, 0.01]);
        assert!(more.total_s() > t.total_s());
        assert!(
            timing.scan(&[-20.0], &[0.5, 0.1]).total_s() > timing.scan(&[-20.0], &[0.5]).total_s()
        );
    }
}
