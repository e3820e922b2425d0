//! The [`Arm`] operations of [`GrblArm`]: homing, moves, status, clearing a fault,
//! declaring the position, the emergency stop and the live angle.

use std::sync::Arc;

use super::session::{AngleWatch, Patience, SOFT_RESET};
use super::{move_time_s, ArmAxis, GrblArm, Homing, MachineState, Reference, Settings};
use crate::{Arm, ArmState, ArmStatus, DeviceError, EmergencyStop, LiveAngle};

impl Arm for GrblArm {
    /// Reference the arm: the homing cycle (`$H`) where the controller homes, refused
    /// while an alarm is latched (clear it first); where it does not, the position an
    /// operator declared, else [`DeviceError::PositionUnknown`].
    fn home(&mut self) -> Result<(), DeviceError> {
        self.prepare()?;
        self.latched_alarm()?;
        if !self.homes() {
            return self.check_ready();
        }
        self.run_homing()
    }

    fn move_to(&mut self, angle_deg: f64) -> Result<(), DeviceError> {
        let (min, max) = (self.config.min_deg, self.config.max_deg);
        if !(angle_deg.is_finite() && (min..=max).contains(&angle_deg)) {
            return Err(DeviceError::OutOfRange {
                what: "arm angle (degrees)".into(),
                value: angle_deg,
                min,
                max,
            });
        }
        self.prepare()?;
        self.check_ready()?;
        let start = self.query_status()?;
        self.check_ready()?;
        let from = start
            .work(self.axis(), self.known_wco())
            .unwrap_or(self.last_angle_deg);
        let expected = self.move_timeout(angle_deg - from);
        let reply = self.config.reply_timeout;
        let line = format!("G90 G0 {}{angle_deg:.3}", self.config.axis.letter());
        self.retrying(|arm| arm.command(&line, Patience::Reply(reply)))?;
        // `G4 P0` is answered once the planner has finished the move; the status
        // reports asked for meanwhile keep the live angle current.
        let patience = self.motion_patience(expected);
        self.session.watch(AngleWatch {
            angle: self.live.clone(),
            axis: self.axis(),
            known_wco: self.known_wco(),
        });
        let finished = self.retrying(|arm| arm.command("G4 P0", patience));
        self.session.unwatch();
        finished?;
        let report = self.query_status()?;
        let at = report
            .work(self.axis(), self.known_wco())
            .unwrap_or(f64::NAN);
        let on_target = (at - angle_deg).abs() <= self.config.position_tolerance_deg;
        if report.state != MachineState::Idle || !on_target {
            return Err(DeviceError::Protocol(format!(
                "after moving to {angle_deg:.3}° the controller reports {:?} at {at:.3}°",
                report.state
            )));
        }
        Ok(())
    }

    /// `G90 G53 G0` on `axis` (machine coordinates: the work offset the driver sets is
    /// the arm's), then `G4 P0`, and the position read back.
    fn move_axis(&mut self, axis: ArmAxis, position: f64) -> Result<(), DeviceError> {
        if axis == self.config.axis {
            return Err(DeviceError::Refused(format!(
                "the {} axis is the arm's",
                axis.letter()
            )));
        }
        let i = axis.index();
        let travel = self.settings.get(Settings::MAX_TRAVEL + i as u32);
        let min = -travel.unwrap_or(f64::INFINITY);
        if !(position.is_finite() && (min..=0.0).contains(&position)) {
            return Err(DeviceError::OutOfRange {
                what: format!("{} axis position", axis.letter()),
                value: position,
                min,
                max: 0.0,
            });
        }
        self.prepare()?;
        self.check_ready()?;
        let start = self.query_status()?;
        self.check_ready()?;
        let from = start.machine(i, self.known_wco()).unwrap_or(0.0);
        let rate = self.settings.get(Settings::MAX_RATE + i as u32);
        let accel = self.settings.get(Settings::ACCEL + i as u32);
        let expected = self.motion_time(move_time_s(
            position - from,
            rate.unwrap_or(0.0),
            accel.unwrap_or(0.0),
        ));
        let reply = self.config.reply_timeout;
        let line = format!("G90 G53 G0 {}{position:.3}", axis.letter());
        self.retrying(|arm| arm.command(&line, Patience::Reply(reply)))?;
        let patience = self.motion_patience(expected);
        self.retrying(|arm| arm.command("G4 P0", patience))?;
        let report = self.query_status()?;
        let at = report.machine(i, self.known_wco()).unwrap_or(f64::NAN);
        if report.state != MachineState::Idle
            || (at - position).abs() > self.config.position_tolerance_deg
        {
            return Err(DeviceError::Protocol(format!(
                "after moving the {} axis to {position:.3} the controller reports {:?} at {at:.3}",
                axis.letter(),
                report.state
            )));
        }
        Ok(())
    }

