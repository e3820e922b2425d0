//! `[notify]`: a command the daemon runs to call a person (server/src/daemon.md,
//! "Notifications"), e.g. to send mail when a scan starts waiting for its sample.
//!
//! Commands run one at a time on a thread of their own, never on a lane: a notice is
//! handed over without waiting, and dropped (logged) when [`QUEUE`] notices are
//! already pending. Each command runs under `sh -c` in its own process group with the
//! notice in its environment, and is killed with its group after `timeout_s`. A
//! command that fails, or is killed, is logged with its exit status and the start of
//! its standard error, and not retried.

use std::io::Read;
use std::os::unix::process::CommandExt;
use std::process::{Command, Stdio};
use std::sync::mpsc::{self, SyncSender, TrySendError};
use std::time::{Duration, Instant};

use serde::Deserialize;

/// The notification command.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NotifyConfig {
    /// Run with `sh -c`; the notice is in its environment (`GONIO_EVENT`,
    /// `GONIO_SCAN_ID`, `GONIO_SWEEP_ID`, `GONIO_SAMPLE`, `GONIO_STATE`,
    /// `GONIO_REASON`).
    pub command: String,
    /// Seconds the command may run before it is killed (with its process group).
    #[serde(default = "default_timeout_s")]
    pub timeout_s: f64,
}

fn default_timeout_s() -> f64 {
    30.0
}

impl NotifyConfig {
    /// Errors naming the key whose value is out of range.
    pub fn check(&self) -> anyhow::Result<()> {
        anyhow::ensure!(
            !self.command.trim().is_empty(),
            "notify.command is empty (leave [notify] out to run none)"
        );
        anyhow::ensure!(
            self.timeout_s.is_finite() && self.timeout_s > 0.0 && self.timeout_s <= 600.0,
            "notify.timeout_s must be a positive number of seconds (at most 600), got {}",
            self.timeout_s
        );
        Ok(())
    }
}

/// Notices pending at most; more are dropped (and logged), never queued without bound.
pub const QUEUE: usize = 32;

/// Most bytes of the command's standard error kept for the log.
const STDERR_KEPT: u64 = 2048;

/// What calls for a person.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Notice {
    /// `scan-waiting` (for the operator: its sample to be mounted), `scan-failed` or
    /// `sweep-ended`.
    pub event: &'static str,
    pub scan_id: i64,
    pub sweep_id: Option<i64>,
    pub sample: String,
    /// The scan's state; for `sweep-ended`, the sweep's (`done` or `finished`).
    pub state: String,
    /// Why: the scan's reason or error; for `sweep-ended`, its scans counted by state.
    pub reason: String,
}

/// Hands notices to the notification thread; does nothing without `[notify]`.
pub struct Notifier {
    queue: Option<SyncSender<Notice>>,
}

impl Notifier {
    /// Starts the notification thread for `config`, if any.
    pub fn start(config: Option<NotifyConfig>) -> std::io::Result<Self> {
        let Some(config) = config else {
            return Ok(Self { queue: None });
        };
        let (queue, notices) = mpsc::sync_channel::<Notice>(QUEUE);
        std::thread::Builder::new()
            .name("notify".into())
            .spawn(move || {
                for notice in notices {
                    match run(&config, &notice) {
                        Ok(()) => tracing::info!(
                            "notify: {} of scan {} sent",
                            notice.event,
                            notice.scan_id
                        ),
                        Err(why) => tracing::warn!(
                            "notify: the command for {} of scan {} failed (not retried): {why}",
                            notice.event,
                            notice.scan_id
                        ),
                    }
                }
            })?;
        Ok(Self { queue: Some(queue) })
    }

    /// Hands `notice` over without waiting.
    pub fn send(&self, notice: Notice) {
        let Some(queue) = &self.queue else {
            return;
        };
        match queue.try_send(notice) {
            Ok(()) => {}
            Err(TrySendError::Full(notice)) => tracing::warn!(
                "notify: {QUEUE} notices pending, {} of scan {} dropped",
                notice.event,
                notice.scan_id
            ),
            Err(TrySendError::Disconnected(notice)) => tracing::warn!(
                "notify: the notification thread ended, {} of scan {} dropped",
                notice.event,
                notice.scan_id
            ),
        }
    }
}

/// The daemon's token may come from this variable (`gonio serve`'s environment); a
/// notification command has no need of it.
const TOKEN_VARIABLE: &str = "GONIO_TOKEN";

/// The command for `notice`: `sh -c`, the notice in its environment, in a process
/// group of its own.
fn command(config: &NotifyConfig, notice: &Notice) -> Command {
    let mut command = Command::new("sh");
    command
        .arg("-c")
        .arg(&config.command)
        .env("GONIO_EVENT", notice.event)
        .env("GONIO_SCAN_ID", notice.scan_id.to_string())
        .env(
            "GONIO_SWEEP_ID",
            notice.sweep_id.map(|id| id.to_string()).unwrap_or_default(),
        )
        .env("GONIO_SAMPLE", &notice.sample)
        .env("GONIO_STATE", &notice.state)
        .env("GONIO_REASON", &notice.reason)
        // The rest of the daemon's environment, but not its bearer token.
        .env_remove(TOKEN_VARIABLE)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .process_group(0);
    command
}

