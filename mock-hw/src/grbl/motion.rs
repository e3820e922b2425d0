//! Motion in time: trapezoidal velocity profiles and the planner queue the stepper
//! executes. All times are machine seconds (real seconds divided by the time scale).

use std::collections::VecDeque;

use super::report::N_AXIS;
use super::settings::AxisSettings;

/// Planner blocks the firmware buffers (`BLOCK_BUFFER_SIZE - 1`).
pub(crate) const PLANNER_BLOCKS: usize = 15;

/// Smallest rate (units/s) and acceleration (units/s²) used, so that a zero setting gives
/// a very slow but finite move instead of a division by zero.
const MIN_RATE: f64 = 1e-9;

/// A velocity profile along a straight path: accelerate from `v0` at `accel` to `peak`,
/// cruise, decelerate at `decel` to rest at `distance`. Units: machine units and seconds.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Profile {
    v0: f64,
    peak: f64,
    accel: f64,
    decel: f64,
    t_accel: f64,
    t_cruise: f64,
    t_decel: f64,
    distance: f64,
}

impl Profile {
    /// The fastest profile from speed `v0` to rest over `distance` with cruise speed at
    /// most `max_speed` and acceleration `accel`. When `v0` is too high to stop in
    /// `distance`, the profile decelerates harder to end at rest exactly there.
    pub fn new(distance: f64, v0: f64, max_speed: f64, accel: f64) -> Self {
        let distance = if distance.is_finite() {
            distance.max(0.0)
        } else {
            0.0
        };
        let v0 = if v0.is_finite() { v0.max(0.0) } else { 0.0 };
        let max_speed = max_speed.max(MIN_RATE);
        let accel = accel.max(MIN_RATE);
        if distance == 0.0 {
            return Profile {
                v0: 0.0,
                peak: 0.0,
                accel,
                decel: accel,
                t_accel: 0.0,
                t_cruise: 0.0,
                t_decel: 0.0,
                distance,
            };
        }
        if v0 * v0 >= 2.0 * accel * distance {
            // Only a (possibly harder) deceleration fits.
            return Profile {
                v0,
                peak: v0,
                accel,
                decel: v0 * v0 / (2.0 * distance),
                t_accel: 0.0,
                t_cruise: 0.0,
                t_decel: 2.0 * distance / v0,
                distance,
            };
        }
        // Triangle peak: (p² − v0²)/2a + p²/2a = d.
        let triangle_peak = (accel * distance + 0.5 * v0 * v0).sqrt();
        let peak = triangle_peak.min(max_speed).max(v0);
        let d_accel = (peak * peak - v0 * v0) / (2.0 * accel);
        let d_decel = peak * peak / (2.0 * accel);
        let d_cruise = (distance - d_accel - d_decel).max(0.0);
        Profile {
            v0,
            peak,
            accel,
            decel: accel,
            t_accel: (peak - v0) / accel,
            t_cruise: d_cruise / peak,
            t_decel: peak / accel,
            distance,
        }
    }

    /// Total time, s.
    pub fn duration(&self) -> f64 {
        self.t_accel + self.t_cruise + self.t_decel
    }

    /// Distance covered and speed at time `t` after the start.
    pub fn at(&self, t: f64) -> (f64, f64) {
        let t = t.max(0.0);
        if t >= self.duration() {
            return (self.distance, 0.0);
        }
        if t < self.t_accel {
            let v = self.v0 + self.accel * t;
            return (self.v0 * t + 0.5 * self.accel * t * t, v);
        }
        let s_accel = (self.v0 + self.peak) * 0.5 * self.t_accel;
        let t = t - self.t_accel;
        if t < self.t_cruise {
            return (s_accel + self.peak * t, self.peak);
        }
        let t = t - self.t_cruise;
        let s_cruise = self.peak * self.t_cruise;
        let s = s_accel + s_cruise + self.peak * t - 0.5 * self.decel * t * t;
        (s.min(self.distance), (self.peak - self.decel * t).max(0.0))
    }
}

/// One linear move in the planner queue: its machine-coordinate target and its requested
/// rate (units/min), to be limited by each axis' maximum rate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Block {
    pub target: [f64; N_AXIS],
    pub rate: f64,
}

/// The block the stepper is executing.
#[derive(Debug, Clone, Copy)]
struct ActiveMove {
    start: [f64; N_AXIS],
    target: [f64; N_AXIS],
    unit: [f64; N_AXIS],
    length: f64,
    max_speed: f64,
    accel: f64,
    /// Distance covered before `profile` began.
    covered: f64,
    profile: Profile,
    /// Machine time `profile` began.
    t0: f64,
    holding: bool,
}

