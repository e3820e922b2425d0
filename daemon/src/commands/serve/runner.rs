//! The hardware owner: one thread that owns the arm and the camera and works through
//! the queue, one step at a time. A step is recorded as started before the hardware is
//! touched and as done, with its result, in one transaction afterwards, so a restart
//! resumes at the first step not done (after re-homing: the position is unknown then).

use std::path::{Path, PathBuf};
use std::sync::atomic::Ordering;
use std::sync::{mpsc, Arc};
use std::time::Duration;

use gonio_drivers::bracket::{auto_bracket, BracketError, BracketRegion, MeteringFrame};
use gonio_drivers::{Arm, ArmState, Camera, DeviceError, Exposure};
use gonio_processing::capture::{sidecar_path, Frame, Sidecar};
use gonio_processing::geometry::{column_angles, Setup};
use serde_json::{json, Value};

use super::calibration;
use super::files::{remove_partials, write_atomic};
use super::hardware::{ArmOpener, Devices, SidecarDefaults};
use super::plan::{exposure_stem, theta_dir_name, ScanPlan, Step};
use super::process;
use super::shared::{lock, scan_dir, Shared, EMERGENCY_STOP};
use super::step_guard;
use super::store::{now_rfc3339, now_unix, ScanRecord, ScanState, Store, StoreError};

/// Why a step did not complete.
enum StepError {
    /// The operator paused, cancelled or stopped the scan: leave it as they set it.
    Halted,
    /// The arm went away: the scan waits until it is back.
    Interrupted(String),
    /// The arm is refused, unhomed or its position undeclared: the scan waits for that
    /// to change (no retries meanwhile).
    Waiting(String),
    /// The scan cannot complete.
    Failed(String),
    Store(StoreError),
}

impl From<StoreError> for StepError {
    fn from(err: StoreError) -> Self {
        StepError::Store(err)
    }
}

/// How often the owner looks at the queue and the devices when nothing wakes it.
const IDLE_POLL: Duration = Duration::from_millis(500);
/// Reopening the arm after a failure waits this long, doubling up to the cap: opening
/// resets an Arduino-based board, so failed opens must not come in a storm.
const RECONNECT_BACKOFF: Duration = Duration::from_secs(1);
const RECONNECT_BACKOFF_MAX: Duration = Duration::from_secs(60);

/// The hardware owner thread's state.
pub struct Runner {
    shared: Arc<Shared>,
    store: Store,
    wake: mpsc::Receiver<()>,
    opener: ArmOpener,
    arm: Option<Box<dyn Arm>>,
    camera: Box<dyn Camera>,
    camera_model: String,
    /// Shutter times the camera allows, seconds.
    allowed_s: Vec<f64>,
    homed: bool,
    /// Where the arm was last sent (degrees), if it got there.
    at_deg: Option<f64>,
    /// Why the arm could not be opened, when it could not; and when to try again.
    arm_error: Option<String>,
    reconnect_backoff: Duration,
    next_connect: std::time::Instant,
    setup: Option<Setup>,
    truth: Option<Value>,
    sidecar: SidecarDefaults,
    iso: Option<u32>,
}

impl Runner {
    pub fn new(
        shared: Arc<Shared>,
        store: Store,
        wake: mpsc::Receiver<()>,
        devices: Devices,
    ) -> Self {
        Self {
            shared,
            store,
            wake,
            opener: devices.arm,
            arm: None,
            camera: devices.camera,
            camera_model: String::new(),
            allowed_s: Vec::new(),
            homed: false,
            at_deg: None,
            arm_error: None,
            reconnect_backoff: RECONNECT_BACKOFF,
            next_connect: std::time::Instant::now(),
            setup: devices.setup,
            truth: devices.truth,
            sidecar: devices.sidecar,
            iso: devices.iso,
        }
    }

    /// Runs forever on the calling thread.
    pub fn run(mut self) {
        self.identify_camera();
        loop {
            if let Err(err) = self.tick() {
                tracing::error!("queue: {err}");
                std::thread::sleep(Duration::from_secs(1));
            }
        }
    }

