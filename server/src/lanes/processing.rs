//! The processing lane: one thread that runs the processing steps of every scan as
//! soon as their inputs exist (docs/ARCHITECTURE.md, "Daemon"), in journal order,
//! while the hardware lane goes on capturing. An HDR step runs in the background as
//! soon as its bracket is captured, beside the other steps (a θL's map is an input of
//! no other step), one at a time.
//! A step that was running when the daemon stopped is run again. With nothing to run,
//! it decodes the frames of the bracket being captured ahead of their HDR step.
//!
//! Its parallel work runs on its own thread pool at a lower priority than the rest of
//! the daemon, so the hardware lane (and an emulated camera's rendering, on the
//! global pool) never waits for it.

use std::path::{Path, PathBuf};
use std::sync::{mpsc, Arc};
use std::time::Duration;

use super::backoff::{Backoff, Failures};
use super::step::{self, Outcome, StepError};
use crate::plan::{Lane, ScanPlan, Step};
use crate::process::{self, Prefetched};
use crate::shared::Shared;
use crate::step_guard;
use crate::storage::{self, Probe};
use crate::store::{ScanState, StepRecord, Store, StoreError, PROCESSABLE};

/// How often the lane looks for ready steps when nothing wakes it.
const IDLE_POLL: Duration = Duration::from_millis(500);

/// An HDR step running on the lane's pool, with the frames decoded ahead, which it
/// hands back with its outcome.
struct Background {
    id: i64,
    index: u32,
    outcome: mpsc::Receiver<(Outcome, Prefetched)>,
}

/// The processing lane's state.
pub struct ProcessingLane {
    shared: Arc<Shared>,
    store: Store,
    prefetched: Prefetched,
    background: Option<Background>,
    /// When to look at the free space again after a step did not fit.
    disk_retry: Backoff,
}

impl ProcessingLane {
    pub fn new(shared: Arc<Shared>, store: Store) -> Self {
        Self {
            shared,
            store,
            prefetched: Prefetched::default(),
            background: None,
            disk_retry: Backoff::now(),
        }
    }

    /// Runs forever on a thread pool of its own, at a lower priority, with a thread per
    /// core beside the lane's own: the lane's thread waits for the background step
    /// most of the time (blocked, not stealing its work), and the step's parallel
    /// parts must still get every core.
    pub fn run(self) {
        let threads = std::thread::available_parallelism().map_or(2, |n| n.get()) + 1;
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .thread_name(|n| format!("processing-{n}"))
            .start_handler(|_| {
                step_guard::mark_lane(Lane::Processing);
                lower_priority()
            })
            .build();
        match pool {
            Ok(pool) => pool.install(|| self.work()),
            Err(err) => {
                tracing::warn!("processing lane on the global thread pool: {err}");
                self.work()
            }
        }
    }

    fn work(mut self) {
        let mut failures = Failures::default();
        loop {
            match self.turn() {
                Ok(()) => failures.ok("processing lane"),
                Err(err) => std::thread::sleep(failures.failed("processing lane", &err)),
            }
        }
    }

    /// One turn of the lane: makes the journal's reserve again if the store used it and
    /// there is room, records a finished background step, starts the next
    /// captured bracket's map in the background (the longest step, so first), then runs
    /// the next other step, or waits for the background one, or decodes ahead.
    fn turn(&mut self) -> Result<(), StoreError> {
        if self
            .shared
            .storage
            .keep_journal_reserve()
            .is_ok_and(|made| made)
        {
            tracing::info!("space held for the journal again");
        }
        self.collect(false)?;
        if self.background.is_none() {
            if let Some((id, step)) = self.store.next_hdr()? {
                if !self.fits(id, &step)? {
                    return self.wait_for_space();
                }
                self.start_background(id, &step)?;
            }
        }
        let running = self.background.as_ref().map(|b| (b.id, b.index));
        match self.store.next_for_processing(running)? {
            // One HDR step at a time: the next waits for the running one.
            Some((_, record)) if matches!(record.step, Step::Hdr { .. }) => self.collect(true),
            Some((id, record)) if !self.fits(id, &record)? => self.wait_for_space(),
            Some((id, record)) => self.run_step(id, &record),
            // Nothing else to do: wait for the background step.
            None if self.background.is_some() => self.collect(true),
            None => {
                if !self.prefetch()? {
                    // A timeout and a wake-up both mean: look again.
                    self.shared.processing_wake.take(IDLE_POLL);
                }
                Ok(())
            }
        }
    }

    /// Whether what step `record` of scan `id` writes fits above the journal's reserve;
    /// if not, the scan waits for space (the hardware lane queues it again once there
    /// is), and the lane looks again with backoff.
    fn fits(&mut self, id: i64, record: &StepRecord) -> Result<bool, StoreError> {
        if !self.disk_retry.due() {
            return Ok(false);
        }
        let Some(scan) = self.store.scan(id)? else {
            return Ok(false);
        };
        let setup =
            gonio_processing::extract::read_setup(&self.shared.scan_dir(id).join("setup.json"));
        let pixels = storage::frame_pixels(setup.ok().as_ref());
        let need = storage::step_need(&record.step, &scan.plan, pixels);
        match self.shared.storage.check(need) {
            Ok(()) => {
                self.disk_retry = Backoff::now();
                Ok(true)
            }
            Err(reason) => {
                self.disk_retry = self.disk_retry.later();
                let waits = scan.state == ScanState::Waiting
                    && scan.error.as_deref().is_some_and(storage::is_disk_wait);
                if !waits {
                    tracing::warn!("scan {id} waiting: {reason}");
                    self.store
                        .log(self.shared.boot, Some(id), "wait", &reason)?;
                    self.store
                        .transition(id, &PROCESSABLE, ScanState::Waiting, Some(&reason))?;
                    self.shared.changed(id);
                }
                Ok(false)
            }
        }
    }

