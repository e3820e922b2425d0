//! State shared by the HTTP handlers and the hardware owner thread.

use std::path::PathBuf;
use std::sync::atomic::AtomicU64;
use std::sync::{mpsc, Arc, Mutex, MutexGuard};

use gonio_drivers::{ArmState, DeviceError, EmergencyStop};
use serde::Serialize;
use tokio::sync::broadcast;

use super::config::Config;
use super::hardware::Emulators;
use super::store::{ScanRecord, Store, StoreError};

/// Why a scan is paused after `POST /api/arm/stop`.
pub const EMERGENCY_STOP: &str = "emergency stop by the operator";

/// A live view of the devices, updated by the hardware owner.
#[derive(Debug, Clone, Serialize)]
pub struct HardwareStatus {
    pub arm: ArmView,
    pub camera: CameraView,
}

#[derive(Debug, Clone, Serialize)]
pub struct ArmView {
    pub state: ArmState,
    /// Last known angle θL, degrees.
    pub angle_deg: Option<f64>,
    pub homed: bool,
    pub device: String,
    /// The last fault, if the arm is not healthy.
    pub error: Option<String>,
}

#[derive(Debug, Clone, Serialize)]
pub struct CameraView {
    pub model: Option<String>,
    pub port: Option<String>,
    /// `idle`, `capturing` or `error`.
    pub state: &'static str,
    /// Allowed shutter range, seconds.
    pub shutter_min_s: f64,
    pub shutter_max_s: f64,
    pub error: Option<String>,
}

/// An operator's declaration of where the arm is, for the hardware owner to apply; the
/// outcome goes back on `reply`.
pub struct PositionRequest {
    pub angle_deg: f64,
    pub reply: mpsc::SyncSender<Result<(), DeviceError>>,
}

/// Everything the handlers and the hardware owner share.
pub struct Shared {
    pub config: Config,
    pub token: String,
    /// Daemon start counter of this data directory.
    pub boot: i64,
    /// The handlers' database connection (the hardware owner has its own).
    pub store: Mutex<Store>,
    /// Progress of scans as they change.
    pub events: broadcast::Sender<ScanRecord>,
    /// Nudges the hardware owner to look at the queue now.
    pub wake: Mutex<mpsc::Sender<()>>,
    pub hardware: Mutex<HardwareStatus>,
    /// Stops the arm from any thread; replaced whenever the arm is reopened.
    pub estop: Mutex<Option<Arc<dyn EmergencyStop>>>,
    /// Emergency stops so far: an arm operation that fails after this changed does
    /// not retry.
    pub stops: AtomicU64,
    /// A declared arm position waiting for the hardware owner (one at a time).
    pub arm_position: Mutex<Option<PositionRequest>>,
    /// Present when the devices are emulated.
    pub emulators: Option<Arc<Emulators>>,
}

/// Locks a mutex, recovering the data of a poisoned one (a panicked holder leaves
/// plain data that is still consistent for these uses).
pub fn lock<T>(mutex: &Mutex<T>) -> MutexGuard<'_, T> {
    mutex
        .lock()
        .unwrap_or_else(|poisoned| poisoned.into_inner())
}

impl Shared {
    /// Directory of scan `id`.
    pub fn scan_dir(&self, id: i64) -> PathBuf {
        scan_dir(&self.config.data_dir, id)
    }

    /// Wakes the hardware owner.
    pub fn wake(&self) {
        // The owner only stops with the process, so a failed send changes nothing.
        let _ = lock(&self.wake).send(());
    }

    /// Broadcasts the current record of scan `id` to event subscribers.
    pub fn publish(&self, store: &Store, id: i64) -> Result<(), StoreError> {
        if let Some(scan) = store.scan(id)? {
            // No subscriber is not an error.
            let _ = self.events.send(scan);
        }
        Ok(())
    }
}

/// Directory of scan `id` under the data directory.
pub fn scan_dir(data_dir: &std::path::Path, id: i64) -> PathBuf {
    data_dir.join("scans").join(id.to_string())
}
