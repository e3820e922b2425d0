//! What the driver expects of the controller and how patiently it talks to it.

use std::time::Duration;

/// How the arm gets a known position after the controller powers up or resets.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Homing {
    /// `$22=1`: the homing cycle (`$H`) references the arm; declaring is refused.
    Required,
    /// Home when the controller has homing enabled, else accept a declared position.
    Optional,
    /// `$22=0`: the operator declares where the arm is (`G92`) after each power-up or
    /// reset; `$H` is never sent.
    Off,
}

/// The controller axis the arm is on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ArmAxis {
    X,
    Y,
    Z,
}

impl ArmAxis {
    /// Index in GRBL's axis triples (X = 0).
    pub fn index(self) -> usize {
        match self {
            ArmAxis::X => 0,
            ArmAxis::Y => 1,
            ArmAxis::Z => 2,
        }
    }

    /// The G-code letter.
    pub fn letter(self) -> char {
        match self {
            ArmAxis::X => 'X',
            ArmAxis::Y => 'Y',
            ArmAxis::Z => 'Z',
        }
    }

    /// Parse `X`, `Y` or `Z` (either case).
    pub fn from_letter(letter: &str) -> Option<ArmAxis> {
        match letter {
            "X" | "x" => Some(ArmAxis::X),
            "Y" | "y" => Some(ArmAxis::Y),
            "Z" | "z" => Some(ArmAxis::Z),
            _ => None,
        }
    }
}

/// The driver's configuration. The arm's axis is in degrees (GRBL's "mm").
#[derive(Debug, Clone, PartialEq)]
pub struct GrblArmConfig {
    pub axis: ArmAxis,
    /// Soft limits of the arm angle θL in degrees; targets outside are refused unsent.
    /// The defaults keep a margin inside the travel, off the home switch at 0.
    pub min_deg: f64,
    pub max_deg: f64,
    /// Expected `$100` (steps per degree; `$101`/`$102` for Y/Z).
    pub steps_per_deg: f64,
    /// Expected `$130` (max travel, degrees).
    pub max_travel_deg: f64,
    /// Expected `$110` (degrees/min) and `$120` (degrees/s²); `None`: any positive value.
    pub max_rate_deg_per_min: Option<f64>,
    pub accel_deg_per_s2: Option<f64>,
    /// How the arm is referenced; `Required` expects `$22=1`, `Off` expects `$22=0`.
    pub homing: Homing,
    /// Write settings that differ from these expectations (`$N=`) and read `$$` back,
    /// instead of refusing the controller.
    pub apply_settings: bool,
    /// How far the confirmed position may be from the target, degrees.
    pub position_tolerance_deg: f64,
    /// Wait for the start-up banner after opening (and again after a soft reset).
    pub banner_timeout: Duration,
    /// Wait for the reply to a command that does not wait for motion.
    pub reply_timeout: Duration,
    /// Motion (a move or the homing cycle) is expected within `motion_time_factor` ×
    /// its computed time + `motion_margin`; past that, a move still counts as alive
    /// while status reports show it progressing, up to `motion_patience` × that time.
    pub motion_time_factor: f64,
    pub motion_margin: Duration,
    pub motion_patience: f64,
    /// How often `?` is sent while waiting for a move, and how long a move may show no
    /// progress once it is late.
    pub status_interval: Duration,
    pub stall_timeout: Duration,
    /// Retries of an idempotent query after a garbled reply.
    pub garbled_retries: u32,
    /// Reconnect attempts after a disconnect, and the first backoff (doubling each
    /// attempt, capped at 16×).
    pub reconnect_attempts: u32,
    pub reconnect_backoff: Duration,
}

impl Default for GrblArmConfig {
    fn default() -> Self {
        Self {
            axis: ArmAxis::X,
            min_deg: -90.0,
            max_deg: -1.0,
            steps_per_deg: 80.0,
            max_travel_deg: 180.0,
            max_rate_deg_per_min: None,
            accel_deg_per_s2: None,
            homing: Homing::Required,
            apply_settings: false,
            position_tolerance_deg: 0.01,
            banner_timeout: Duration::from_secs(3),
            reply_timeout: Duration::from_secs(2),
            motion_time_factor: 1.5,
            motion_margin: Duration::from_secs(2),
            motion_patience: 10.0,
            status_interval: Duration::from_millis(200),
            stall_timeout: Duration::from_secs(2),
            garbled_retries: 3,
            reconnect_attempts: 5,
            reconnect_backoff: Duration::from_millis(200),
        }
    }
}

impl GrblArmConfig {
    /// Reasons this configuration cannot work, one line each; empty when it can.
    pub fn problems(&self) -> Vec<String> {
        let mut problems = Vec::new();
        if !(self.min_deg.is_finite() && self.max_deg.is_finite() && self.min_deg < self.max_deg) {
            problems.push(format!(
                "soft limits: min_deg ({}) must be below max_deg ({})",
                self.min_deg, self.max_deg
            ));
        }
        // Homed, the angle is the machine position: GRBL's travel is [−$130, 0].
        if self.homing == Homing::Required
            && (self.max_deg > 0.0 || self.min_deg < -self.max_travel_deg)
        {
            problems.push(format!(
                "soft limits [{}, {}] reach outside the travel [{}, 0] of a homed arm",
                self.min_deg, self.max_deg, -self.max_travel_deg
            ));
        }
        let positive = [
            ("steps_per_deg", Some(self.steps_per_deg)),
            ("max_travel_deg", Some(self.max_travel_deg)),
            ("max_rate_deg_per_min", self.max_rate_deg_per_min),
            ("accel_deg_per_s2", self.accel_deg_per_s2),
            ("position_tolerance_deg", Some(self.position_tolerance_deg)),
            ("motion_time_factor", Some(self.motion_time_factor)),
            ("motion_patience", Some(self.motion_patience)),
        ];
        for (name, value) in positive {
            if let Some(value) = value {
                if !(value.is_finite() && value > 0.0) {
                    problems.push(format!("{name} must be positive, got {value}"));
                }
            }
        }
        problems
    }
}
