//! A camera run in a supervised child process.
//!
//! A call stuck inside a camera library cannot be cancelled from the calling process,
//! so the camera lives in a worker process (`gonio-camera-worker`, built with the
//! `gphoto2` feature) that [`SupervisedCamera`] talks to over line-delimited JSON on
//! stdin/stdout. Every call has a deadline; on expiry the worker is killed, the call
//! fails with [`DeviceError::Timeout`], and the next call starts a fresh worker (and
//! re-applies the last exposure), so one hung capture costs one frame, not the scan.
//! A worker whose camera reports a lost connection (I/O error, disconnected, not
//! found) is restarted the same way: the fresh worker looks for the camera again, so
//! an unplugged camera comes back once it is plugged in.
//!
//! Protocol: the worker first writes one [`WorkerReply`] (`ready` with the camera's
//! [`CameraInfo`], or `error`), then answers each [`WorkerRequest`] line with one reply
//! line.

use std::io::{self, BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, Command, Stdio};
use std::sync::mpsc::{self, Receiver, RecvTimeoutError};
use std::thread;
use std::time::Duration;

use serde::{Deserialize, Serialize};

use crate::{Camera, CameraInfo, Capture, DeviceError, Exposure};

/// One request line to the worker.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "op", rename_all = "snake_case")]
pub enum WorkerRequest {
    Identify,
    ShutterSpeeds,
    SetExposure { exposure: Exposure },
    CaptureTo { path: PathBuf },
}

/// One reply line from the worker.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum WorkerReply {
    /// The camera is open (the first line a worker writes).
    Ready(CameraInfo),
    Info(CameraInfo),
    ShutterSpeeds(Vec<f64>),
    Exposure(Exposure),
    Capture(Capture),
    Error(WireError),
}

/// A [`DeviceError`] as it crosses the process boundary.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum WireError {
    Io {
        message: String,
    },
    Timeout {
        what: String,
        seconds: f64,
    },
    Rejected {
        code: u32,
        meaning: String,
    },
    Alarm {
        code: u32,
        meaning: String,
    },
    Reset,
    Disconnected {
        message: String,
    },
    OutOfRange {
        what: String,
        value: f64,
        min: f64,
        max: f64,
    },
    Busy,
    NotFound {
        message: String,
    },
    Protocol {
        message: String,
    },
}

impl From<&DeviceError> for WireError {
    fn from(error: &DeviceError) -> Self {
        match error {
            DeviceError::Io(e) => WireError::Io {
                message: e.to_string(),
            },
            DeviceError::Timeout { what, seconds } => WireError::Timeout {
                what: what.clone(),
                seconds: *seconds,
            },
            DeviceError::Rejected { code, meaning } => WireError::Rejected {
                code: *code,
                meaning: meaning.clone(),
            },
            DeviceError::Alarm { code, meaning } => WireError::Alarm {
                code: *code,
                meaning: meaning.clone(),
            },
            DeviceError::Reset => WireError::Reset,
            DeviceError::Disconnected(message) => WireError::Disconnected {
                message: message.clone(),
            },
            DeviceError::OutOfRange {
                what,
                value,
                min,
                max,
            } => WireError::OutOfRange {
                what: what.clone(),
                value: *value,
                min: *min,
                max: *max,
            },
            DeviceError::Busy => WireError::Busy,
            DeviceError::NotFound(message) => WireError::NotFound {
                message: message.clone(),
            },
            DeviceError::Protocol(message) => WireError::Protocol {
                message: message.clone(),
            },
            // Arm faults never come from a camera; should one, its message travels.
            DeviceError::PositionUnknown(_)
            | DeviceError::HomingFailed { .. }
            | DeviceError::Refused(_)
            | DeviceError::SettingsDiffer(_) => WireError::Protocol {
                message: error.to_string(),
            },
        }
    }
}

