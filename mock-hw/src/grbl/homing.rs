//! The homing cycle as GRBL 1.1h's `limits_go_home` runs it, planned phase by phase:
//! for each compile-time cycle (stock: Z, then X and Y together) seek the switches at the
//! seek rate, pull off, locate them again at the feed rate, pull off again, with the
//! debounce delay after each phase. Where the switches are is known, so each phase's
//! end and outcome are computed when it starts. Timing is that of one move per phase
//! (the firmware stops each axis dead at its switch); positions and outcomes are exact.

use super::motion;
use super::report::{alarm, N_AXIS};
use super::settings::Settings;

/// Homing gives up after this multiple of the largest max travel of the cycle's axes.
const SEARCH_SCALAR: f64 = 1.5;
/// The locate approach searches this multiple of the pull-off distance.
const LOCATE_SCALAR: f64 = 5.0;
/// Phases per cycle: seek, pull-off, locate, pull-off (N_HOMING_LOCATE_CYCLE = 1).
const PHASES: usize = 4;

/// Where the homing switches are: the machine position at which each axis' switch
/// closes (pressed at and above it), or `None` where no switch is wired.
pub(crate) type Switches = [Option<f64>; N_AXIS];

/// Whether each axis presses its switch at `position`.
pub(crate) fn pressed(switches: &Switches, position: &[f64; N_AXIS]) -> [bool; N_AXIS] {
    std::array::from_fn(|i| switches[i].is_some_and(|at| position[i] >= at))
}

/// The phase being run and what follows it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Phase {
    /// Index into the cycles, and phase within the cycle (0..4).
    cycle: usize,
    step: usize,
    /// The alarm this phase ends in, known when it starts.
    pub fails: Option<u8>,
    /// Machine time the phase started (set by the controller).
    pub started_at: f64,
}

/// What the controller does next in a homing cycle.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum Next {
    /// Run this phase: move to `block` (if it moves at all), then call [`after`] once
    /// the debounce delay has passed.
    Run(Phase, Option<motion::Block>),
    /// Every cycle done: set these axes (bit mask) to MPos −pull-off.
    Homed { mask: u8, position: [f64; N_AXIS] },
}

/// The first phase of homing with `cycles` (axis bit masks, X = 1).
pub(crate) fn start(
    cycles: &[u8],
    position: [f64; N_AXIS],
    switches: &Switches,
    settings: &Settings,
) -> Next {
    plan(cycles, 0, 0, position, switches, settings)
}

/// What follows `phase` (after its debounce delay).
pub(crate) fn after(
    cycles: &[u8],
    phase: Phase,
    position: [f64; N_AXIS],
    switches: &Switches,
    settings: &Settings,
) -> Next {
    let (cycle, step) = if phase.step + 1 < PHASES {
        (phase.cycle, phase.step + 1)
    } else {
        (phase.cycle + 1, 0)
    };
    plan(cycles, cycle, step, position, switches, settings)
}