    fn identify_camera(&mut self) {
        let info = self.camera.identify();
        let speeds = self.camera.shutter_speeds();
        let mut status = lock(&self.shared.hardware);
        match (info, speeds) {
            (Ok(info), Ok(speeds)) => {
                self.camera_model = info.model.clone();
                status.camera.model = Some(info.model);
                status.camera.port = Some(info.port);
                if let (Some(min), Some(max)) = (speeds.first(), speeds.last()) {
                    status.camera.shutter_min_s = *min;
                    status.camera.shutter_max_s = *max;
                }
                self.allowed_s = speeds;
                status.camera.state = "idle";
                status.camera.error = None;
            }
            (Err(err), _) | (_, Err(err)) => {
                tracing::warn!("camera: {err}");
                status.camera.state = "error";
                status.camera.error = Some(err.to_string());
            }
        }
    }

    /// One pass: (re)connect the arm if needed, apply a declared position, then run
    /// the next scan or wait.
    fn tick(&mut self) -> Result<(), StoreError> {
        if self.arm.is_none() && !self.connect_arm()? {
            self.answer_position_request()?;
            self.wait_for_arm()?;
            self.idle();
            return Ok(());
        }
        self.answer_position_request()?;
        match self.store.next_runnable(now_unix())? {
            Some(scan) => {
                if self.allowed_s.is_empty() {
                    // The camera was not ready at start: ask again before using it.
                    self.identify_camera();
                }
                self.run_scan(scan)
            }
            None => {
                self.refresh_arm_status();
                self.idle();
                Ok(())
            }
        }
    }

    fn idle(&self) {
        // A timeout and a wake-up both mean: look again.
        let _ = self.wake.recv_timeout(IDLE_POLL);
    }

    /// Opens the arm, at most once per backoff period; on success, interrupted scans go
    /// back to running and waiting ones to the queue. Returns whether the arm is
    /// connected.
    fn connect_arm(&mut self) -> Result<bool, StoreError> {
        if std::time::Instant::now() < self.next_connect {
            return Ok(false);
        }
        match self.opener.open() {
            Ok(mut arm) => {
                *lock(&self.shared.estop) = Some(arm.emergency_stop());
                let state = arm.status().map_or(ArmState::NeedsHoming, |s| s.state);
                self.arm = Some(arm);
                self.homed = false;
                self.at_deg = None;
                self.arm_error = None;
                self.reconnect_backoff = RECONNECT_BACKOFF;
                self.log(None, "connect", &self.opener.path().display().to_string())?;
                {
                    let mut status = lock(&self.shared.hardware);
                    status.arm.state = state;
                    status.arm.homed = false;
                    status.arm.error = None;
                }
                for id in
                    self.store
                        .transition_all(ScanState::Interrupted, ScanState::Running, None)?
                {
                    tracing::info!("scan {id}: arm back, resuming");
                    self.shared.publish(&self.store, id)?;
                }
                self.requeue_waiting("arm connected")?;
                Ok(true)
            }
            Err(err) => {
                let reason = err.to_string();
                if self.arm_error.as_deref() != Some(reason.as_str()) {
                    tracing::warn!("arm {}: {err}", self.opener.path().display());
                }
                self.log(None, "connect failed", &reason)?;
                self.next_connect = std::time::Instant::now() + self.reconnect_backoff;
                self.reconnect_backoff = (self.reconnect_backoff * 2).min(RECONNECT_BACKOFF_MAX);
                let mut status = lock(&self.shared.hardware);
                status.arm.state = ArmState::Disconnected;
                status.arm.error = Some(reason.clone());
                self.arm_error = Some(reason);
                Ok(false)
            }
        }
    }

    /// Without an arm, the scan next in line waits, with the reason.
    fn wait_for_arm(&mut self) -> Result<(), StoreError> {
        let Some(scan) = self.store.next_runnable(now_unix())? else {
            return Ok(());
        };
        let reason = format!(
            "arm not available: {}",
            self.arm_error.as_deref().unwrap_or("not connected")
        );
        if scan.state == ScanState::Queued
            && self.store.transition(
                scan.id,
                &[ScanState::Queued],
                ScanState::Waiting,
                Some(&reason),
            )?
        {
            tracing::info!("scan {}: waiting: {reason}", scan.id);
            self.shared.publish(&self.store, scan.id)?;
        }
        Ok(())
    }

