//! Captures decoded in child processes (`gonio decode-worker`), each under a memory
//! limit and a time limit, so that a file that crashes or aborts a decoder, or makes
//! it allocate without end or spin, fails its read with a one-line error instead of
//! taking the daemon (or a command) along.
//!
//! [`install`] makes every capture read of this process go through [`Workers`]: a
//! pool of children reused from one frame to the next (a spawn per frame would cost
//! more than some decodes), each speaking [`wire`] on its stdin and stdout. Limits,
//! sized from the largest capture allowed ([`capture::max_pixels`]) when a child is
//! started (docs/ARCHITECTURE.md, "Limits and access"):
//! - memory: the child's address space (`RLIMIT_AS`), [`BASE_MEMORY_BYTES`] plus
//!   [`BYTES_PER_PIXEL`] per allowed pixel;
//! - time: each decode may use [`BASE_CPU_SECONDS`] plus one second per
//!   [`PIXELS_PER_CPU_SECOND`] allowed pixels of processor time (`RLIMIT_CPU`, moved on
//!   before each decode), and twice that plus [`WALL_SLACK`] of wall-clock time, after
//!   which the parent kills it.
//!
//! No system-call filter (seccomp) is applied: a decoder runs with the rights of the
//! user, bounded in memory and time only.
#![doc = include_str!("decode_workers.md")]

use std::io::{self, BufReader, BufWriter, Read};
use std::ops::Range;
use std::os::fd::AsFd;
use std::os::unix::process::ExitStatusExt;
use std::path::Path;
use std::process::{Child, ChildStdin, ChildStdout, Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{mpsc, Arc, Mutex};
use std::thread::{self, JoinHandle};
use std::time::Duration;

use gonio_processing::capture::{self, wire, CaptureError, Decoded, Decoder};

/// Address space of a child beyond its frame: the program, its threads' stacks and
/// allocator arenas, a raw file's previews and metadata.
pub const BASE_MEMORY_BYTES: u64 = 512 << 20;
/// Address space per allowed pixel: a decoder's buffers of a frame (up to 8 bytes a
/// pixel for 16-bit RGBA), its RGB copy, the rows kept and the file itself.
pub const BYTES_PER_PIXEL: u64 = 32;
/// Processor time every decode may use, seconds.
pub const BASE_CPU_SECONDS: u64 = 10;
/// Allowed pixels that add one second to a decode's processor time.
pub const PIXELS_PER_CPU_SECOND: u64 = 2_000_000;
/// Wall-clock time a decode may take beyond twice its processor time.
pub const WALL_SLACK: Duration = Duration::from_secs(10);
/// Idle children kept for later decodes.
const MAX_IDLE: usize = 8;
/// Capacity asked for the pipe a child's frames come through.
const PIPE_BYTES: libc::c_int = 1 << 20;
/// First bytes of a child's stderr kept, to tell why it died.
const STDERR_HEAD: usize = 4096;

/// The limits of a child.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Limits {
    pub memory_bytes: u64,
    pub cpu_seconds: u64,
}

impl Limits {
    /// The limits for captures of at most `max_pixels` pixels.
    pub fn for_pixels(max_pixels: u64) -> Limits {
        Limits {
            memory_bytes: max_pixels
                .saturating_mul(BYTES_PER_PIXEL)
                .saturating_add(BASE_MEMORY_BYTES),
            cpu_seconds: BASE_CPU_SECONDS + max_pixels / PIXELS_PER_CPU_SECOND,
        }
    }

    fn wall(&self) -> Duration {
        Duration::from_secs(2 * self.cpu_seconds) + WALL_SLACK
    }
}

/// Has every capture read of this process decoded by child processes.
pub fn install() {
    capture::set_decoder(Box::new(Workers::default()));
}

/// A pool of decoding children.
#[derive(Default)]
pub struct Workers {
    idle: Mutex<Vec<Worker>>,
}