    /// Waits while no step fits on the disk (the background step, if any, goes on).
    fn wait_for_space(&mut self) -> Result<(), StoreError> {
        self.collect(false)?;
        self.shared.processing_wake.take(IDLE_POLL);
        Ok(())
    }

    /// Decodes one frame awaiting its HDR step ahead of it; returns whether it did.
    fn prefetch(&mut self) -> Result<bool, StoreError> {
        let wanted: Vec<PathBuf> = self
            .store
            .frames_awaiting_hdr()?
            .into_iter()
            .map(|(id, path)| self.shared.scan_dir(id).join(path))
            .collect();
        Ok(self.prefetched.advance(&wanted))
    }

    /// Starts the HDR step `record` of scan `id` in the background, with the frames
    /// decoded ahead.
    fn start_background(&mut self, id: i64, record: &StepRecord) -> Result<(), StoreError> {
        let Some(scan) = self.store.scan(id)? else {
            return Ok(());
        };
        step::begin(&self.shared, &mut self.store, id, record.index)?;
        let dir = self.shared.scan_dir(id);
        let mut prefetched = std::mem::take(&mut self.prefetched);
        let step = record.step.clone();
        let storage = self.shared.storage.clone();
        let (sender, outcome) = mpsc::channel();
        rayon::spawn(move || {
            let outcome = run(&step, &dir, &scan.plan, &mut prefetched, &storage);
            // The lane only drops the receiver when it stops.
            let _ = sender.send((outcome, prefetched));
        });
        self.background = Some(Background {
            id,
            index: record.index,
            outcome,
        });
        Ok(())
    }

    /// Records the background step's outcome once it has one (waiting for it if
    /// `wait`), and takes back the frames decoded ahead.
    fn collect(&mut self, wait: bool) -> Result<(), StoreError> {
        let Some(background) = &self.background else {
            return Ok(());
        };
        let (outcome, prefetched) = match background.outcome.try_recv() {
            Ok(received) => received,
            Err(mpsc::TryRecvError::Empty) if !wait => return Ok(()),
            Err(mpsc::TryRecvError::Empty) => match background.outcome.recv() {
                Ok(received) => received,
                Err(mpsc::RecvError) => lost(),
            },
            Err(mpsc::TryRecvError::Disconnected) => lost(),
        };
        let (id, index) = (background.id, background.index);
        self.background = None;
        self.prefetched = prefetched;
        self.finish(id, index, outcome)
    }

    fn run_step(&mut self, id: i64, record: &StepRecord) -> Result<(), StoreError> {
        let Some(scan) = self.store.scan(id)? else {
            return Ok(());
        };
        step::begin(&self.shared, &mut self.store, id, record.index)?;
        let dir = self.shared.scan_dir(id);
        let outcome = run(
            &record.step,
            &dir,
            &scan.plan,
            &mut self.prefetched,
            &self.shared.storage,
        );
        self.finish(id, record.index, outcome)
    }

    /// Records the outcome of step `index` of scan `id`.
    fn finish(&mut self, id: i64, index: u32, outcome: Outcome) -> Result<(), StoreError> {
        step::finish(
            &self.shared,
            &mut self.store,
            id,
            index,
            &PROCESSABLE,
            outcome,
        )?;
        // The hardware lane may be waiting for a bracket to be processed.
        self.shared.hardware_wake.post(|wake| *wake = true);
        Ok(())
    }
}

/// Runs processing step `step` of a scan planned as `plan` in `dir`; a panic fails
/// the step, not the daemon, and a full disk makes the scan wait for space.
fn run(
    step: &Step,
    dir: &Path,
    plan: &ScanPlan,
    prefetched: &mut Prefetched,
    storage: &Probe,
) -> Outcome {
    step_guard::run_processing(&step.describe(), || {
        process::run(step, dir, plan, prefetched)
    })
    .map(|result| (result, Vec::new()))
    .map_err(|message| {
        if storage::says_disk_full(&message) {
            tracing::warn!("{message}");
            let setup = gonio_processing::extract::read_setup(&dir.join("setup.json"));
            let pixels = storage::frame_pixels(setup.ok().as_ref());
            StepError::Waiting(storage.full_reason(storage::step_need(step, plan, pixels)))
        } else {
            StepError::Failed(message)
        }
    })
}

/// The outcome of a background step whose worker ended without one.
fn lost() -> (Outcome, Prefetched) {
    let reason = "the background worker stopped without an outcome".to_owned();
    (Err(StepError::Failed(reason)), Prefetched::default())
}

/// How much less urgent the processing threads are than the others (nice levels).
const NICER_BY: i32 = 10;

/// Lowers the calling thread's scheduling priority by [`NICER_BY`] (on Linux the nice
/// value is per thread); a failure leaves it as it is.
pub(super) fn lower_priority() {
    #[cfg(unix)]
    // SAFETY: getpriority and setpriority only read and set the calling thread's nice
    // value; errors are reported through the return value, which is ignored (the
    // thread then keeps its priority).
    unsafe {
        let now = libc::getpriority(libc::PRIO_PROCESS, 0);
        libc::setpriority(libc::PRIO_PROCESS, 0, (now + NICER_BY).min(19));
    }
}
