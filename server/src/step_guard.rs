//! The step boundary. A processing step runs under a panic guard, so a panic fails
//! that step with the panic's message instead of ending the daemon (captures are
//! decoded in child processes, so a corrupt one cannot end it either: see
//! `decode_workers`). A step that ends the daemon anyway is counted at the
//! next start, and only then: the daemon records its own fatal faults (a fatal signal
//! such as an abort or a segmentation fault, or a lane that panicked) with the lane of
//! the thread at fault, in `DATA/daemon.fault`; a kill, a power cut or an out-of-memory
//! kill leaves no record and counts against no step. A step of the lane at fault that
//! was running at [`MAX_CRASHES`] recorded faults fails its scan, so the queue goes on
//! without it (docs/ARCHITECTURE.md, "Limits and access").

use std::cell::Cell;
use std::os::fd::IntoRawFd;
use std::path::Path;
use std::sync::atomic::{AtomicI32, Ordering};
use std::sync::OnceLock;

use gonio_files::input::{read_input_to_string, MAX_SMALL_FILE_BYTES};
use gonio_processing::guard;
use serde_json::Value;

use super::plan::Lane;
use super::shared::Shared;
use super::store::{Store, StoreError};

/// Recorded faults a step may be running at before its scan fails.
pub const MAX_CRASHES: u32 = 3;

/// Where the daemon records the fault it dies of, in the data directory.
pub const FAULT_FILE: &str = "daemon.fault";

/// Runs processing step `what` under the panic guard: its error, or its panic, becomes
/// the step's error message.
pub fn run_processing(
    what: &str,
    step: impl FnOnce() -> anyhow::Result<Value>,
) -> Result<Value, String> {
    match guard::catch(step) {
        Ok(Ok(value)) => Ok(value),
        Ok(Err(err)) => Err(format!("{what}: {err:#}")),
        Err(panic) => Err(format!("{what}: internal error (panicked: {panic})")),
    }
}

/// At start, before the queue runs: counts the fault the previous daemon recorded (if
/// it died of one) against the steps of the lane at fault it was running, and fails
/// the scans of steps at [`MAX_CRASHES`].
pub fn fail_crash_looping_scans(
    shared: &Shared,
    store: &mut Store,
    fault: Option<&Fault>,
) -> Result<(), StoreError> {
    if let Some(fault) = fault {
        tracing::warn!("the previous daemon died of a fault: {}", fault.what);
    }
    let lane = fault.and_then(|f| f.lane);
    for id in store.count_crashes(MAX_CRASHES, lane)? {
        let scan = store.scan(id)?;
        let reason = scan.and_then(|s| s.error).unwrap_or_default();
        tracing::error!("scan {id} failed: {reason}");
        store.log(shared.boot, Some(id), "crash-loop", &reason)?;
        shared.changed(id);
    }
    Ok(())
}

/// A fault the previous daemon recorded as it died.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Fault {
    /// The lane of the thread at fault; `None` for any other thread.
    pub lane: Option<Lane>,
    /// The record as written, e.g. `processing signal 6`.
    pub what: String,
}

impl Fault {
    /// Parses a record (`<lane or "other"> <cause>`); `None` for an empty one.
    fn parse(record: &str) -> Option<Fault> {
        let what = record.lines().next()?.trim();
        let lane = match what.split_whitespace().next()? {
            "hardware" => Some(Lane::Hardware),
            "processing" => Some(Lane::Processing),
            _ => None,
        };
        Some(Fault {
            lane,
            what: what.to_owned(),
        })
    }
}

/// The descriptor of the fault record, once open.
static FAULT_FD: AtomicI32 = AtomicI32::new(-1);
/// The signals the daemon dies of by its own fault.
const FATAL_SIGNALS: [libc::c_int; 5] = [
    libc::SIGABRT,
    libc::SIGSEGV,
    libc::SIGBUS,
    libc::SIGILL,
    libc::SIGFPE,
];
/// The actions those signals had before ours (Rust's stack-overflow report, say),
/// restored before the signal is raised again.
static PREVIOUS: OnceLock<[libc::sigaction; FATAL_SIGNALS.len()]> = OnceLock::new();

thread_local! {
    /// The lane this thread works for, if any.
    static THREAD_LANE: Cell<Option<Lane>> = const { Cell::new(None) };
}

/// Marks the calling thread as working for `lane`: a fault in it is that lane's.
pub fn mark_lane(lane: Lane) {
    THREAD_LANE.with(|l| l.set(Some(lane)));
}