    /// Waiting scans go back to the queue (what they waited for may have changed).
    fn requeue_waiting(&mut self, why: &str) -> Result<(), StoreError> {
        for id in self
            .store
            .transition_all(ScanState::Waiting, ScanState::Queued, None)?
        {
            tracing::info!("scan {id}: {why}, queued again");
            self.shared.publish(&self.store, id)?;
        }
        Ok(())
    }

    /// Applies an operator's declared arm position, if one is pending, and answers it.
    fn answer_position_request(&mut self) -> Result<(), StoreError> {
        let Some(request) = lock(&self.shared.arm_position).take() else {
            return Ok(());
        };
        let angle = request.angle_deg;
        let result = match self.arm.as_mut() {
            Some(arm) => arm.declare_position(angle),
            None => Err(DeviceError::Disconnected(format!(
                "arm not available: {}",
                self.arm_error.as_deref().unwrap_or("not connected")
            ))),
        };
        match &result {
            Ok(()) => {
                self.homed = true;
                self.at_deg = None;
                self.log(
                    None,
                    "declare",
                    &format!("θL {angle:.3}° declared by the operator"),
                )?;
                self.note_arm(Some(angle));
                self.requeue_waiting("arm position declared")?;
            }
            Err(err) => {
                self.log(None, "declare refused", &format!("θL {angle:.3}°: {err}"))?;
            }
        }
        // The handler may have given up waiting: nothing to tell then.
        let _ = request.reply.send(result);
        Ok(())
    }

    fn refresh_arm_status(&mut self) {
        let Some(arm) = self.arm.as_mut() else {
            return;
        };
        match arm.status() {
            Ok(s) => {
                if matches!(s.state, ArmState::NeedsHoming | ArmState::NeedsPosition) {
                    self.homed = false;
                }
                let mut status = lock(&self.shared.hardware);
                status.arm.state = s.state;
                status.arm.angle_deg = Some(s.angle_deg);
                status.arm.homed = self.homed;
            }
            Err(err @ (DeviceError::Disconnected(_) | DeviceError::NotFound(_))) => {
                tracing::warn!("arm status: {err}; reconnecting");
                self.disconnect_arm(&err.to_string());
            }
            Err(err) => {
                // The driver resynchronises by itself; reopening would reset the board.
                self.homed = false;
                lock(&self.shared.hardware).arm.error = Some(err.to_string());
            }
        }
    }

    fn disconnect_arm(&mut self, reason: &str) {
        self.arm = None;
        self.homed = false;
        self.at_deg = None;
        *lock(&self.shared.estop) = None;
        let mut status = lock(&self.shared.hardware);
        status.arm.state = ArmState::Disconnected;
        status.arm.homed = false;
        status.arm.error = Some(reason.to_owned());
    }

    fn log(&mut self, scan: Option<i64>, action: &str, detail: &str) -> Result<(), StoreError> {
        self.store.log(self.shared.boot, scan, action, detail)
    }

    fn still_running(&self, id: i64) -> Result<bool, StoreError> {
        Ok(self
            .store
            .scan(id)?
            .is_some_and(|s| s.state == ScanState::Running))
    }