impl From<WireError> for DeviceError {
    fn from(error: WireError) -> Self {
        match error {
            WireError::Io { message } => DeviceError::Io(io::Error::other(message)),
            WireError::Timeout { what, seconds } => DeviceError::Timeout { what, seconds },
            WireError::Rejected { code, meaning } => DeviceError::Rejected { code, meaning },
            WireError::Alarm { code, meaning } => DeviceError::Alarm { code, meaning },
            WireError::Reset => DeviceError::Reset,
            WireError::Disconnected { message } => DeviceError::Disconnected(message),
            WireError::OutOfRange {
                what,
                value,
                min,
                max,
            } => DeviceError::OutOfRange {
                what,
                value,
                min,
                max,
            },
            WireError::Busy => DeviceError::Busy,
            WireError::NotFound { message } => DeviceError::NotFound(message),
            WireError::Protocol { message } => DeviceError::Protocol(message),
        }
    }
}

fn write_reply(output: &mut impl Write, reply: &WorkerReply) -> io::Result<()> {
    let line = serde_json::to_string(reply).map_err(io::Error::other)?;
    writeln!(output, "{line}")?;
    output.flush()
}

/// The worker side: open the camera, announce it, then answer requests until `input`
/// ends. A request line that does not parse gets an `error` reply.
pub fn serve_worker<C: Camera>(
    open: impl FnOnce() -> Result<C, DeviceError>,
    input: impl BufRead,
    mut output: impl Write,
) -> io::Result<()> {
    let mut camera = match open().and_then(|mut c| c.identify().map(|info| (c, info))) {
        Ok((camera, info)) => {
            write_reply(&mut output, &WorkerReply::Ready(info))?;
            camera
        }
        Err(e) => return write_reply(&mut output, &WorkerReply::Error((&e).into())),
    };
    for line in input.lines() {
        let line = line?;
        if line.trim().is_empty() {
            continue;
        }
        let reply = match serde_json::from_str::<WorkerRequest>(&line) {
            Err(e) => Err(DeviceError::Protocol(format!("bad request {line:?}: {e}"))),
            Ok(WorkerRequest::Identify) => camera.identify().map(WorkerReply::Info),
            Ok(WorkerRequest::ShutterSpeeds) => {
                camera.shutter_speeds().map(WorkerReply::ShutterSpeeds)
            }
            Ok(WorkerRequest::SetExposure { exposure }) => {
                camera.set_exposure(exposure).map(WorkerReply::Exposure)
            }
            Ok(WorkerRequest::CaptureTo { path }) => {
                camera.capture_to(&path).map(WorkerReply::Capture)
            }
        };
        let reply = reply.unwrap_or_else(|e| WorkerReply::Error((&e).into()));
        write_reply(&mut output, &reply)?;
    }
    Ok(())
}

/// How to start the worker process. It inherits the environment plus `env`.
#[derive(Debug, Clone, PartialEq)]
pub struct WorkerSpec {
    pub program: PathBuf,
    pub args: Vec<String>,
    pub env: Vec<(String, String)>,
}

impl WorkerSpec {
    /// `gonio-camera-worker` next to the running executable, with `args`.
    pub fn beside_current_exe(args: Vec<String>) -> io::Result<WorkerSpec> {
        let exe = std::env::current_exe()?;
        let dir = exe
            .parent()
            .ok_or_else(|| io::Error::other("current executable has no directory"))?;
        Ok(WorkerSpec {
            program: dir.join("gonio-camera-worker"),
            args,
            env: Vec::new(),
        })
    }
}

/// Deadlines of the supervised calls.
#[derive(Debug, Clone, PartialEq)]
pub struct SupervisorConfig {
    /// From spawning the worker to its `ready` line (camera detection and set-up).
    pub start_timeout: Duration,
    /// Identify, list shutter speeds, set exposure.
    pub call_timeout: Duration,
    /// A capture and its download, on top of the shutter time.
    pub capture_timeout: Duration,
}

