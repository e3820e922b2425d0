//! The hardware lane: one thread that owns the arm and the camera and only moves and
//! captures (docs/ARCHITECTURE.md, "Daemon"). It works through the hardware steps of
//! one scan at a time, recording each as started before the hardware is touched and
//! as done, with its result, afterwards; it waits before a new bracket while the
//! processing lane is too far behind.

use std::path::{Path, PathBuf};
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::Duration;

use gonio_drivers::bracket::{auto_bracket, BracketError, BracketRegion, MeteringFrame};
use gonio_drivers::{Arm, ArmState, Camera, DeviceError, Exposure};
use gonio_processing::capture::{sidecar_path, Frame, Sidecar};
use gonio_processing::geometry::{column_angles, Setup};
use serde_json::{json, Value};

use super::backoff::{Backoff, Failures};
use super::step::{self, Flow, Outcome, StepError};
use crate::calibration;
use crate::devices::{ArmOpener, Devices, LinkId, SceneFacts, SidecarDefaults};
use crate::files::write_atomic;
use crate::plan::{exposure_stem, mount_reason, theta_dir_name, Lane, ScanPlan, Step};
use crate::shared::{Shared, EMERGENCY_STOP};
use crate::storage;
use crate::store::{now_rfc3339, now_unix, ScanRecord, ScanState, StepState, Store, StoreError};
use crate::sync::lock;
use crate::timing::METER_START_S;

/// How often the lane looks at the queue and the devices when nothing wakes it.
const IDLE_POLL: Duration = Duration::from_millis(500);

mod carousel;
mod device_link;
mod requests;

use carousel::CarouselTarget;

/// The scan states the hardware lane works in.
const RUNNING: &[ScanState] = &[ScanState::Running];

/// The hardware lane's state.
pub struct HardwareLane {
    shared: Arc<Shared>,
    store: Store,
    opener: ArmOpener,
    arm: Option<Box<dyn Arm>>,
    camera: Box<dyn Camera>,
    camera_model: String,
    /// Shutter times the camera allows, seconds.
    allowed_s: Vec<f64>,
    /// When to look for the camera again while it is not ready (`None`: it is).
    camera_retry: Option<Backoff>,
    /// A device came back: interrupted scans resume once both are ready.
    resume: bool,
    homed: bool,
    /// Where the arm was last sent (degrees), if it got there.
    at_deg: Option<f64>,
    /// What the arm's device path named when the arm was opened: the driver is let go
    /// when it vanishes or names another device (unplugged, plugged in again).
    arm_link: Option<LinkId>,
    /// The device path was absent at the last look (the board unplugged).
    arm_absent: bool,
    /// Why the arm could not be opened, when it could not; and when to try again.
    arm_error: Option<String>,
    arm_retry: Backoff,
    /// The board answered but its settings differ: it is not opened again until the
    /// operator asks or it is unplugged and plugged in.
    arm_refused: Option<Refusal>,
    setup: Option<Setup>,
    /// Where `setup` comes from (each field's provenance in setup.json).
    setup_source: &'static str,
    truth: Option<Value>,
    sidecar: SidecarDefaults,
    iso: Option<u32>,
    /// Where the carousel must be before each capture of the running scan.
    carousel: Option<CarouselTarget>,
    /// When to look at the free space again while scans wait for it.
    disk_retry: Backoff,
    /// Bytes the step being executed will write (what a full disk leaves it short of).
    need: u64,
}

impl HardwareLane {
    pub fn new(shared: Arc<Shared>, store: Store, devices: Devices) -> Self {
        Self {
            shared,
            store,
            opener: devices.arm,
            arm: None,
            camera: devices.camera,
            camera_model: String::new(),
            allowed_s: Vec::new(),
            camera_retry: Some(Backoff::now()),
            resume: true,
            homed: false,
            at_deg: None,
            arm_link: None,
            arm_absent: false,
            arm_error: None,
            arm_retry: Backoff::now(),
            arm_refused: None,
            setup: devices.setup,
            setup_source: devices.setup_source,
            truth: devices.truth,
            sidecar: devices.sidecar,
            iso: devices.iso,
            carousel: None,
            disk_retry: Backoff::now(),
            need: 0,
        }
    }