    fn run_scan(&mut self, scan: ScanRecord) -> Result<(), StoreError> {
        let id = scan.id;
        if scan.state == ScanState::Queued
            && !self
                .store
                .transition(id, &[ScanState::Queued], ScanState::Running, None)?
        {
            return Ok(());
        }
        tracing::info!("scan {id} ({}): running", scan.plan.sample);
        self.shared.publish(&self.store, id)?;
        let dir = scan_dir(&self.shared.config.data_dir, id);
        if let Err(err) = self.prepare_dir(&dir) {
            let reason = format!("preparing {}: {err}", dir.display());
            return self.finish_with(id, ScanState::Failed, &reason);
        }
        while self.still_running(id)? {
            // Re-read each time: a step may have planned further steps.
            let Some(step) = self.store.next_step(id)? else {
                // Every step done (the last one while the scan was paused).
                self.store
                    .transition(id, &[ScanState::Running], ScanState::Done, None)?;
                break;
            };
            self.store.step_started(id, step.index)?;
            self.shared.publish(&self.store, id)?;
            match self.execute(id, &dir, &step.step) {
                Ok((result, followers)) => {
                    self.store.step_done(id, step.index, &result, &followers)?;
                }
                Err(StepError::Halted) => break,
                Err(StepError::Interrupted(reason)) => {
                    tracing::warn!("scan {id} interrupted: {reason}");
                    self.disconnect_arm(&reason);
                    return self.finish_with(id, ScanState::Interrupted, &reason);
                }
                Err(StepError::Waiting(reason)) => {
                    tracing::warn!("scan {id} waiting: {reason}");
                    self.log(Some(id), "wait", &reason)?;
                    lock(&self.shared.hardware).arm.error = Some(reason.clone());
                    return self.finish_with(id, ScanState::Waiting, &reason);
                }
                Err(StepError::Failed(reason)) => {
                    tracing::error!("scan {id} failed: {reason}");
                    return self.finish_with(id, ScanState::Failed, &reason);
                }
                Err(StepError::Store(err)) => return Err(err),
            }
            self.shared.publish(&self.store, id)?;
        }
        self.shared.publish(&self.store, id)?;
        if let Some(scan) = self.store.scan(id)? {
            tracing::info!("scan {id}: {}", scan.state.as_str());
        }
        Ok(())
    }

    /// Moves a running scan to `state` with `reason` (a no-op if the operator changed
    /// it meanwhile).
    fn finish_with(&mut self, id: i64, state: ScanState, reason: &str) -> Result<(), StoreError> {
        self.store
            .transition(id, &[ScanState::Running], state, Some(reason))?;
        self.shared.publish(&self.store, id)
    }

    /// The setup of a scan starting now: the calibrated one, else the configured one.
    fn setup(&self) -> Option<Setup> {
        calibration::current_setup(&self.shared.config.data_dir, self.setup.as_ref())
    }

    /// Creates the scan directory with setup.json (and truth.json for emulated scans),
    /// and removes temporary files a crash left behind.
    fn prepare_dir(&self, dir: &Path) -> std::io::Result<()> {
        std::fs::create_dir_all(dir)?;
        let removed = remove_partials(dir)?;
        if removed > 0 {
            tracing::info!("{}: removed {removed} partial file(s)", dir.display());
        }
        let files = [
            ("setup.json", self.setup().map(|s| json!(s))),
            ("truth.json", self.truth.clone()),
        ];
        for (name, value) in files {
            let path = dir.join(name);
            if let (Some(value), false) = (value, path.exists()) {
                let text = serde_json::to_vec_pretty(&value).map_err(std::io::Error::other)?;
                write_atomic(&path, &text)?;
            }
        }
        Ok(())
    }

    /// Executes one step; returns its result and the steps it adds after itself.
    fn execute(
        &mut self,
        id: i64,
        dir: &Path,
        step: &Step,
    ) -> Result<(Value, Vec<Step>), StepError> {
        let result = match step {
            Step::Home => {
                self.home(id)?;
                json!({ "homed": true })
            }
            Step::Move { theta_l } => {
                self.move_to(id, *theta_l)?;
                json!({ "angle_deg": theta_l })
            }
            Step::Meter { theta_l } => return self.meter(id, *theta_l),
            Step::Capture {
                theta_l,
                index,
                shutter_s,
            } => self.capture(id, dir, *theta_l, *index, *shutter_s)?,
            Step::Hdr { .. } | Step::Extract | Step::Fit { .. } => {
                step_guard::run_processing(&step.describe(), || process::run(step, dir))
                    .map_err(StepError::Failed)?
            }
        };
        Ok((result, Vec::new()))
    }

