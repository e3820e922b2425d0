//! What the emulated firmware was asked, in order: the lines its main loop executed (as
//! it sees them: upper-cased, without spaces or comments), `^X` for each soft reset and
//! `DTR` for each reset by opening the port. Tests read it to check what a driver sent.

use std::collections::VecDeque;
use std::sync::{Arc, Mutex, PoisonError};

/// Entries kept; older ones are dropped.
const CAPACITY: usize = 4096;

/// Shared between the emulator thread and its handle. Cheap to clone.
#[derive(Debug, Clone, Default)]
pub(crate) struct Transcript {
    entries: Arc<Mutex<VecDeque<String>>>,
}

impl Transcript {
    pub fn record(&self, entry: impl Into<String>) {
        let mut entries = self.entries.lock().unwrap_or_else(PoisonError::into_inner);
        if entries.len() == CAPACITY {
            entries.pop_front();
        }
        entries.push_back(entry.into());
    }

    pub fn entries(&self) -> Vec<String> {
        let entries = self.entries.lock().unwrap_or_else(PoisonError::into_inner);
        entries.iter().cloned().collect()
    }
}
