//! The one emulated world: the arm's angle, which is where the light is.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

/// Shared between the GRBL emulator (which moves the arm) and the camera emulator
/// (which renders the light where the arm currently is). Cheap to clone.
#[derive(Debug, Clone, Default)]
pub struct World {
    arm_deg_bits: Arc<AtomicU64>,
}

impl World {
    pub fn new(arm_deg: f64) -> Self {
        let world = Self::default();
        world.set_arm_deg(arm_deg);
        world
    }

    /// Current arm (light) angle θL in degrees.
    pub fn arm_deg(&self) -> f64 {
        f64::from_bits(self.arm_deg_bits.load(Ordering::Acquire))
    }

    pub fn set_arm_deg(&self, deg: f64) {
        self.arm_deg_bits.store(deg.to_bits(), Ordering::Release);
    }
}
