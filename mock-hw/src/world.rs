//! The one emulated world: the arm's angle, which is where the light is, and where the
//! board's other axes (a sample carousel) physically are.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

/// Axes of the emulated board (X, Y, Z).
const AXES: usize = 3;

/// Shared between the GRBL emulator (which moves the arm and the other axes) and the
/// camera emulator (which renders the light where the arm currently is, and the sample
/// a carousel holds before it). Cheap to clone.
#[derive(Debug, Clone)]
pub struct World {
    arm_deg_bits: Arc<AtomicU64>,
    /// Each axis' physical position (its units, 0 at its homing switch, the machine
    /// position once homed); NaN until the board places it.
    axis_bits: Arc<[AtomicU64; AXES]>,
}

impl Default for World {
    fn default() -> Self {
        Self {
            arm_deg_bits: Arc::new(AtomicU64::new(0.0f64.to_bits())),
            axis_bits: Arc::new(std::array::from_fn(|_| AtomicU64::new(f64::NAN.to_bits()))),
        }
    }
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

    /// Physical position of axis `index` (0 = X), 0 at its switch; NaN until the board
    /// placed it, and for an index beyond Z.
    pub fn axis(&self, index: usize) -> f64 {
        self.axis_bits.get(index).map_or(f64::NAN, |bits| {
            f64::from_bits(bits.load(Ordering::Acquire))
        })
    }

    /// Sets the physical position of axis `index` (ignored beyond Z).
    pub fn set_axis(&self, index: usize, position: f64) {
        if let Some(bits) = self.axis_bits.get(index) {
            bits.store(position.to_bits(), Ordering::Release);
        }
    }
}