struct Worker {
    child: Child,
    stdin: ChildStdin,
    stdout: BufReader<ChildStdout>,
    stderr: JoinHandle<Vec<u8>>,
    limits: Limits,
}

impl Workers {
    /// An idle child started for the current limits, or a new one.
    fn take(&self) -> io::Result<Worker> {
        let limits = Limits::for_pixels(capture::max_pixels());
        let mut idle = self.idle.lock().unwrap_or_else(|e| e.into_inner());
        while let Some(mut worker) = idle.pop() {
            // One that died meanwhile, or was started for other limits, is let go.
            if worker.limits == limits && matches!(worker.child.try_wait(), Ok(None)) {
                return Ok(worker);
            }
            drop(worker.end());
        }
        drop(idle);
        Worker::spawn(limits)
    }

    fn give_back(&self, worker: Worker) {
        let mut idle = self.idle.lock().unwrap_or_else(|e| e.into_inner());
        if idle.len() < MAX_IDLE {
            idle.push(worker);
        } else {
            drop(idle);
            drop(worker.end());
        }
    }
}

impl Decoder for Workers {
    fn decode(
        &self,
        path: &Path,
        select: &mut dyn FnMut(usize, usize) -> Option<Vec<Range<usize>>>,
    ) -> Result<Option<Decoded>, CaptureError> {
        let image_error = |reason: String| CaptureError::Image {
            path: path.to_path_buf(),
            reason,
        };
        let mut worker = self
            .take()
            .map_err(|e| image_error(format!("cannot start the decoder: {e}")))?;
        let (finished, watch) = mpsc::channel::<()>();
        let timed_out = Arc::new(AtomicBool::new(false));
        let watchdog = {
            let timed_out = Arc::clone(&timed_out);
            let pid = worker.child.id() as libc::pid_t;
            let wall = worker.limits.wall();
            thread::spawn(move || {
                if let Err(mpsc::RecvTimeoutError::Timeout) = watch.recv_timeout(wall) {
                    timed_out.store(true, Ordering::SeqCst);
                    // SAFETY: a plain signal to our own child, not reaped before this
                    // thread is joined (so its id is not reused meanwhile).
                    unsafe { libc::kill(pid, libc::SIGKILL) };
                }
            })
        };
        let outcome = wire::request(&mut worker.stdin, &mut worker.stdout, path, select);
        drop(finished);
        let _ = watchdog.join();
        let timed_out = timed_out.load(Ordering::SeqCst);
        match outcome {
            Ok(result) if !timed_out => {
                self.give_back(worker);
                result
            }
            Ok(result) => {
                drop(worker.end());
                result
            }
            Err(error) => {
                let limits = worker.limits;
                let (status, stderr) = worker.end();
                Err(image_error(death(
                    status, &stderr, timed_out, limits, &error,
                )))
            }
        }
    }
}

impl Worker {
    fn spawn(limits: Limits) -> io::Result<Worker> {
        // The program this process runs, also once its file was replaced or removed
        // (an install while the daemon runs): /proc/self/exe opens the running image.
        let running = Path::new("/proc/self/exe");
        let exe = if running.exists() {
            running.to_path_buf()
        } else {
            std::env::current_exe()?
        };
        let mut child = Command::new(exe)
            .arg("decode-worker")
            .arg("--memory-bytes")
            .arg(limits.memory_bytes.to_string())
            .arg("--cpu-seconds")
            .arg(limits.cpu_seconds.to_string())
            // Few allocator arenas: each reserves 64 MiB of address space.
            .env("MALLOC_ARENA_MAX", "2")
            .env("RUST_BACKTRACE", "0")
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()?;
        let (Some(stdin), Some(stdout), Some(mut stderr)) =
            (child.stdin.take(), child.stdout.take(), child.stderr.take())
        else {
            let _ = child.kill();
            let _ = child.wait();
            return Err(io::Error::other("decoder started without pipes"));
        };
        // A larger pipe buffer moves a frame in fewer turns between the processes
        // (best effort: the default works too).
        // SAFETY: fcntl on a descriptor this function owns.
        unsafe {
            use std::os::fd::AsRawFd;
            libc::fcntl(stdout.as_raw_fd(), libc::F_SETPIPE_SZ, PIPE_BYTES);
        }
        let stderr = thread::spawn(move || {
            // The first lines say why (an allocation that failed, a stack overflow);
            // the rest is read and dropped, so the child never blocks on its stderr.
            let mut head = Vec::new();
            let mut buf = [0u8; 1024];
            while let Ok(n @ 1..) = stderr.read(&mut buf) {
                let room = STDERR_HEAD.saturating_sub(head.len());
                head.extend_from_slice(&buf[..n.min(room)]);
            }
            head
        });
        Ok(Worker {
            child,
            stdin,
            stdout: BufReader::with_capacity(1 << 20, stdout),
            stderr,
            limits,
        })
    }