impl ActiveMove {
    fn new(from: [f64; N_AXIS], block: &Block, axes: &[AxisSettings; N_AXIS], t0: f64) -> Self {
        let delta: Vec<f64> = (0..N_AXIS).map(|i| block.target[i] - from[i]).collect();
        let length = delta.iter().map(|d| d * d).sum::<f64>().sqrt();
        let mut unit = [0.0; N_AXIS];
        let mut max_speed = block.rate / 60.0;
        let mut accel = f64::INFINITY;
        for i in 0..N_AXIS {
            unit[i] = if length > 0.0 { delta[i] / length } else { 0.0 };
            let u = unit[i].abs();
            if u > 0.0 {
                max_speed = max_speed.min(axes[i].max_rate / 60.0 / u);
                accel = accel.min(axes[i].accel / u);
            }
        }
        if !accel.is_finite() {
            accel = MIN_RATE;
        }
        ActiveMove {
            start: from,
            target: block.target,
            unit,
            length,
            max_speed,
            accel,
            covered: 0.0,
            profile: Profile::new(length, 0.0, max_speed, accel),
            t0,
            holding: false,
        }
    }

    fn end_time(&self) -> f64 {
        self.t0 + self.profile.duration()
    }

    /// Distance along the block and speed at `now`.
    fn progress(&self, now: f64) -> (f64, f64) {
        let (s, v) = self.profile.at(now - self.t0);
        ((self.covered + s).min(self.length), v)
    }

    fn position_at(&self, distance: f64) -> [f64; N_AXIS] {
        let mut p = self.start;
        for (pi, ui) in p.iter_mut().zip(self.unit) {
            *pi += ui * distance;
        }
        p
    }
}

/// The planner queue and the stepper executing it. Blocks run stop to stop.
#[derive(Debug, Clone)]
pub(crate) struct Motion {
    queue: VecDeque<Block>,
    active: Option<ActiveMove>,
    /// Position when no block is active (machine units).
    rest: [f64; N_AXIS],
    /// Machine time the last block finished.
    rest_since: f64,
    /// A feed hold keeps queued blocks from starting.
    held: bool,
}

impl Motion {
    pub fn new(position: [f64; N_AXIS]) -> Self {
        Motion {
            queue: VecDeque::new(),
            active: None,
            rest: position,
            rest_since: 0.0,
            held: false,
        }
    }

    /// Machine time the last block finished (while idle).
    pub fn idle_since(&self) -> f64 {
        self.rest_since
    }

    /// Start `block` at machine time `t0` (which may be past) when nothing moves;
    /// [`Motion::update`] then finishes it if its time is up.
    pub fn start_at(&mut self, block: Block, t0: f64, axes: &[AxisSettings; N_AXIS]) {
        if self.is_idle() {
            self.active = Some(ActiveMove::new(self.rest, &block, axes, t0));
        } else {
            self.push(block);
        }
    }

    pub fn is_full(&self) -> bool {
        self.queue.len() + usize::from(self.active.is_some()) >= PLANNER_BLOCKS
    }

    /// Free planner blocks.
    pub fn available(&self) -> usize {
        PLANNER_BLOCKS.saturating_sub(self.queue.len() + usize::from(self.active.is_some()))
    }

    /// No block executing or queued.
    pub fn is_idle(&self) -> bool {
        self.active.is_none() && self.queue.is_empty()
    }

    pub fn push(&mut self, block: Block) {
        self.queue.push_back(block);
    }

    /// Advance to `now`: finish blocks whose time is up and start queued ones, back to
    /// back in machine time so loop jitter does not stretch the motion.
    pub fn update(&mut self, now: f64, axes: &[AxisSettings; N_AXIS]) {
        let mut t_free = now;
        loop {
            if let Some(active) = &self.active {
                if active.holding || now < active.end_time() {
                    return;
                }
                t_free = active.end_time();
                self.rest = active.target;
                self.rest_since = t_free;
                self.active = None;
            }
            if self.held {
                return;
            }
            let Some(block) = self.queue.pop_front() else {
                return;
            };
            self.active = Some(ActiveMove::new(self.rest, &block, axes, t_free.min(now)));
        }
    }

    /// Current position (machine units) and speed (units/s).
    pub fn state(&self, now: f64) -> ([f64; N_AXIS], f64) {
        match &self.active {
            Some(active) => {
                let (s, v) = active.progress(now);
                (active.position_at(s), v)
            }
            None => (self.rest, 0.0),
        }
    }

