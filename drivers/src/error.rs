//! The one error type of both device traits.

use thiserror::Error;

/// A device fault. Hardware faults are expected events: callers retry the transient
/// ones ([`DeviceError::is_transient`]) with bounded backoff.
#[derive(Debug, Error)]
pub enum DeviceError {
    #[error("I/O error: {0}")]
    Io(std::io::Error),
    #[error("timed out after {seconds:.1} s waiting for {what}")]
    Timeout { what: String, seconds: f64 },
    #[error("rejected with error:{code} ({meaning})")]
    Rejected { code: u32, meaning: String },
    #[error("alarm {code} ({meaning})")]
    Alarm { code: u32, meaning: String },
    #[error("controller reset: position unknown, home before moving")]
    Reset,
    /// The arm has no known position since the controller powered up or reset: home
    /// it, or declare where it is (the message says which).
    #[error("arm position unknown: {0}")]
    PositionUnknown(String),
    /// The homing cycle failed (GRBL's ALARM:6–9): what GRBL means, and what to check.
    #[error("homing failed, alarm {code} ({meaning}); {advice}")]
    HomingFailed {
        code: u32,
        meaning: String,
        advice: String,
    },
    /// The controller (or the configuration) refuses the request; one line per reason.
    #[error("refused: {0}")]
    Refused(String),
    /// The controller answers but its settings differ from what the configuration
    /// expects: one line per differing setting (`$100 (X steps per degree) is 250,
    /// configuration expects 80`). It stays so until the settings or the configuration
    /// change.
    #[error(
        "refused: controller settings differ from the configuration (set them, or let the \
         driver write them with apply_settings):\n{}",
        .0.join("\n")
    )]
    SettingsDiffer(Vec<String>),
    #[error("disconnected: {0}")]
    Disconnected(String),
    #[error("{what} {value} out of range [{min}, {max}]")]
    OutOfRange {
        what: String,
        value: f64,
        min: f64,
        max: f64,
    },
    #[error("camera busy")]
    Busy,
    #[error("no device: {0}")]
    NotFound(String),
    #[error("protocol error: {0}")]
    Protocol(String),
}

// Messages quote their cause instead of returning it as `source()`, so that a chain
// printer shows it once (docs/ARCHITECTURE.md, "Errors").
impl From<std::io::Error> for DeviceError {
    fn from(error: std::io::Error) -> Self {
        DeviceError::Io(error)
    }
}

impl DeviceError {
    /// Faults worth retrying after a backoff (the device may recover by itself).
    pub fn is_transient(&self) -> bool {
        matches!(
            self,
            DeviceError::Io(_)
                | DeviceError::Timeout { .. }
                | DeviceError::Busy
                | DeviceError::Disconnected(_)
        )
    }
}
