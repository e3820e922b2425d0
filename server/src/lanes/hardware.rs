//! The hardware lane: one thread that owns the arm and the camera and only moves and
//! captures (docs/ARCHITECTURE.md, "Daemon"). It works through the hardware steps of
//! one scan at a time, recording each as started before the hardware is touched and
//! as done, with its result, afterwards; it waits before a new bracket while the
//! processing lane is too far behind.
//!
//! Here: the lane's state and its loop. Its moves, captures and metering, the states
//! of its devices and the waits of the scans it cannot go on with are in submodules.

use std::path::Path;
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::Duration;

use gonio_drivers::grbl::ArmAxis;
use gonio_drivers::{Arm, Camera, DeviceError};
use gonio_processing::geometry::Setup;
use serde_json::{json, Value};

use super::backoff::{Backoff, Failures};
use super::step::{self, Flow, Outcome, StepError};
use crate::calibration;
use crate::devices::{ArmOpener, Devices, LinkId, SceneFacts, SidecarDefaults};
use crate::files::write_atomic;
use crate::plan::{Lane, ScanPlan, Step};
use crate::shared::Shared;
use crate::storage;
use crate::store::{now_unix, ScanRecord, ScanState, Store, StoreError};
use crate::sync::lock;

/// How often the lane looks at the queue and the devices when nothing wakes it.
const IDLE_POLL: Duration = Duration::from_millis(500);

mod captures;
mod carousel;
mod device_link;
mod device_states;
mod metering;
mod moves;
mod requests;
mod scan_waits;

/// The scan states the hardware lane works in.
const RUNNING: &[ScanState] = &[ScanState::Running];

/// Where the carousel must be for the running scan: its sample's slot on `axis`
/// (aimed and reached in `carousel.rs`).
#[derive(Debug, Clone)]
struct CarouselTarget {
    axis: ArmAxis,
    slot: f64,
    sample: String,
}

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
        if self.shared.halted.load(Ordering::Acquire) {
            // An emergency stop holds the instrument until the operator goes on.
            self.refresh_arm_status();
            self.idle();
            return Ok(());
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
            let reason = crate::files::without_server_paths(
                &format!("preparing {}: {err}", dir.display()),
                &[&self.shared.config.data_dir],
            );
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