fn plan(
    cycles: &[u8],
    cycle: usize,
    step: usize,
    position: [f64; N_AXIS],
    switches: &Switches,
    settings: &Settings,
) -> Next {
    let Some(&mask) = cycles.get(cycle) else {
        let all = cycles.iter().fold(0, |m, c| m | c);
        let mut homed = position;
        for (i, p) in homed.iter_mut().enumerate() {
            if all & (1 << i) != 0 {
                *p = -settings.homing_pulloff;
            }
        }
        return Next::Homed {
            mask: all,
            position: homed,
        };
    };
    let axes: Vec<usize> = (0..N_AXIS).filter(|i| mask & (1 << i) != 0).collect();
    let approach = step.is_multiple_of(2);
    let distance = match step {
        0 => {
            SEARCH_SCALAR
                * axes
                    .iter()
                    .map(|&i| settings.axes[i].max_travel)
                    .fold(0.0, f64::max)
        }
        2 => LOCATE_SCALAR * settings.homing_pulloff,
        _ => settings.homing_pulloff,
    };
    let rate = if step == 2 {
        settings.homing_feed
    } else {
        settings.homing_seek
    };
    let mut target = position;
    let mut fails = None;
    for &i in &axes {
        // `$23` bit set: home towards the negative end, where no switch is wired.
        let positive = settings.homing_dir_mask & (1 << i) == 0;
        let toward = if approach == positive { 1.0 } else { -1.0 };
        let switch = switches[i].filter(|_| positive);
        target[i] = position[i] + toward * distance;
        if approach {
            match switch {
                Some(at) if position[i] >= at => target[i] = position[i],
                Some(at) if at - position[i] <= distance => target[i] = at,
                _ => fails = Some(alarm::HOMING_FAIL_APPROACH),
            }
        } else if switch.is_some_and(|at| target[i] >= at) {
            fails = Some(alarm::HOMING_FAIL_PULLOFF);
        }
    }
    let block = (target != position).then_some(motion::Block {
        target,
        // Each axis at the homing rate, as the firmware scales it by √(axes).
        rate: rate * (axes.len() as f64).sqrt(),
    });
    Next::Run(
        Phase {
            cycle,
            step,
            fails,
            started_at: 0.0,
        },
        block,
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grbl::config::GrblConfig;

    fn settings(pulloff: f64) -> Settings {
        let mut s = Settings::from_config(&GrblConfig::default());
        s.homing_pulloff = pulloff;
        s
    }

    /// Run every phase, returning the targets moved to and the outcome.
    fn run(
        cycles: &[u8],
        switches: Switches,
        pulloff: f64,
    ) -> (Vec<[f64; N_AXIS]>, Result<[f64; N_AXIS], u8>) {
        let s = settings(pulloff);
        let mut position = [0.0; N_AXIS];
        let mut moves = Vec::new();
        let mut next = start(cycles, position, &switches, &s);
        loop {
            match next {
                Next::Homed { position, .. } => return (moves, Ok(position)),
                Next::Run(phase, block) => {
                    if let Some(block) = block {
                        position = block.target;
                        moves.push(position);
                    }
                    if let Some(code) = phase.fails {
                        return (moves, Err(code));
                    }
                    next = after(cycles, phase, position, &switches, &s);
                }
            }
        }
    }

    #[test]
    fn stock_cycles_home_z_then_xy() {
        let switches = [Some(30.0), Some(2.0), Some(2.0)];
        let (moves, homed) = run(&[4, 3], switches, 1.0);
        assert_eq!(homed, Ok([-1.0, -1.0, -1.0]));
        assert_eq!(
            moves,
            [
                [0.0, 0.0, 2.0],
                [0.0, 0.0, 1.0],
                [0.0, 0.0, 2.0],
                [0.0, 0.0, 1.0],
                [30.0, 2.0, 1.0],
                [29.0, 1.0, 1.0],
                [30.0, 2.0, 1.0],
                [29.0, 1.0, 1.0],
            ]
        );
    }

    #[test]
    fn no_pulloff_no_switch_or_too_far_fail_with_the_firmware_alarms() {
        // $27=0: the switch stays pressed after the (empty) pull-off.
        let (moves, homed) = run(&[1], [Some(5.0), None, None], 0.0);
        assert_eq!((moves.len(), homed), (1, Err(alarm::HOMING_FAIL_PULLOFF)));
        // Stock cycles with nothing wired on Z: not found within 1.5 × $132.
        let (moves, homed) = run(&[4, 3], [Some(5.0), None, None], 1.0);
        assert_eq!(moves, [[0.0, 0.0, 300.0]]);
        assert_eq!(homed, Err(alarm::HOMING_FAIL_APPROACH));
        let (_, homed) = run(&[1], [Some(301.0), None, None], 1.0);
        assert_eq!(homed, Err(alarm::HOMING_FAIL_APPROACH));
        // Already on the switch: no seek move, the pull-off clears it unless the axis
        // sits further past the switch than the pull-off.
        let (moves, homed) = run(&[1], [Some(-0.5), None, None], 1.0);
        assert_eq!(moves[0], [-1.0, 0.0, 0.0]);
        assert!(homed.is_ok());
        let (_, homed) = run(&[1], [Some(-3.0), None, None], 1.0);
        assert_eq!(homed, Err(alarm::HOMING_FAIL_PULLOFF));
    }
}
