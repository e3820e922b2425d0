//! Looking again with backoff: at once, then after [`FIRST`], doubling after each
//! failure up to [`MAX`]. The hardware lane looks for a lost device (arm or camera)
//! this way, since opening resets an Arduino-based board and failed opens must not
//! come in a storm; both lanes look at the free space this way while scans wait for
//! it, and pause this way after a turn that failed (the journal cannot be written).

use std::time::{Duration, Instant};

/// The wait after the first failure.
pub const FIRST: Duration = Duration::from_secs(1);
/// The longest wait.
pub const MAX: Duration = Duration::from_secs(60);

/// When to look again.
#[derive(Debug, Clone, Copy)]
pub struct Backoff {
    at: Instant,
    delay: Duration,
}

impl Backoff {
    /// Due at once.
    pub fn now() -> Self {
        Self {
            at: Instant::now(),
            delay: Duration::ZERO,
        }
    }

    pub fn due(&self) -> bool {
        Instant::now() >= self.at
    }

    /// The next try after a failed one.
    pub fn later(self) -> Self {
        let delay = (self.delay * 2).clamp(FIRST, MAX);
        Self {
            at: Instant::now() + delay,
            delay,
        }
    }
}

/// A lane's pauses after turns that failed: [`FIRST`] doubling up to [`MAX`] while they
/// keep failing. One line per change: the error when it is new, and that the lane works
/// again after the first turn that goes well (a journal that cannot write once logged
/// its error every second).
#[derive(Debug, Default)]
pub struct Failures {
    last: Option<String>,
    pause: Duration,
}

impl Failures {
    /// A turn of `lane` went well.
    pub fn ok(&mut self, lane: &str) {
        if let Some(last) = self.last.take() {
            tracing::info!("{lane}: working again after \"{last}\"");
        }
        *self = Self::default();
    }

    /// A turn of `lane` failed with `err`: logs it if it is new, and returns how long to
    /// pause.
    pub fn failed(&mut self, lane: &str, err: &dyn std::fmt::Display) -> Duration {
        let message = err.to_string();
        if self.last.as_deref() != Some(message.as_str()) {
            tracing::error!("{lane}: {message} (trying again with backoff, up to {MAX:?})");
        }
        self.last = Some(message);
        self.pause = (self.pause * 2).clamp(FIRST, MAX);
        self.pause
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn waits_double_from_the_first_up_to_the_cap() {
        let mut backoff = Backoff::now();
        assert!(backoff.due());
        let mut delays = Vec::new();
        for _ in 0..9 {
            backoff = backoff.later();
            delays.push(backoff.delay.as_secs());
        }
        assert_eq!(delays, [1, 2, 4, 8, 16, 32, 60, 60, 60]);
        assert!(!backoff.due());
    }

    #[test]
    fn a_failing_lane_pauses_longer_until_a_turn_goes_well() {
        let mut failures = Failures::default();
        let pauses: Vec<u64> = (0..8)
            .map(|_| {
                failures
                    .failed("lane", &"database or disk is full")
                    .as_secs()
            })
            .collect();
        assert_eq!(pauses, [1, 2, 4, 8, 16, 32, 60, 60]);
        // Another error starts no new schedule; a good turn does.
        assert_eq!(failures.failed("lane", &"another").as_secs(), 60);
        failures.ok("lane");
        assert_eq!(failures.failed("lane", &"another").as_secs(), 1);
    }
}
