//! gonio-drivers: the two device traits the daemon depends on, and their real drivers.
//!
//! Both traits are synchronous and blocking: callers keep them off async worker
//! threads (a dedicated thread or `spawn_blocking`). Angles are degrees, shutter times
//! seconds.
//!
//! - [`grbl`]: the light arm on a GRBL 1.1 controller over a serial port.
//! - [`supervised_camera`]: a [`Camera`] run in a child process under a watchdog;
//!   `gphoto2_camera` (cargo feature `gphoto2`) is the libgphoto2 camera it runs, in the
//!   `gonio-camera-worker` binary.
//! - [`bracket`]: choosing a bracket of shutter speeds from a metering capture.
//! - [`camera_choice`]: reading a camera's shutter and ISO choice strings.

pub mod bracket;
pub mod camera_choice;
mod error;
#[cfg(feature = "gphoto2")]
pub mod gphoto2_camera;
pub mod grbl;
pub mod supervised_camera;

pub use error::DeviceError;

use std::path::Path;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

use serde::{Deserialize, Serialize};

/// State of the light arm as the controller reports it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(rename_all = "snake_case")]
pub enum ArmState {
    Idle,
    Moving,
    Homing,
    Hold,
    Alarm,
    /// Position unknown (after a reset or reconnect): home before the next move.
    NeedsHoming,
    /// Position unknown and the controller does not home: declare where the arm is.
    NeedsPosition,
    Disconnected,
    /// The controller answers but its settings differ from the configuration: it is
    /// not opened (nor reset) again until that changes.
    Refused,
}

/// A snapshot of the arm: state and angle θL (degrees; for a GRBL arm its work
/// position, the machine position once homed).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ArmStatus {
    pub state: ArmState,
    pub angle_deg: f64,
}

/// The arm's angle as its controller last reported it (degrees, machine position),
/// readable from any thread, also while another thread is inside [`Arm::move_to`]:
/// drivers report the angle during moves. Cheap to clone; `None` before the first
/// report.
#[derive(Debug, Clone)]
pub struct LiveAngle {
    bits: Arc<AtomicU64>,
}

impl Default for LiveAngle {
    fn default() -> Self {
        Self {
            bits: Arc::new(AtomicU64::new(f64::NAN.to_bits())),
        }
    }
}

impl LiveAngle {
    /// The last reported angle, degrees.
    pub fn get(&self) -> Option<f64> {
        let deg = f64::from_bits(self.bits.load(Ordering::Acquire));
        (!deg.is_nan()).then_some(deg)
    }

    /// Records a reported angle, degrees.
    pub fn set(&self, deg: f64) {
        self.bits.store(deg.to_bits(), Ordering::Release);
    }
}

/// Stops the arm at once from any thread, even while another thread is inside
/// [`Arm::move_to`] (feed hold, then soft reset).
pub trait EmergencyStop: Send + Sync {
    fn stop(&self) -> Result<(), DeviceError>;
}

/// The rotating light-source arm.
pub trait Arm: Send {
    /// Reference the arm: run the homing cycle, or, on a controller that does not home,
    /// accept the position declared with [`Arm::declare_position`] (an error when none
    /// was). Afterwards the position is known.
    fn home(&mut self) -> Result<(), DeviceError>;
    /// Declare where the arm is (degrees), for controllers without homing; refused
    /// where the arm is referenced by homing, and outside the arm's travel.
    fn declare_position(&mut self, angle_deg: f64) -> Result<(), DeviceError>;
    /// Move to `angle_deg` and return once the arm is idle there.
    fn move_to(&mut self, angle_deg: f64) -> Result<(), DeviceError>;
    /// Move another axis of the controller (a sample carousel) to machine position
    /// `position` (the axis' units) and return once it is idle there. The arm must be
    /// referenced: the homing cycle references the axes it homes.
    fn move_axis(&mut self, axis: grbl::ArmAxis, position: f64) -> Result<(), DeviceError>;
    /// The travel of `axis` as the controller was last read (its units: positions on
    /// [−travel, 0] once homed), if known.
    fn axis_travel(&self, _axis: grbl::ArmAxis) -> Option<f64> {
        None
    }
    /// Whether the controller references the arm with its homing cycle (else by a
    /// declared position).
    fn homes(&self) -> bool {
        true
    }
    /// Query state and position.
    fn status(&mut self) -> Result<ArmStatus, DeviceError>;
    /// Clear an alarm or reset condition; the caller re-homes afterwards.
    fn clear_fault(&mut self) -> Result<(), DeviceError>;
    /// A handle that stops this arm from another thread.
    fn emergency_stop(&self) -> Arc<dyn EmergencyStop>;
    /// A handle on the angle the arm reports, also during moves.
    fn live_angle(&self) -> LiveAngle;
}

/// What a camera says of itself.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CameraInfo {
    pub model: String,
    pub port: String,
}

/// Exposure settings; `iso` is `None` where the body has no ISO setting.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Exposure {
    pub shutter_s: f64,
    pub iso: Option<u32>,
}

/// A finished capture: the file written and the exposure actually used.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Capture {
    pub path: std::path::PathBuf,
    pub exposure: Exposure,
}

/// A still camera.
pub trait Camera: Send {
    fn identify(&mut self) -> Result<CameraInfo, DeviceError>;
    /// Shutter times the body allows, in seconds, ascending.
    fn shutter_speeds(&mut self) -> Result<Vec<f64>, DeviceError>;
    /// Set the exposure (shutter snapped to the nearest allowed value) and return the
    /// exposure read back from the body.
    fn set_exposure(&mut self, exposure: Exposure) -> Result<Exposure, DeviceError>;
    /// Capture one frame and store it atomically at `path` (the file's extension is the
    /// camera's own: the returned [`Capture::path`] is where it landed).
    fn capture_to(&mut self, path: &Path) -> Result<Capture, DeviceError>;
}