    fn homes(&self) -> bool {
        GrblArm::homes(self)
    }

    /// `$13N` of `axis` as last read.
    fn axis_travel(&self, axis: ArmAxis) -> Option<f64> {
        self.settings
            .get(Settings::MAX_TRAVEL + axis.index() as u32)
    }

    fn status(&mut self) -> Result<ArmStatus, DeviceError> {
        self.prepare()?;
        let report = self.query_status()?;
        let state = match report.state {
            _ if self.alarm.is_some() => ArmState::Alarm,
            MachineState::Home => ArmState::Homing,
            MachineState::Run | MachineState::Jog => ArmState::Moving,
            MachineState::Hold | MachineState::Door => ArmState::Hold,
            _ if self.reference.is_none() && self.homes() => ArmState::NeedsHoming,
            _ if self.reference.is_none() => ArmState::NeedsPosition,
            MachineState::Alarm => ArmState::Alarm,
            MachineState::Idle | MachineState::Check | MachineState::Sleep => ArmState::Idle,
        };
        Ok(ArmStatus {
            state,
            angle_deg: self.last_angle_deg,
        })
    }

    /// Soft reset, wait for the banner, forget the alarm; the arm must then be homed or
    /// declared again.
    fn clear_fault(&mut self) -> Result<(), DeviceError> {
        self.prepare()?;
        self.session.realtime(SOFT_RESET)?;
        let greeted = self.session.await_banner(self.config.banner_timeout)?;
        self.session.take_seen();
        if !greeted {
            return Err(DeviceError::Timeout {
                what: format!("GRBL banner after soft reset on {}", self.path.display()),
                seconds: self.config.banner_timeout.as_secs_f64(),
            });
        }
        self.alarm = None;
        self.reference = None;
        Ok(())
    }

    /// `$X` if locked, then `G92` so the arm's angle is `angle_deg`; refused where the
    /// arm is homed ([`Homing::Required`]) or while it moves.
    fn declare_position(&mut self, angle_deg: f64) -> Result<(), DeviceError> {
        if self.config.homing == Homing::Required {
            return Err(DeviceError::Refused(
                "homing is required: the homing cycle references the arm, a declared \
                 position is not accepted"
                    .into(),
            ));
        }
        // The arm is somewhere on its travel: [−$130, 0], the switch at 0.
        let (min, max) = (-self.config.max_travel_deg, 0.0);
        if !(angle_deg.is_finite() && (min..=max).contains(&angle_deg)) {
            return Err(DeviceError::OutOfRange {
                what: "declared arm angle (degrees, on the travel)".into(),
                value: angle_deg,
                min,
                max,
            });
        }
        self.prepare()?;
        if self.alarm.is_some() {
            self.clear_fault()?;
        }
        let report = self.query_status()?;
        match report.state {
            MachineState::Alarm => {
                self.command("$X", Patience::Reply(self.config.reply_timeout))?;
            }
            MachineState::Idle => {}
            state => {
                return Err(DeviceError::Refused(format!(
                    "the controller is {state:?}: declare the position at rest"
                )))
            }
        }
        let wco = self.set_work_position(angle_deg)?;
        self.reference = Some(Reference::Declared { wco });
        Ok(())
    }

    fn emergency_stop(&self) -> Arc<dyn EmergencyStop> {
        self.stop.clone()
    }

    fn live_angle(&self) -> LiveAngle {
        self.live.clone()
    }
}