    /// Runs forever on the calling thread.
    pub fn run(mut self) {
        let mut failures = Failures::default();
        loop {
            match self.tick() {
                Ok(()) => failures.ok("hardware lane"),
                Err(err) => std::thread::sleep(failures.failed("hardware lane", &err)),
            }
        }
    }

    /// Asks the camera who it is and which shutter times it allows; returns whether
    /// it answered.
    fn identify_camera(&mut self) -> bool {
        let answer = self
            .camera
            .identify()
            .and_then(|info| Ok((info, self.camera.shutter_speeds()?)));
        let mut status = lock(&self.shared.hardware);
        match answer {
            Ok((info, speeds)) => {
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
                true
            }
            Err(err) => {
                if status.camera.error.is_none() {
                    tracing::warn!("camera: {err}");
                }
                status.camera.state = camera_state_after(&err);
                status.camera.error = Some(err.to_string());
                false
            }
        }
    }

    /// Looks for the camera if it is not ready and its next try is due; returns
    /// whether it is ready. Once it is back, interrupted scans resume (at the next
    /// pass) and waiting ones go back to the queue.
    fn connect_camera(&mut self) -> Result<bool, StoreError> {
        let Some(retry) = self.camera_retry else {
            return Ok(true);
        };
        if !retry.due() {
            return Ok(false);
        }
        if self.identify_camera() {
            self.camera_retry = None;
            self.resume = true;
            let model = self.camera_model.clone();
            self.log(None, "camera", &model)?;
            self.requeue_waiting("camera connected")?;
            return Ok(true);
        }
        self.camera_retry = Some(retry.later());
        Ok(false)
    }

