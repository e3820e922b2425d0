//! The serial line to the controller: the port opened at 115200 8N1, whole lines in (a
//! partial line that stops arriving counts as one), bytes out. An I/O failure means the
//! device went away.

use std::io::{self, Read, Write};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use serialport::SerialPort;

use crate::DeviceError;

/// Serial speed of GRBL 1.1.
pub const BAUD_RATE: u32 = 115_200;
/// Port read timeout: how often a blocked read checks its deadline.
pub const POLL_INTERVAL: Duration = Duration::from_millis(20);
/// How long a partial line may sit without more bytes before it counts as a
/// (truncated) line: GRBL sends a whole line within milliseconds.
pub const LINE_GRACE: Duration = Duration::from_millis(200);

/// An open serial line.
pub struct Link {
    path: PathBuf,
    port: Box<dyn SerialPort>,
    /// Received bytes not yet forming a full line, and when the last byte came.
    pending: Vec<u8>,
    last_rx: Instant,
}

impl Link {
    /// Open `path`; also returns a second handle on the port (for an emergency stop
    /// from another thread).
    pub fn open(path: &Path) -> Result<(Link, Box<dyn SerialPort>), DeviceError> {
        let port = serialport::new(path.to_string_lossy(), BAUD_RATE)
            .data_bits(serialport::DataBits::Eight)
            .parity(serialport::Parity::None)
            .stop_bits(serialport::StopBits::One)
            .flow_control(serialport::FlowControl::None)
            .timeout(POLL_INTERVAL)
            .open()
            .map_err(|e| match e.kind() {
                serialport::ErrorKind::NoDevice => {
                    DeviceError::NotFound(format!("no serial device at {}: {e}", path.display()))
                }
                _ => disconnected(path, e),
            })?;
        let clone = port.try_clone().map_err(|e| disconnected(path, e))?;
        let link = Link {
            path: path.to_owned(),
            port,
            pending: Vec::new(),
            last_rx: Instant::now(),
        };
        Ok((link, clone))
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Send `bytes` at once.
    pub fn write(&mut self, bytes: &[u8]) -> Result<(), DeviceError> {
        self.port
            .write_all(bytes)
            .and_then(|()| self.port.flush())
            .map_err(|e| disconnected(&self.path, e))
    }

    /// The next complete line (trimmed, never empty), or `None` once `deadline` passes.
    pub fn read_line(&mut self, deadline: Instant) -> Result<Option<String>, DeviceError> {
        loop {
            if let Some(end) = self.pending.iter().position(|&b| b == b'\n') {
                let raw: Vec<u8> = self.pending.drain(..=end).collect();
                let line = String::from_utf8_lossy(&raw).trim().to_owned();
                if line.is_empty() {
                    continue;
                }
                return Ok(Some(line));
            }
            if !self.pending.is_empty() && self.last_rx.elapsed() >= LINE_GRACE {
                let line = String::from_utf8_lossy(&self.pending).trim().to_owned();
                self.pending.clear();
                if !line.is_empty() {
                    return Ok(Some(line));
                }
            }
            if Instant::now() >= deadline {
                return Ok(None);
            }
            let mut buf = [0u8; 256];
            match self.port.read(&mut buf) {
                Ok(0) => {
                    let eof = io::Error::new(io::ErrorKind::UnexpectedEof, "port closed");
                    return Err(disconnected(&self.path, eof));
                }
                Ok(n) => {
                    self.pending.extend_from_slice(&buf[..n]);
                    self.last_rx = Instant::now();
                }
                Err(e)
                    if matches!(
                        e.kind(),
                        io::ErrorKind::TimedOut | io::ErrorKind::Interrupted
                    ) => {}
                Err(e) => return Err(disconnected(&self.path, e)),
            }
        }
    }
}

fn disconnected(path: &Path, why: impl std::fmt::Display) -> DeviceError {
    DeviceError::Disconnected(format!("{}: {why}", path.display()))
}