    /// Ends the child (its input closed, then killed if it is still there) and
    /// returns how it ended and the start of what it wrote to stderr.
    fn end(self) -> (Option<std::process::ExitStatus>, String) {
        let Worker {
            mut child,
            stdin,
            stdout,
            stderr,
            ..
        } = self;
        drop(stdin);
        drop(stdout);
        let _ = child.kill();
        let status = child.wait().ok();
        let head = stderr.join().unwrap_or_default();
        (status, String::from_utf8_lossy(&head).into_owned())
    }
}

/// Why a child stopped answering, on one line.
fn death(
    status: Option<std::process::ExitStatus>,
    stderr: &str,
    timed_out: bool,
    limits: Limits,
    error: &io::Error,
) -> String {
    let mib = limits.memory_bytes >> 20;
    if timed_out {
        return format!(
            "the decoder ran past its time limit ({} s) and was stopped",
            limits.wall().as_secs()
        );
    }
    let signal = status.and_then(|s| s.signal());
    if stderr.contains("memory allocation of") {
        return format!("the decoder was killed by its memory limit ({mib} MiB)");
    }
    match signal {
        Some(libc::SIGXCPU) => format!(
            "the decoder was killed by its processor time limit ({} s)",
            limits.cpu_seconds
        ),
        Some(libc::SIGKILL) => {
            "the decoder was killed (signal 9; by the system, for memory?)".to_owned()
        }
        Some(_) if stderr.contains("has overflowed its stack") => {
            "the decoder crashed: it overflowed its stack".to_owned()
        }
        Some(libc::SIGABRT) => "the decoder aborted (signal 6)".to_owned(),
        Some(libc::SIGSEGV) => "the decoder crashed (segmentation fault, signal 11)".to_owned(),
        Some(signal) => format!("the decoder crashed (signal {signal})"),
        None => match status {
            Some(status) if !status.success() => {
                format!("the decoder exited unexpectedly ({status})")
            }
            _ => format!(
                "the decoder broke off: {}",
                gonio_processing::guard::one_line(&error.to_string())
            ),
        },
    }
}