    /// One pass: (re)connect the devices if needed, apply a declared position, resume
    /// the scans the devices interrupted once both are ready, then run the next scan's
    /// hardware steps or wait.
    fn tick(&mut self) -> Result<(), StoreError> {
        self.check_arm_link();
        let arm_ready = self.arm.is_some() || self.connect_arm()?;
        let camera_ready = self.connect_camera()?;
        self.answer_position_request()?;
        self.answer_home_request()?;
        if self.waiting_for_disk()? {
            self.idle();
            return Ok(());
        }
        if !(arm_ready && camera_ready) {
            self.wait_for_devices()?;
            self.idle();
            return Ok(());
        }
        if std::mem::take(&mut self.resume) {
            for id in self
                .store
                .transition_all(ScanState::Interrupted, ScanState::Running, None)?
            {
                tracing::info!("scan {id}: devices back, resuming");
                self.shared.changed(id);
            }
        }
        if self.store.waiting_for_sample()?.is_some() {
            // The operator is changing the sample: nothing moves meanwhile.
            self.refresh_arm_status();
            self.idle();
            return Ok(());
        }
        match self.store.next_for_hardware(now_unix())? {
            Some(scan) if self.sample_ready(&scan)? => self.run_scan(scan),
            Some(_) => {
                self.idle();
                Ok(())
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
        self.shared.hardware_wake.take(IDLE_POLL);
    }

    /// Opens the arm, at most once per backoff period (at once when the operator asks);
    /// a refused board only when the operator asks or it was plugged in again. On
    /// success, interrupted scans go back to running (at the next pass) and waiting
    /// ones to the queue. Returns whether the arm is connected.
    fn connect_arm(&mut self) -> Result<bool, StoreError> {
        let asked = self.shared.arm_reconnect.swap(false, Ordering::AcqRel);
        if let Some(refusal) = &mut self.arm_refused {
            let replugged = refusal.replugged(self.opener.link());
            if !(asked || replugged) {
                return Ok(false);
            }
            let why = if asked {
                "asked by the operator"
            } else {
                "the board was plugged in again"
            };
            self.arm_refused = None;
            self.arm_retry = Backoff::now();
            self.log(None, "reconnect", why)?;
        }
        if asked {
            self.arm_retry = Backoff::now();
        }
        if self.arm_device_absent()? {
            return Ok(false);
        }
        if !self.arm_retry.due() {
            return Ok(false);
        }
        let link = self.opener.link();
        match self.opener.open() {
            Ok(mut arm) => {
                self.arm_link = link;
                *lock(&self.shared.estop) = Some(arm.emergency_stop());
                *lock(&self.shared.arm_angle) = Some(arm.live_angle());
                let state = arm.status().map_or(ArmState::NeedsHoming, |s| s.state);
                let arm_homes = arm.homes();
                let carousel = self.shared.config.carousel.as_ref();
                let carousel_travel = carousel.and_then(|c| arm.axis_travel(c.axis()));
                let unreachable = carousel
                    .zip(carousel_travel)
                    .map(|(c, t)| c.beyond_travel(t));
                for (_, why) in unreachable.unwrap_or_default() {
                    tracing::warn!("arm: {why}");
                    self.log(None, "carousel", &why)?;
                }
                self.arm = Some(arm);
                self.homed = false;
                self.at_deg = None;
                self.shared.carousel_moved();
                self.arm_error = None;
                self.arm_retry = Backoff::now();
                self.log(None, "connect", &self.opener.path().display().to_string())?;
                {
                    let mut status = lock(&self.shared.hardware);
                    status.arm.state = state;
                    status.arm.homes = arm_homes;
                    status.arm.carousel_travel = carousel_travel;
                    status.arm.homed = false;
                    status.arm.angle_deg = None;
                    status.arm.error = None;
                    status.arm.settings.clear();
                }
                self.resume = true;
                self.requeue_waiting("arm connected")?;
                Ok(true)
            }
            Err(err) => {
                let reason = err.to_string();
                if self.arm_error.as_deref() != Some(reason.as_str()) {
                    tracing::warn!("arm {}: {err}", self.opener.path().display());
                }
                self.log(None, "connect failed", &reason)?;
                self.arm_retry = self.arm_retry.later();
                if let DeviceError::SettingsDiffer(settings) = err {
                    self.refuse_arm(settings, &reason);
                } else {
                    let mut status = lock(&self.shared.hardware);
                    status.arm.state = ArmState::Disconnected;
                    status.arm.angle_deg = None;
                    status.arm.error = Some(reason.clone());
                    self.arm_error = Some(reason);
                }
                Ok(false)
            }
        }
    }

    /// Without an arm or a camera, the scan next in line waits, with the reason.
    fn wait_for_devices(&mut self) -> Result<(), StoreError> {
        let Some(scan) = self.store.next_for_hardware(now_unix())? else {
            return Ok(());
        };
        let reason = if self.arm.is_none() {
            format!(
                "arm not available: {}",
                self.arm_error.as_deref().unwrap_or("not connected")
            )
        } else {
            let camera = lock(&self.shared.hardware).camera.error.clone();
            format!(
                "camera not available: {}",
                camera.as_deref().unwrap_or("not connected")
            )
        };
        if scan.state == ScanState::Queued
            && self.store.transition(
                scan.id,
                &[ScanState::Queued],
                ScanState::Waiting,
                Some(&reason),
            )?
        {
            tracing::info!("scan {}: waiting: {reason}", scan.id);
            self.shared.changed(scan.id);
        }
        Ok(())
    }

    /// Whether the sample `scan` measures is known to be on the cylinder, or the
    /// carousel brings it; if neither, the scan waits for the operator to mount it and
    /// confirm, before any of its steps.
    fn sample_ready(&mut self, scan: &ScanRecord) -> Result<bool, StoreError> {
        let sample = &scan.plan.sample;
        if self.shared.mount.is_mounted(sample) || self.shared.config.carousel.is_some() {
            return Ok(true);
        }
        let reason = mount_reason(sample);
        if self.store.transition(
            scan.id,
            &[ScanState::Queued, ScanState::Running],
            ScanState::Waiting,
            Some(&reason),
        )? {
            tracing::info!("scan {}: waiting: {reason}", scan.id);
            self.log(Some(scan.id), "wait", &reason)?;
            self.shared.changed(scan.id);
        }
        Ok(false)
    }

    /// Waiting scans go back to the queue (what they waited for may have changed).
    fn requeue_waiting(&mut self, why: &str) -> Result<(), StoreError> {
        for id in self
            .store
            .transition_all(ScanState::Waiting, ScanState::Queued, None)?
        {
            tracing::info!("scan {id}: {why}, queued again");
            self.shared.changed(id);
        }
        Ok(())
    }

    /// While scans wait for disk space nothing starts: the scan next in line waits too,
    /// and the free space is looked at again with backoff; once the next steps of every
    /// scan waiting for it fit, those scans are queued again. Returns whether scans
    /// still wait for space.
    fn waiting_for_disk(&mut self) -> Result<bool, StoreError> {
        let waiting: Vec<ScanRecord> = self
            .store
            .scans_in(ScanState::Waiting)?
            .into_iter()
            .filter(|s| s.error.as_deref().is_some_and(storage::is_disk_wait))
            .collect();
        if waiting.is_empty() {
            self.disk_retry = Backoff::now();
            return Ok(false);
        }
        if !self.disk_retry.due() {
            return Ok(true);
        }
        let mut need = 0;
        for scan in &waiting {
            need = need.max(self.scan_need(scan)?);
        }
        match self.shared.storage.check(need) {
            Ok(()) => {
                self.disk_retry = Backoff::now();
                self.log(None, "disk", "space for the waiting scans")?;
                for scan in waiting {
                    if self.store.transition(
                        scan.id,
                        &[ScanState::Waiting],
                        ScanState::Queued,
                        None,
                    )? {
                        tracing::info!("scan {}: disk space back, queued again", scan.id);
                        self.shared.changed(scan.id);
                    }
                }
                Ok(false)
            }
            Err(reason) => {
                self.disk_retry = self.disk_retry.later();
                if let Some(next) = self.store.next_for_hardware(now_unix())? {
                    waiting_for_space(&self.shared, &mut self.store, &next, &reason)?;
                }
                for scan in &waiting {
                    waiting_for_space(&self.shared, &mut self.store, scan, &reason)?;
                }
                Ok(true)
            }
        }
    }

    /// Pixels of the frames of scan `id`: from its own setup, else the current one.
    fn frame_pixels(&self, id: i64) -> u64 {
        let own =
            gonio_processing::extract::read_setup(&self.shared.scan_dir(id).join("setup.json"));
        storage::frame_pixels(own.ok().or_else(|| self.setup()).as_ref())
    }

    /// The most that the next hardware step and the next processing step of `scan`
    /// will write.
    fn scan_need(&self, scan: &ScanRecord) -> Result<u64, StoreError> {
        let pixels = self.frame_pixels(scan.id);
        let steps = self.store.steps(scan.id)?;
        let pending = || steps.iter().filter(|s| s.state != StepState::Done);
        Ok([Lane::Hardware, Lane::Processing]
            .into_iter()
            .filter_map(|lane| pending().find(|s| s.step.lane() == lane))
            .map(|s| storage::step_need(&s.step, &scan.plan, pixels))
            .max()
            .unwrap_or(0))
    }

    fn refresh_arm_status(&mut self) {
        let Some(arm) = self.arm.as_mut() else {
            return;
        };
        match arm.status() {
            Ok(s) => {
                if matches!(
                    s.state,
                    ArmState::NeedsHoming | ArmState::NeedsPosition | ArmState::Alarm
                ) {
                    self.homed = false;
                    self.shared.carousel_moved();
                }
                let mut status = lock(&self.shared.hardware);
                status.arm.state = s.state;
                status.arm.homed = self.homed;
                status.arm.angle_deg = status.arm.shown_angle(Some(s.angle_deg));
            }
            Err(DeviceError::SettingsDiffer(settings)) => {
                // Reopened by the driver after a reset or unplug, and refused.
                let reason = DeviceError::SettingsDiffer(settings.clone()).to_string();
                tracing::warn!("arm: {reason}");
                self.refuse_arm(settings, &reason);
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
        self.shared.carousel_moved();
        *lock(&self.shared.estop) = None;
        *lock(&self.shared.arm_angle) = None;
        let mut status = lock(&self.shared.hardware);
        status.arm.state = ArmState::Disconnected;
        status.arm.homed = false;
        status.arm.angle_deg = None;
        status.arm.error = Some(reason.to_owned());
    }

    /// The board answers but its `settings` differ from the configuration: it is let
    /// go and not opened again (each open resets it) until the operator asks or it is
    /// unplugged and plugged in; `/api/hardware` shows it `refused` with the settings.
    fn refuse_arm(&mut self, settings: Vec<String>, reason: &str) {
        self.disconnect_arm(reason);
        self.arm_error = Some(reason.to_owned());
        self.arm_refused = Some(Refusal {
            link: self.opener.link(),
            unplugged: false,
        });
        let mut status = lock(&self.shared.hardware);
        status.arm.state = ArmState::Refused;
        status.arm.settings = settings;
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

    /// Runs the hardware steps of `scan` until none is left or the scan stops.
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
        self.shared.changed(id);
        if !self.aim_carousel(id, &scan.plan.sample)? {
            return Ok(());
        }
        let dir = self.shared.scan_dir(id);
        if let Err(err) = self.prepare_dir(&dir, &scan.plan) {
            if storage::is_disk_full(&err) {
                let reason = self.shared.storage.full_reason(0);
                let now = self.store.scan(id)?;
                if let Some(scan) = now {
                    waiting_for_space(&self.shared, &mut self.store, &scan, &reason)?;
                }
                return Ok(());
            }
            let reason = format!("preparing {}: {err}", dir.display());
            self.store
                .transition(id, RUNNING, ScanState::Failed, Some(&reason))?;
            self.shared.changed(id);
            return Ok(());
        }
        let pixels = self.frame_pixels(id);
        while self.still_running(id)? {
            // Re-read each time: a metering step plans the captures after it.
            let Some(step) = self.store.next_step(id, Lane::Hardware)? else {
                // The processing lane finishes the scan (or every step was done
                // already, the last while the scan was paused).
                if self.store.complete_if_done(id)? {
                    self.shared.changed(id);
                }
                break;
            };
            if matches!(step.step, Step::Move { .. }) && !self.wait_for_processing(id)? {
                break;
            }
            // What the step writes (before a move: the bracket and its map) must fit
            // above the journal's reserve, else the scan waits for space.
            self.need = storage::step_need(&step.step, &scan.plan, pixels);
            if let Err(reason) = self.shared.storage.check(self.need) {
                let now = self.store.scan(id)?;
                if let Some(scan) = now {
                    waiting_for_space(&self.shared, &mut self.store, &scan, &reason)?;
                }
                self.disk_retry = Backoff::now().later();
                break;
            }
            step::begin(&self.shared, &mut self.store, id, step.index)?;
            let outcome = self.execute(id, &dir, &step.step);
            if let Err(StepError::Waiting(reason)) = &outcome {
                lock(&self.shared.hardware).arm.error = Some(reason.clone());
            }
            let flow = step::finish(
                &self.shared,
                &mut self.store,
                id,
                step.index,
                RUNNING,
                outcome,
            )?;
            // A captured bracket may be ready for processing.
            self.shared.processing_wake.post(|wake| *wake = true);
            if flow == Flow::Stop {
                break;
            }
        }
        Ok(())
    }

    /// Before a new bracket: waits while the processing lane has as many captured
    /// brackets left as the configuration allows (back-pressure), so a slow disk or
    /// CPU never lets them pile up. Returns whether scan `id` is still running.
    fn wait_for_processing(&mut self, id: i64) -> Result<bool, StoreError> {
        let limit = self.shared.config.processing.max_backlog;
        let mut noted = false;
        loop {
            let behind = self.store.unprocessed_brackets()?;
            if behind < limit {
                return Ok(true);
            }
            if !self.still_running(id)? {
                return Ok(false);
            }
            if !noted {
                tracing::info!("scan {id}: waiting for processing ({behind} brackets behind)");
                noted = true;
            }
            self.shared.hardware_wake.take(IDLE_POLL);
        }
    }

    /// The setup of a scan starting now: the calibrated one, else the configured one.
    fn setup(&self) -> Option<Setup> {
        calibration::current_setup(&self.shared.config.data_dir, self.setup.as_ref())
    }

    /// Creates the scan directory with setup.json, plan.json (and truth.json for emulated
    /// scans, of the scene of the plan's sample, whose levels its capture sidecars then
    /// carry).
    fn prepare_dir(&mut self, dir: &Path, plan: &ScanPlan) -> std::io::Result<()> {
        let scene = self.shared.mount.emulated_scene(&plan.sample);
        if let Some(scene) = scene.map_err(std::io::Error::other)? {
            let facts = SceneFacts::of(&scene).map_err(std::io::Error::other)?;
            self.setup = Some(facts.setup);
            self.truth = Some(facts.truth);
            self.sidecar = facts.sidecar;
        }
        std::fs::create_dir_all(dir)?;
        let files = [
            (
                "setup.json",
                calibration::current_setup_json(
                    &self.shared.config.data_dir,
                    self.setup.as_ref(),
                    self.setup_source,
                ),
            ),
            ("truth.json", self.truth.clone()),
            (
                gonio_processing::scan_plan::PLAN_FILE,
                serde_json::to_value(plan.folder_plan()).ok(),
            ),
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

    /// Executes one hardware step; returns its result and the steps it adds after
    /// itself.
    fn execute(&mut self, id: i64, dir: &Path, step: &Step) -> Outcome {
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
            Step::Samples { .. } | Step::Hdr { .. } | Step::Extract | Step::Fit { .. } => {
                return Err(StepError::Failed(format!(
                    "{} is not a hardware step",
                    step.describe()
                )))
            }
        };
        Ok((result, Vec::new()))
    }

    /// Meters θL and plans its bracket: a capture at a middle shutter (shortened while
    /// the strips clip), then the fewest allowed shutters that expose every strip pixel
    /// well ([`auto_bracket`]).
    fn meter(&mut self, id: i64, theta_l: f64) -> Outcome {
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
        self.place_for_capture(id, theta_l)?;
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
    /// the scan (the arm is reopened and re-homed once it answers), anything else
    /// fails it.
    ///
    /// With `home_first`, an arm whose position is unknown is homed before `op`.
    fn arm_op(
        &mut self,
        id: i64,
        what: &str,
        home_first: bool,
        op: impl FnMut(&mut dyn Arm) -> Result<(), DeviceError>,
    ) -> Result<(), StepError> {
        let result = self.try_arm(id, what, home_first, op);
        if let Err(StepError::Interrupted(reason)) = &result {
            self.disconnect_arm(reason);
        }
        if result.is_err() {
            // A reset, a homing or a reconnect may have moved the carousel.
            self.shared.carousel_moved();
            // Not `moving` or `homing` any more: what the controller says now.
            self.refresh_arm_status();
        }
        result
    }

    fn try_arm(
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
                self.at_deg = None;
                lock(&self.shared.hardware).arm.state = ArmState::Homing;
                let homed = arm.home();
                lock(&self.shared.hardware).arm.state = ArmState::Moving;
                // The homing cycle moves the carousel too.
                self.shared.carousel_moved();
                homed.and_then(|()| op(arm.as_mut()))
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
                    // The driver may have reset, re-homed or reopened the board.
                    self.shared.carousel_moved();
                    if self.shared.stops.load(Ordering::Acquire) != stops {
                        self.homed = false;
                        self.at_deg = None;
                        return self.halt_after_stop(id);
                    }
                    if let DeviceError::SettingsDiffer(settings) = &err {
                        let reason = err.to_string();
                        self.refuse_arm(settings.clone(), &reason);
                        return Err(StepError::Waiting(format!("{what}: {reason}")));
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
        self.shared.carousel_moved();
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
        self.at_deg = None;
        self.arm_busy(ArmState::Homing);
        let homed = self.arm_op(id, "home", false, |arm| arm.home());
        // The cycle homes the carousel too: it is turned back before the next capture.
        self.shared.carousel_moved();
        homed?;
        self.homed = true;
        self.at_deg = None;
        self.log(Some(id), "home", "")?;
        self.note_arm(None);
        Ok(())
    }

    fn move_to(&mut self, id: i64, theta_l: f64) -> Result<(), StepError> {
        self.at_deg = None;
        self.arm_busy(ArmState::Moving);
        self.arm_op(id, &format!("move to θL {theta_l:.1}°"), true, |arm| {
            arm.move_to(theta_l)
        })?;
        self.at_deg = Some(theta_l);
        self.log(Some(id), "move", &format!("{theta_l:.1}"))?;
        self.note_arm(Some(theta_l));
        Ok(())
    }

    /// Shows the arm `moving` or `homing` on `/api/hardware` until the operation ends.
    fn arm_busy(&self, state: ArmState) {
        let mut status = lock(&self.shared.hardware);
        status.arm.state = state;
        status.arm.error = None;
    }

    fn note_arm(&self, angle: Option<f64>) {
        let mut status = lock(&self.shared.hardware);
        status.arm.state = ArmState::Idle;
        status.arm.homed = self.homed;
        status.arm.error = None;
        status.arm.angle_deg = status.arm.shown_angle(angle.or(Some(0.0)));
    }

    /// Runs `op` on the camera with bounded retries of transient faults (busy, timeout,
    /// I/O). A camera that is gone (disconnected, not found) interrupts the scan until
    /// it is back.
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
                Err(err) if storage::says_disk_full(&err.to_string()) => {
                    // The camera did its part: the host's disk is full.
                    status.camera.state = "idle";
                    tracing::warn!("scan {id}: camera {what}: {err}");
                    return Err(StepError::Waiting(
                        self.shared.storage.full_reason(self.need),
                    ));
                }
                Err(err) => {
                    tracing::warn!("scan {id}: camera {what} (try {}): {err}", attempt + 1);
                    status.camera.state = camera_state_after(&err);
                    status.camera.error = Some(err.to_string());
                    if is_camera_gone(&err) {
                        self.camera_retry = Some(Backoff::now());
                        return Err(StepError::Interrupted(format!(
                            "camera {what}: {err}; waiting for the camera to come back"
                        )));
                    }
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
                self.place_for_capture(id, theta_l)?;
                self.camera_op(id, &format!("exposure for {what}"), |c| {
                    c.set_exposure(requested)
                })?;
                std::fs::create_dir_all(&frame_dir)
                    .map_err(|e| self.write_error(format!("{}: {e}", frame_dir.display())))?;
                let target = frame_dir.join(format!("{stem}.tiff"));
                let capture =
                    self.camera_op(id, &format!("capture {what}"), |c| c.capture_to(&target))?;
                self.log(Some(id), "capture", &what)?;
                (capture.path, capture.exposure)
            }
        };
        self.write_sidecar(&sidecar_path, exposure, theta_l)
            .map_err(|e| self.write_error(e))?;
        Ok(frame_result(dir, &image, false))
    }

    /// The step error of a write that failed with `message`: waiting for space when the
    /// disk is full, else a failure.
    fn write_error(&self, message: String) -> StepError {
        if storage::says_disk_full(&message) {
            tracing::warn!("{message}");
            StepError::Waiting(self.shared.storage.full_reason(self.need))
        } else {
            StepError::Failed(message)
        }
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
            aperture: None,
            width: None,
            height: None,
        };
        let text = serde_json::to_vec_pretty(&sidecar).map_err(|e| e.to_string())?;
        write_atomic(path, &text).map_err(|e| format!("{}: {e}", path.display()))
    }
}

/// Scan `scan` waits for disk space with `reason` (from the queue, or running, or
/// waiting with another reason; a scan waiting for space has its reason brought up to
/// date).
fn waiting_for_space(
    shared: &Shared,
    store: &mut Store,
    scan: &ScanRecord,
    reason: &str,
) -> Result<(), StoreError> {
    if scan.state == ScanState::Waiting && scan.error.as_deref() == Some(reason) {
        return Ok(());
    }
    let from = [ScanState::Queued, ScanState::Running, ScanState::Waiting];
    if store.transition(scan.id, &from, ScanState::Waiting, Some(reason))? {
        if !(scan.state == ScanState::Waiting
            && scan.error.as_deref().is_some_and(storage::is_disk_wait))
        {
            tracing::warn!("scan {}: waiting: {reason}", scan.id);
            store.log(shared.boot, Some(scan.id), "wait", reason)?;
        }
        shared.changed(scan.id);
    }
    Ok(())
}

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

/// A refused board's device path as it was when refused.
#[derive(Debug, Clone, Copy)]
struct Refusal {
    /// What the path named then.
    link: Option<LinkId>,
    /// The path was seen absent since (the board unplugged).
    unplugged: bool,
}

impl Refusal {
    /// Whether the board was unplugged and plugged in since the refusal, given what its
    /// path names `now`: the path went away and came back, or names another device.
    fn replugged(&mut self, now: Option<LinkId>) -> bool {
        match now {
            None => {
                self.unplugged = true;
                false
            }
            Some(now) => self.unplugged || self.link != Some(now),
        }
    }
}

/// Whether a camera error means the camera is gone (unplugged, switched off).
fn is_camera_gone(err: &DeviceError) -> bool {
    matches!(err, DeviceError::Disconnected(_) | DeviceError::NotFound(_))
}

/// The camera state shown after `err`.
fn camera_state_after(err: &DeviceError) -> &'static str {
    if is_camera_gone(err) {
        "disconnected"
    } else {
        "error"
    }
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
