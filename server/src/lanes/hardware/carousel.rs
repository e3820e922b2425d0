//! The sample carousel (server/src/lanes/hardware.md, "Sample carousel"): which sample the
//! running scan needs before the camera, and turning the carousel there before each
//! capture. Anything that may have moved the carousel (a homing cycle, a reset, an
//! emergency stop, a reconnect, a failed arm operation) forgets which sample is in
//! place, so the next capture turns it back first.

use gonio_drivers::ArmState;

use super::{CarouselTarget, HardwareLane};
use crate::lanes::step::{self, StepError};
use crate::store::StoreError;

/// Rounds of "arm to θL, carousel to its slot" before a capture gives up: each round
/// only repeats when putting one in place moved the other (a re-homing).
const PLACING_ROUNDS: usize = 3;

impl HardwareLane {
    /// With a carousel: aims it at the slot of scan `id`'s `sample` (turned before the
    /// scan's first capture, after its homing); a sample without a slot fails the scan.
    /// Returns whether the scan goes on.
    pub(super) fn aim_carousel(&mut self, id: i64, sample: &str) -> Result<bool, StoreError> {
        let carousel = self.shared.config.carousel.as_ref();
        let Some((axis, slot)) = carousel.map(|c| (c.axis(), c.slot(sample))) else {
            self.carousel = None;
            return Ok(true);
        };
        let Some(slot) = slot else {
            let reason = format!("the carousel has no slot for sample {sample}");
            step::stop(
                &self.shared,
                &mut self.store,
                id,
                super::RUNNING,
                StepError::Failed(reason),
            )?;
            return Ok(false);
        };
        self.carousel = Some(CarouselTarget {
            axis,
            slot,
            sample: sample.to_owned(),
        });
        Ok(true)
    }

    /// Before a capture: the arm at `theta_l` and, with a carousel, the scan's sample
    /// before the camera, whichever moved the other last.
    pub(super) fn place_for_capture(&mut self, id: i64, theta_l: f64) -> Result<(), StepError> {
        for _ in 0..PLACING_ROUNDS {
            if !self.homed || self.at_deg != Some(theta_l) {
                self.move_to(id, theta_l)?;
            }
            self.turn_carousel(id)?;
            if self.homed && self.at_deg == Some(theta_l) && self.sample_in_place() {
                return Ok(());
            }
        }
        Err(StepError::Failed(format!(
            "the arm at θL {theta_l:.1}° and the carousel at its slot: one kept moving the \
             other ({PLACING_ROUNDS} tries)"
        )))
    }

    /// Whether the running scan's sample is known to be before the camera (always, without
    /// a carousel: the operator confirmed it).
    fn sample_in_place(&self) -> bool {
        self.carousel
            .as_ref()
            .is_none_or(|t| self.shared.mount.is_mounted(&t.sample))
    }

    /// Turns the carousel to the running scan's slot unless its sample is known to be
    /// there (homing first if the arm is not referenced), and records it as mounted.
    fn turn_carousel(&mut self, id: i64) -> Result<(), StepError> {
        let Some(target) = self.carousel.clone().filter(|_| !self.sample_in_place()) else {
            return Ok(());
        };
        let CarouselTarget { axis, slot, sample } = target;
        let what = format!("turn the carousel to sample {sample}");
        self.arm_busy(ArmState::Moving);
        self.arm_op(id, &what, true, |arm| arm.move_axis(axis, slot))?;
        self.note_arm(self.at_deg);
        self.shared
            .mount
            .mount(&sample)
            .map_err(|e| StepError::Failed(format!("{what}: {e:#}")))?;
        self.log(
            Some(id),
            "carousel",
            &format!("sample {sample} at {} {slot:.3}", axis.letter()),
        )?;
        Ok(())
    }
}
