//! The arm's device path as the hardware lane sees it (server/src/lanes/hardware.md, "Device
//! faults"): the driver is let go as soon as the path vanishes (unplugged) or names
//! another device (plugged in again), and nothing is opened while it is absent, so the
//! arm is reopened the moment it is back rather than after a grown backoff. Only the
//! path is looked at: opening resets the board.

use gonio_drivers::ArmState;

use super::HardwareLane;
use crate::lanes::arm_watch;
use crate::lanes::backoff::Backoff;
use crate::store::StoreError;
use crate::sync::lock;

impl HardwareLane {
    /// Lets the driver go when the arm's device path vanished (unplugged) or names
    /// another device (plugged in again meanwhile): the arm is shown disconnected and
    /// reopened as soon as the path is back. Only looks at the path.
    pub(super) fn check_arm_link(&mut self) {
        if self.arm.is_none() {
            return;
        }
        let now = self.opener.link();
        if now == self.arm_link {
            return;
        }
        let reason = match now {
            None => arm_watch::gone_reason(self.opener.path()),
            Some(_) => format!("{}: plugged in again", self.opener.path().display()),
        };
        tracing::warn!("arm: {reason}; reconnecting");
        self.disconnect_arm(&reason);
        self.arm_error = Some(reason);
        self.arm_retry = Backoff::now();
    }

    /// Whether the arm's device path is absent (unplugged): then it is shown
    /// disconnected and not opened; once it is back, it is opened at once.
    pub(super) fn arm_device_absent(&mut self) -> Result<bool, StoreError> {
        if self.opener.link().is_some() {
            if std::mem::take(&mut self.arm_absent) {
                self.arm_retry = Backoff::now();
            }
            return Ok(false);
        }
        let reason = arm_watch::gone_reason(self.opener.path());
        if !self.arm_absent {
            tracing::warn!("arm: {reason}");
            self.log(None, "connect failed", &reason)?;
        }
        self.arm_absent = true;
        self.arm_error = Some(reason.clone());
        let mut status = lock(&self.shared.hardware);
        status.arm.state = ArmState::Disconnected;
        status.arm.angle_deg = None;
        status.arm.error = Some(reason);
        Ok(true)
    }
}