    /// Current velocity vector (units/s).
    pub fn velocity(&self, now: f64) -> [f64; N_AXIS] {
        match &self.active {
            Some(active) => {
                let (_, v) = active.progress(now);
                active.unit.map(|u| u * v)
            }
            None => [0.0; N_AXIS],
        }
    }

    /// Fraction of the active block covered, if one is executing.
    pub fn block_fraction(&self, now: f64) -> Option<f64> {
        self.active.as_ref().map(|a| {
            if a.length > 0.0 {
                a.progress(now).0 / a.length
            } else {
                1.0
            }
        })
    }

    /// Start a feed hold: decelerate at the block's acceleration to rest.
    pub fn hold(&mut self, now: f64) {
        self.held = true;
        if let Some(active) = &mut self.active {
            if active.holding {
                return;
            }
            let (s, v) = active.progress(now);
            let stop = (v * v / (2.0 * active.accel)).min(active.length - s);
            active.covered = s;
            active.profile = Profile::new(stop, v, v, active.accel);
            active.t0 = now;
            active.holding = true;
        }
    }

    /// The hold has brought the machine to rest.
    pub fn hold_complete(&self, now: f64) -> bool {
        match &self.active {
            Some(active) => !active.holding || now >= active.end_time(),
            None => true,
        }
    }

    /// Resume after a completed hold: accelerate again to finish the block.
    pub fn resume(&mut self, now: f64) {
        self.held = false;
        if let Some(active) = &mut self.active {
            if active.holding {
                let (s, _) = active.progress(now);
                active.covered = s;
                active.profile =
                    Profile::new(active.length - s, 0.0, active.max_speed, active.accel);
                active.t0 = now;
                active.holding = false;
            }
        }
    }

    /// Stop at once (steppers killed) and drop every queued block. Returns the position
    /// where the machine stopped.
    pub fn kill(&mut self, now: f64) -> [f64; N_AXIS] {
        let (position, _) = self.state(now);
        self.rest = position;
        self.rest_since = now;
        self.active = None;
        self.queue.clear();
        self.held = false;
        position
    }

    /// Set the position (homing, power-up) with nothing moving.
    pub fn set_position(&mut self, position: [f64; N_AXIS]) {
        self.active = None;
        self.queue.clear();
        self.held = false;
        self.rest = position;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn trapezoid_and_triangle_durations() {
        // 90 units at 10 u/s, 5 u/s²: 2 s ramps (10 u each), 70 u cruise (7 s).
        let p = Profile::new(90.0, 0.0, 10.0, 5.0);
        assert!((p.duration() - 11.0).abs() < 1e-12);
        assert_eq!(p.at(1.0), (2.5, 5.0));
        assert_eq!(p.at(11.0), (90.0, 0.0));
        let (s_mid, v_mid) = p.at(5.5);
        assert!((s_mid - 45.0).abs() < 1e-9 && v_mid == 10.0);
        // 10 units: triangle with peak √50.
        let p = Profile::new(10.0, 0.0, 10.0, 5.0);
        assert!((p.duration() - 2.0 * 50f64.sqrt() / 5.0).abs() < 1e-12);
    }

    #[test]
    fn hold_decelerates_and_resume_finishes_the_block() {
        let mut axes = [AxisSettings {
            steps_per_unit: 100.0,
            max_rate: 600.0,
            accel: 5.0,
            max_travel: 200.0,
        }; N_AXIS];
        axes[1].max_rate = 1.0;
        let mut motion = Motion::new([0.0; N_AXIS]);
        motion.push(Block {
            target: [-90.0, 0.0, 0.0],
            rate: 6000.0,
        });
        motion.update(0.0, &axes);
        motion.hold(5.5);
        assert!(!motion.hold_complete(5.5));
        // From 10 u/s: 2 s and 10 units to stop.
        assert!(motion.hold_complete(7.5));
        let (p, v) = motion.state(8.0);
        assert!((p[0] + 55.0).abs() < 1e-9 && v == 0.0);
        motion.resume(8.0);
        // 35 units left: 2 s ramps (10 units each) and 1.5 s cruise.
        motion.update(13.4, &axes);
        assert!(!motion.is_idle());
        motion.update(13.6, &axes);
        assert!(motion.is_idle());
        assert_eq!(motion.state(100.0).0, [-90.0, 0.0, 0.0]);
    }
}