    /// Meters θL and plans its bracket: a capture at a middle shutter (shortened while
    /// the strips clip), then the fewest allowed shutters that expose every strip pixel
    /// well ([`auto_bracket`]).
    fn meter(&mut self, id: i64, theta_l: f64) -> Result<(Value, Vec<Step>), StepError> {
        // The scan's own setup (written when it started), whatever was calibrated since.
        let own =
            gonio_processing::extract::read_setup(&self.shared.scan_dir(id).join("setup.json"));
        let setup = own.ok().or_else(|| self.setup()).ok_or_else(|| {
            StepError::Failed("an automatic bracket needs the setup geometry ([setup])".into())
        })?;
        let allowed = self.allowed_s.clone();
        let Some(mut shutter_s) = nearest_at_most(&allowed, METER_START_S) else {
            return Err(StepError::Failed(
                "the camera reported no shutter speeds to meter with".into(),
            ));
        };
        if !self.homed || self.at_deg != Some(theta_l) {
            self.move_to(id, theta_l)?;
        }
        let path = self
            .shared
            .config
            .data_dir
            .join("metering")
            .join(format!("scan-{id}-{}.tiff", theta_dir_name(theta_l)));
        let failed = |what: String| StepError::Failed(format!("metering θL {theta_l:.1}°: {what}"));
        std::fs::create_dir_all(path.parent().unwrap_or(Path::new(".")))
            .map_err(|e| failed(e.to_string()))?;
        for _ in 0..METER_ATTEMPTS {
            let exposure = Exposure {
                shutter_s,
                iso: self.iso,
            };
            self.camera_op(id, "metering exposure", |c| c.set_exposure(exposure))?;
            let capture = self.camera_op(id, "metering capture", |c| c.capture_to(&path))?;
            self.log(
                Some(id),
                "meter",
                &format!("θL {theta_l:.1}° at {shutter_s} s"),
            )?;
            // Read like any capture (TIFF or camera raw, with its levels).
            let sidecar = sidecar_path(&capture.path);
            let frame = self
                .write_sidecar(&sidecar, capture.exposure, theta_l)
                .and_then(|()| Frame::read(&capture.path).map_err(|e| e.to_string()));
            // The metering frame is not part of the scan.
            let _ = std::fs::remove_file(&capture.path);
            let _ = std::fs::remove_file(&sidecar);
            let frame = frame.map_err(|e| failed(format!("reading the frame: {e}")))?;
            let metering = MeteringFrame {
                width: frame.width,
                height: frame.height,
                channels: 3,
                data: &frame.data,
                shutter_s: capture.exposure.shutter_s,
            };
            let region = strip_region(&setup, theta_l, &frame);
            match auto_bracket(&metering, &region, &allowed) {
                Ok(bracket) => {
                    let mut shutters = bracket.shutters_s.clone();
                    shutters.reverse();
                    let result = json!({
                        "shutter_s": shutters,
                        "metering_shutter_s": capture.exposure.shutter_s,
                        "clipped_at_shortest": bracket.clipped_at_shortest,
                        "dark_at_longest": bracket.dark_at_longest,
                    });
                    return Ok((result, ScanPlan::captures(theta_l, &shutters)));
                }
                Err(BracketError::MeteringClipped { .. }) => {
                    shutter_s = nearest_at_most(&allowed, shutter_s / 16.0)
                        .filter(|s| *s < shutter_s)
                        .ok_or_else(|| failed("clipped even at the shortest shutter".into()))?;
                }
                Err(err) => return Err(failed(err.to_string())),
            }
        }
        Err(failed(format!(
            "still clipped after {METER_ATTEMPTS} metering captures"
        )))
    }