/// The child: sets its limits, then decodes what its parent asks until its input
/// ends (or its parent dies).
pub fn serve(limits: Limits) -> anyhow::Result<()> {
    // SAFETY: plain system calls on this process with valid arguments.
    unsafe {
        // The parent's end ends the child; a stop meant for the parent (Ctrl-C in a
        // terminal, a service manager's SIGTERM to all its processes) does not, so the
        // parent's step in flight is cut short by its own stop, not failed by ours.
        libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGKILL);
        for signal in [libc::SIGINT, libc::SIGTERM, libc::SIGHUP] {
            libc::signal(signal, libc::SIG_IGN);
        }
        let no_core = libc::rlimit {
            rlim_cur: 0,
            rlim_max: 0,
        };
        libc::setrlimit(libc::RLIMIT_CORE, &no_core);
        let memory = libc::rlimit {
            rlim_cur: limits.memory_bytes,
            rlim_max: limits.memory_bytes,
        };
        if libc::setrlimit(libc::RLIMIT_AS, &memory) != 0 {
            anyhow::bail!("setting the memory limit: {}", io::Error::last_os_error());
        }
    }
    let abort_on = std::env::var_os(ABORT_ON_ENV);
    // Frames are binary: written to the descriptor itself, past stdout's line
    // buffering, which would search every write (tens of megabytes) for a newline.
    let stdout = std::fs::File::from(io::stdout().as_fd().try_clone_to_owned()?);
    let output = BufWriter::with_capacity(1 << 20, stdout);
    wire::serve(io::stdin().lock(), output, |path| {
        if abort_on
            .as_deref()
            .is_some_and(|name| path.file_name() == Some(name))
        {
            std::process::abort();
        }
        cpu_budget(limits.cpu_seconds);
    })?;
    Ok(())
}

/// A file name on which the child aborts before decoding (set by tests, to stand for
/// a decoder that aborts).
pub const ABORT_ON_ENV: &str = "GONIO_DECODE_WORKER_ABORT_ON";

/// Lets the next decode use `seconds` of processor time beyond what this process has
/// used: its soft `RLIMIT_CPU` (SIGXCPU on expiry) moved on.
fn cpu_budget(seconds: u64) {
    // SAFETY: plain system calls on this process with valid pointers.
    unsafe {
        let mut usage: libc::rusage = std::mem::zeroed();
        libc::getrusage(libc::RUSAGE_SELF, &mut usage);
        let used = (usage.ru_utime.tv_sec + usage.ru_stime.tv_sec) as u64 + 1;
        let mut limit: libc::rlimit = std::mem::zeroed();
        libc::getrlimit(libc::RLIMIT_CPU, &mut limit);
        limit.rlim_cur = used.saturating_add(seconds).min(limit.rlim_max);
        libc::setrlimit(libc::RLIMIT_CPU, &limit);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn limits_grow_with_the_largest_capture() {
        let small = Limits::for_pixels(1_000_000);
        assert_eq!(small.memory_bytes, (512 << 20) + 32_000_000);
        assert_eq!(small.cpu_seconds, 10);
        let default = Limits::for_pixels(capture::DEFAULT_MAX_PIXELS);
        assert_eq!(default.cpu_seconds, 60);
        assert_eq!(default.wall(), Duration::from_secs(130));
        assert_eq!(Limits::for_pixels(u64::MAX).memory_bytes, u64::MAX);
    }

    #[test]
    fn a_death_is_told_on_one_line() {
        let limits = Limits::for_pixels(1_000_000);
        let killed = |signal| Some(std::process::ExitStatus::from_raw(signal));
        let eof = io::Error::from(io::ErrorKind::UnexpectedEof);
        let said = "memory allocation of 68719476736 bytes failed\n";
        assert_eq!(
            death(killed(libc::SIGABRT), said, false, limits, &eof),
            "the decoder was killed by its memory limit (542 MiB)"
        );
        assert_eq!(
            death(killed(libc::SIGABRT), "", false, limits, &eof),
            "the decoder aborted (signal 6)"
        );
        assert_eq!(
            death(killed(libc::SIGKILL), "", true, limits, &eof),
            "the decoder ran past its time limit (30 s) and was stopped"
        );
        assert_eq!(
            death(killed(libc::SIGXCPU), "", false, limits, &eof),
            "the decoder was killed by its processor time limit (10 s)"
        );
        let bad = io::Error::new(io::ErrorKind::InvalidData, "a text\nof lines");
        assert_eq!(
            death(
                Some(std::process::ExitStatus::from_raw(0)),
                "",
                false,
                limits,
                &bad
            ),
            "the decoder broke off: a text of lines"
        );
    }
}
