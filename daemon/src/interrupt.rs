//! Ctrl-C (SIGINT) and SIGTERM during an offline command: a word on stderr saying what
//! was stopped, the command's registered temporary directories removed, exit status
//! 130 (128 + SIGINT). `gonio serve` and `gonio emulate-arm` handle their signals
//! themselves (an interrupt is how they end).

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Mutex, PoisonError};
use std::time::Duration;

/// Temporary directories to remove if the command is interrupted.
static TEMPORARY: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());

/// Exit status after an interruption.
const EXIT_INTERRUPTED: i32 = 130;

/// Set once a signal came, before the temporary directories are removed.
static INTERRUPTED: AtomicBool = AtomicBool::new(false);

/// How long a command that failed after a signal waits for the watcher to end the
/// process (it removes the directories, a few hundred milliseconds at most), before it
/// exits as interrupted itself.
const WATCHER_GRACE: Duration = Duration::from_secs(5);

/// Watches for SIGINT and SIGTERM on a thread of its own while `command` runs.
pub fn install(command: String) {
    let watcher = std::thread::Builder::new()
        .name("signals".into())
        .spawn(move || {
            let runtime = match tokio::runtime::Builder::new_current_thread()
                .enable_io()
                .build()
            {
                Ok(runtime) => runtime,
                // Without a watcher the default action applies: the process just ends.
                Err(_) => return,
            };
            let signal = runtime.block_on(wait_for_signal());
            INTERRUPTED.store(true, Ordering::SeqCst);
            let removed = remove_registered();
            crate::progress::say(format_args!(
                "\ngonio {command}: interrupted by {signal}; stopped before finishing{}",
                if removed > 0 {
                    format!(" ({removed} temporary directories removed)")
                } else {
                    String::new()
                }
            ));
            std::process::exit(EXIT_INTERRUPTED);
        });
    // Failing to start the watcher leaves the default signal action: acceptable.
    drop(watcher);
}

/// Called when the command failed: if a signal came, the failure is its consequence
/// (a directory removed under the command) and not the news, so this waits for the
/// watcher to say what was stopped and exit with 130 (not returning then).
pub fn yield_to_signal() {
    if INTERRUPTED.load(Ordering::SeqCst) {
        std::thread::sleep(WATCHER_GRACE);
        std::process::exit(EXIT_INTERRUPTED);
    }
}

/// Waits for SIGINT or SIGTERM and names the one that came.
pub async fn wait_for_signal() -> &'static str {
    #[cfg(unix)]
    {
        use tokio::signal::unix::{signal, SignalKind};
        if let Ok(mut term) = signal(SignalKind::terminate()) {
            return tokio::select! {
                _ = tokio::signal::ctrl_c() => "Ctrl-C (SIGINT)",
                _ = term.recv() => "SIGTERM",
            };
        }
    }
    let _ = tokio::signal::ctrl_c().await;
    "Ctrl-C (SIGINT)"
}

/// Removal attempts per directory: the command's threads may still be writing into
/// it (and re-creating it) until the process exits.
const REMOVE_ATTEMPTS: usize = 10;
/// Pause between removal attempts.
const REMOVE_PAUSE: Duration = Duration::from_millis(20);

/// Removes every registered directory, holding the registry so none is added meanwhile;
/// returns how many are gone.
fn remove_registered() -> usize {
    let registry = TEMPORARY.lock().unwrap_or_else(PoisonError::into_inner);
    registry
        .iter()
        .filter(|dir| {
            (0..REMOVE_ATTEMPTS).any(|_| {
                let _ = std::fs::remove_dir_all(dir);
                std::thread::sleep(REMOVE_PAUSE);
                !dir.exists()
            })
        })
        .count()
}

/// Keeps `dir` registered for removal on interruption until dropped.
pub struct RemoveOnInterrupt(PathBuf);

impl RemoveOnInterrupt {
    /// Creates a temporary directory in `parent` as `builder` names it, registered
    /// while the registry is held, so an interruption never finds it unregistered.
    pub fn tempdir_in(
        builder: &tempfile::Builder,
        parent: &Path,
    ) -> std::io::Result<(tempfile::TempDir, Self)> {
        let mut registry = TEMPORARY.lock().unwrap_or_else(PoisonError::into_inner);
        let dir = builder.tempdir_in(parent)?;
        registry.push(dir.path().to_path_buf());
        let guard = Self(dir.path().to_path_buf());
        Ok((dir, guard))
    }
}

impl Drop for RemoveOnInterrupt {
    fn drop(&mut self) {
        TEMPORARY
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .retain(|d| d != &self.0);
    }
}