    /// Runs `op` on the arm with bounded retries. Transient faults back off and retry;
    /// a reset or alarm is cleared and the arm re-homed before the next try; a stop
    /// by the operator halts at once. A dead connection after the last try interrupts
    /// the scan, anything else fails it.
    ///
    /// With `home_first`, an arm whose position is unknown is homed before `op`.
    fn arm_op(
        &mut self,
        id: i64,
        what: &str,
        home_first: bool,
        mut op: impl FnMut(&mut dyn Arm) -> Result<(), DeviceError>,
    ) -> Result<(), StepError> {
        let retry = self.shared.config.retry;
        let stops = self.shared.stops.load(Ordering::Acquire);
        let mut last = None;
        for attempt in 0..retry.attempts {
            if attempt > 0 {
                std::thread::sleep(backoff(retry.backoff_ms, attempt));
            }
            if !self.still_running(id)? {
                return Err(StepError::Halted);
            }
            let Some(arm) = self.arm.as_mut() else {
                return Err(StepError::Interrupted("arm disconnected".into()));
            };
            let mut rehomed = false;
            let result = if self.homed || !home_first {
                op(arm.as_mut())
            } else {
                rehomed = true;
                arm.home().and_then(|()| op(arm.as_mut()))
            };
            match result {
                Ok(()) => {
                    if rehomed {
                        self.homed = true;
                        self.log(Some(id), "home", "before the next move")?;
                    }
                    return Ok(());
                }
                Err(err) => {
                    tracing::warn!("scan {id}: {what} (try {}): {err}", attempt + 1);
                    if self.shared.stops.load(Ordering::Acquire) != stops {
                        self.homed = false;
                        self.at_deg = None;
                        return self.halt_after_stop(id);
                    }
                    if matches!(err, DeviceError::Disconnected(_) | DeviceError::NotFound(_)) {
                        // The driver already tried to reconnect: wait for the device.
                        return Err(StepError::Interrupted(format!(
                            "{what}: {err}; waiting for the arm to come back"
                        )));
                    }
                    // What only the operator can change: wait for them, no retries. A
                    // position still unknown after homing was tried means it must be
                    // declared.
                    let unreferenced =
                        matches!(err, DeviceError::PositionUnknown(_)) && (rehomed || !home_first);
                    if unreferenced
                        || matches!(
                            err,
                            DeviceError::Refused(_) | DeviceError::HomingFailed { .. }
                        )
                    {
                        self.homed = false;
                        return Err(StepError::Waiting(format!("{what}: {err}")));
                    }
                    let recoverable = matches!(
                        err,
                        DeviceError::Reset
                            | DeviceError::Alarm { .. }
                            | DeviceError::PositionUnknown(_)
                    );
                    if recoverable {
                        self.homed = false;
                        self.at_deg = None;
                        if let Err(clear) = arm.clear_fault() {
                            tracing::warn!("clearing the arm fault: {clear}");
                        }
                    } else if !err.is_transient() {
                        return Err(StepError::Failed(format!("{what}: {err}")));
                    }
                    last = Some(err);
                }
            }
        }
        let attempts = retry.attempts;
        if !self.still_running(id)? {
            return Err(StepError::Halted);
        }
        let connection_lost = last.as_ref().is_some_and(is_connection_loss);
        let err = last.map(|e| e.to_string()).unwrap_or_default();
        if connection_lost {
            Err(StepError::Interrupted(format!(
                "{what}: {err} (after {attempts} attempts); waiting for the arm to come back"
            )))
        } else {
            Err(StepError::Failed(format!(
                "{what} failed after {attempts} attempts: {err}"
            )))
        }
    }

    /// After an emergency stop interrupted an arm operation: the operator's pause of
    /// the scan is on its way; wait for it (bounded), else record it here, so the scan
    /// never moves on by itself.
    fn halt_after_stop(&mut self, id: i64) -> Result<(), StepError> {
        let deadline = std::time::Instant::now() + Duration::from_secs(5);
        while self.still_running(id)? && std::time::Instant::now() < deadline {
            std::thread::sleep(Duration::from_millis(20));
        }
        self.store.transition(
            id,
            &[ScanState::Running],
            ScanState::Paused,
            Some(EMERGENCY_STOP),
        )?;
        Err(StepError::Halted)
    }

