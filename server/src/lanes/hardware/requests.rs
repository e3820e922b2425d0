//! The operator's requests to the arm that the hardware lane carries out between scans
//! (docs/ARCHITECTURE.md, "HTTP API"): a declared position (`POST /api/arm/position`)
//! and homing (`POST /api/arm/home`), which first clears an alarm (soft reset) the way
//! an operator expects.

use std::sync::atomic::Ordering;

use gonio_drivers::{ArmState, DeviceError};

use super::HardwareLane;
use crate::store::StoreError;
use crate::sync::lock;

impl HardwareLane {
    /// Applies an operator's declared arm position, if one is pending, and answers it.
    pub(super) fn answer_position_request(&mut self) -> Result<(), StoreError> {
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

    /// Homes the arm if the operator asked (`POST /api/arm/home`); the lane only looks
    /// between scans, so no scan's step is under way. An alarm (after an emergency stop
    /// or a failed homing) is cleared first with a soft reset; the hardware log says what
    /// was done (`home`: `asked by the operator: alarm cleared (soft reset), then $H`).
    /// A homing that succeeds ends an emergency stop's hold; an emergency stop meanwhile
    /// abandons it, before any command it has not sent yet.
    pub(super) fn answer_home_request(&mut self) -> Result<(), StoreError> {
        // Read before the request is taken: a stop between the two would otherwise go
        // unseen (it clears a request only while it is still there).
        let stops = self.shared.stops.load(Ordering::Acquire);
        if !self.shared.home_requested.swap(false, Ordering::AcqRel) {
            return Ok(());
        }
        let stopped = || self.shared.stops.load(Ordering::Acquire) != stops;
        let Some(arm) = self.arm.as_mut() else {
            return self.log(None, "home refused", "arm not connected");
        };
        let in_alarm = matches!(arm.status(), Ok(s) if s.state == ArmState::Alarm);
        {
            let mut status = lock(&self.shared.hardware);
            status.arm.state = ArmState::Homing;
            status.arm.error = None;
        }
        let mut done = Vec::new();
        let mut result = Ok(());
        if in_alarm && !stopped() {
            result = arm.clear_fault();
            done.push("alarm cleared (soft reset)");
        }
        if result.is_ok() && !stopped() {
            result = arm.home();
            if matches!(
                result,
                Err(DeviceError::Alarm { .. } | DeviceError::HomingFailed { .. })
            ) && !in_alarm
                && !stopped()
            {
                // An alarm the status did not show yet: clear it and home once more.
                result = arm.clear_fault().and_then(|()| arm.home());
                done.push("alarm cleared (soft reset)");
            }
            done.push("$H");
        }
        let abandoned = stopped();
        self.at_deg = None;
        // The homing cycle (and a soft reset) move the carousel.
        self.shared.carousel_moved();
        let what = format!("asked by the operator: {}", done.join(", then "));
        match result {
            // The stop's reset may have cut the cycle short: the position is not known.
            _ if abandoned => {
                tracing::warn!("homing asked by the operator: abandoned, emergency stop");
                self.homed = false;
                self.log(None, "home abandoned", &format!("{what}: emergency stop"))?;
                self.refresh_arm_status();
            }
            Ok(()) => {
                self.homed = true;
                self.shared.end_hold();
                self.log(None, "home", &what)?;
                self.note_arm(None);
                self.requeue_waiting("arm homed")?;
            }
            Err(err) => {
                tracing::warn!("homing asked by the operator: {err}");
                self.homed = false;
                self.log(None, "home failed", &format!("{what}: {err}"))?;
                lock(&self.shared.hardware).arm.error = Some(format!("homing failed: {err}"));
                self.refresh_arm_status();
            }
        }
        Ok(())
    }
}
