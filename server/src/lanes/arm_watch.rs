//! Watches the arm's device path beside the hardware lane (server/src/lanes/hardware.md,
//! "Device faults"): whatever the lane is doing (a long move, a homing cycle, waiting
//! for the processing lane), an arm whose device is gone (unplugged) is shown
//! `disconnected` on `/api/hardware` within a poll. The path is looked at, never
//! opened (opening resets the board); the lane lets the driver go and reopens the arm
//! once it is back.

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use anyhow::Context;
use gonio_drivers::ArmState;

use crate::devices::LinkId;
use crate::shared::Shared;
use crate::sync::lock;

/// How often the device path is looked at.
pub const WATCH_INTERVAL: Duration = Duration::from_millis(250);

/// Why an arm whose device path vanished is shown disconnected.
pub fn gone_reason(path: &std::path::Path) -> String {
    format!("{}: the device is gone (unplugged)", path.display())
}

/// Starts the watch on `path` for the daemon's life.
pub fn spawn(shared: Arc<Shared>, path: PathBuf) -> anyhow::Result<()> {
    std::thread::Builder::new()
        .name("arm-device-watch".into())
        .spawn(move || loop {
            std::thread::sleep(WATCH_INTERVAL);
            if LinkId::of(&path).is_some() {
                continue;
            }
            let mut status = lock(&shared.hardware);
            if status.arm.state != ArmState::Disconnected {
                status.arm.state = ArmState::Disconnected;
                status.arm.homed = false;
                status.arm.angle_deg = None;
                status.arm.error = Some(gone_reason(&path));
            }
        })
        .context("starting the arm device watch")?;
    Ok(())
}
