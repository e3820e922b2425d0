//! Synchronisation between the daemon's threads: poison-tolerant locking, a mailbox
//! that wakes a waiting thread with work, and counted slots that cap how many of a
//! kind of request run at once.

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Condvar, Mutex, MutexGuard};
use std::time::Duration;

/// Locks a mutex, recovering the data of a poisoned one (a panicked holder leaves
/// plain data that is still consistent for these uses).
pub fn lock<T>(mutex: &Mutex<T>) -> MutexGuard<'_, T> {
    mutex
        .lock()
        .unwrap_or_else(|poisoned| poisoned.into_inner())
}

/// Work handed to one waiting thread: producers add to it and wake the thread, which
/// takes everything at once. `Mailbox<bool>` is a plain wake-up call.
#[derive(Debug, Default)]
pub struct Mailbox<T> {
    items: Mutex<T>,
    posted: Condvar,
}

impl<T: Default + PartialEq> Mailbox<T> {
    /// Adds work with `add` and wakes the waiting thread.
    pub fn post(&self, add: impl FnOnce(&mut T)) {
        add(&mut lock(&self.items));
        self.posted.notify_all();
    }

    /// Waits until there is work (or `timeout` passes) and takes all of it; the
    /// default (empty) value after a timeout.
    pub fn take(&self, timeout: Duration) -> T {
        let guard = lock(&self.items);
        let (mut guard, _) = self
            .posted
            .wait_timeout_while(guard, timeout, |items| *items == T::default())
            .unwrap_or_else(|poisoned| poisoned.into_inner());
        std::mem::take(&mut *guard)
    }
}

/// A count of things of one kind in progress (open event streams, archives being
/// written), each counted by the [`Slot`] it holds.
#[derive(Debug, Default)]
pub struct Slots(AtomicUsize);

/// One of [`Slots`], counted until dropped.
#[derive(Debug)]
pub struct Slot(&'static Slots);

impl Slots {
    pub const fn new() -> Self {
        Self(AtomicUsize::new(0))
    }

    /// A slot, unless `max` are taken.
    pub fn take(&'static self, max: usize) -> Option<Slot> {
        self.0
            .fetch_update(Ordering::AcqRel, Ordering::Acquire, |n| {
                (n < max).then_some(n + 1)
            })
            .ok()
            .map(|_| Slot(self))
    }
}

impl Drop for Slot {
    fn drop(&mut self) {
        self.0 .0.fetch_sub(1, Ordering::AcqRel);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::BTreeSet;
    use std::sync::Arc;
    use std::time::Instant;

    #[test]
    fn mailbox_wakes_the_taker_with_everything_posted() {
        let mailbox: Arc<Mailbox<BTreeSet<i64>>> = Arc::default();
        mailbox.post(|ids| {
            ids.insert(3);
        });
        mailbox.post(|ids| {
            ids.insert(1);
        });
        assert_eq!(mailbox.take(Duration::from_secs(5)), BTreeSet::from([1, 3]));
        // Empty again: a take times out with nothing.
        let started = Instant::now();
        assert!(mailbox.take(Duration::from_millis(50)).is_empty());
        assert!(started.elapsed() >= Duration::from_millis(50));
        // A post from another thread wakes a waiting taker early.
        let poster = mailbox.clone();
        let thread = std::thread::spawn(move || {
            std::thread::sleep(Duration::from_millis(20));
            poster.post(|ids| {
                ids.insert(7);
            });
        });
        let started = Instant::now();
        assert_eq!(mailbox.take(Duration::from_secs(10)), BTreeSet::from([7]));
        assert!(started.elapsed() < Duration::from_secs(5));
        thread.join().unwrap();
    }

    #[test]
    fn slots_are_counted_until_dropped() {
        static SLOTS: Slots = Slots::new();
        let first = SLOTS.take(2).unwrap();
        let second = SLOTS.take(2).unwrap();
        assert!(SLOTS.take(2).is_none());
        drop(first);
        let third = SLOTS.take(2).unwrap();
        assert!(SLOTS.take(2).is_none());
        drop((second, third));
        assert!(SLOTS.take(1).is_some());
    }
}
