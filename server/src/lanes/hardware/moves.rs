//! The arm's moves: homing and moving to θL through bounded retries with backoff (a
//! reset or an alarm cleared and the arm homed again before the next try, an emergency
//! stop halting at once, a lost connection interrupting the scan), the arm shown
//! `homing` or `moving` on `/api/hardware` meanwhile.

use std::sync::atomic::Ordering;
use std::time::Duration;

use gonio_drivers::{Arm, ArmState, DeviceError};

use super::{backoff, HardwareLane};
use crate::lanes::step::StepError;
use crate::shared::EMERGENCY_STOP;
use crate::store::ScanState;
use crate::sync::lock;

impl HardwareLane {
    /// Runs `op` on the arm with bounded retries. Transient faults back off and retry;
    /// a reset or alarm is cleared and the arm re-homed before the next try; a stop
    /// by the operator halts at once. A dead connection after the last try interrupts
    /// the scan (the arm is reopened and re-homed once it answers), anything else
    /// fails it.
    ///
    /// With `home_first`, an arm whose position is unknown is homed before `op`.
    pub(super) fn arm_op(
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

    pub(super) fn home(&mut self, id: i64) -> Result<(), StepError> {
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

    pub(super) fn move_to(&mut self, id: i64, theta_l: f64) -> Result<(), StepError> {
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
    pub(super) fn arm_busy(&self, state: ArmState) {
        let mut status = lock(&self.shared.hardware);
        status.arm.state = state;
        status.arm.error = None;
    }

    pub(super) fn note_arm(&self, angle: Option<f64>) {
        let mut status = lock(&self.shared.hardware);
        status.arm.state = ArmState::Idle;
        status.arm.homed = self.homed;
        status.arm.error = None;
        status.arm.angle_deg = status.arm.shown_angle(angle.or(Some(0.0)));
    }
}

/// Whether an arm error that outlasted the retries means the connection is gone
/// (rather than a refusal).
fn is_connection_loss(err: &DeviceError) -> bool {
    matches!(err, DeviceError::Io(_) | DeviceError::Timeout { .. })
}