    fn home(&mut self, id: i64) -> Result<(), StepError> {
        self.arm_op(id, "home", false, |arm| arm.home())?;
        self.homed = true;
        self.at_deg = None;
        self.log(Some(id), "home", "")?;
        self.note_arm(None);
        Ok(())
    }

    fn move_to(&mut self, id: i64, theta_l: f64) -> Result<(), StepError> {
        self.at_deg = None;
        self.arm_op(id, &format!("move to θL {theta_l:.1}°"), true, |arm| {
            arm.move_to(theta_l)
        })?;
        self.at_deg = Some(theta_l);
        self.log(Some(id), "move", &format!("{theta_l:.1}"))?;
        self.note_arm(Some(theta_l));
        Ok(())
    }

    fn note_arm(&self, angle: Option<f64>) {
        let mut status = lock(&self.shared.hardware);
        status.arm.state = ArmState::Idle;
        status.arm.homed = self.homed;
        status.arm.error = None;
        status.arm.angle_deg = angle.or(Some(0.0));
    }

    /// Runs `op` on the camera with bounded retries of transient faults (busy, timeout).
    fn camera_op<T>(
        &mut self,
        id: i64,
        what: &str,
        mut op: impl FnMut(&mut dyn Camera) -> Result<T, DeviceError>,
    ) -> Result<T, StepError> {
        let retry = self.shared.config.retry;
        let mut last = String::new();
        for attempt in 0..retry.attempts {
            if attempt > 0 {
                std::thread::sleep(backoff(retry.backoff_ms, attempt));
            }
            if !self.still_running(id)? {
                return Err(StepError::Halted);
            }
            lock(&self.shared.hardware).camera.state = "capturing";
            let result = op(self.camera.as_mut());
            let mut status = lock(&self.shared.hardware);
            match result {
                Ok(value) => {
                    status.camera.state = "idle";
                    status.camera.error = None;
                    return Ok(value);
                }
                Err(err) => {
                    tracing::warn!("scan {id}: camera {what} (try {}): {err}", attempt + 1);
                    status.camera.state = "error";
                    status.camera.error = Some(err.to_string());
                    if !err.is_transient() {
                        return Err(StepError::Failed(format!("camera {what}: {err}")));
                    }
                    last = err.to_string();
                }
            }
        }
        Err(StepError::Failed(format!(
            "camera {what} failed after {} attempts: {last}",
            retry.attempts
        )))
    }

    fn capture(
        &mut self,
        id: i64,
        dir: &Path,
        theta_l: f64,
        index: usize,
        shutter_s: f64,
    ) -> Result<Value, StepError> {
        let frame_dir = dir.join(theta_dir_name(theta_l));
        let stem = exposure_stem(index);
        let sidecar_path = frame_dir.join(format!("{stem}.json"));
        let existing = find_frame(&frame_dir, &stem);
        if let (Some(image), true) = (&existing, sidecar_path.exists()) {
            return Ok(frame_result(dir, image, true));
        }
        let requested = Exposure {
            shutter_s,
            iso: self.iso,
        };
        let what = format!("θL {theta_l:.1}° {stem}");
        let (image, exposure) = match existing {
            // The image landed but the crash came before its sidecar: only the
            // exposure actually set is missing.
            Some(image) => {
                let exposure = self.camera_op(id, &format!("exposure for {what}"), |c| {
                    c.set_exposure(requested)
                })?;
                (image, exposure)
            }
            None => {
                if !self.homed || self.at_deg != Some(theta_l) {
                    self.move_to(id, theta_l)?;
                }
                self.camera_op(id, &format!("exposure for {what}"), |c| {
                    c.set_exposure(requested)
                })?;
                std::fs::create_dir_all(&frame_dir)
                    .map_err(|e| StepError::Failed(format!("{}: {e}", frame_dir.display())))?;
                let target = frame_dir.join(format!("{stem}.tiff"));
                let capture =
                    self.camera_op(id, &format!("capture {what}"), |c| c.capture_to(&target))?;
                self.log(Some(id), "capture", &what)?;
                (capture.path, capture.exposure)
            }
        };
        self.write_sidecar(&sidecar_path, exposure, theta_l)
            .map_err(StepError::Failed)?;
        Ok(frame_result(dir, &image, false))
    }

