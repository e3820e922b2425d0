//! State shared by the HTTP handlers and the daemon's threads (docs/ARCHITECTURE.md,
//! "Daemon").

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64};
use std::sync::{mpsc, Arc, Mutex, OnceLock};

use gonio_drivers::{ArmState, DeviceError, EmergencyStop, LiveAngle};
use serde::Serialize;
use tokio::sync::broadcast;

use super::config::Config;
use super::devices::Emulators;
use super::mount::Mount;
use super::queued_times::QueuedTimes;
use super::storage::Probe;
use super::store::{ScanState, Store};
use super::sync::Mailbox;
use super::timing::{Costs, Timing};

/// Why a scan is paused after `POST /api/arm/stop`.
pub const EMERGENCY_STOP: &str = "emergency stop by the operator";

/// A live view of the devices, updated by the hardware lane.
#[derive(Debug, Clone, Serialize)]
pub struct HardwareStatus {
    pub arm: ArmView,
    pub camera: CameraView,
}

/// The arm as `GET /api/hardware` shows it.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct ArmView {
    pub state: ArmState,
    /// Angle θL, degrees; `None` while the position is unknown (not homed or declared
    /// since the controller powered up or reset).
    pub angle_deg: Option<f64>,
    /// Whether the position is known (homed, or declared).
    pub homed: bool,
    pub device: String,
    /// The last fault, if the arm is not healthy.
    pub error: Option<String>,
    /// While `refused`: each setting that differs from the configuration, one line each.
    pub settings: Vec<String>,
    /// Whether the controller runs the homing cycle (else its position is declared).
    pub homes: bool,
    /// The carousel axis' travel (`$13N`) as the board reported it on connecting;
    /// slots beyond it are refused.
    #[serde(skip)]
    #[schema(ignore)]
    pub carousel_travel: Option<f64>,
}

impl ArmView {
    /// The angle to show for a `reported` one: none while the position is unknown (not
    /// homed or declared, or in a state that loses it: an alarm, homing, after a reset or
    /// a stop, disconnected, refused).
    pub fn shown_angle(&self, reported: Option<f64>) -> Option<f64> {
        let lost = matches!(
            self.state,
            ArmState::Alarm
                | ArmState::Homing
                | ArmState::NeedsHoming
                | ArmState::NeedsPosition
                | ArmState::Disconnected
                | ArmState::Refused
        );
        reported.filter(|_| self.homed && !lost)
    }
}

/// The camera as `GET /api/hardware` shows it.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct CameraView {
    pub model: Option<String>,
    pub port: Option<String>,
    /// `idle`, `capturing`, `error` or `disconnected` (looked for again with backoff;
    /// the scan it interrupted resumes once it is back).
    #[schema(value_type = String, pattern = "^(idle|capturing|error|disconnected)$")]
    pub state: &'static str,
    /// Allowed shutter range, seconds.
    pub shutter_min_s: f64,
    pub shutter_max_s: f64,
    pub error: Option<String>,
}

/// An operator's declaration of where the arm is, for the hardware lane to apply; the
/// outcome goes back on `reply`.
pub struct PositionRequest {
    pub angle_deg: f64,
    pub reply: mpsc::SyncSender<Result<(), DeviceError>>,
}

/// A scan's view as it changed, for event subscribers.
#[derive(Debug, Clone)]
pub struct ScanEvent {
    pub id: i64,
    pub state: ScanState,
    /// The scan's JSON view.
    pub view: Arc<str>,
}