impl Default for SupervisorConfig {
    fn default() -> Self {
        Self {
            start_timeout: Duration::from_secs(20),
            call_timeout: Duration::from_secs(15),
            capture_timeout: Duration::from_secs(30),
        }
    }
}

struct Worker {
    child: Child,
    stdin: ChildStdin,
    lines: Receiver<io::Result<String>>,
}

impl Worker {
    fn kill(mut self) {
        // Already gone is fine; either way reap it.
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// A [`Camera`] whose every call runs in a worker process under a deadline.
pub struct SupervisedCamera {
    spec: WorkerSpec,
    config: SupervisorConfig,
    worker: Option<Worker>,
    /// The last exposure set, re-applied after a restart.
    exposure: Option<Exposure>,
    /// Workers started so far.
    spawns: u32,
}

impl SupervisedCamera {
    /// Start the worker and wait for its camera to be ready.
    pub fn start(
        spec: WorkerSpec,
        config: SupervisorConfig,
    ) -> Result<SupervisedCamera, DeviceError> {
        let mut camera = Self::new(spec, config);
        camera.spawn()?;
        Ok(camera)
    }

    /// A camera whose worker starts with the first call (so that a camera absent now
    /// is found once it is plugged in).
    pub fn new(spec: WorkerSpec, config: SupervisorConfig) -> SupervisedCamera {
        SupervisedCamera {
            spec,
            config,
            worker: None,
            exposure: None,
            spawns: 0,
        }
    }

    /// How many times the worker was restarted after a timeout, a crash or a lost
    /// camera.
    pub fn restarts(&self) -> u32 {
        self.spawns.saturating_sub(1)
    }

    fn spawn(&mut self) -> Result<CameraInfo, DeviceError> {
        let program = self.spec.program.display().to_string();
        let mut child = Command::new(&self.spec.program)
            .args(&self.spec.args)
            .envs(self.spec.env.iter().map(|(k, v)| (k, v)))
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .map_err(|e| match e.kind() {
                io::ErrorKind::NotFound => {
                    DeviceError::NotFound(format!("camera worker {program}: {e}"))
                }
                _ => DeviceError::Io(e),
            })?;
        let (Some(stdin), Some(stdout)) = (child.stdin.take(), child.stdout.take()) else {
            let _ = child.kill();
            let _ = child.wait();
            return Err(DeviceError::Protocol("camera worker without pipes".into()));
        };
        let (sender, lines) = mpsc::channel();
        thread::spawn(move || {
            for line in BufReader::new(stdout).lines() {
                let end = line.is_err();
                if sender.send(line).is_err() || end {
                    break;
                }
            }
        });
        self.worker = Some(Worker {
            child,
            stdin,
            lines,
        });
        match self.receive(self.config.start_timeout, "camera worker start")? {
            WorkerReply::Ready(info) => {
                self.spawns += 1;
                Ok(info)
            }
            WorkerReply::Error(e) => {
                self.discard();
                Err(e.into())
            }
            other => {
                self.discard();
                Err(DeviceError::Protocol(format!(
                    "camera worker started with {other:?}"
                )))
            }
        }
    }

    fn discard(&mut self) {
        if let Some(worker) = self.worker.take() {
            worker.kill();
        }
    }

    /// Wait for one reply; on a deadline, a dead worker or garbage, kill the worker.
    fn receive(&mut self, timeout: Duration, what: &str) -> Result<WorkerReply, DeviceError> {
        let Some(worker) = self.worker.as_mut() else {
            return Err(DeviceError::Disconnected(
                "camera worker not running".into(),
            ));
        };
        let received = worker.lines.recv_timeout(timeout);
        let error = match received {
            Ok(Ok(line)) => match serde_json::from_str::<WorkerReply>(&line) {
                Ok(reply) => return Ok(reply),
                Err(e) => DeviceError::Protocol(format!("camera worker said {line:?}: {e}")),
            },
            Err(RecvTimeoutError::Timeout) => DeviceError::Timeout {
                what: what.to_owned(),
                seconds: timeout.as_secs_f64(),
            },
            Ok(Err(e)) => DeviceError::Disconnected(format!("camera worker output: {e}")),
            Err(RecvTimeoutError::Disconnected) => {
                let status = match worker.child.try_wait() {
                    Ok(Some(status)) => status.to_string(),
                    _ => "output closed".to_owned(),
                };
                DeviceError::Disconnected(format!("camera worker exited ({status})"))
            }
        };
        self.discard();
        Err(error)
    }

    fn call(
        &mut self,
        request: &WorkerRequest,
        timeout: Duration,
    ) -> Result<WorkerReply, DeviceError> {
        if self.worker.is_none() {
            self.spawn()?;
            if let Some(exposure) = self.exposure {
                self.exchange(
                    &WorkerRequest::SetExposure { exposure },
                    self.config.call_timeout,
                )?;
            }
        }
        self.exchange(request, timeout)
    }

    fn exchange(
        &mut self,
        request: &WorkerRequest,
        timeout: Duration,
    ) -> Result<WorkerReply, DeviceError> {
        let line =
            serde_json::to_string(request).map_err(|e| DeviceError::Protocol(e.to_string()))?;
        let worker = self
            .worker
            .as_mut()
            .ok_or_else(|| DeviceError::Disconnected("camera worker not running".into()))?;
        if let Err(e) = writeln!(worker.stdin, "{line}").and_then(|()| worker.stdin.flush()) {
            self.discard();
            return Err(DeviceError::Disconnected(format!(
                "camera worker input: {e}"
            )));
        }
        match self.receive(timeout, &format!("camera worker reply to {line}"))? {
            WorkerReply::Error(e) => {
                let error = DeviceError::from(e);
                if matches!(
                    error,
                    DeviceError::Io(_) | DeviceError::Disconnected(_) | DeviceError::NotFound(_)
                ) {
                    // The worker's camera connection is gone: the next call starts a
                    // worker that looks for the camera again.
                    self.discard();
                }
                Err(error)
            }
            reply => Ok(reply),
        }
    }
}

impl Drop for SupervisedCamera {
    fn drop(&mut self) {
        self.discard();
    }
}

fn unexpected(reply: WorkerReply) -> DeviceError {
    DeviceError::Protocol(format!("unexpected camera worker reply {reply:?}"))
}

impl Camera for SupervisedCamera {
    fn identify(&mut self) -> Result<CameraInfo, DeviceError> {
        match self.call(&WorkerRequest::Identify, self.config.call_timeout)? {
            WorkerReply::Info(info) => Ok(info),
            other => Err(unexpected(other)),
        }
    }

    fn shutter_speeds(&mut self) -> Result<Vec<f64>, DeviceError> {
        match self.call(&WorkerRequest::ShutterSpeeds, self.config.call_timeout)? {
            WorkerReply::ShutterSpeeds(speeds) => Ok(speeds),
            other => Err(unexpected(other)),
        }
    }

    fn set_exposure(&mut self, exposure: Exposure) -> Result<Exposure, DeviceError> {
        match self.call(
            &WorkerRequest::SetExposure { exposure },
            self.config.call_timeout,
        )? {
            WorkerReply::Exposure(actual) => {
                self.exposure = Some(actual);
                Ok(actual)
            }
            other => Err(unexpected(other)),
        }
    }

    fn capture_to(&mut self, path: &Path) -> Result<Capture, DeviceError> {
        let shutter = self.exposure.map_or(0.0, |e| e.shutter_s);
        let timeout =
            self.config.capture_timeout + Duration::try_from_secs_f64(shutter).unwrap_or_default();
        let request = WorkerRequest::CaptureTo {
            path: path.to_owned(),
        };
        match self.call(&request, timeout)? {
            WorkerReply::Capture(capture) => Ok(capture),
            other => Err(unexpected(other)),
        }
    }
}

#[cfg(test)]
mod tests;