    /// Writes the JSON sidecar of a capture (docs/ARCHITECTURE.md, "File formats") atomically at `path`.
    fn write_sidecar(&self, path: &Path, exposure: Exposure, theta_l: f64) -> Result<(), String> {
        let sidecar = Sidecar {
            shutter_s: exposure.shutter_s,
            iso: exposure.iso.map(f64::from),
            theta_l,
            camera: self.camera_model.clone(),
            time: now_rfc3339(),
            black_level: self.sidecar.black_level,
            white_level: self.sidecar.white_level,
            response: self.sidecar.response,
            significant_bits: self.sidecar.significant_bits,
            width: None,
            height: None,
        };
        let text = serde_json::to_vec_pretty(&sidecar).map_err(|e| e.to_string())?;
        write_atomic(path, &text).map_err(|e| format!("{}: {e}", path.display()))
    }
}

/// First metering shutter, seconds (the allowed one at or below it).
const METER_START_S: f64 = 1.0 / 60.0;
/// Metering captures before giving up on a scene that clips.
const METER_ATTEMPTS: u32 = 4;

/// The longest of `allowed` (seconds) at most `target`, else the shortest allowed.
fn nearest_at_most(allowed: &[f64], target: f64) -> Option<f64> {
    let shortest = allowed.iter().copied().min_by(f64::total_cmp)?;
    Some(
        allowed
            .iter()
            .copied()
            .filter(|s| *s <= target * (1.0 + 1e-9))
            .max_by(f64::total_cmp)
            .unwrap_or(shortest),
    )
}

/// The rows (±2 around each strip's centre) and the cylinder's columns at θL that the
/// bracket must expose well in `frame`, with its levels.
fn strip_region(setup: &Setup, theta_l: f64, frame: &Frame) -> BracketRegion {
    let (width, height) = (frame.width, frame.height);
    let rows: Vec<usize> = [setup.sample_row, setup.white_row]
        .iter()
        .flat_map(|&centre| {
            let centre = centre as usize;
            centre.saturating_sub(2)..=centre + 2
        })
        .filter(|&r| r < height)
        .collect();
    let on_cylinder: Vec<usize> = column_angles(setup, theta_l)
        .iter()
        .enumerate()
        .filter_map(|(u, a)| a.map(|_| u))
        .filter(|&u| u < width)
        .collect();
    let columns = match (on_cylinder.first(), on_cylinder.last()) {
        (Some(&first), Some(&last)) => first..last + 1,
        _ => 0..width,
    };
    let span = (frame.white_level - frame.black_level).max(1.0);
    BracketRegion {
        rows,
        columns,
        black_level: frame.black_level,
        clip_level: frame.black_level + 0.95 * span,
        noise_floor: (0.01 * span).max(1.0),
    }
}

/// Backoff before try `attempt` (1-based after the first): base · 2^(attempt−1).
fn backoff(base_ms: u64, attempt: u32) -> Duration {
    Duration::from_millis(base_ms.saturating_mul(1 << (attempt - 1).min(10)))
}

/// Whether an arm error that outlasted the retries means the connection is gone
/// (rather than a refusal).
fn is_connection_loss(err: &DeviceError) -> bool {
    matches!(err, DeviceError::Io(_) | DeviceError::Timeout { .. })
}

/// The captured image of `stem` in `dir`, whatever its extension (sidecars excluded).
fn find_frame(dir: &Path, stem: &str) -> Option<PathBuf> {
    let entries = std::fs::read_dir(dir).ok()?;
    entries.filter_map(Result::ok).map(|e| e.path()).find(|p| {
        p.file_stem().is_some_and(|s| s == stem) && p.extension().is_some_and(|e| e != "json")
    })
}

fn frame_result(scan_dir: &Path, image: &Path, reused: bool) -> Value {
    let rel = image
        .strip_prefix(scan_dir)
        .unwrap_or(image)
        .to_string_lossy()
        .into_owned();
    json!({ "path": rel, "reused": reused })
}