/// Runs the command for `notice`, killed with its process group after the timeout.
fn run(config: &NotifyConfig, notice: &Notice) -> Result<(), String> {
    let mut child = command(config, notice)
        .spawn()
        .map_err(|e| format!("cannot start sh: {e}"))?;
    // The standard error is read beside the wait, so that a talkative command never
    // blocks on a full pipe; what is past the first bytes is read and dropped.
    // A process the command left behind may hold the pipe open: its text is awaited
    // only briefly once the command has ended.
    let (said_tx, said_rx) = mpsc::channel();
    if let Some(mut pipe) = child.stderr.take() {
        std::thread::spawn(move || {
            let mut kept = Vec::new();
            let _ = (&mut pipe).take(STDERR_KEPT).read_to_end(&mut kept);
            let _ = said_tx.send(String::from_utf8_lossy(&kept).trim().to_owned());
            let _ = std::io::copy(&mut pipe, &mut std::io::sink());
        });
    }
    let deadline = Instant::now() + Duration::from_secs_f64(config.timeout_s);
    let status = loop {
        match child.try_wait() {
            Ok(Some(status)) => break Some(status),
            Ok(None) if Instant::now() < deadline => std::thread::sleep(Duration::from_millis(50)),
            Ok(None) => break None,
            Err(e) => return Err(format!("waiting for the command: {e}")),
        }
    };
    let Some(status) = status else {
        // SAFETY: kill only sends a signal, to the process group the command leads.
        unsafe {
            libc::kill(-(child.id() as i32), libc::SIGKILL);
        }
        let _ = child.wait();
        return Err(format!(
            "still running after {} s, killed with its process group",
            config.timeout_s
        ));
    };
    if status.success() {
        return Ok(());
    }
    let said = said_rx
        .recv_timeout(Duration::from_millis(500))
        .unwrap_or_default();
    Err(if said.is_empty() {
        format!("{status}")
    } else {
        format!("{status}: {said}")
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn notice() -> Notice {
        Notice {
            event: "scan-failed",
            scan_id: 7,
            sweep_id: None,
            sample: "gold".into(),
            state: "failed".into(),
            reason: "camera: it's \"gone\"; $HOME".into(),
        }
    }

    fn config(command: String, timeout_s: f64) -> NotifyConfig {
        NotifyConfig { command, timeout_s }
    }

    #[test]
    fn the_notice_reaches_the_command_s_environment_as_it_is() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("env");
        // The notice's variables (the test's own environment may hold other GONIO_ ones).
        let command = format!(
            "env | grep -E '^GONIO_(EVENT|REASON|SAMPLE|SCAN_ID|STATE|SWEEP_ID)=' | sort > '{}'",
            out.display()
        );
        run(&config(command, 5.0), &notice()).unwrap();
        let env = std::fs::read_to_string(out).unwrap();
        assert_eq!(
            env,
            "GONIO_EVENT=scan-failed\nGONIO_REASON=camera: it's \"gone\"; $HOME\n\
             GONIO_SAMPLE=gold\nGONIO_SCAN_ID=7\nGONIO_STATE=failed\nGONIO_SWEEP_ID=\n"
        );
    }

    #[test]
    fn the_daemon_s_token_is_not_passed_on() {
        let command = command(&config("true".into(), 5.0), &notice());
        let token = command
            .get_envs()
            .find(|(name, _)| *name == std::ffi::OsStr::new(TOKEN_VARIABLE));
        assert_eq!(token, Some((std::ffi::OsStr::new(TOKEN_VARIABLE), None)));
    }

    #[test]
    fn a_failing_command_is_reported_with_its_status_and_standard_error() {
        let err = run(
            &config("echo no mail here >&2; exit 3".into(), 5.0),
            &notice(),
        )
        .unwrap_err();
        assert!(err.contains("3") && err.contains("no mail here"), "{err}");
    }

    #[test]
    fn a_command_that_hangs_is_killed_with_what_it_started() {
        let dir = tempfile::tempdir().unwrap();
        let pid_file = dir.path().join("pid");
        let command = format!("sleep 60 & echo $! > '{}'; wait", pid_file.display());
        let started = Instant::now();
        let err = run(&config(command, 0.5), &notice()).unwrap_err();
        assert!(err.contains("killed"), "{err}");
        assert!(started.elapsed() < Duration::from_secs(5), "{err}");
        let pid: i32 = std::fs::read_to_string(pid_file)
            .unwrap()
            .trim()
            .parse()
            .unwrap();
        // The command's own child is gone too (reaped once orphaned).
        let deadline = Instant::now() + Duration::from_secs(5);
        // SAFETY: signal 0 only asks whether the process exists.
        while unsafe { libc::kill(pid, 0) } == 0 {
            assert!(Instant::now() < deadline, "sleep {pid} outlived the kill");
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    #[test]
    fn bad_settings_are_named() {
        assert!(config(" ".into(), 5.0)
            .check()
            .unwrap_err()
            .to_string()
            .contains("notify.command"));
        for timeout in [0.0, -1.0, f64::NAN, 601.0] {
            let err = config("true".into(), timeout).check().unwrap_err();
            assert!(err.to_string().contains("notify.timeout_s"), "{err}");
        }
    }
}
