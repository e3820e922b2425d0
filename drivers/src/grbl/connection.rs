//! Connecting to the controller: opening the port, the banner handshake, reading `$I`
//! and `$$`, checking (or writing) the settings, and reopening a lost port with bounded
//! exponential backoff.

use std::thread;

use super::expected::{self, Mismatch};
use super::link::Link;
use super::session::{Patience, SOFT_RESET};
use super::{GrblArm, Line, Settings};
use crate::DeviceError;

impl GrblArm {
    pub(super) fn connect(&mut self) -> Result<(), DeviceError> {
        let (link, clone) = Link::open(&self.path)?;
        self.session.attach(link);
        self.stop.replace(Some(clone));
        self.reference = None;
        self.alarm = None;
        let result = self.handshake();
        if result.is_err() {
            self.disconnect();
        }
        result
    }

    fn disconnect(&mut self) {
        self.session.detach();
        self.stop.replace(None);
        self.reference = None;
    }

    fn handshake(&mut self) -> Result<(), DeviceError> {
        // Opening resets an Arduino-based board; anything else gets a soft reset.
        if !self.session.await_banner(self.config.banner_timeout)? {
            self.session.realtime(SOFT_RESET)?;
            if !self.session.await_banner(self.config.banner_timeout)? {
                return Err(DeviceError::Timeout {
                    what: format!("GRBL banner from {}", self.path.display()),
                    seconds: 2.0 * self.config.banner_timeout.as_secs_f64(),
                });
            }
        }
        self.session.take_seen();
        let reply = self.config.reply_timeout;
        self.firmware = self.retrying(|arm| {
            let lines = arm.session.command("$I", Patience::Reply(reply))?;
            lines
                .iter()
                .find_map(|l| match l {
                    Line::Feedback(f) => f.strip_prefix("VER:").map(str::to_owned),
                    _ => None,
                })
                .ok_or_else(|| DeviceError::Protocol("no [VER:…] in the reply to $I".into()))
        })?;
        self.read_settings()?;
        let mismatches = expected::mismatches(&self.settings, &self.config);
        if mismatches.is_empty() {
            return Ok(());
        }
        let fixes: Option<Vec<String>> = mismatches.iter().map(Mismatch::fix).collect();
        match fixes {
            Some(fixes) if self.config.apply_settings => self.apply(&fixes),
            _ => Err(refusal(&mismatches)),
        }
    }

    /// `$$`, read again while settings the checks need are missing (a garbled line).
    fn read_settings(&mut self) -> Result<(), DeviceError> {
        let reply = self.config.reply_timeout;
        let axis = self.axis() as u32;
        self.settings = self.retrying(|arm| {
            let lines = arm.session.command("$$", Patience::Reply(reply))?;
            let settings = Settings::from_lines(&lines);
            let needed = [
                Settings::HOMING_ENABLE,
                Settings::STEPS_PER_UNIT + axis,
                Settings::MAX_RATE + axis,
                Settings::ACCEL + axis,
                Settings::MAX_TRAVEL + axis,
            ];
            match needed.iter().find(|&&k| settings.get(k).is_none()) {
                Some(key) => Err(DeviceError::Protocol(format!("${key} missing from $$"))),
                None => Ok(settings),
            }
        })?;
        Ok(())
    }

    /// Write `$N=value` lines, then verify with `$$`.
    fn apply(&mut self, fixes: &[String]) -> Result<(), DeviceError> {
        for fix in fixes {
            self.session
                .command(fix, Patience::Reply(self.config.reply_timeout))?;
        }
        self.read_settings()?;
        let left = expected::mismatches(&self.settings, &self.config);
        if left.is_empty() {
            Ok(())
        } else {
            Err(refusal(&left))
        }
    }

    /// Reopen the port if it was lost, with bounded exponential backoff.
    pub(super) fn ensure_connected(&mut self) -> Result<(), DeviceError> {
        if self.session.connected() {
            return Ok(());
        }
        self.disconnect();
        let mut backoff = self.config.reconnect_backoff;
        let attempts = self.config.reconnect_attempts.max(1);
        let mut last = DeviceError::Disconnected("not connected".into());
        for attempt in 0..attempts {
            if attempt > 0 {
                thread::sleep(backoff);
                backoff = (backoff * 2).min(self.config.reconnect_backoff * 16);
            }
            match self.connect() {
                Ok(()) => return Ok(()),
                // A controller that answers but is refused will not get better.
                Err(
                    e @ (DeviceError::Refused(_)
                    | DeviceError::SettingsDiffer(_)
                    | DeviceError::Protocol(_)),
                ) => return Err(e),
                Err(e) => last = e,
            }
        }
        Err(DeviceError::Disconnected(format!(
            "{}: reconnect failed after {attempts} attempts: {last}",
            self.path.display()
        )))
    }
}

/// The refusal listing each differing setting on its own line.
fn refusal(mismatches: &[Mismatch]) -> DeviceError {
    DeviceError::SettingsDiffer(mismatches.iter().map(ToString::to_string).collect())
}
