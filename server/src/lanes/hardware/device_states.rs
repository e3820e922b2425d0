//! The devices as the hardware lane keeps them (docs/ARCHITECTURE.md, "Device
//! faults"): the camera looked for and identified, the arm opened at most once per
//! backoff period (a refused board only when the operator asks or it is plugged in
//! again), its status refreshed, and the arm let go when it is disconnected or refused;
//! `/api/hardware` shows the state each is in.

use std::sync::atomic::Ordering;

use gonio_drivers::{ArmState, DeviceError};

use super::{camera_state_after, HardwareLane, Refusal};
use crate::lanes::backoff::Backoff;
use crate::store::StoreError;
use crate::sync::lock;

impl HardwareLane {
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
    pub(super) fn connect_camera(&mut self) -> Result<bool, StoreError> {
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

    /// Opens the arm, at most once per backoff period (at once when the operator asks);
    /// a refused board only when the operator asks or it was plugged in again. On
    /// success, interrupted scans go back to running (at the next pass) and waiting
    /// ones to the queue. Returns whether the arm is connected.
    pub(super) fn connect_arm(&mut self) -> Result<bool, StoreError> {
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

    pub(super) fn refresh_arm_status(&mut self) {
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

    pub(super) fn disconnect_arm(&mut self, reason: &str) {
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
    pub(super) fn refuse_arm(&mut self, settings: Vec<String>, reason: &str) {
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
}