/// Reads the fault the previous daemon of `data_dir` recorded, if any, empties the
/// record, and from now on records this daemon's fatal signals there. Call once, with
/// the data directory locked.
pub fn record_faults(data_dir: &Path) -> anyhow::Result<Option<Fault>> {
    use anyhow::Context;
    let path = data_dir.join(FAULT_FILE);
    let previous = match read_input_to_string(&path, MAX_SMALL_FILE_BYTES) {
        Ok(text) => Fault::parse(&text),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => None,
        Err(e) => return Err(e).with_context(|| format!("reading {}", path.display())),
    };
    let file = {
        use std::os::unix::fs::OpenOptionsExt;
        std::fs::OpenOptions::new()
            .write(true)
            .create(true)
            .truncate(true)
            .mode(0o600)
            .open(&path)
            .with_context(|| format!("creating {}", path.display()))?
    };
    file.sync_all()
        .with_context(|| format!("emptying {}", path.display()))?;
    // Kept open for the life of the process: the handler only writes to it.
    FAULT_FD.store(file.into_raw_fd(), Ordering::Release);
    install_handlers();
    Ok(previous)
}

/// Records that the thread of `lane` ended by a panic (the process then exits).
pub fn record_lane_death(lane: Lane) {
    write_record(Some(lane), b"panic", None);
}

fn install_handlers() {
    let mut previous = [empty_action(); FATAL_SIGNALS.len()];
    for (signal, old) in FATAL_SIGNALS.iter().zip(previous.iter_mut()) {
        let mut action = empty_action();
        action.sa_sigaction = on_fatal_signal as *const () as usize;
        action.sa_flags = libc::SA_SIGINFO | libc::SA_ONSTACK;
        // SAFETY: sigemptyset initialises the mask of a plain struct we own; sigaction
        // installs a handler that only calls async-signal-safe functions (write, fsync,
        // sigaction, raise) and reads atomics and a constant-initialised thread-local.
        unsafe {
            libc::sigemptyset(&mut action.sa_mask);
            libc::sigaction(*signal, &action, old);
        }
    }
    let _ = PREVIOUS.set(previous);
}

fn empty_action() -> libc::sigaction {
    // SAFETY: sigaction is a plain C struct for which all-zero bytes is a valid value
    // (no handler, empty flags).
    unsafe { std::mem::zeroed() }
}

extern "C" fn on_fatal_signal(
    signal: libc::c_int,
    _info: *mut libc::siginfo_t,
    _context: *mut libc::c_void,
) {
    let lane = THREAD_LANE.try_with(Cell::get).ok().flatten();
    write_record(lane, b"signal", Some(signal));
    // Back to the action before ours, and the signal again: it is delivered once this
    // handler returns (a fault re-executes and meets that action too).
    if let Some(previous) = PREVIOUS.get() {
        if let Some(k) = FATAL_SIGNALS.iter().position(|s| *s == signal) {
            // SAFETY: sigaction and raise are async-signal-safe; `previous[k]` is the
            // action sigaction returned for this signal.
            unsafe {
                libc::sigaction(signal, &previous[k], std::ptr::null_mut());
            }
        }
    }
    // SAFETY: raise is async-signal-safe.
    unsafe {
        libc::raise(signal);
    }
}

/// Appends `<lane> <cause>[ <signal>]` to the fault record, without allocating (it
/// runs in a signal handler).
fn write_record(lane: Option<Lane>, cause: &[u8], signal: Option<libc::c_int>) {
    let fd = FAULT_FD.load(Ordering::Acquire);
    if fd < 0 {
        return;
    }
    let mut line = [0u8; 48];
    let mut len = 0;
    let mut push = |bytes: &[u8]| {
        let n = bytes.len().min(line.len() - len);
        line[len..len + n].copy_from_slice(&bytes[..n]);
        len += n;
    };
    push(lane.map_or("other", Lane::name).as_bytes());
    push(b" ");
    push(cause);
    if let Some(signal) = signal {
        let mut digits = [0u8; 10];
        let mut k = digits.len();
        let mut n = signal.unsigned_abs();
        loop {
            k -= 1;
            digits[k] = b'0' + (n % 10) as u8;
            n /= 10;
            if n == 0 {
                break;
            }
        }
        push(b" ");
        push(&digits[k..]);
    }
    push(b"\n");
    // SAFETY: write and fsync are async-signal-safe; `line[..len]` is initialised and
    // `fd` is the record's descriptor, open for the life of the process.
    unsafe {
        libc::write(fd, line.as_ptr().cast(), len);
        libc::fsync(fd);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn records_name_the_lane_at_fault() {
        assert_eq!(
            Fault::parse("processing signal 11\n"),
            Some(Fault {
                lane: Some(Lane::Processing),
                what: "processing signal 11".into()
            })
        );
        assert_eq!(
            Fault::parse("hardware panic\n").map(|f| f.lane),
            Some(Some(Lane::Hardware))
        );
        assert_eq!(Fault::parse("other signal 6\n").map(|f| f.lane), Some(None));
        assert_eq!(Fault::parse(""), None);
    }
}