/// Everything the handlers and the daemon's threads share.
pub struct Shared {
    pub config: Config,
    pub token: String,
    /// Daemon start counter of this data directory.
    pub boot: i64,
    /// The handlers' database connection (each thread has its own).
    pub store: Mutex<Store>,
    /// Scan views as they change.
    pub events: broadcast::Sender<ScanEvent>,
    /// Scans whose view changed, for the publisher thread.
    pub changed: Mailbox<BTreeSet<i64>>,
    /// Nudges the hardware lane to look at the queue and the devices now.
    pub hardware_wake: Mailbox<bool>,
    /// Nudges the processing lane to look for ready steps now.
    pub processing_wake: Mailbox<bool>,
    pub hardware: Mutex<HardwareStatus>,
    /// Stops the arm from any thread; replaced whenever the arm is reopened.
    pub estop: Mutex<Option<Arc<dyn EmergencyStop>>>,
    /// The angle the connected arm reports, also during moves.
    pub arm_angle: Mutex<Option<LiveAngle>>,
    /// Emergency stops so far: an arm operation that fails after this changed does
    /// not retry.
    pub stops: AtomicU64,
    /// An emergency stop holds the instrument (`POST /api/arm/stop`): the hardware lane
    /// starts no scan and moves nothing until the operator homes the arm (the lane ends
    /// the hold once homed), declares its position or resumes a scan (or the daemon
    /// starts again).
    pub halted: AtomicBool,
    /// A declared arm position waiting for the hardware lane (one at a time).
    pub arm_position: Mutex<Option<PositionRequest>>,
    /// The operator asked to home the arm (`POST /api/arm/home`); the hardware lane
    /// homes it when no scan runs and clears this.
    pub home_requested: AtomicBool,
    /// The operator asked to open the arm again (`POST /api/arm/reconnect`), also a
    /// refused one.
    pub arm_reconnect: AtomicBool,
    /// Held while a confirmation mounts a sample: concurrent confirmations of a scan
    /// mount it once (the others find it no longer waiting).
    pub confirming: tokio::sync::Mutex<()>,
    /// What the devices' steps are expected to take, with the stated processing costs.
    pub timing: Timing,
    /// What processing costs on this machine, once measured (or read from the cache).
    pub costs: OnceLock<Costs>,
    /// The time left of the queued scans not begun, kept between plans of the waits.
    pub queued_times: QueuedTimes,
    /// Present when the devices are emulated.
    pub emulators: Option<Arc<Emulators>>,
    /// The sample on the cylinder.
    pub mount: Arc<Mount>,
    /// The data directory's free space.
    pub storage: Probe,
}

impl Shared {
    /// Directory of scan `id`.
    pub fn scan_dir(&self, id: i64) -> PathBuf {
        scan_dir(&self.config.data_dir, id)
    }

    /// The timing model as it stands: this machine's processing costs once measured.
    pub fn timing_now(&self) -> Timing {
        let costs = self.costs.get().copied().unwrap_or(self.timing.costs);
        Timing {
            costs,
            max_backlog: self.config.processing.max_backlog,
            ..self.timing
        }
    }

    /// Wakes both lanes (the queue or a scan's state changed).
    pub fn wake(&self) {
        self.hardware_wake.post(|wake| *wake = true);
        self.processing_wake.post(|wake| *wake = true);
    }

    /// The sample carousel may have moved (a homing cycle, a reset, a stop, a
    /// reconnect, a failed arm operation): which sample is before the camera is no
    /// longer known, so the next capture turns the carousel to its slot first.
    pub fn carousel_moved(&self) {
        if self.config.carousel.is_some() {
            self.mount.forget();
        }
    }

    /// The operator goes on after an emergency stop (homes the arm, declares its
    /// position, resumes a scan): the hold ends and the lanes look again.
    pub fn end_hold(&self) {
        self.halted
            .store(false, std::sync::atomic::Ordering::Release);
        self.wake();
    }

    /// Announces that scan `id` changed: its view is published to event subscribers.
    pub fn changed(&self, id: i64) {
        self.changed.post(|ids| {
            ids.insert(id);
        });
    }
}

/// Directory of scan `id` under the data directory.
pub fn scan_dir(data_dir: &Path, id: i64) -> PathBuf {
    data_dir.join("scans").join(id.to_string())
}
